"""Epipolar check (Zhang et al. 2023 eqs. 16-17, Ge et al. 2024 Sec. 2.3) against OpenCV and known motion."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dynslam_lab.dynamic.epipolar import (
    EpipolarConfig,
    LkConfig,
    epipolar_check,
    estimate_fundamental,
    track_lk,
    track_lk_async,
)
from dynslam_lab.geometry.se3 import make_pose, so3_exp, transform_points
from dynslam_lab.geometry.epipolar import epipolar_distance
from tests.dynamic.scenes import CAM, two_layer_frames


def _two_views(n=300, seed=0, moving_frac=0.2, move=0.15):
    """Random 3-D points seen by two cameras; a fraction moves between the views."""
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(2, 6, n)])
    T_c1_c0 = make_pose(so3_exp(np.array([0.01, -0.03, 0.005])), np.array([0.12, 0.02, 0.03]))
    moving = np.zeros(n, bool)
    moving[: int(moving_frac * n)] = True
    X1 = transform_points(T_c1_c0, X)
    X1[moving] += rng.normal(0, 1, (moving.sum(), 3)) * move
    uv0, _ = CAM.project(X)
    uv1, _ = CAM.project(X1)
    return uv0, uv1, moving, T_c1_c0


def test_distance_matches_opencv_epilines():
    uv0, uv1, _, _ = _two_views()
    F, _ = cv2.findFundamentalMat(uv0, uv1, cv2.FM_8POINT)
    lines = cv2.computeCorrespondEpilines(uv0.reshape(-1, 1, 2), 1, F).reshape(-1, 3)  # normalised a^2+b^2=1
    ref = np.abs(np.sum(np.column_stack([uv1, np.ones(len(uv1))]) * lines, axis=1))
    assert np.allclose(epipolar_distance(F, uv0, uv1), ref, atol=1e-6)


def test_static_points_lie_on_their_epipolar_lines_for_the_true_F():
    uv0, uv1, moving, T = _two_views()
    R, t = T[:3, :3], T[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    K = CAM.K
    F = np.linalg.inv(K).T @ tx @ R @ np.linalg.inv(K)  # Zhang et al. 2023 eq. 15
    d = epipolar_distance(F, uv0, uv1)
    assert np.all(d[~moving] < 1e-6)
    assert np.median(d[moving]) > 1.0


def test_check_flags_moved_points_with_ransac_F():
    uv0, uv1, moving, _ = _two_views(moving_frac=0.25)
    res = epipolar_check(uv1, uv0, np.ones(len(uv0), bool), None, (CAM.height, CAM.width), EpipolarConfig(border_px=0))
    assert res.F is not None
    recall = (res.dynamic & moving).sum() / moving.sum()
    assert recall > 0.8  # a point moving along its own epipolar line stays hidden
    assert not res.dynamic[~moving].any()


def test_excluded_pairs_do_not_enter_F_and_rest_is_skipped_when_too_few():
    uv0, uv1, moving, _ = _two_views(moving_frac=0.6)  # moving majority: F needs the exclusion
    full = epipolar_check(uv1, uv0, np.ones(len(uv0), bool), moving, (CAM.height, CAM.width), EpipolarConfig(border_px=0))
    assert not full.used[moving].any()
    assert not full.dynamic[~moving].any() and full.dynamic[moving].mean() > 0.8
    few = np.zeros(len(uv0), bool)
    few[:5] = True
    skipped = epipolar_check(uv1, uv0, few, None, (CAM.height, CAM.width))
    assert skipped.F is None and not skipped.dynamic.any()


def test_camera_at_rest_gives_no_F():
    uv = np.random.default_rng(0).uniform(50, 400, (100, 2))
    F, inl = estimate_fundamental(uv, uv + 0.01)
    assert F is None and inl is None


def test_lk_tracks_the_wall_to_its_true_shift():
    (f0, _, _), (f1, mask, _) = two_layer_frames(2)
    rng = np.random.default_rng(0)
    uv = np.column_stack([rng.uniform(40, 600, 400), rng.uniform(40, 440, 400)])
    uv_prev, ok = track_lk(f0.gray, f1.gray, uv, LkConfig())
    left_wall = (uv[:, 0] < 250) & ~mask[uv[:, 1].round().astype(int), uv[:, 0].round().astype(int)]
    shift = uv_prev[left_wall & ok] - uv[left_wall & ok]
    # the camera moved 0.02 m right: a wall point at 3 m was fx * 0.02 / 3 px further right before
    assert np.median(shift[:, 0]) == pytest.approx(CAM.fx * 0.02 / 3.0, abs=0.05)
    assert np.median(np.abs(shift[:, 1])) < 0.05
    assert ok.mean() > 0.9


def test_lk_started_in_the_worker_thread_gives_the_same_pairs():
    (f0, _, _), (f1, _, _) = two_layer_frames(2)
    uv = np.column_stack([np.linspace(40, 600, 300), np.linspace(40, 440, 300)])
    future = track_lk_async(f0.gray, f1.gray, uv, LkConfig())
    uv[:] = 0  # the caller may reuse its array: the worker tracks a copy
    (uv_prev, ok), ms = future.result()
    expected, expected_ok = track_lk(f0.gray, f1.gray, np.column_stack([np.linspace(40, 600, 300), np.linspace(40, 440, 300)]))
    assert np.array_equal(uv_prev, expected, equal_nan=True) and np.array_equal(ok, expected_ok) and ms > 0


def test_bad_shapes_are_named():
    with pytest.raises(ValueError, match="F must be"):
        epipolar_distance(np.eye(2), np.zeros((1, 2)), np.zeros((1, 2)))
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        epipolar_distance(np.eye(3), np.zeros((1, 3)), np.zeros((1, 2)))
    with pytest.raises(ValueError, match="min_pairs"):
        EpipolarConfig(min_pairs=5)
