"""``build_pipeline``: every stage is built from the one config, and ``summary.json`` records it."""

from __future__ import annotations

import dataclasses
import json

import pytest

from dynslam_lab.config import Config, config_to_dict, with_overrides
from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.datasets.tum import TumSequence
from dynslam_lab.pipeline import build_pipeline
from dynslam_lab.runs import run_sequence

#: a config where every stage section differs from its default
CUSTOM = with_overrides(Config(), {
    "orb": {"n_features": 900},
    "tracking": {"bf": 42.0, "min_local_inliers": 25},
    "local_mapping": {"ba_iterations": 7},
    "detection": {"score_threshold": 0.4},
    "screening": {"epipolar": {"threshold_px": 1.5}, "multiview": {"reprojection_px": 5.0}},
    "loop_closing": {"min_inliers": 25},
    "dense_map": {"voxel_size": 0.03},
})


def test_custom_config_differs_from_default_in_every_section():
    default = Config()
    for f in dataclasses.fields(Config):
        assert getattr(CUSTOM, f.name) != getattr(default, f.name), f.name


def test_every_stage_runs_with_the_pipeline_config():
    from dynslam_lab.camera import CAMERA_PRESETS

    camera = CAMERA_PRESETS["default"]
    system = build_pipeline(CUSTOM, camera, detector="oracle", filters="full")
    assert system.config is CUSTOM
    assert system.tracker.cfg is CUSTOM.tracking
    assert system.mapper.cfg is CUSTOM.local_mapping
    assert system.detector.config is CUSTOM.detection
    assert system.screener.config is CUSTOM.screening
    assert system.loop_closer.config is CUSTOM.loop_closing
    assert system.loop_closer.camera is camera and system.loop_closer.bf == 42.0
    assert system.effective_config() == CUSTOM
    assert system.description == {"detector": "oracle", "filters": "full", "loop_closing": True}


def test_summary_records_the_config_every_stage_used(tmp_path):
    seq = TumSequence(synthetic_sequence("walking_xyz", n_frames=30, seed=0), max_frames=6)
    system = build_pipeline(CUSTOM, seq.camera, detector="oracle", filters="full", loop_closing=False)
    run_sequence(seq, tmp_path / "run", system, progress=False)
    saved = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert saved["config"] == json.loads(json.dumps(config_to_dict(CUSTOM)))
    assert saved["pipeline"] == {"detector": "oracle", "filters": "full", "loop_closing": False}


def test_a_hand_built_stage_is_recorded_as_it_ran():
    from dynslam_lab.camera import CAMERA_PRESETS
    from dynslam_lab.dynamic.screening import build_screener
    from dynslam_lab.slam.system import System

    other = dataclasses.replace(Config().screening, geometry_mask_margin_px=3)
    system = System(CAMERA_PRESETS["default"], Config(), screener=build_screener("geometry", other))
    assert system.effective_config().screening is other


def test_filters_that_need_detections_are_refused_without_a_detector():
    from dynslam_lab.camera import CAMERA_PRESETS

    for filters in ("semantic", "depth_ransac", "full", "semantic,epipolar"):
        with pytest.raises(ValueError, match="--detector is 'none'"):
            build_pipeline(Config(), CAMERA_PRESETS["default"], detector="none", filters=filters)
    assert build_pipeline(Config(), CAMERA_PRESETS["default"], filters="geometry").screener is not None
