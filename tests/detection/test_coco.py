"""COCO classes and the motion-prior tables of Zhang et al. 2023, Chang et al. 2021 and Ge et al. 2024."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dynslam_lab.config import with_overrides
from dynslam_lab.detection import DetectionConfig, Detections
from dynslam_lab.detection.coco import (
    APRIORI_DYNAMIC,
    ASG_CATEGORIES,
    ASG_PROBABILITIES,
    COCO_CLASSES,
    DYNAMIC_LEVELS,
    class_id,
    dynamic_level,
    is_apriori_dynamic,
    motion_probability,
)


def test_coco_classes_match_the_ultralytics_export_order():
    assert len(COCO_CLASSES) == 80 and len(set(COCO_CLASSES)) == 80
    # spot checks against the names embedded in ../shared yolov8n metadata (0: person ... 79)
    assert (COCO_CLASSES[0], COCO_CLASSES[56], COCO_CLASSES[62], COCO_CLASSES[79]) == (
        "person", "chair", "tv", "toothbrush")
    assert class_id("keyboard") == 66
    with pytest.raises(ValueError, match="unknown COCO class 'sofa'"):
        class_id("sofa")
    assert Detections(np.zeros((2, 4)), [1, 1], [0, 99], (4, 4)).names == ["person", "class99"]


def test_apriori_dynamic_set_is_chang_2021():
    # Chang et al. 2021 Sec. III-A lists 19 labels: people, vehicles and animals
    assert len(APRIORI_DYNAMIC) == 19 and set(APRIORI_DYNAMIC) <= set(COCO_CLASSES)
    flags = is_apriori_dynamic(np.array([0, 2, 15, 56, 62, -1, 200]))
    np.testing.assert_array_equal(flags, [True, True, True, False, False, False, False])


def test_asg_categories_partition_coco_in_increasing_motion():
    members = [c for group in ASG_CATEGORIES.values() for c in group]
    assert sorted(members) == sorted(COCO_CLASSES)  # every class exactly once
    assert list(ASG_CATEGORIES) == [
        "public_facility", "household_office", "vehicle", "personal_belonging", "human", "animal"]
    p = [ASG_PROBABILITIES[c] for c in ASG_CATEGORIES]
    assert p == sorted(p) and len(set(p)) == 6  # the paper's order, strictly increasing
    probs = motion_probability(np.array([0, 15, 56, 13, 999]))
    np.testing.assert_allclose(probs, [ASG_PROBABILITIES["human"], ASG_PROBABILITIES["animal"],
                                       ASG_PROBABILITIES["household_office"],
                                       ASG_PROBABILITIES["public_facility"], 0.0])


def test_dynamic_levels_partition_coco():
    members = [c for group in DYNAMIC_LEVELS.values() for c in group]
    assert sorted(members) == sorted(COCO_CLASSES)
    assert dynamic_level(np.array([0, 16, 2, 66])) == ["high", "high", "medium", "low"]


def test_priors_are_editable_in_the_config():
    cfg = with_overrides(DetectionConfig(), {
        "priors": {"asg_probabilities": {"human": 0.3}, "dynamic_level_of": {"person": "medium"},
                   "apriori_dynamic": ["person", "chair"]},
    })
    assert motion_probability(np.array([0]), cfg.priors)[0] == pytest.approx(0.3)
    assert motion_probability(np.array([15]), cfg.priors)[0] == ASG_PROBABILITIES["animal"]  # merged, not replaced
    assert dynamic_level(np.array([0]), cfg.priors) == ["medium"]
    np.testing.assert_array_equal(is_apriori_dynamic(np.array([0, 56, 2]), cfg.priors), [True, True, False])
    # the defaults are untouched
    assert DetectionConfig().priors.asg_probabilities["human"] == ASG_PROBABILITIES["human"]
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.priors.apriori_dynamic = ()


def test_detection_config_from_toml(tmp_path):
    from dynslam_lab.config import load_config

    p = tmp_path / "det.toml"
    p.write_text('score_threshold = 0.4\nnms = "soft"\nclasses = ["person"]\n'
                 "[oracle]\nmiss_rate = 0.2\n[priors.asg_probabilities]\nhuman = 0.8\n")
    cfg = load_config(p, DetectionConfig())
    assert (cfg.score_threshold, cfg.nms, cfg.classes, cfg.oracle.miss_rate) == (0.4, "soft", ("person",), 0.2)
    assert cfg.priors.asg_probabilities["human"] == 0.8 and cfg.priors.asg_probabilities["animal"] == 0.95
    p.write_text('nms = "fastest"\n')
    with pytest.raises(ValueError, match="detection.nms: 'fastest'"):
        load_config(p, DetectionConfig())
