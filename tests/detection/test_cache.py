"""Detections saved as npz per frame and read back."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.datasets.frame import Frame
from dynslam_lab.detection import Detections, build_detector, load_detections, save_detections
from dynslam_lab.detection.cache import CacheDetector
from dynslam_lab.detection.config import DetectionConfig


class CountingDetector:
    config = DetectionConfig(score_threshold=0.3)

    def __init__(self):
        self.calls = 0

    def detect(self, frame):
        self.calls += 1
        rng = np.random.default_rng(frame.index)
        masks = rng.random((2, 30, 40)) > 0.5
        return Detections(rng.random((2, 4)) * 30, [0.9, 0.5], [0, 56], (30, 40), masks=masks, source="count")


def _frame(i):
    return Frame(i, 1341846313.553992 + i / 30, np.zeros((30, 40, 3), np.uint8), np.zeros((30, 40), np.float32),
                 CAMERA_PRESETS["tum_fr3"])


def test_roundtrip_with_and_without_masks(tmp_path):
    d = CountingDetector().detect(_frame(0))
    p = save_detections(tmp_path / "a", d)
    assert p.name == "a.npz"
    r = load_detections(p)
    np.testing.assert_array_equal(r.boxes, d.boxes)
    np.testing.assert_array_equal(r.scores, d.scores)
    np.testing.assert_array_equal(r.class_ids, d.class_ids)
    np.testing.assert_array_equal(r.masks, d.masks)
    assert (r.image_size, r.source) == ((30, 40), "count")
    boxes_only = d.select(np.array([1]))
    boxes_only.masks = None
    r2 = load_detections(save_detections(tmp_path / "b.npz", boxes_only))
    assert r2.masks is None and r2.names == ["chair"]
    empty = load_detections(save_detections(tmp_path / "e.npz", Detections.empty((30, 40), with_masks=True)))
    assert len(empty) == 0 and empty.masks.shape == (0, 30, 40)


def test_cache_detector_fills_then_reads(tmp_path):
    inner = CountingDetector()
    cached = CacheDetector(tmp_path / "dets", fallback=inner)
    first = [cached.detect(_frame(i)) for i in range(3)]
    assert inner.calls == 3 and cached.misses == 3
    assert sorted(p.name for p in (tmp_path / "dets").iterdir()) == [
        "1341846313.553992.npz", "1341846313.587325.npz", "1341846313.620659.npz"]
    reader = build_detector(f"cache:{tmp_path / 'dets'}")
    again = [reader.detect(_frame(i)) for i in range(3)]
    assert inner.calls == 3 and reader.hits == 3
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a.masks, b.masks)
        np.testing.assert_array_equal(a.boxes, b.boxes)


def test_cache_errors_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="cache directory not found"):
        build_detector(f"cache:{tmp_path / 'none'}")
    (tmp_path / "d").mkdir()
    reader = CacheDetector(tmp_path / "d")
    with pytest.raises(FileNotFoundError, match=r"1341846313\.553992\.npz: no cached detections for frame 0"):
        reader.detect(_frame(0))
    bad = tmp_path / "d" / "1341846313.553992.npz"
    np.savez(bad, something=np.zeros(3))
    with pytest.raises(ValueError, match="not a detection cache file"):
        reader.detect(_frame(0))
    save_detections(bad, Detections.empty((10, 10)))
    with pytest.raises(ValueError, match=r"cached for a \(10, 10\) image"):
        reader.detect(_frame(0))


def test_build_detector_specs(tmp_path):
    assert build_detector("none") is None
    assert build_detector("oracle").source == "oracle"
    with pytest.raises(ValueError, match="unknown detector spec 'yolo'"):
        build_detector("yolo")
    with pytest.raises(ValueError, match="needs a model path"):
        build_detector("onnx:")
    with pytest.raises(FileNotFoundError, match="missing.onnx: ONNX model not found"):
        build_detector(str(tmp_path / "missing.onnx"))
    filled = build_detector(f"cache:{tmp_path / 'c'}=oracle")
    assert isinstance(filled, CacheDetector) and filled.fallback.source == "oracle"
