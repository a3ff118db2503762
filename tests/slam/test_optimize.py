"""Pose-only optimisation and local BA against ground-truth poses of generated scenes."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.geometry.se3 import make_pose, nearest_rotation, se3_inv, so3_exp, transform_points
from dynslam_lab.slam.optimize import (
    Observations,
    local_bundle_adjustment,
    observation_chi2,
    optimize_pose,
)

CAM = CAMERA_PRESETS["default"]
BF = 40.0


def _points(rng, n):
    return np.c_[rng.uniform(-1.5, 1.5, n), rng.uniform(-1.0, 1.0, n), rng.uniform(1.5, 4.0, n)]


def test_optimize_pose_recovers_pose_and_flags_outliers():
    rng = np.random.default_rng(0)
    X = _points(rng, 400)
    T_true = make_pose(so3_exp([0.04, -0.06, 0.02]), [0.12, -0.05, 0.09])
    uv, z = CAM.project(transform_points(T_true, X))
    uv = uv + rng.normal(0, 0.5, uv.shape)
    bad = np.zeros(400, bool)
    bad[rng.choice(400, 60, replace=False)] = True
    uv[bad] += rng.uniform(20, 60, (60, 2)) * rng.choice([-1, 1], (60, 2))
    z = np.where(rng.random(400) < 0.3, np.nan, z)  # some keypoints without depth
    obs = Observations.from_keypoints(uv, z, rng.integers(0, 3, 400), BF, 1.2)
    T, out = optimize_pose(np.eye(4), X, obs, CAM, BF)
    assert np.abs(T[:3, 3] - T_true[:3, 3]).max() < 5e-3
    assert np.degrees(np.linalg.norm(so3_exp(np.zeros(3)) - T[:3, :3] @ T_true[:3, :3].T)) < 0.2
    assert out[bad].all() and out[~bad].mean() < 0.1
    chi2, flagged = observation_chi2(transform_points(T, X), obs, CAM, BF)
    assert np.array_equal(flagged, out)


def test_optimize_pose_keeps_rotation_orthonormal_from_drifted_start():
    rng = np.random.default_rng(1)
    X = _points(rng, 200)
    T_true = make_pose(so3_exp([0.0, 0.1, 0.0]), [0.2, 0.0, 0.0])
    uv, z = CAM.project(transform_points(T_true, X))
    obs = Observations.from_keypoints(uv, z, np.zeros(200), BF, 1.2)
    T0 = T_true.copy()
    T0[:3, :3] *= 1.01  # a product of poses that left SO(3)
    T, _ = optimize_pose(T0, X, obs, CAM, BF)
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
    assert np.abs(T - T_true).max() < 1e-6
    R = nearest_rotation(np.diag([1.02, 0.98, 1.0]) @ so3_exp([0.3, 0.1, 0.0]))
    assert np.isclose(np.linalg.det(R), 1.0) and np.allclose(R @ R.T, np.eye(3))


def _ba_problem(rng, n_cams=5, n_pts=500):
    X = _points(rng, n_pts)
    poses = {0: np.eye(4)}
    for k in range(1, n_cams):
        poses[k] = make_pose(so3_exp(rng.normal(0, 0.03, 3)), rng.normal(0, 0.1, 3))
    oc, op, uvs, zs = [], [], [], []
    for k, T in poses.items():
        uv, z = CAM.project(transform_points(T, X))
        vis = CAM.in_image(uv) & (rng.random(n_pts) < 0.8)
        oc.append(np.full(vis.sum(), k))
        op.append(np.flatnonzero(vis))
        uvs.append(uv[vis] + rng.normal(0, 0.3, (vis.sum(), 2)))
        zs.append(z[vis])
    oc, op, uv, z = map(np.concatenate, (oc, op, uvs, zs))
    return X, poses, oc, op, Observations.from_keypoints(uv, z, np.zeros(len(uv)), BF, 1.2)


def test_local_ba_reduces_pose_and_point_errors():
    rng = np.random.default_rng(2)
    X, poses, oc, op, obs = _ba_problem(rng)
    init = {k: (make_pose(so3_exp(rng.normal(0, 0.003, 3)), rng.normal(0, 0.01, 3)) @ T if k else T) for k, T in poses.items()}
    Xn = X + rng.normal(0, 0.01, X.shape)
    res = local_bundle_adjustment(init, {0}, Xn, oc, op, obs, CAM, BF, max_nfev=10)
    assert res.cost_after < 0.05 * res.cost_before
    err_before = max(np.abs(init[k] - poses[k])[:3, 3].max() for k in poses)
    err_after = max(np.abs(res.T_c_w[k] - poses[k])[:3, 3].max() for k in poses)
    assert err_after < 0.2 * err_before and err_after < 3e-3
    # points: along the ray the depth residual (bf / z^2 px per metre) is weak, across it strong
    def px_err(P):
        return np.median(np.linalg.norm(CAM.project(P)[0] - CAM.project(X)[0], axis=1))

    assert px_err(res.points) < 0.3 * px_err(Xn)
    assert np.array_equal(res.T_c_w[0], np.eye(4))  # the fixed keyframe does not move


def test_local_ba_jacobian_matches_finite_differences(monkeypatch):
    import dynslam_lab.slam.optimize as opt

    rng = np.random.default_rng(3)
    X, poses, oc, op, obs = _ba_problem(rng, n_cams=3, n_pts=40)
    seen = {}
    real = opt.least_squares

    def spy(fun, x0, jac, **kw):
        if "J" not in seen:
            x = x0 + rng.normal(0, 1e-3, x0.shape)
            J = jac(x).toarray()
            eps = 1e-6
            num = np.stack([(fun(x + e) - fun(x - e)) / (2 * eps) for e in np.eye(len(x)) * eps], axis=1)
            seen["J"] = (J, num)
        return real(fun, x0, jac=jac, **kw)

    monkeypatch.setattr(opt, "least_squares", spy)
    local_bundle_adjustment(poses, {0}, X, oc, op, obs, CAM, BF, max_nfev=2)
    J, num = seen["J"]
    assert np.abs(J - num).max() < 1e-4 * max(1.0, np.abs(num).max())


def test_bad_input():
    with pytest.raises(ValueError, match="observations"):
        optimize_pose(np.eye(4), np.zeros((5, 3)), Observations(np.zeros((4, 2)), np.zeros(4), np.ones(4)), CAM, BF)
    assert se3_inv(np.eye(4)).shape == (4, 4)
