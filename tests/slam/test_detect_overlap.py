"""Detection of frame t run beside ORB extraction (``tracking.overlap_detection``): the detector
runs in the worker thread, and the results are the same as run one after the other."""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np
import pytest

from dynslam_lab.config import Config
from dynslam_lab.detection.detections import Detections
from dynslam_lab.dynamic.screening import build_screener
from dynslam_lab.features.orb import extract_features
from dynslam_lab.slam.system import System
from tests.slam import scene


class MovingBoxDetector:
    """A 'person' box that slides with the frame index; records the thread it ran in."""

    def __init__(self) -> None:
        self.config = Config().detection
        self.threads: set[str] = set()

    def detect(self, frame) -> Detections:
        self.threads.add(threading.current_thread().name)
        x = 40.0 + 8.0 * frame.index
        return Detections(np.array([[x, 100.0, x + 160.0, 400.0]]), np.array([0.9]), np.array([0]), frame.shape)


def _run(frames, overlap: bool):
    cfg = Config()
    cfg = replace(cfg, tracking=replace(cfg.tracking, overlap_detection=overlap))
    det = MovingBoxDetector()
    system = System(frames[0].camera, cfg, detector=det, screener=build_screener("semantic", cfg.screening))
    results = [system.process(f) for f in frames]
    return system, det, results


def test_overlap_gives_the_same_results_and_runs_in_the_worker():
    frames = scene.frames(40, "xyz")[:10]
    sys_a, det_a, res_a = _run(frames, overlap=True)
    sys_b, det_b, res_b = _run(frames, overlap=False)
    assert det_a.threads and all(t.startswith("dynslam-detect") for t in det_a.threads)
    assert det_b.threads == {threading.current_thread().name}
    for a, b in zip(res_a, res_b):
        assert a.state == b.state and a.is_keyframe == b.is_keyframe
        np.testing.assert_array_equal(a.dynamic, b.dynamic)
        np.testing.assert_array_equal(a.T_w_c, b.T_w_c)
        assert a.timings_ms["detect"] >= 0 and a.timings_ms["orb"] > 0
    assert sum(int(r.dynamic.sum()) for r in res_a) > 100  # the box did mark keypoints dynamic
    ta, tb = sys_a.trajectory(), sys_b.trajectory()
    np.testing.assert_array_equal(ta.poses, tb.poses)
    gt = np.stack([f.T_w_c_gt for f in frames])
    assert np.abs(ta.poses[:, :3, 3] - gt[:, :3, 3]).max() < 0.01


def test_a_failing_detector_fails_that_frame_only():
    frames = scene.frames(40, "xyz")[:4]

    class Flaky(MovingBoxDetector):
        def detect(self, frame):
            if frame.index == 2:
                raise RuntimeError("detector crashed on frame 2")
            return super().detect(frame)

    cfg = Config()
    system = System(frames[0].camera, cfg, detector=Flaky(), screener=build_screener("semantic", cfg.screening))
    system.process(frames[0])
    system.process(frames[1])
    with pytest.raises(RuntimeError, match="frame 2"):
        system.process(frames[2])
    assert system.process(frames[3]).tracked


def test_prepare_ahead_in_another_thread_gives_the_same_results():
    """``System.prepare`` (ORB and detection started ahead in worker threads, as the runner's reader
    thread does) gives
    the frame-by-frame results of plain ``process``; a frame whose extraction failed fails alone."""
    frames = scene.frames(40, "xyz")[:8]
    _, _, plain = _run(frames, overlap=True)
    cfg = Config()
    det = MovingBoxDetector()
    system = System(frames[0].camera, cfg, detector=det, screener=build_screener("semantic", cfg.screening))
    reader = threading.Thread(target=lambda: [system.prepare(f) for f in frames[:4]], name="reader")
    reader.start()
    reader.join()
    assert sorted(system._prepared) == [0, 1, 2, 3]
    ahead = [system.process(f) for f in frames]  # 0-3 prepared ahead, 4-7 extracted in process
    assert not system._prepared
    for a, b in zip(ahead, plain):
        assert a.state == b.state and a.is_keyframe == b.is_keyframe
        np.testing.assert_array_equal(a.uv, b.uv)
        np.testing.assert_array_equal(a.dynamic, b.dynamic)
        np.testing.assert_array_equal(a.T_w_c, b.T_w_c)
        assert a.timings_ms["orb"] > 0
    # the prepared work of another frame object with the same index is not used
    other = replace(frames[1], rgb=np.zeros_like(frames[1].rgb))
    system.prepare(other)
    assert system._take_prepared(frames[1]) is None and not system._prepared
    # an extraction error surfaces in process(), for that frame only
    bad = replace(frames[2], rgb=np.zeros((2, 2, 3), np.uint8))
    with pytest.raises(Exception) as direct:
        extract_features(bad.gray, cfg.orb)
    system.prepare(bad)
    with pytest.raises(type(direct.value)):
        system.process(bad)
    assert system.process(frames[3]).state is not None


class _Recording:
    """A screener that records the detections each frame was screened with."""

    def __init__(self, inner) -> None:
        self.inner = inner
        self.seen: list[Detections] = []

    def screen(self, frame, uv, detections, **kw):
        self.seen.append(detections)
        return self.inner.screen(frame, uv, detections, **kw)

    def __getattr__(self, name):
        return getattr(self.inner, name)


class _Counting(MovingBoxDetector):
    def __init__(self, stride: int, fail_on: int = -1) -> None:
        super().__init__()
        self.config = replace(self.config, stride=stride, carry_margin_px=5.0)
        self.called: list[int] = []
        self.fail_on = fail_on

    def detect(self, frame):
        self.called.append(int(frame.index))
        if frame.index == self.fail_on:
            raise RuntimeError(f"detector crashed on frame {frame.index}")
        return super().detect(frame)


def _strided(frames, overlap: bool, stride: int = 3, ahead: int = 0, fail_on: int = -1):
    cfg = Config()
    cfg = replace(cfg, tracking=replace(cfg.tracking, overlap_detection=overlap))
    det = _Counting(stride, fail_on)
    screener = _Recording(build_screener("semantic", cfg.screening))
    system = System(frames[0].camera, cfg, detector=det, screener=screener)
    if ahead:
        reader = threading.Thread(target=lambda: [system.prepare(f) for f in frames[:ahead]], name="reader")
        reader.start()
        reader.join()
    results = []
    for f in frames:
        try:
            results.append(system.process(f))
        except RuntimeError as exc:
            results.append(exc)
    return det, screener, results


def test_detection_stride_detects_every_third_frame_and_carries_the_boxes_grown():
    """``detection.stride = 3``: frames 0, 3, 6 are detected; frames 1-2 and 4-5 take the last
    detection's box grown by 5 px per frame since; the same in the worker, in the frame loop, and
    prepared ahead."""
    frames = scene.frames(40, "xyz")[:7]
    det, screener, res = _strided(frames, overlap=True)
    assert det.called == [0, 3, 6]
    x = lambda i: 40.0 + 8.0 * i  # noqa: E731  the detector's box of frame i
    for i, (src, grow) in enumerate([(0, 0), (0, 5), (0, 10), (3, 0), (3, 5), (3, 10), (6, 0)]):
        np.testing.assert_allclose(screener.seen[i].boxes, [[x(src) - grow, 100 - grow, x(src) + 160 + grow, 400 + grow]])
        assert ("carried from frame" in screener.seen[i].source) == (grow > 0)
    assert all(r.timings_ms["detect"] >= 0 for r in res)
    for other in (_strided(frames, overlap=False), _strided(frames, overlap=True, ahead=5)):
        assert other[0].called == [0, 3, 6]
        for a, b, da, db in zip(res, other[2], screener.seen, other[1].seen):
            np.testing.assert_array_equal(da.boxes, db.boxes)
            np.testing.assert_array_equal(a.dynamic, b.dynamic)
            np.testing.assert_array_equal(a.T_w_c, b.T_w_c)


def test_a_frame_whose_source_detection_failed_is_detected_itself():
    frames = scene.frames(40, "xyz")[:6]
    det, screener, res = _strided(frames, overlap=True, fail_on=3)
    assert isinstance(res[3], RuntimeError) and "frame 3" in str(res[3])
    assert det.called == [0, 3, 4, 5]  # 4 and 5 cannot take frame 3's: each detected
    assert all(not isinstance(r, Exception) and r.tracked for r in res[4:])
    assert [s.source for s in screener.seen[3:]] == ["", ""]
