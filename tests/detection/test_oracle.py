"""The oracle detector on hand-built synthetic frames (and the renderer's, once it lands)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.datasets.frame import Frame
from dynslam_lab.detection import DetectionConfig, OracleConfig, OracleDetector, build_detector
from dynslam_lab.detection.oracle import instances_to_detections

H, W = 120, 160


def _frame(index=0):
    mask = np.zeros((H, W), np.int32)
    mask[20:100, 30:60] = 1  # person: x 30..59, y 20..99
    mask[70:110, 100:150] = 2  # chair
    mask[0:3, 0:3] = 3  # 9 px speck, below min_area
    rgb = np.zeros((H, W, 3), np.uint8)
    return Frame(index, 0.1 * index, rgb, np.ones((H, W), np.float32), CAMERA_PRESETS["tum_fr3"],
                 instance_mask=mask, instance_classes={1: "person", 2: "chair", 3: "cup"})


def _oracle(**oracle):
    return OracleDetector(DetectionConfig(oracle=OracleConfig(**oracle)))


def test_perfect_oracle_gives_tight_boxes_and_exact_masks():
    f = _frame()
    d = build_detector("oracle").detect(f)
    np.testing.assert_array_equal(d.class_ids, [0, 56])  # the 9 px cup is below min_area 20
    np.testing.assert_array_equal(d.boxes, [[30, 20, 60, 100], [100, 70, 150, 110]])
    np.testing.assert_array_equal(d.scores, [1, 1])
    np.testing.assert_array_equal(d.masks[0], f.instance_mask == 1)
    np.testing.assert_array_equal(d.masks[1], f.instance_mask == 2)
    assert d.source == "oracle"
    small = instances_to_detections(f.instance_mask, f.instance_classes, min_area=1)
    assert small.names == ["person", "chair", "cup"]
    # a non-COCO class and an id absent from the image are skipped
    odd = instances_to_detections(f.instance_mask, {1: "wall", 2: "chair", 9: "person"})
    assert odd.names == ["chair"]
    np.testing.assert_array_equal(odd.boxes, [[100, 70, 150, 110]])


def test_misses_are_seeded_per_frame_and_at_the_configured_rate():
    assert len(_oracle(miss_rate=1.0).detect(_frame())) == 0
    det = _oracle(miss_rate=0.3, seed=4)
    kept = np.array([len(det.detect(_frame(i))) for i in range(400)])
    assert kept.sum() / 800 == pytest.approx(0.7, abs=0.05)
    # same frame index, same answer, whatever the order
    again = np.array([len(det.detect(_frame(i))) for i in reversed(range(400))])[::-1]
    np.testing.assert_array_equal(kept, again)
    other_seed = np.array([len(_oracle(miss_rate=0.3, seed=5).detect(_frame(i))) for i in range(400)])
    assert not np.array_equal(kept, other_seed)


def test_jitter_moves_box_corners_by_the_configured_fraction():
    det = _oracle(jitter=0.05, seed=1)
    dx = np.array([det.detect(_frame(i)).boxes[0] - [30, 20, 60, 100] for i in range(300)])
    # person box is 30 x 80 px: corner std 1.5 px in x, 4 px in y
    np.testing.assert_allclose(dx.std(axis=0), [1.5, 4.0, 1.5, 4.0], rtol=0.15)
    assert abs(dx.mean()) < 0.5
    d = det.detect(_frame(3))
    shift = np.round((d.boxes[0, :2] + d.boxes[0, 2:] - [90, 120]) / 2).astype(int)
    ys, xs = np.nonzero(d.masks[0])
    assert (xs.min(), ys.min()) == (30 + shift[0], 20 + shift[1])  # mask moved with the box centre


def test_false_positives_follow_the_poisson_mean():
    det = _oracle(false_positives=1.5, seed=2)
    counts = []
    for i in range(300):
        d = det.detect(_frame(i))
        fp = d.select(d.scores < 1.0)
        counts.append(len(fp))
        assert np.all(fp.class_ids == 0) and np.all(fp.scores >= 0.3)
        assert fp.masks is not None and np.array_equal(fp.masks, fp.region_masks())
    assert np.mean(counts) == pytest.approx(1.5, abs=0.2)


def test_class_filter_and_missing_mask_error():
    d = OracleDetector(dataclasses.replace(DetectionConfig(), classes=("chair",))).detect(_frame())
    assert d.names == ["chair"]
    f = _frame()
    f.instance_mask = None
    with pytest.raises(ValueError, match="needs a synthetic frame with an instance mask"):
        OracleDetector().detect(f)


def test_oracle_on_the_synthetic_renderer():
    from dynslam_lab.datasets import synthetic
    from dynslam_lab.datasets import TumSequence

    seq = TumSequence(synthetic.synthetic_sequence("walking_xyz", n_frames=3, seed=0))
    f = seq[0]
    d = OracleDetector().detect(f)
    assert len(d) >= 1
    union = d.masks.any(axis=0)
    truth = f.instance_mask > 0
    assert not np.any(union & ~truth)  # nothing outside the true instances
    assert union.sum() >= 0.99 * truth.sum()  # everything but specks below min_area
    for k in range(len(d)):  # each mask is exactly one instance, with its class
        ids = np.unique(f.instance_mask[d.masks[k]])
        assert len(ids) == 1 and f.instance_classes[int(ids[0])] == d.names[k]


def test_perfect_masks_take_the_keypoints_within_the_margin_of_a_moving_outline():
    """``--filters oracle``: a keypoint within ``oracle_margin_px`` of a moving instance is dynamic (its FAST
    circle reaches the mover), one farther is not, a still instance's outline changes nothing; the truth the
    scores use stays the pixel's."""
    from dynslam_lab.dynamic.config import ScreeningConfig
    from dynslam_lab.dynamic.oracle import OracleScreener, truth_dynamic

    f = dataclasses.replace(_frame(), moving_ids={1})  # the person (x 30..59, y 20..99) moves, the chair does not
    uv = np.array([[45.0, 50.0],  # inside the person
                   [62.0, 50.0],  # 3 px right of its last column (59)
                   [64.0, 50.0],  # 5 px right
                   [45.0, 103.0],  # 4 px below its last row (99)
                   [98.0, 80.0]])  # 2 px left of the still chair
    truth = truth_dynamic(f, uv)
    np.testing.assert_array_equal(truth, [True, False, False, False, False])
    exact = OracleScreener(ScreeningConfig(oracle_margin_px=0))
    np.testing.assert_array_equal(exact.screen(f, uv).dynamic, truth)
    np.testing.assert_array_equal(exact.known_region(f), f.instance_mask == 1)
    grown = OracleScreener(ScreeningConfig(oracle_margin_px=4))
    np.testing.assert_array_equal(grown.screen(f, uv).dynamic, [True, True, False, True, False])
    region = grown.known_region(f)
    # by hand: a pixel's distance to the person's rectangle of pixels (x 30..59, y 20..99)
    y, x = np.mgrid[0:H, 0:W]
    dx, dy = np.maximum.reduce([30 - x, 0 * x, x - 59]), np.maximum.reduce([20 - y, 0 * y, y - 99])
    np.testing.assert_array_equal(region, np.hypot(dx, dy) <= 4)
    # the mask is made once per frame, never taken from another frame of the same index (another sequence)
    empty = dataclasses.replace(f, instance_mask=np.zeros_like(f.instance_mask))
    assert not grown.screen(empty, uv).dynamic.any() and not grown.known_region(empty).any()
    assert not grown.screen(dataclasses.replace(f, moving_ids=set()), uv).dynamic.any()
    with pytest.raises(ValueError, match="oracle_margin_px"):
        ScreeningConfig(oracle_margin_px=-1)

