"""The whole system on rendered frames: accuracy against ground truth, keyframes and local BA,
loss and relocalisation, poses anchored to keyframes, the loop-closer hook."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.config import Config
from dynslam_lab.datasets.frame import Frame
from dynslam_lab.evaluation import compute_ate
from dynslam_lab.evaluation.trajectory import Trajectory
from dynslam_lab.geometry.se3 import make_pose
from dynslam_lab.slam.system import System
from dynslam_lab.slam.tracking import TrackState
from tests.slam import scene

CAM = CAMERA_PRESETS["default"]


def _gt(frames):
    return Trajectory(np.array([f.timestamp for f in frames]), np.stack([f.T_w_c_gt for f in frames]))


@pytest.mark.slow
def test_turning_camera_keyframes_local_ba_and_ate_below_1cm():
    frames = scene.frames(100, "arc")
    s = System(CAM, Config())
    res = [s.process(f) for f in frames]
    assert not s.lost_frames and all(r.tracked for r in res)
    traj = s.trajectory()
    assert len(traj) == 100
    ate = compute_ate(_gt(frames), traj, align="se3")
    assert ate.stats.rmse < 0.01
    kfs = [r for r in res if r.is_keyframe]
    assert len(kfs) >= 3 and len(s.map.keyframes) >= 3
    ba = [r.local_mapping for r in kfs if "ba_cost_after" in r.local_mapping]
    assert ba and all(b["ba_cost_after"] <= b["ba_cost_before"] for b in ba)
    # covisibility: every later keyframe shares points with another and has a parent
    for kid, kf in s.map.keyframes.items():
        if kid:
            assert s.map.covisibility(kid) and kf.parent_id >= 0
    arrays = s.keyframe_arrays()
    assert arrays["poses"].shape == (len(s.map.keyframes), 4, 4) and arrays["loop_edges"].shape[1] == 2


def test_lost_on_blank_frame_then_relocalized():
    frames = scene.frames(40, "xyz")
    s = System(CAM, Config())
    for f in frames[:20]:
        assert s.process(f).tracked
    # no texture and no depth (with depth alone the dense term, tracking.dense = "auto", would track it)
    blank = Frame(20, frames[20].timestamp, np.full_like(frames[20].rgb, 120), np.zeros_like(frames[20].depth), CAM)
    r = s.process(blank)
    assert r.state == TrackState.LOST and r.T_w_c is None and r.n_features == 0
    after = [s.process(dataclasses.replace(f, index=f.index + 1)) for f in frames[21:30]]
    assert after[0].state == TrackState.RELOCALIZED and after[0].method == "relocalization"
    assert all(a.tracked for a in after)
    assert s.lost_frames == [20]
    err = np.linalg.norm(after[0].T_w_c[:3, 3] - frames[21].T_w_c_gt[:3, 3])
    assert err < 0.01
    assert len(s.trajectory()) == 29  # the lost frame has no pose


def test_trajectory_follows_keyframe_corrections():
    frames = scene.frames(40, "xyz")
    s = System(CAM, Config())
    for f in frames[:10]:
        s.process(f)
    before = s.trajectory().poses.copy()
    kf0 = s.map.keyframes[0]
    shift = make_pose(t=[0.5, 0.0, 0.0])
    kf0.T_w_c = shift @ kf0.T_w_c  # what a loop correction does to a keyframe
    after = s.trajectory().poses
    assert np.allclose(after, shift @ before)


class _FakeLoop:
    """Loop closer stand-in: claims a loop on keyframe 1, raises on keyframe 2 (no database: the
    system keeps its own for relocalisation)."""

    bf = Config().tracking.bf
    config = dataclasses.replace(Config().loop_closing, enabled=False)

    def __init__(self):
        self.seen = []

    def on_keyframe(self, kf, mp):
        self.seen.append(kf.id)
        assert kf.id in mp.keyframes and kf.descriptors.shape[1] == 32 and kf.points_c.shape[1] == 3
        if kf.id == 1:
            return type("R", (), {"keyframe_ids": (1, 0)})()
        if kf.id == 2:
            raise RuntimeError("boom")
        return None


@pytest.mark.slow
def test_loop_closer_hook_called_per_keyframe_and_never_loses_the_pose():
    frames = scene.frames(100, "arc")
    fake = _FakeLoop()
    s = System(CAM, Config(), loop_closer=fake)
    res = [s.process(f) for f in frames]
    kf_ids = [r.keyframe_id for r in res if r.is_keyframe]
    assert fake.seen == kf_ids and len(kf_ids) >= 3
    assert (1, 0) in s.loop_edges and s.keyframe_arrays()["loop_edges"].tolist().count([1, 0]) == 1
    failed = [r for r in res if r.keyframe_id == 2][0]
    assert "boom" in failed.error and failed.tracked
    assert all(r.tracked for r in res)


def test_no_depth_means_no_map_and_every_frame_listed_as_lost():
    frames = scene.frames(40, "xyz")[:3]
    s = System(CAM, Config())
    res = [s.process(dataclasses.replace(f, depth=np.zeros_like(f.depth))) for f in frames]
    assert all(r.state == TrackState.NOT_INITIALIZED and r.T_w_c is None for r in res)
    assert s.lost_frames == [0, 1, 2] and len(s.trajectory()) == 0 and not s.map.keyframes
    with pytest.raises(ValueError, match="screener returned 2 verdicts"):
        bad = type("S", (), {"screen": lambda self, f, uv, d: type("T", (), {"dynamic": np.zeros(2, bool)})()})()
        System(CAM, Config(), screener=bad).process(frames[0])
