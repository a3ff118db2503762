"""The depth scale checked before a run (the depth's range) and after it (the path's size against the
ground truth): rendered sequences of the test room with a camera.json of the wrong scale, and hand-made
trajectories."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dynslam_lab.camera import CAMERA_PRESETS, save_camera_json
from dynslam_lab.cli import main
from dynslam_lab.datasets.depth_scale import check_depth_range, depth_scale_from_trajectory, sample_depth
from dynslam_lab.datasets.tum import DatasetError, TumSequence
from dynslam_lab.evaluation.trajectory import Trajectory
from dynslam_lab.geometry.se3 import make_pose, so3_exp
from tests.runs.sequences import write_sequence
from tests.slam import scene


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    return write_sequence(tmp_path_factory.mktemp("depth_scale") / "room", n=40)


def _with_scale(src, dst, scale):
    import shutil

    shutil.copytree(src, dst)
    save_camera_json(CAMERA_PRESETS["default"].with_(depth_scale=scale, name="camera.json"), dst / "camera.json")
    return dst


def test_the_median_depth_of_a_few_frames_against_the_renderer(room):
    frames = scene.frames(40, "xyz")
    idx = np.linspace(0, 39, 5).round().astype(int)
    truth = np.median([np.median(frames[i].depth[frames[i].depth > 0]) for i in idx])
    s = sample_depth(TumSequence(room, camera="default"), k=5)
    assert len(s.paths) == 5 and s.depth_scale == 5000.0
    assert s.median_m == pytest.approx(truth, abs=1e-3)  # the PNGs hold the depth rounded to 0.2 mm
    assert s.median_units == pytest.approx(5000.0 * s.median_m)
    assert check_depth_range(TumSequence(room, camera="default"), None, 0.1, 8.0).median_m == s.median_m


def test_depth_read_at_a_fifth_of_its_scale_is_refused_before_the_run(room, tmp_path, capsys):
    seq = _with_scale(room, tmp_path / "mm", 1000.0)  # 5000 units per metre in the files, read as millimetres
    with pytest.raises(DatasetError, match=r"depth_scale 1000 units per metre.*outside the 0.1-8 m"):
        check_depth_range(TumSequence(seq), None, 0.1, 8.0)
    out = tmp_path / "out"
    assert main(["run", str(seq), "--out", str(out), "--quiet", "--no-loop"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and "camera.json" in err and "at 5000 units per metre" in err
    assert not out.exists()  # refused before anything is written


def test_depth_read_five_times_too_small_is_said_after_the_run(room, tmp_path, caplog):
    seq = _with_scale(room, tmp_path / "small", 25000.0)  # 0.5 m: in range, only the ground truth can tell
    out = tmp_path / "out"
    assert main(["run", str(seq), "--out", str(out), "--quiet", "--no-loop"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["trajectory_scale"] == pytest.approx(5.0, rel=0.1)
    assert len(s["warnings"]) == 1 and "depth scale is likely wrong" in s["warnings"][0]
    fit = float(s["warnings"][0].split("about ")[1].split()[0])
    assert fit == pytest.approx(5000.0, rel=0.1)
    assert "depth scale is likely wrong" in caplog.text
    ok = tmp_path / "ok"
    assert main(["run", str(room), "--out", str(ok), "--quiet", "--no-loop", "--camera", "default"]) == 0
    s = json.loads((ok / "summary.json").read_text())
    assert "warnings" not in s and s["trajectory_scale"] == pytest.approx(1.0, abs=0.05)


def _curve(n=60, size=1.0):
    t = np.linspace(0, 1, n)
    P = np.stack([make_pose(so3_exp([0.0, 0.3 * s, 0.1 * s]), size * np.array([np.sin(3 * s), 0.5 * s, np.cos(2 * s) - 1]))
                  for s in t])
    return Trajectory(t * 2.0, P)


def test_the_scale_of_the_path_against_hand_made_trajectories():
    gt = _curve()
    T = make_pose(so3_exp([0.2, -0.1, 0.4]), [1.0, 2.0, 0.5])
    est = Trajectory(gt.timestamps, np.stack([T @ p for p in gt.poses])).transformed(np.eye(4), scale=0.2)
    r = depth_scale_from_trajectory(gt, est, 25000.0)
    assert r.scale == pytest.approx(5.0, rel=1e-6) and r.ate_sim3_m < 1e-9 < r.ate_se3_m
    assert "0.20 times the size" in r.warning and "about 5000 would fit" in r.warning
    # a path that drifts (tracking that failed) is not a scale: the similarity explains little of its error
    rng = np.random.default_rng(2)
    drift = np.cumsum(rng.normal(0.0, 0.08, (60, 3)), axis=0)
    P = gt.poses.copy()
    P[:, :3, 3] += drift
    r = depth_scale_from_trajectory(gt, Trajectory(gt.timestamps, P), 5000.0)
    assert r.warning is None and r.ate_sim3_m > 0.25 * r.ate_se3_m
    # a camera that turns in place (a small circle) while tracking follows movers far away: shrunk to the
    # circle's centre the estimate fits to the circle's radius, a fraction of the rigid ATE, but not the path
    a = np.linspace(0, 4 * np.pi, 60)
    P = np.tile(np.eye(4), (60, 1, 1))
    P[:, :3, 3] = 0.02 * np.c_[np.cos(a), np.sin(a), np.zeros(60)]
    turning = Trajectory(gt.timestamps, P)
    wild = P.copy()
    wild[:, :3, 3] += np.cumsum(rng.normal(0.0, 0.05, (60, 3)), axis=0)
    r = depth_scale_from_trajectory(turning, Trajectory(gt.timestamps, wild), 5000.0)
    assert r.path_m > 0.1 and r.ate_sim3_m < 0.25 * r.ate_se3_m and r.scale < 0.5
    assert r.spread_m == pytest.approx(0.02, rel=1e-3) and r.warning is None
    # a camera that hardly moves has no size to measure
    still = _curve(size=0.01)
    r = depth_scale_from_trajectory(still, still.transformed(np.eye(4), scale=0.2), 5000.0)
    assert r.path_m < 0.1 and r.warning is None
