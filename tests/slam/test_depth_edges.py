"""Odometry edges of the essential graph measured by depth (loop_closing.correction.depth_edges).

Two keyframes of the ray-cast box room of :mod:`tests.slam.scene` (exact depth, known poses); the edge's
measurement is off by a turn and a shift within the floor sigmas (as tracking's chained relative pose can
be across a plain wall); the depth alignment must bring it back to the truth and add information."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.dynamic.history import reduce_depth
from dynslam_lab.geometry.se3 import make_pose, se3_inv, so3_exp
from dynslam_lab.slam.loop_closing.correction import depth_edges
from dynslam_lab.slam.pose_graph import PoseGraphConfig
from tests.slam import scene

CAM = CAMERA_PRESETS["default"]


def _error(T: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    D = T @ se3_inv(T_true)
    return float(np.linalg.norm(D[:3, 3])), float(np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1))))


def _snapshot(poses: list[np.ndarray], with_depth: bool = True) -> SimpleNamespace:
    textures = scene.make_textures(1)
    kfs = {}
    for k, T in enumerate(poses):
        depth = scene.render(T, textures, CAM)[1] if with_depth else None
        kfs[k] = SimpleNamespace(id=k, depth_small=None if depth is None else reduce_depth(depth, 8))
    return SimpleNamespace(ids=np.arange(len(poses)), keyframes=kfs)


def test_an_edge_is_measured_again_by_depth():
    T_w_i = make_pose(so3_exp(np.radians([0.0, 10.0, 0.0])), np.array([0.2, 0.0, -1.0]))
    T_w_j = T_w_i @ make_pose(so3_exp(np.radians([2.0, -6.0, 1.0])), np.array([0.12, -0.03, 0.08]))
    snap = _snapshot([T_w_i, T_w_j])
    Z_true = se3_inv(T_w_i) @ T_w_j
    Z = (Z_true @ make_pose(so3_exp(np.radians([0.3, 0.6, -0.4])), np.array([0.012, -0.008, 0.01])))[None].copy()
    before = _error(Z[0], Z_true)
    info = np.tile(np.eye(6), (1, 1, 1))
    pg = PoseGraphConfig()
    assert depth_edges(snap, np.array([[0, 1]]), Z, info, None, CAM, pg) == 1
    after = _error(Z[0], Z_true)
    # measured: 17.6 mm / 0.78 deg -> 0.4 mm / 0.006 deg (the room's walls fix every direction)
    assert before[0] > 0.015 and before[1] > 0.7
    assert after[0] < 0.002 and after[1] < 0.03
    added = info[0] - np.eye(6)
    assert np.allclose(added, added.T) and np.linalg.eigvalsh(added).min() > 0  # six directions fixed


def test_the_loop_edge_and_keyframes_without_depth_are_left_alone():
    T_w_i = make_pose(np.eye(3), np.array([0.0, 0.0, -1.0]))
    T_w_j = T_w_i @ make_pose(so3_exp(np.radians([0.0, 3.0, 0.0])), np.array([0.05, 0.0, 0.0]))
    Z0 = (se3_inv(T_w_i) @ T_w_j)[None]
    for snap, loop_edge in ((_snapshot([T_w_i, T_w_j]), 0), (_snapshot([T_w_i, T_w_j], with_depth=False), None)):
        Z, info = Z0.copy(), np.tile(np.eye(6), (1, 1, 1))
        assert depth_edges(snap, np.array([[0, 1]]), Z, info, loop_edge, CAM, PoseGraphConfig()) == 0
        assert np.array_equal(Z, Z0) and np.array_equal(info[0], np.eye(6))
