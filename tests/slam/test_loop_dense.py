"""The loop pose refined on its map matches and the query's depth together (verification.dense_loop_pose).

The ray-cast box room of :mod:`tests.slam.scene` gives exact depth from known poses. The map matches lie
on the far wall only (the case of the plain room's revisit, where a sideways shift and a turn explain them
alike); the depth of the whole view (walls, floor and ceiling) fixes what they leave open."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.dynamic.history import reduce_depth
from dynslam_lab.geometry.se3 import make_pose, se3_inv, so3_exp, transform_points
from dynslam_lab.slam.loop_closing.verification import dense_loop_pose
from dynslam_lab.slam.optimize import Observations, optimize_pose
from tests.slam import scene

CAM = CAMERA_PRESETS["default"]
BF = 40.0


def _keyframe(T_w_c: np.ndarray, textures) -> SimpleNamespace:
    _, depth = scene.render(T_w_c, textures, CAM)
    return SimpleNamespace(T_w_c=T_w_c, T_c_w=se3_inv(T_w_c), depth_small=reduce_depth(depth, 8), depth=depth)


def _errors(T_c_w: np.ndarray, T_true_c_w: np.ndarray) -> tuple[float, float]:
    """Camera-centre error (m) and rotation error (deg)."""
    D = T_c_w @ se3_inv(T_true_c_w)
    ang = np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(se3_inv(T_c_w)[:3, 3] - se3_inv(T_true_c_w)[:3, 3])), float(ang)


def _far_wall_matches(q: SimpleNamespace, n: int, rng) -> tuple[np.ndarray, Observations]:
    """``n`` map points on the far wall (world z = the room's far end) seen by the query, with their
    measurements (0.5 px of pixel noise, 1 % of depth noise)."""
    v, u = np.mgrid[20 : CAM.height - 20, 20 : CAM.width - 20]
    z = q.depth[v, u]
    X_c = np.stack([(u - CAM.cx) / CAM.fx * z, (v - CAM.cy) / CAM.fy * z, z], axis=-1).reshape(-1, 3)
    X_w = transform_points(q.T_w_c, X_c)
    far = np.flatnonzero(X_w[:, 2] > scene.ROOM[2, 1] - 0.01)
    pick = rng.choice(far, n, replace=False)
    X_w, X_c = X_w[pick], X_c[pick]
    uv = np.stack([CAM.fx * X_c[:, 0] / X_c[:, 2] + CAM.cx, CAM.fy * X_c[:, 1] / X_c[:, 2] + CAM.cy], axis=1)
    uv = uv + rng.normal(0.0, 0.5, uv.shape)
    zm = X_c[:, 2] * (1.0 + rng.normal(0.0, 0.01, n))
    return X_w, Observations.from_keypoints(uv, zm, np.zeros(n, np.int64), BF, 1.2)


def test_depth_fixes_the_turn_that_far_wall_matches_leave_open():
    textures = scene.make_textures(0)
    T_w_q = make_pose(so3_exp(np.radians([0.0, 3.0, 0.0])), np.array([0.1, 0.0, -1.2]))
    T_w_c = T_w_q @ make_pose(so3_exp(np.radians([1.0, -8.0, 0.5])), np.array([0.15, 0.02, -0.1]))
    q, cand = _keyframe(T_w_q, textures), _keyframe(T_w_c, textures)
    T_true = se3_inv(T_w_q)
    # a start off by a sideways shift and the turn that nearly mimics it at the wall's distance (3.7 m)
    start = make_pose(so3_exp(np.radians([0.0, 0.8, 0.0])), np.array([0.05, 0.0, 0.0])) @ T_true
    worst_feature = 0.0
    for seed in range(5):
        X_w, obs = _far_wall_matches(q, 40, np.random.default_rng(seed))
        T_feat, _ = optimize_pose(start, X_w, obs, CAM, BF)
        c_feat, r_feat = _errors(T_feat, T_true)
        stats: dict = {}
        T_dense = dense_loop_pose(q, cand, T_feat, X_w, obs, CAM, BF, stats)
        c_dense, r_dense = _errors(T_dense, T_true)
        worst_feature = max(worst_feature, r_feat)
        # measured: features 1.5-37 mm / 0.02-0.53 deg; with the depth 0.4-0.9 mm / 0.011-0.017 deg
        assert c_dense < 0.002 and r_dense < 0.025 and c_dense < c_feat and r_dense < r_feat, (seed, c_feat, r_feat)
        assert stats["dense_d_end"] < stats["dense_d_start"]
    assert worst_feature > 0.2  # the far wall alone leaves the turn open by tenths of a degree


def test_without_kept_depth_the_feature_pose_is_returned_unchanged():
    textures = scene.make_textures(0)
    T_w_q = make_pose(np.eye(3), np.array([0.0, 0.0, -1.0]))
    q, cand = _keyframe(T_w_q, textures), _keyframe(T_w_q, textures)
    X_w, obs = _far_wall_matches(q, 60, np.random.default_rng(0))
    T = make_pose(so3_exp(np.radians([0.0, 1.0, 0.0])), np.zeros(3)) @ se3_inv(T_w_q)
    for a, b in ((SimpleNamespace(**{**vars(q), "depth_small": None}), cand),
                 (q, SimpleNamespace(**{**vars(cand), "depth_small": None}))):
        stats: dict = {}
        assert np.array_equal(dense_loop_pose(a, b, T, X_w, obs, CAM, BF, stats), T) and not stats
