"""Multi-view RGB-D check (Chang et al. 2021 eq. 2): rough PnP pose and the 4 px / 0.1 m test."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.dynamic.multiview import MultiViewConfig, multiview_check, rough_pose
from dynslam_lab.geometry.se3 import make_pose, se3_inv, so3_exp, transform_points
from tests.dynamic.scenes import CAM


def _scene(n=400, seed=3):
    rng = np.random.default_rng(seed)
    uv_prev = np.column_stack([rng.uniform(20, 620, n), rng.uniform(20, 460, n)])
    z_prev = rng.uniform(1.0, 5.0, n)
    P = CAM.backproject(uv_prev, z_prev)
    T_c_p = make_pose(so3_exp(np.array([0.02, -0.01, 0.01])), np.array([0.05, -0.02, 0.04]))
    X = transform_points(T_c_p, P)
    moving = np.zeros(n, bool)
    moving[:80] = True
    X[:40] += np.array([0.15, 0.0, 0.0])  # sideways: pixel error
    X[40:80, 2] += 0.3  # along the ray: depth error only (small pixel change)
    uv, z = CAM.project(X)
    return uv, z, uv_prev, z_prev, moving, T_c_p


def test_rough_pose_recovers_the_true_motion_despite_movers():
    uv, _, uv_prev, z_prev, moving, T_true = _scene()
    P = CAM.backproject(uv_prev, z_prev)
    T, inl = rough_pose(P, uv, CAM.K)
    assert T is not None
    err = se3_inv(T_true) @ T
    assert np.linalg.norm(err[:3, 3]) < 1e-4
    assert np.allclose(err[:3, :3], np.eye(3), atol=1e-5)
    assert not inl[:40].any()  # the sideways movers are RANSAC outliers


def test_check_flags_pixel_and_depth_violations():
    uv, z, uv_prev, z_prev, moving, T_true = _scene()
    res = multiview_check(uv, z, uv_prev, z_prev, np.ones(len(uv), bool), None, CAM)
    assert res.dynamic[:40].all()  # 0.15 m sideways at <= 5 m: > 4 px
    assert res.dynamic[40:80].all()  # 0.3 m along the ray: depth difference > 0.1 m
    assert not res.dynamic[~moving].any()
    assert np.all(res.depth_error_m[40:80] == pytest.approx(0.3, abs=1e-6))
    assert np.nanmax(res.reprojection_px[~moving]) < 1e-3


def test_exclusion_and_thresholds():
    uv, z, uv_prev, z_prev, moving, _ = _scene()
    z_noisy = z + 0.05  # a depth bias below 0.1 m keeps static points static
    res = multiview_check(uv, z_noisy, uv_prev, z_prev, np.ones(len(uv), bool), moving, CAM)
    assert not res.inliers[moving].any()
    assert not res.dynamic[~moving].any()
    strict = multiview_check(uv, z_noisy, uv_prev, z_prev, np.ones(len(uv), bool), moving, CAM, MultiViewConfig(depth_m=0.04, depth_quadratic=0.0))
    assert strict.dynamic[~moving].all()


def test_depth_threshold_grows_with_depth_squared():
    uv, z, uv_prev, z_prev, moving, _ = _scene()
    z_biased = z + 0.15  # 0.15 m: over 0.1 m, but within 0.01 z^2 beyond 3.9 m
    res = multiview_check(uv, z_biased, uv_prev, z_prev, np.ones(len(uv), bool), moving, CAM)
    far = ~moving & (z_biased > 3.9)
    near = ~moving & (z_biased < 3.1)
    assert far.sum() > 20 and near.sum() > 20
    assert not res.dynamic[far].any() and res.dynamic[near].all()
    paper = multiview_check(uv, z_biased, uv_prev, z_prev, np.ones(len(uv), bool), moving, CAM,
                            MultiViewConfig(depth_quadratic=0.0))
    assert paper.dynamic[~moving].all()


def test_too_few_pairs_skip_the_check():
    uv, z, uv_prev, z_prev, _, _ = _scene(n=8)
    res = multiview_check(uv, z, uv_prev, z_prev, np.ones(8, bool), None, CAM)
    assert res.T_c_p is None and not res.dynamic.any()
    with pytest.raises(ValueError, match="same length"):
        multiview_check(uv, z[:3], uv_prev, z_prev, np.ones(8, bool), None, CAM)
