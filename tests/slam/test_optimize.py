"""Pose-only optimisation and bundle adjustment against ground-truth poses of generated scenes, and
against scipy's ``least_squares`` on the same costs (same minimum)."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.geometry.se3 import make_pose, nearest_rotation, se3_inv, so3_exp, so3_log, transform_points
from dynslam_lab.slam import optimize as opt
from dynslam_lab.slam.optimize import (
    HUBER_DELTA2,
    Observations,
    huber_cost,
    local_bundle_adjustment,
    observation_chi2,
    optimize_pose,
    project_stereo,
)
from dynslam_lab.threads import blas_single_thread
from dynslam_lab.slam.scipy_reference import bundle_adjustment_least_squares, pose_only_least_squares

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
    res = local_bundle_adjustment(init, {0}, Xn, oc, op, obs, CAM, BF, max_iterations=10)
    assert res.cost_after < 0.05 * res.cost_before
    err_before = max(np.abs(init[k] - poses[k])[:3, 3].max() for k in poses)
    err_after = max(np.abs(res.T_c_w[k] - poses[k])[:3, 3].max() for k in poses)
    assert err_after < 0.2 * err_before and err_after < 3e-3
    # points: along the ray the depth residual (bf / z^2 px per metre) is weak, across it strong
    def px_err(P):
        return np.median(np.linalg.norm(CAM.project(P)[0] - CAM.project(X)[0], axis=1))

    assert px_err(res.points) < 0.3 * px_err(Xn)
    assert np.array_equal(res.T_c_w[0], np.eye(4))  # the fixed keyframe does not move


def test_bundle_adjustment_with_every_pose_fixed_refines_the_points_alone():
    """Every keyframe held (structure only, no free camera): the points move to the truth, no pose moves."""
    rng = np.random.default_rng(5)
    X, poses, oc, op, obs = _ba_problem(rng)
    Xn = X + rng.normal(0, 0.01, X.shape)
    res = local_bundle_adjustment(poses, set(poses), Xn, oc, op, obs, CAM, BF, max_iterations=10)
    assert all(np.allclose(res.T_c_w[k], poses[k], rtol=0, atol=1e-12) for k in poses)
    err = lambda P: np.median(np.linalg.norm(CAM.project(P)[0] - CAM.project(X)[0], axis=1))  # noqa: E731
    assert err(res.points) < 0.2 * err(Xn) and res.cost_after < 0.05 * res.cost_before


def _noisy_pose_problem(rng, n=300):
    X = _points(rng, n)
    T_true = make_pose(so3_exp([0.04, -0.06, 0.02]), [0.12, -0.05, 0.09])
    uv, z = CAM.project(transform_points(T_true, X))
    uv = uv + rng.normal(0, 1.0, uv.shape)
    bad = rng.random(n) < 0.1
    uv[bad] += rng.uniform(5, 30, (bad.sum(), 2))  # outliers a few sigma out: the kernel matters
    z = np.where(rng.random(n) < 0.3, np.nan, z)
    obs = Observations.from_keypoints(uv, z, rng.integers(0, 3, n), BF, 1.2)
    T0 = make_pose(so3_exp([0.01, 0.0, 0.01]), [0.02, 0.0, 0.0]) @ T_true
    return X, obs, T0


@pytest.mark.parametrize("robust", [True, False])
def test_pose_only_reaches_the_scipy_minimum(robust):
    """Our Levenberg-Marquardt and scipy's least_squares (its own Huber loss) on the same cost."""
    X, obs, T0 = _noisy_pose_problem(np.random.default_rng(4))
    delta2 = HUBER_DELTA2 if robust else None
    R, t, cost = opt._lm_pose(T0[:3, :3], T0[:3, 3], X, obs, CAM, BF, delta2, 50)
    T_ref, cost_ref = pose_only_least_squares(T0, X, obs, CAM, BF, robust=robust)
    assert abs(cost - cost_ref) <= 1e-6 * cost_ref
    assert np.abs(R - T_ref[:3, :3]).max() < 1e-5 and np.abs(t - T_ref[:3, 3]).max() < 1e-5
    chi2 = np.sum(opt._residuals(X @ R.T + t, obs, CAM, BF)[0] ** 2, axis=1)
    assert np.isclose(huber_cost(chi2, delta2).sum(), cost)


@pytest.mark.parametrize("robust", [True, False])
def test_bundle_adjustment_reaches_the_scipy_minimum(robust):
    rng = np.random.default_rng(5)
    X, poses, oc, op, obs = _ba_problem(rng, n_cams=5, n_pts=80)
    obs.uv[rng.random(len(oc)) < 0.05] += 12.0  # a few outliers
    init = {k: (make_pose(so3_exp(rng.normal(0, 0.003, 3)), rng.normal(0, 0.01, 3)) @ T if k else T) for k, T in poses.items()}
    Xn = X + rng.normal(0, 0.01, X.shape)
    fixed = {0, 4}
    delta2 = HUBER_DELTA2 if robust else None
    pb, ids = opt._ba_problem(init, fixed, Xn, oc, op, obs, CAM, BF)
    with blas_single_thread():
        opt._lm_ba(pb, np.ones(len(oc)), delta2, 100)
        T_ref, X_ref, cost_ref = bundle_adjustment_least_squares(init, fixed, Xn, oc, op, obs, CAM, BF,
                                                                 robust=robust, max_nfev=200)
    cost = pb.cost(np.ones(len(oc)), delta2)
    assert cost <= cost_ref * (1 + 1e-6)
    assert abs(cost - cost_ref) <= 1e-5 * cost_ref
    for i, k in enumerate(ids):
        assert np.abs(pb.R[i] - T_ref[k][:3, :3]).max() < 1e-4 and np.abs(pb.t[i] - T_ref[k][:3, 3]).max() < 1e-4
    # points: a point seen once without depth may slide along its ray; compare every observation's
    # predicted pixels instead
    ref = pb.camera_points(np.stack([T_ref[k][:3, :3] for k in ids]), np.stack([T_ref[k][:3, 3] for k in ids]), X_ref)
    pred_ref = project_stereo(ref[1], CAM, BF)[:, :2]
    assert np.abs(project_stereo(pb.camera_points()[1], CAM, BF)[:, :2] - pred_ref).max() < 0.02  # pixels


def test_normal_equations_match_a_finite_difference_jacobian():
    """The blocks of H = J^T W J and g = J^T W e against a numerical Jacobian of the residuals."""
    rng = np.random.default_rng(3)
    X, poses, oc, op, obs = _ba_problem(rng, n_cams=3, n_pts=30)
    pb, ids = opt._ba_problem(poses, {0}, X + rng.normal(0, 1e-3, X.shape), oc, op, obs, CAM, BF)
    ne = opt._ba_normal_equations(pb, np.ones(len(oc)), None)
    F, P = len(pb.free_cam), len(pb.X)

    def residuals(x):
        R, t, Xs = pb.moved(x[: 6 * F].reshape(F, 6), x[6 * F :].reshape(P, 3))
        return opt._residuals(pb.camera_points(R, t, Xs)[1], obs, CAM, BF)[0].ravel()

    eps = 1e-6
    x0 = np.zeros(6 * F + 3 * P)
    J = np.stack([(residuals(x0 + e) - residuals(x0 - e)) / (2 * eps) for e in np.eye(len(x0)) * eps], axis=1)
    H, g = J.T @ J, J.T @ residuals(x0)
    scale = np.abs(H).max()
    for c in range(F):
        assert np.abs(ne.H_cc[c] - H[6 * c : 6 * c + 6, 6 * c : 6 * c + 6]).max() < 1e-5 * scale
        assert np.abs(ne.g_c[c] - g[6 * c : 6 * c + 6]).max() < 1e-5 * np.abs(g).max()
    Hpp = H[6 * F :, 6 * F :]
    for p in range(P):
        assert np.abs(ne.H_pp[p] - Hpp[3 * p : 3 * p + 3, 3 * p : 3 * p + 3]).max() < 1e-5 * scale
    for k, (s, p) in enumerate(zip(ne.s, ne.p)):
        assert np.abs(ne.H_cp[k] - H[6 * s : 6 * s + 6, 6 * F + 3 * p : 6 * F + 3 * p + 3]).max() < 1e-5 * scale


def test_schur_step_equals_the_full_normal_equations():
    """Eliminating the points gives the step of the full damped system, dense and sparse paths."""
    rng = np.random.default_rng(6)
    X, poses, oc, op, obs = _ba_problem(rng, n_cams=4, n_pts=60)
    pb, _ = opt._ba_problem(poses, {0}, X + rng.normal(0, 1e-2, X.shape), oc, op, obs, CAM, BF)
    ne = opt._ba_normal_equations(pb, np.ones(len(oc)), HUBER_DELTA2)
    F, P = len(ne.H_cc), len(ne.H_pp)
    H = np.zeros((6 * F + 3 * P,) * 2)
    for c in range(F):
        H[6 * c : 6 * c + 6, 6 * c : 6 * c + 6] = opt._damped(ne.H_cc[c], 0.1)
    for p in range(P):
        H[6 * F + 3 * p : 6 * F + 3 * p + 3, 6 * F + 3 * p : 6 * F + 3 * p + 3] = opt._damped(ne.H_pp[p], 0.1)
    for k, (s, p) in enumerate(zip(ne.s, ne.p)):
        H[6 * s : 6 * s + 6, 6 * F + 3 * p : 6 * F + 3 * p + 3] += ne.H_cp[k]
        H[6 * F + 3 * p : 6 * F + 3 * p + 3, 6 * s : 6 * s + 6] += ne.H_cp[k].T
    full = np.linalg.solve(H, -np.concatenate([ne.g_c.ravel(), ne.g_p.ravel()]))
    for dense_max in (opt._DENSE_SCHUR_MAX, 0):
        opt_max, opt._DENSE_SCHUR_MAX = opt._DENSE_SCHUR_MAX, dense_max
        try:
            dc, dp = opt._schur_step(ne, 0.1)
        finally:
            opt._DENSE_SCHUR_MAX = opt_max
        np.testing.assert_allclose(np.concatenate([dc.ravel(), dp.ravel()]), full, rtol=1e-6, atol=1e-10)


def test_bad_input():
    with pytest.raises(ValueError, match="observations"):
        optimize_pose(np.eye(4), np.zeros((5, 3)), Observations(np.zeros((4, 2)), np.zeros(4), np.ones(4)), CAM, BF)
    assert se3_inv(np.eye(4)).shape == (4, 4)


def _nguyen(z):
    return 0.0012 + 0.0019 * (z - 0.4) ** 2  # Nguyen et al. 2012, Kinect v1 axial noise (m)


def test_metric_depth_row_jacobian_matches_finite_differences():
    """The pose columns of the metric depth row against a numerical derivative of the residuals."""
    rng = np.random.default_rng(7)
    X = _points(rng, 40)
    T = make_pose(so3_exp([0.02, -0.03, 0.01]), [0.05, 0.02, -0.04])
    uv, z = CAM.project(transform_points(T, X))
    z = np.where(rng.random(40) < 0.25, np.nan, z + rng.normal(0, 0.01, 40))
    obs = Observations.from_keypoints(uv + rng.normal(0, 0.5, uv.shape), z, rng.integers(0, 3, 40), BF, 1.2,
                                      z_sigma=np.where(np.isfinite(z), _nguyen(np.nan_to_num(z)), np.nan))
    R, t = T[:3, :3], T[:3, 3]

    def residuals(dx):
        Rn, tn = opt._rodrigues(dx[:3]) @ R, t + dx[3:]
        return opt._pose_residuals(X @ Rn.T + tn, obs, CAM, BF)[0].ravel()

    eps = 1e-6
    J_num = np.stack([(residuals(e) - residuals(-e)) / (2 * eps) for e in np.eye(6) * eps], axis=1)
    J = opt._pose_columns(opt._pose_point_jacobian(X @ R.T + t, obs, CAM, BF), X @ R.T).reshape(-1, 6)
    np.testing.assert_allclose(J, J_num, atol=1e-4 * np.abs(J_num).max())
    # the depth row by hand: (z_c - z) / sigma_z, and no u_R left in it
    r = opt._pose_residuals(X @ R.T + t, obs, CAM, BF)[0]
    d = np.isfinite(z)
    np.testing.assert_allclose(r[d, 2], ((X @ R.T + t)[d, 2] - z[d]) / _nguyen(z[d]))
    assert np.all(r[~d, 2] == 0)


@pytest.mark.parametrize("metric", [False, True])
def test_pose_terms_match_the_reference_residuals_and_jacobian(metric):
    """The LM loop's precomputed terms (``_PoseTerms``) give the residuals and the Jacobian of
    ``_pose_residuals`` / ``_pose_point_jacobian`` (u_R row and metric depth row, keypoints without
    depth among them), and ``_rotation_step`` is ``_rodrigues`` (OpenCV's Rodrigues checks that one)."""
    rng = np.random.default_rng(11)
    X = _points(rng, 60)
    T = make_pose(so3_exp([0.03, 0.01, -0.02]), [0.04, -0.03, 0.02])
    uv, z = CAM.project(transform_points(T, X))
    z = np.where(rng.random(60) < 0.3, np.nan, z + rng.normal(0, 0.01, 60))
    zs = np.where(np.isfinite(z), _nguyen(np.nan_to_num(z)), np.nan) if metric else None
    obs = Observations.from_keypoints(uv + rng.normal(0, 0.5, uv.shape), z, rng.integers(0, 4, 60), BF, 1.2, z_sigma=zs)
    R, t = T[:3, :3], T[:3, 3]
    X_c, RX = X @ R.T + t, X @ R.T
    terms = opt._PoseTerms(X, obs, CAM, BF)
    np.testing.assert_allclose(terms.residuals(X_c), opt._pose_residuals(X_c, obs, CAM, BF)[0], rtol=1e-12, atol=1e-12)
    J_ref = opt._pose_columns(opt._pose_point_jacobian(X_c, obs, CAM, BF), RX).reshape(-1, 6)
    np.testing.assert_allclose(terms.jacobian(X_c, RX), J_ref, rtol=1e-12, atol=1e-12)
    keep = rng.random(60) < 0.5
    np.testing.assert_allclose(terms.subset(keep).residuals(X_c[keep]), opt._pose_residuals(X_c[keep], obs.subset(keep), CAM, BF)[0],
                               rtol=1e-12, atol=1e-12)
    for w in ([0.0, 0.0, 0.0], [1e-9, -2e-9, 3e-10], [0.3, -0.2, 0.1], [2.0, 1.0, -0.5]):
        np.testing.assert_allclose(opt._rotation_step(np.array(w)), opt._rodrigues(np.array(w)), atol=1e-14)


def test_metric_depth_row_resolves_rotation_against_translation_on_a_wall():
    """A camera 3 m before a flat wall (the loop scenes' failure): pixels alone barely tell a small yaw
    from a sideways step; with Kinect-like depth noise the metric depth row recovers the pose closer to
    the truth than ORB-SLAM2's u_R row (bf = 40), over 20 noise draws."""
    rng = np.random.default_rng(8)
    n = 250
    X = np.c_[rng.uniform(-1.4, 1.4, n), rng.uniform(-1.0, 1.0, n), np.full(n, 3.0)]
    errs = {"stereo": [], "metric": []}
    for _ in range(20):
        T_true = make_pose(so3_exp(rng.normal(0, 0.02, 3)), rng.normal(0, 0.05, 3))
        uv, z = CAM.project(transform_points(T_true, X))
        uv = uv + rng.normal(0, 1.0, uv.shape)
        zm = z + rng.normal(0, 1.0, n) * _nguyen(z)
        for kind in errs:
            obs = Observations.from_keypoints(uv, zm, np.zeros(n), BF, 1.2,
                                              z_sigma=_nguyen(zm) if kind == "metric" else None)
            T, _ = optimize_pose(np.eye(4), X, obs, CAM, BF)
            errs[kind].append(np.linalg.norm(se3_inv(T)[:3, 3] - se3_inv(T_true)[:3, 3]))
    stereo, metric = np.sqrt(np.mean(np.square(errs["stereo"]))), np.sqrt(np.mean(np.square(errs["metric"])))
    assert metric < 0.6 * stereo and metric < 0.006, (metric, stereo)


@pytest.mark.parametrize("spread", ["clustered", "spread"])
def test_pose_uncertainty_matches_the_spread_of_motion_only_ba_under_pixel_noise(spread):
    """``pose_uncertainty`` (the inverse Gauss-Newton information of motion-only BA) against a Monte Carlo
    of ``optimize_pose`` itself: 1-pixel noise on ``(u, v, u_R)`` of points clustered in a 60 x 60 px patch
    at 3 m (a poster on a plain wall: a lateral step and a rotation explain them alike) or spread over the
    image; the largest standard deviation of the estimated camera centre and orientation agree within 25 %,
    and the cluster's are several times the spread set's."""
    rng = np.random.default_rng(3)
    T_true = make_pose(so3_exp([0.02, -0.03, 0.01]), [0.1, -0.05, 0.2])
    n = 150
    if spread == "clustered":
        uv = rng.uniform([300, 200], [360, 260], (n, 2))
        z = rng.uniform(2.9, 3.1, n)
    else:
        uv = rng.uniform([20, 20], [620, 460], (n, 2))
        z = rng.uniform(1.5, 4.0, n)
    X_c = np.c_[(uv[:, 0] - CAM.cx) / CAM.fx * z, (uv[:, 1] - CAM.cy) / CAM.fy * z, z]
    X_w = transform_points(se3_inv(T_true), X_c)
    clean = project_stereo(X_c, CAM, 400.0)
    s_c, s_r = opt.pose_uncertainty(T_true, X_w, Observations(clean[:, :2], clean[:, 2], np.ones(n)), CAM, 400.0)
    centres, rotations = [], []
    for _ in range(300):
        meas = clean + rng.normal(0.0, 1.0, clean.shape)
        T, _ = optimize_pose(T_true, X_w, Observations(meas[:, :2], meas[:, 2], np.ones(n)), CAM, 400.0)
        centres.append(se3_inv(T)[:3, 3])
        rotations.append(so3_log(T[:3, :3] @ T_true[:3, :3].T))
    emp_c = np.sqrt(np.linalg.eigvalsh(np.cov(np.array(centres).T))[-1])
    emp_r = np.degrees(np.sqrt(np.linalg.eigvalsh(np.cov(np.array(rotations).T))[-1]))
    assert 0.75 < s_c / emp_c < 1.25 and 0.75 < s_r / emp_r < 1.25, (s_c, emp_c, s_r, emp_r)
    if spread == "clustered":
        assert s_c > 5e-3 and s_r > 0.1  # what triggers the joint refinement (TrackingConfig.joint_position_sigma)
    else:
        assert s_c < 2e-3 and s_r < 0.05


def test_gauss_newton_pose_reaches_the_scipy_minimum_with_one_evaluation_a_step(monkeypatch):
    """``damped=False`` (the joint refinement's solver): plain Gauss-Newton steps, each taken, the pose not
    evaluated after the last. Without outliers and from a pose a few centimetres off, a few steps reach
    scipy's least-squares minimum of the same (non-robust) cost, and ``k`` steps cost ``k`` evaluations of
    the cost (LM costs at least one more per step, and more when it damps)."""
    rng = np.random.default_rng(7)
    X = _points(rng, 300)
    T_true = make_pose(so3_exp([0.04, -0.06, 0.02]), [0.12, -0.05, 0.09])
    uv, z = CAM.project(transform_points(T_true, X))
    uv = uv + rng.normal(0, 1.0, uv.shape)
    z = np.where(rng.random(300) < 0.3, np.nan, z)
    obs = Observations.from_keypoints(uv, z, rng.integers(0, 3, 300), BF, 1.2)
    T0 = make_pose(so3_exp([0.01, 0.0, 0.01]), [0.02, 0.0, 0.0]) @ T_true
    T_ref, _ = pose_only_least_squares(T0, X, obs, CAM, BF, robust=False)
    calls = []
    real = opt._evaluate_pose
    monkeypatch.setattr(opt, "_evaluate_pose", lambda *a, **k: calls.append(1) or real(*a, **k))
    T, _ = optimize_pose(T0, X, obs, CAM, BF, rounds=1, max_iterations=6, damped=False)
    assert np.abs(T[:3, :3] - T_ref[:3, :3]).max() < 1e-7 and np.abs(T[:3, 3] - T_ref[:3, 3]).max() < 1e-7
    calls.clear()
    T2, _ = optimize_pose(T0, X, obs, CAM, BF, rounds=1, max_iterations=2, damped=False)
    assert len(calls) == 2
    assert np.abs(T2[:3, 3] - T_ref[:3, 3]).max() < 1e-4  # two steps from 2 cm: within 0.1 mm
    calls.clear()
    optimize_pose(T0, X, obs, CAM, BF, rounds=1, max_iterations=2)
    assert len(calls) >= 3


@pytest.mark.parametrize("spread", ["band", "spread"])
def test_pose_step_mahalanobis_is_the_cost_a_small_step_adds(spread):
    """``pose_step_mahalanobis`` (``xi^T H xi``) against the cost itself: observations made exactly at
    ``T_from`` (``cv2.projectPoints`` for the pixels, ``u - bf / z`` for the depth row, one pixel a unit), the
    summed squares of their residuals at a pose a few millimetres and hundredths of a degree away agree
    within 3 % for steps in random directions."""
    import cv2

    rng = np.random.default_rng(11)
    n = 120
    if spread == "band":  # far corners along a wall's foot: the plain room's keypoints
        uv = np.c_[rng.uniform(150, 500, n), rng.uniform(300, 330, n)]
        z = rng.uniform(3.8, 4.5, n)
    else:
        uv = rng.uniform([20, 20], [620, 460], (n, 2))
        z = rng.uniform(1.5, 4.0, n)
    T_from = make_pose(so3_exp([0.02, -0.03, 0.01]), [0.1, -0.05, 0.2])
    X_c = np.c_[(uv[:, 0] - CAM.cx) / CAM.fx * z, (uv[:, 1] - CAM.cy) / CAM.fy * z, z]
    X_w = transform_points(se3_inv(T_from), X_c)
    obs = Observations(uv, uv[:, 0] - 400.0 / z, np.ones(n))
    K = np.array([[CAM.fx, 0, CAM.cx], [0, CAM.fy, CAM.cy], [0, 0, 1.0]])
    for _ in range(5):
        omega, tau = rng.normal(0, 3e-4, 3), rng.normal(0, 3e-3, 3)
        T_to = make_pose(so3_exp(omega) @ T_from[:3, :3], T_from[:3, 3] + tau)
        px, _ = cv2.projectPoints(X_w, cv2.Rodrigues(T_to[:3, :3])[0], T_to[:3, 3], K, None)
        z_to = transform_points(T_to, X_w)[:, 2]
        px = px.reshape(-1, 2)
        cost = float(np.sum((px - uv) ** 2) + np.sum((px[:, 0] - 400.0 / z_to - obs.ur) ** 2))
        d2 = opt.pose_step_mahalanobis(T_from, T_to, X_w, obs, CAM, 400.0)
        assert d2 == pytest.approx(cost, rel=0.03), (d2, cost)


def test_a_band_of_far_points_lets_a_centimetre_go_where_spread_points_do_not():
    """The joint refinement's gate (``TrackingConfig.joint_gate_chi2``): a step of 2 cm sideways with the
    rotation that keeps the view's centre in place (the ambiguity of far points) is cheap for corners in a
    band at ~4 m (``d^2`` below the chi^2 95 % quantile of 6 dof, 12.6) and far outside for corners spread
    over the image at 1.5-4 m."""
    rng = np.random.default_rng(5)
    n = 120
    T_from = np.eye(4)
    step = make_pose(so3_exp([0.0, 0.02 / 4.1, 0.0]), [-0.02, 0.0, 0.0])  # x slides, the ray at 4.1 m held
    d2 = {}
    for name, uv, z in (("band", np.c_[rng.uniform(150, 500, n), rng.uniform(300, 330, n)], rng.uniform(3.8, 4.5, n)),
                        ("spread", rng.uniform([20, 20], [620, 460], (n, 2)), rng.uniform(1.5, 4.0, n))):
        X = np.c_[(uv[:, 0] - CAM.cx) / CAM.fx * z, (uv[:, 1] - CAM.cy) / CAM.fy * z, z]
        d2[name] = opt.pose_step_mahalanobis(T_from, step, X, Observations(uv, uv[:, 0] - 400.0 / z, np.ones(n)), CAM, 400.0)
    assert d2["band"] < 12.6 < 10 * 12.6 < d2["spread"], d2
