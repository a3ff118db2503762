"""Solver speed on the SLAM core's three problems: motion-only BA, local BA, pose graph.

Each generated problem (sizes of a real local BA on the synthetic walking sequence: 7 free and 10
fixed keyframes, ~1000 points, ~3500 observations; a pose with 500 matches; a loop of 60 keyframes)
is solved to convergence (one robust round) by

* ``ours``: the Levenberg-Marquardt of ``slam/optimize.py`` / ``slam/pose_graph.py`` (analytic
  Jacobians, Schur complement, block-sparse normal equations);
* ``scipy``: ``scipy.optimize.least_squares`` on the same cost (``slam/scipy_reference.py``);
* ``gtsam``: GTSAM's Levenberg-Marquardt with its stereo factor (``GenericStereoFactor3D``, the
  same ``(u_L, u_R, v)`` measurement) and Huber noise model, when ``gtsam`` is installed.

The table gives milliseconds (median of ``--repeat`` runs, BLAS on one thread) and the final cost
``sum rho(chi^2)`` evaluated by ``slam.optimize`` for every solver (pose graph: ``sum ||r||^2``).
Usage::

    python benchmarks/solver_speed.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.geometry.se3 import make_pose, relative_pose, se3_inv, so3_exp, transform_points
from dynslam_lab.slam import optimize as opt
from dynslam_lab.slam.pose_graph import PoseGraphConfig, edge_residuals, optimize_pose_graph
from dynslam_lab.threads import blas_single_thread
from dynslam_lab.slam.scipy_reference import (
    bundle_adjustment_least_squares,
    pose_graph_least_squares,
    pose_only_least_squares,
)

CAM = CAMERA_PRESETS["default"]
BF = 40.0


def _points(rng, n):
    return np.c_[rng.uniform(-1.5, 1.5, n), rng.uniform(-1.0, 1.0, n), rng.uniform(1.5, 4.0, n)]


def _observe(rng, T_c_w, X, keep=1.0):
    uv, z = CAM.project(transform_points(T_c_w, X))
    vis = np.flatnonzero(CAM.in_image(uv) & (rng.random(len(X)) < keep))
    uv = uv[vis] + rng.normal(0, 1.0, (len(vis), 2))
    bad = rng.random(len(vis)) < 0.05
    uv[bad] += rng.uniform(5, 30, (bad.sum(), 2))
    z = np.where(rng.random(len(vis)) < 0.25, np.nan, z[vis])
    return vis, uv, z


def pose_problem(rng):
    X = _points(rng, 500)
    T = make_pose(so3_exp([0.04, -0.06, 0.02]), [0.12, -0.05, 0.09])
    vis, uv, z = _observe(rng, T, X)
    obs = opt.Observations.from_keypoints(uv, z, rng.integers(0, 4, len(vis)), BF, 1.2)
    T0 = make_pose(so3_exp(rng.normal(0, 0.01, 3)), rng.normal(0, 0.02, 3)) @ T
    return T0, X[vis], obs


def ba_problem(rng, n_free=7, n_fixed=10, n_pts=1000):
    X = _points(rng, n_pts)
    poses = {k: make_pose(so3_exp(rng.normal(0, 0.03, 3)), rng.normal(0, 0.1, 3)) for k in range(n_free + n_fixed)}
    oc, op, uvs, zs = [], [], [], []
    for k, T in poses.items():
        vis, uv, z = _observe(rng, T, X, keep=0.22)
        oc.append(np.full(len(vis), k))
        op.append(vis)
        uvs.append(uv)
        zs.append(z)
    oc, op, uv, z = map(np.concatenate, (oc, op, uvs, zs))
    obs = opt.Observations.from_keypoints(uv, z, rng.integers(0, 4, len(uv)), BF, 1.2)
    init = {k: make_pose(so3_exp(rng.normal(0, 0.002, 3)), rng.normal(0, 0.005, 3)) @ T for k, T in poses.items()}
    fixed = set(range(n_free, n_free + n_fixed))
    return init, fixed, X + rng.normal(0, 0.005, X.shape), oc, op, obs


def pose_graph_problem(rng, n=60):
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    T = np.stack([make_pose(so3_exp([0, -t, 0]), [2 * np.cos(t), 0, 2 * np.sin(t)]) for t in a])
    e = np.concatenate([np.stack([np.arange(n - 1), np.arange(1, n)], 1), [[n - 1, 0]],
                        np.stack([np.arange(0, n - 5, 3), np.arange(5, n, 3)], 1)])
    Z = relative_pose(T[e[:, 0]], T[e[:, 1]])
    Z = np.stack([make_pose(so3_exp(rng.normal(0, 0.01, 3)), rng.normal(0, 0.02, 3)) @ z for z in Z])
    T0 = T.copy()
    for k in range(1, n):  # odometry drift
        T0[k] = T0[k - 1] @ Z[k - 1]
    return T0, e, Z


def ba_cost(poses, X, oc, op, obs):
    pb, _ = opt._ba_problem(poses, set(), X, oc, op, obs, CAM, BF)
    return pb.cost(np.ones(len(oc)), opt.HUBER_DELTA2)


def pose_cost(T, X, obs):
    return opt._evaluate_pose(T[:3, :3], T[:3, 3], opt._PoseTerms(X, obs, CAM, BF), opt.HUBER_DELTA2)[0]


# ------------------------------------------------------------------------------ GTSAM (optional)
def _gtsam():
    try:  # optional heavy dependency: the benchmark runs without it
        import gtsam
    except ImportError:
        return None
    return gtsam


def _gtsam_pose(T_c_w):
    gtsam = _gtsam()
    T_w_c = se3_inv(T_c_w)
    return gtsam.Pose3(gtsam.Rot3(T_w_c[:3, :3]), T_w_c[:3, 3])


def gtsam_ba(poses, fixed, X, oc, op, obs, free_points=True):
    """Bundle adjustment (or, with one pose and fixed points, motion-only BA) in GTSAM: stereo factors
    ``(u_L, u_R, v)`` with a Huber noise model (per observation sigma); observations without depth get
    a 2D projection factor."""
    gtsam = _gtsam()
    K = gtsam.Cal3_S2Stereo(CAM.fx, CAM.fy, 0.0, CAM.cx, CAM.cy, BF / CAM.fx)
    K2 = gtsam.Cal3_S2(CAM.fx, CAM.fy, 0.0, CAM.cx, CAM.cy)
    huber = gtsam.noiseModel.mEstimator.Huber.Create(np.sqrt(opt.HUBER_DELTA2))
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    C, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L
    for k, T in poses.items():
        values.insert(C(k), _gtsam_pose(T))
        if k in fixed:
            graph.add(gtsam.NonlinearEqualityPose3(C(k), _gtsam_pose(T)))
    for p in np.unique(op):
        values.insert(L(int(p)), gtsam.Point3(*X[p]))
        if not free_points:
            graph.add(gtsam.NonlinearEqualityPoint3(L(int(p)), gtsam.Point3(*X[p])))
    for i, (k, p) in enumerate(zip(oc, op)):
        s = float(obs.sigma[i])
        if np.isfinite(obs.ur[i]):
            noise = gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Isotropic.Sigma(3, s))
            m = gtsam.StereoPoint2(obs.uv[i, 0], obs.ur[i], obs.uv[i, 1])
            graph.add(gtsam.GenericStereoFactor3D(m, noise, C(int(k)), L(int(p)), K))
        else:
            noise = gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Isotropic.Sigma(2, s))
            graph.add(gtsam.GenericProjectionFactorCal3_S2(gtsam.Point2(*obs.uv[i]), noise, C(int(k)), L(int(p)), K2))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    params.setRelativeErrorTol(1e-6)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    out = {}
    for k in poses:
        out[k] = se3_inv(result.atPose3(C(k)).matrix())
    Xo = X.copy()
    for p in np.unique(op):
        Xo[p] = result.atPoint3(L(int(p)))
    return out, Xo


def gtsam_pose_graph(T0, e, Z):
    gtsam = _gtsam()
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    noise = gtsam.noiseModel.Unit.Create(6)
    for k, T in enumerate(T0):
        values.insert(k, gtsam.Pose3(T))
    graph.add(gtsam.NonlinearEqualityPose3(0, gtsam.Pose3(T0[0])))
    for (i, j), z in zip(e, Z):
        graph.add(gtsam.BetweenFactorPose3(int(i), int(j), gtsam.Pose3(z), noise))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    params.setRelativeErrorTol(1e-10)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    return np.stack([result.atPose3(k).matrix() for k in range(len(T0))])


# ------------------------------------------------------------------------------------- timing
def timed(fn, repeat):
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(1e3 * (time.perf_counter() - t0))
    return float(np.median(times)), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="runs per solver (median reported)")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    rows = []
    with blas_single_thread():
        T0, X, obs = pose_problem(rng)
        ms, (R, t, _) = timed(lambda: opt._lm_pose(T0[:3, :3], T0[:3, 3], X, obs, CAM, BF, opt.HUBER_DELTA2, 50), args.repeat)
        rows.append(("pose only (500 obs)", "ours", ms, pose_cost(make_pose(R, t), X, obs)))
        ms, (T, _) = timed(lambda: pose_only_least_squares(T0, X, obs, CAM, BF, robust=True, max_nfev=100), args.repeat)
        rows.append(("pose only (500 obs)", "scipy", ms, pose_cost(T, X, obs)))
        if _gtsam() is not None:
            ms, (P, _) = timed(lambda: gtsam_ba({0: T0}, set(), X, np.zeros(len(X), int), np.arange(len(X)), obs,
                                                free_points=False), args.repeat)
            rows.append(("pose only (500 obs)", "gtsam", ms, pose_cost(P[0], X, obs)))

        init, fixed, Xn, oc, op, obs = ba_problem(rng)
        name = f"local BA ({len(init) - len(fixed)}+{len(fixed)} kf, {len(Xn)} pts, {len(oc)} obs)"

        def ours():
            pb, ids = opt._ba_problem(init, fixed, Xn, oc, op, obs, CAM, BF)
            opt._lm_ba(pb, np.ones(len(oc)), opt.HUBER_DELTA2, 50)
            return {int(k): make_pose(pb.R[i], pb.t[i]) for i, k in enumerate(ids)}, pb.X

        ms, (P, Xo) = timed(ours, args.repeat)
        rows.append((name, "ours", ms, ba_cost(P, Xo, oc, op, obs)))
        ms, (P, Xo, _) = timed(lambda: bundle_adjustment_least_squares(init, fixed, Xn, oc, op, obs, CAM, BF, robust=True,
                                                                       max_nfev=100), max(1, args.repeat // 2))
        rows.append((name, "scipy", ms, ba_cost(P, Xo, oc, op, obs)))
        if _gtsam() is not None:
            ms, (P, Xo) = timed(lambda: gtsam_ba(init, fixed, Xn, oc, op, obs), args.repeat)
            rows.append((name, "gtsam", ms, ba_cost(P, Xo, oc, op, obs)))

        T0, e, Z = pose_graph_problem(rng)
        name = f"pose graph ({len(T0)} kf, {len(e)} edges)"
        w_rot = 1.0  # the rotation weight of the problem every solver is given: GTSAM's unit noise model

        def pg_cost(T):
            r = edge_residuals(T[:, :3, :3], T[:, :3, 3], e, Z, np.ones(len(e)), w_rot)
            return float((r**2).sum())

        ms, res = timed(lambda: optimize_pose_graph(T0, e, Z, fixed=[0], config=PoseGraphConfig(max_iterations=50, rotation_weight=w_rot)),
                        args.repeat)
        rows.append((name, "ours", ms, pg_cost(res.poses)))
        ms, (T, _) = timed(lambda: pose_graph_least_squares(T0, e, Z, [0], np.ones(len(e)), rotation_weight=w_rot), args.repeat)
        rows.append((name, "scipy", ms, pg_cost(T)))
        if _gtsam() is not None:
            ms, T = timed(lambda: gtsam_pose_graph(T0, e, Z), args.repeat)
            rows.append((name, "gtsam", ms, pg_cost(T)))
    if _gtsam() is None:
        print("gtsam not installed: its rows are missing (pip install gtsam)\n")
    print(f"| {'problem':<40} | {'solver':<6} | {'ms':>8} | {'final cost':>12} |")
    print(f"|{'-' * 42}|{'-' * 8}|{'-' * 10}|{'-' * 14}|")
    for problem, solver, ms, cost in rows:
        print(f"| {problem:<40} | {solver:<6} | {ms:8.1f} | {cost:12.2f} |")


if __name__ == "__main__":
    main()
