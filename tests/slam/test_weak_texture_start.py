"""Starting the map in a room of weak texture (``tracking.init_weak_min_points``).

``random_409`` without its movers is a plain grey room (walls and floor of flat colour, a few posters) seen by a
half-sphere camera path: every frame has fewer than 500 ORB keypoints with depth, so ORB-SLAM2's rule (500 static
keypoints with depth) never starts the map and nothing is tracked. With the weak-texture rule the first frame
starts it and the dense depth term of tracking carries the plain room. Checked against the renderer's poses.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dynslam_lab.config import Config
from dynslam_lab.datasets import stress
from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.datasets.tum import TumSequence
from dynslam_lab.evaluation import compute_ate
from dynslam_lab.pipeline import build_pipeline
from dynslam_lab.threads import blas_single_thread

pytestmark = pytest.mark.slow

SEED, N = 409, 40


def _run(seq: TumSequence, weak: int, **tracking):
    cfg = Config()
    cfg = replace(cfg, tracking=replace(cfg.tracking, init_weak_min_points=weak, **tracking))
    system = build_pipeline(cfg, seq.camera, detector="none", filters="none", loop_closing=False)
    with_depth = []
    system.methods = []
    with blas_single_thread():
        for i in range(N):
            frame = seq[i]
            r = system.process(frame)
            system.methods.append(r.method)
            u, v = np.round(r.uv).astype(int).T
            z = frame.depth[v.clip(0, frame.depth.shape[0] - 1), u.clip(0, frame.depth.shape[1] - 1)]
            with_depth.append(int(((z > cfg.tracking.min_depth) & (z < cfg.tracking.max_depth)).sum()))
    return system, with_depth


@pytest.fixture(scope="module")
def plain_room() -> TumSequence:
    preset = stress.random_scene_preset(SEED, name=f"random_{SEED}", n_frames=N).without_movers()
    return TumSequence(synthetic_sequence(preset, seed=SEED))


def test_a_plain_room_is_never_started_by_orbslam2s_rule(plain_room):
    system, with_depth = _run(plain_room, weak=0)
    assert max(with_depth) < Config().tracking.init_min_points  # the case: no frame offers 500 keypoints with depth
    assert len(system.lost_frames) == N and len(system.trajectory()) == 0


def test_a_plain_room_starts_with_the_weak_texture_rule_and_tracks_every_frame(plain_room):
    system, with_depth = _run(plain_room, weak=Config().tracking.init_weak_min_points)
    assert with_depth[0] >= Config().tracking.init_weak_min_points
    assert not system.lost_frames
    ate = compute_ate(plain_room.groundtruth, system.trajectory(), align="se3")
    assert ate.stats.n == N
    # measured 10.8 mm RMSE, worst frame 20 mm (22 and 46 without the gate of the joint refinement): the plain walls
    # leave the pose noisy, but it follows the renderer's path
    assert ate.stats.rmse <= 0.02, ate.stats.rmse
    assert ate.stats.max <= 0.04, ate.stats.max


def test_the_image_moves_a_weak_feature_pose_as_far_as_the_features_allow(plain_room):
    """``tracking.joint_gate_chi2``: the plain room's keypoints are far corners in a band along the walls' foot,
    which leave the pose centimetres free sideways (a slide and a turn explain them alike). The joint
    refinement (features and image edges) moves the feature pose by more than the fixed bound (1 cm, 0.5 deg) on
    most frames; bounded by the features' own information instead, it is kept there and the path follows the
    renderer's more closely (measured: 22.4 -> 10.8 mm RMSE, worst frame 45.8 -> 19.9 mm)."""
    weak = Config().tracking.init_weak_min_points
    fixed, _ = _run(plain_room, weak, joint_gate_chi2=0.0)
    gated, _ = _run(plain_room, weak, joint_gate_chi2=12.6)
    assert not fixed.lost_frames and not gated.lost_frames
    assert gated.methods.count("joint") >= N - 3 > fixed.methods.count("joint") + 15, (gated.methods, fixed.methods)
    ate = {name: compute_ate(plain_room.groundtruth, s.trajectory(), align="se3").stats
           for name, s in (("fixed", fixed), ("gated", gated))}
    assert ate["gated"].rmse <= 0.7 * ate["fixed"].rmse, ate
    assert ate["gated"].max <= 0.7 * ate["fixed"].max, ate
