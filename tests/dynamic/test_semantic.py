"""Semantic prior and the keypoint table."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.detection.detections import Detections
from dynslam_lab.dynamic.semantic import SemanticConfig, level_codes, semantic_prior
from dynslam_lab.dynamic.table import KeypointTable, depth_at, pixel_index


def _dets():
    h, w = 100, 120
    masks = np.zeros((2, h, w), bool)
    masks[0, 10:60, 10:40] = True  # person (class 0)
    masks[1, 20:50, 70:110] = True  # chair (class 56)
    return Detections(np.array([[5, 5, 50, 70], [70, 20, 110, 50]]), np.array([0.9, 0.8]), np.array([0, 56]),
                      (h, w), masks=masks)


def test_masks_classes_and_prior_sets():
    uv = np.array([[20, 20], [45, 65], [80, 30], [5, 90]], float)  # in person mask, in person box only, chair, nothing
    r = semantic_prior(uv, _dets(), SemanticConfig())
    assert r.instance.tolist() == [0, -1, 1, -1]
    assert r.class_id.tolist() == [0, -1, 56, -1]
    assert r.flagged.tolist() == [True, False, False, False]  # chair is not a-priori dynamic (Chang et al. 2021)
    assert r.motion_prob[0] > r.motion_prob[2] > 0 and r.motion_prob[3] == 0
    boxes = semantic_prior(uv, _dets(), SemanticConfig(use_masks=False))
    assert boxes.flagged.tolist() == [True, True, False, False]
    levels = semantic_prior(uv, _dets(), SemanticConfig(prior="levels"))
    assert levels.flagged[0] and levels.level[0] == 3
    assert levels.flagged[2] == (level_codes(np.array([56]))[0] >= 2)  # chair's level from detection.coco
    low = semantic_prior(uv, _dets(), SemanticConfig(min_score=0.85))
    assert low.instance.tolist() == [0, -1, -1, -1]


def test_no_detections():
    r = semantic_prior(np.zeros((3, 2)), None)
    assert not r.flagged.any() and (r.instance == -1).all()
    with pytest.raises(ValueError, match="prior"):
        SemanticConfig(prior="all")


def test_table_dataframe_and_validation():
    uv = np.array([[1.0, 2.0], [3.4, 4.6], [700, 5]])
    depth = np.zeros((10, 10), np.float32)
    depth[2, 1] = 1.5
    depth[5, 3] = 2.5
    z = depth_at(depth, uv)
    assert z[0] == 1.5 and z[1] == 2.5 and np.isnan(z[2])
    rows, cols, inside = pixel_index(uv, (10, 10))
    assert inside.tolist() == [True, True, False]
    t = KeypointTable.blank(uv, z)
    t.stages["semantic"] = np.array([True, False, False])
    df = t.to_dataframe()
    assert list(df.columns[:3]) == ["u", "v", "depth_m"] and "semantic" in df and len(df) == 3
    with pytest.raises(ValueError, match="rows"):
        KeypointTable(uv=uv, depth=z[:2], class_id=np.zeros(3), instance=np.zeros(3), motion_prob=np.zeros(3),
                      dynamic=np.zeros(3, bool), reason=np.full(3, ""))
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        KeypointTable.blank(np.zeros((3, 3)))


def test_mask_owner_is_the_best_scoring_mask_of_many():
    """Many overlapping masks (an oracle gives ~70 a frame): each keypoint's instance is the highest-scoring
    mask containing its pixel, as Detections.instance_at (an independent lookup) finds it."""
    rng = np.random.default_rng(3)
    h, w, d = 60, 80, 40
    masks = np.zeros((d, h, w), bool)
    boxes = np.zeros((d, 4))
    for k in range(d):
        x0, y0 = rng.integers(0, w - 10), rng.integers(0, h - 10)
        x1, y1 = x0 + rng.integers(5, 30), y0 + rng.integers(5, 30)
        masks[k, y0:y1, x0:x1] = rng.random((min(y1, h) - y0, min(x1, w) - x0)) < 0.7
        boxes[k] = (x0, y0, x1, y1)
    dets = Detections(boxes, rng.random(d), np.zeros(d, np.int64), (h, w), masks=masks)
    uv = rng.uniform(0, [w - 1, h - 1], (500, 2))
    r = semantic_prior(uv, dets, SemanticConfig())
    assert (r.instance >= 0).sum() > 100
    np.testing.assert_array_equal(r.instance, dets.instance_at(uv))
