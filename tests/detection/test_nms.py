"""Hard and Gaussian soft-NMS against OpenCV's implementations and hand-computed cases."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dynslam_lab.detection.nms import box_iou, nms, soft_nms, suppress


def _random_boxes(rng, n, size=200):
    xy = rng.integers(0, size, (n, 2))
    wh = rng.integers(10, 80, (n, 2))
    return np.concatenate([xy, xy + wh], axis=1).astype(np.float64), rng.random(n)


def _xywh(b):
    return [[int(x1), int(y1), int(x2 - x1), int(y2 - y1)] for x1, y1, x2, y2 in b]


def test_box_iou_hand_cases():
    a = np.array([[0, 0, 10, 10], [0, 0, 0, 0]], float)
    b = np.array([[5, 0, 15, 10], [20, 20, 30, 30], [0, 0, 10, 10]], float)
    iou = box_iou(a, b)
    np.testing.assert_allclose(iou[0], [50 / 150, 0.0, 1.0])
    np.testing.assert_array_equal(iou[1], [0, 0, 0])  # empty box: 0, no division warning
    with pytest.raises(ValueError, match=r"expected shape \(N, 4\)"):
        box_iou(np.zeros((3, 5)), b)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("thr", [0.3, 0.5, 0.7])
def test_hard_nms_matches_opencv(seed, thr):
    rng = np.random.default_rng(seed)
    boxes, scores = _random_boxes(rng, 150)
    ours = nms(boxes, scores, thr)
    ref = np.asarray(cv2.dnn.NMSBoxes(_xywh(boxes), scores.tolist(), 0.0, thr)).reshape(-1)
    assert sorted(ours.tolist()) == sorted(ref.tolist())
    assert np.all(np.diff(scores[ours]) <= 0)  # by decreasing score


def test_class_aware_nms_matches_opencv_batched():
    rng = np.random.default_rng(5)
    boxes, scores = _random_boxes(rng, 120)
    cls = rng.integers(0, 3, 120)
    ours = nms(boxes, scores, 0.45, class_ids=cls)
    ref = np.asarray(cv2.dnn.NMSBoxesBatched(_xywh(boxes), scores.tolist(), cls.tolist(), 0.0, 0.45)).reshape(-1)
    assert sorted(ours.tolist()) == sorted(ref.tolist())
    # class-aware keeps at least as many as class-agnostic
    assert len(ours) >= len(nms(boxes, scores, 0.45))


@pytest.mark.parametrize("sigma", [0.3, 0.5, 1.0])
def test_gaussian_soft_nms_matches_opencv(sigma):
    rng = np.random.default_rng(11)
    boxes, scores = _random_boxes(rng, 60, size=120)
    keep, new = soft_nms(boxes, scores, sigma=sigma, score_threshold=0.05)
    ref_scores, ref_idx = cv2.dnn.softNMSBoxes(
        _xywh(boxes), scores.astype(np.float32).tolist(), 0.05, 0.3, 0, sigma,
        cv2.dnn.SOFT_NMSMETHOD_SOFTNMS_GAUSSIAN,
    )
    ref_idx = np.asarray(ref_idx).reshape(-1)
    ref_scores = np.asarray(ref_scores).reshape(-1)
    assert keep.tolist() == ref_idx.tolist()
    np.testing.assert_allclose(new, ref_scores, rtol=1e-5, atol=1e-6)


def test_soft_nms_hand_case():
    boxes = np.array([[0, 0, 10, 10], [0, 0, 10, 5], [100, 100, 110, 110]], float)
    keep, s = soft_nms(boxes, [0.9, 0.8, 0.5], sigma=0.5, score_threshold=0.01)
    # box 1 overlaps box 0 by IoU 0.5: 0.8 exp(-0.25 / 0.5) = 0.485 < 0.5 -> ranked last
    assert keep.tolist() == [0, 2, 1]
    np.testing.assert_allclose(s, [0.9, 0.5, 0.8 * np.exp(-0.5)])
    # hard NMS at N_t = 0.5 removes it (IoU >= N_t, Zhang et al. 2023 eq. 5)
    assert nms(boxes, [0.9, 0.8, 0.5], 0.5).tolist() == [0, 2]


def test_suppress_dispatch_and_errors():
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10]], float)
    cls = np.array([0, 0])
    assert suppress(boxes, [0.9, 0.8], cls, "hard")[0].tolist() == [0]
    assert suppress(boxes, [0.9, 0.8], cls, "none")[0].tolist() == [0, 1]
    assert suppress(boxes, [0.9, 0.8], np.array([0, 1]), "hard")[0].tolist() == [0, 1]
    assert suppress(boxes, [0.9, 0.8], np.array([0, 1]), "hard", class_agnostic=True)[0].tolist() == [0]
    k, s = suppress(boxes, [0.9, 0.8], cls, "soft", sigma=0.5, score_threshold=0.01)
    assert k.tolist() == [0, 1] and s[1] < 0.8
    with pytest.raises(ValueError, match="nms kind 'fast'"):
        suppress(boxes, [0.9, 0.8], cls, "fast")
    with pytest.raises(ValueError, match="sigma"):
        soft_nms(boxes, [0.9, 0.8], sigma=0)
    assert nms(np.zeros((0, 4)), np.zeros(0)).shape == (0,)
