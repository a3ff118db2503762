"""The optimisation problems of the SLAM core posed to scipy's general solver, as a reference.

:mod:`.optimize` and :mod:`.pose_graph` solve motion-only BA, bundle adjustment and the pose graph
with a Levenberg-Marquardt written for them (normal equations, Schur complement). This module
states the *same costs* for ``scipy.optimize.least_squares`` (trust-region reflective, sparse
Jacobians), so that tests can check that both reach the same minimum and
``benchmarks/solver_speed.py`` can time both; a notebook can show the two side by side.

The robust cost is written into the residuals themselves: an observation's whitened residual
``e_k`` is scaled to ``f_k = sqrt(rho(chi^2_k) / chi^2_k) e_k``, so that scipy's plain sum of squares
``sum ||f_k||^2`` is the Huber cost ``sum rho(chi^2_k)`` (``rho(c) = c`` inside ``delta^2``,
``2 delta sqrt(c) - delta^2`` beyond), with the exact Jacobian of that scaling; no re-weighting.
(scipy's own ``loss="huber"`` would act on each residual component, not on an observation's
``chi^2``.) Without the kernel the residuals are the ``3 K`` whitened components.
Poses are stepped as in :mod:`.optimize`: ``R = Exp(omega) R0``, ``t = t0 + tau``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ..camera import PinholeCamera
from .optimize import HUBER_DELTA2, Observations, project_stereo, stereo_jacobian
from .pose_graph import edge_residuals, sqrt_information

__all__ = ["pose_only_least_squares", "bundle_adjustment_least_squares", "pose_graph_least_squares"]


def _whitened(X_c: np.ndarray, obs: Observations, camera: PinholeCamera, bf: float) -> tuple[np.ndarray, np.ndarray]:
    """Whitened residuals ``(K, 3)`` and their Jacobian in ``X_c`` ``(K, 3, 3)`` (third rows zero
    without depth)."""
    has_d = np.isfinite(obs.ur)
    meas = np.column_stack([obs.uv, np.where(has_d, obs.ur, 0.0)])
    e = (project_stereo(X_c, camera, bf) - meas) / obs.sigma[:, None]
    J = stereo_jacobian(X_c, camera, bf) / obs.sigma[:, None, None]
    e[~has_d, 2] = 0.0
    J[~has_d, 2] = 0.0
    return e, J


def _residual_rows(e: np.ndarray, J_cols: list[np.ndarray], robust: bool) -> tuple[np.ndarray, list[np.ndarray]]:
    """The residual vector and its Jacobian blocks (rows ``3 K``).

    Without the kernel: the whitened components ``e``. With it: ``f_k = s(chi^2_k) e_k`` with
    ``s(c) = sqrt(rho(c) / c)``, so that ``||f_k||^2 = rho(chi^2_k)`` exactly, and
    ``df_k = s J_k + 2 s'(c) e_k e_k^T J_k``.
    """
    if not robust:
        return e.ravel(), [j.reshape(-1, j.shape[-1]) for j in J_cols]
    d2 = HUBER_DELTA2
    c = np.maximum(np.einsum("ka,ka->k", e, e), 1e-300)
    out = c > d2
    co = np.maximum(c, d2)  # the outer branch, evaluated where it applies
    so = np.sqrt((2.0 * np.sqrt(d2 * co) - d2) / co)
    s = np.where(out, so, 1.0)
    ds = np.where(out, (-np.sqrt(d2) * co**-1.5 + d2 * co**-2.0) / (2.0 * so), 0.0)
    f = e * s[:, None]
    blocks = []
    for j in J_cols:
        eTJ = np.einsum("ka,kai->ki", e, j)
        blocks.append((s[:, None, None] * j + 2.0 * ds[:, None, None] * e[:, :, None] * eTJ[:, None, :]).reshape(-1, j.shape[-1]))
    return f.ravel(), blocks


def _solve(fun, jac, x0, max_nfev: int, tr_solver: str):
    return least_squares(fun, x0, jac=jac, method="trf", x_scale="jac", tr_solver=tr_solver, max_nfev=max_nfev,
                         ftol=1e-12, xtol=1e-12, gtol=1e-12)


def pose_only_least_squares(T_c_w: np.ndarray, X_w: np.ndarray, obs: Observations, camera: PinholeCamera, bf: float,
                            robust: bool = True, max_nfev: int = 50) -> tuple[np.ndarray, float]:
    """Motion-only BA of one pose (one round, no outlier re-classification) with scipy.

    Returns ``(T_c_w (4, 4), cost)`` with ``cost = sum rho(chi^2)`` (``sum chi^2`` without kernel).
    """
    R0, t0 = np.asarray(T_c_w, float)[:3, :3], np.asarray(T_c_w, float)[:3, 3]
    X_w = np.asarray(X_w, float).reshape(-1, 3)

    def parts(p):
        R = Rotation.from_rotvec(p[:3]).as_matrix() @ R0
        RX = X_w @ R.T
        e, Jx = _whitened(RX + t0 + p[3:], obs, camera, bf)
        # dX_c/domega = -[R X]_x (small steps around p), dX_c/dtau = I
        return _residual_rows(e, [np.concatenate([np.cross(RX[:, None, :], Jx), Jx], axis=2)], robust)

    res = _solve(lambda p: parts(p)[0], lambda p: parts(p)[1][0], np.zeros(6), max_nfev, "exact")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(res.x[:3]).as_matrix() @ R0
    T[:3, 3] = t0 + res.x[3:]
    return T, 2.0 * float(res.cost)


def bundle_adjustment_least_squares(poses: dict[int, np.ndarray], fixed: set[int], points: np.ndarray,
                                    obs_cam: np.ndarray, obs_pt: np.ndarray, obs: Observations,
                                    camera: PinholeCamera, bf: float, robust: bool = True,
                                    max_nfev: int = 50) -> tuple[dict[int, np.ndarray], np.ndarray, float]:
    """Bundle adjustment (one round) with scipy and a sparse analytic Jacobian.

    Returns ``(T_c_w per keyframe id, points (P, 3), cost)``.
    """
    cam_ids = np.array(sorted(poses), np.int64)
    free_ids = [int(k) for k in cam_ids if int(k) not in fixed]
    slot_of = {k: i for i, k in enumerate(free_ids)}
    cam = np.searchsorted(cam_ids, np.asarray(obs_cam, np.int64))
    pt = np.asarray(obs_pt, np.int64)
    slot = np.array([slot_of.get(int(k), -1) for k in cam_ids], np.int64)[cam]
    R0 = np.stack([np.asarray(poses[int(k)], float)[:3, :3] for k in cam_ids])
    t0 = np.stack([np.asarray(poses[int(k)], float)[:3, 3] for k in cam_ids])
    X0 = np.asarray(points, float).reshape(-1, 3)
    F, P, K = len(free_ids), len(X0), len(pt)
    free = slot >= 0

    def unpack(p):
        d = np.zeros((len(cam_ids), 6))
        d[[int(np.searchsorted(cam_ids, k)) for k in free_ids]] = p[: 6 * F].reshape(F, 6)
        return Rotation.from_rotvec(d[:, :3]).as_matrix() @ R0, t0 + d[:, 3:], p[6 * F :].reshape(P, 3)

    def parts(p):
        R, t, X = unpack(p)
        RX = np.einsum("kij,kj->ki", R[cam], X[pt])
        e, Jx = _whitened(RX + t[cam], obs, camera, bf)
        J_pose = np.concatenate([np.cross(RX[:, None, :], Jx), Jx], axis=2)
        return _residual_rows(e, [J_pose, Jx @ R[cam]], robust)

    def jac(p):
        _, (J_pose, J_pt) = parts(p)
        m = 3  # rows per observation
        row = np.arange(K * m).reshape(K, m)
        r_pt = np.repeat(row[:, :, None], 3, axis=2)
        c_pt = np.broadcast_to(6 * F + 3 * pt[:, None, None] + np.arange(3), r_pt.shape)
        J_pose = J_pose.reshape(K, m, 6)[free]
        r_c = np.repeat(row[free][:, :, None], 6, axis=2)
        c_c = np.broadcast_to(6 * slot[free][:, None, None] + np.arange(6), r_c.shape)
        data = np.concatenate([J_pt.ravel(), J_pose.ravel()])
        rows = np.concatenate([r_pt.ravel(), r_c.ravel()])
        cols = np.concatenate([c_pt.ravel(), c_c.ravel()])
        return sp.csr_matrix((data, (rows, cols)), shape=(K * m, 6 * F + 3 * P))

    x0 = np.concatenate([np.zeros(6 * F), X0.ravel()])
    # small problems: the exact trust-region subproblem (dense); large ones: LSMR
    exact = len(x0) <= 2000
    res = _solve(lambda p: parts(p)[0], (lambda p: jac(p).toarray()) if exact else jac, x0, max_nfev,
                 "exact" if exact else "lsmr")
    R, t, X = unpack(res.x)
    out = {}
    for i, k in enumerate(cam_ids):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R[i], t[i]
        out[int(k)] = T
    return out, X, 2.0 * float(res.cost)


def pose_graph_least_squares(T_w_c: np.ndarray, edges: np.ndarray, T_i_j: np.ndarray, fixed, weights: np.ndarray,
                             rotation_weight: float, max_nfev: int = 50,
                             information: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """The pose graph of :mod:`.pose_graph` with scipy: finite-difference Jacobian with its sparsity
    (each 6-row edge residual depends on the 12 parameters of its two poses); ``information (E, 6, 6)``
    as :func:`~.pose_graph.optimize_pose_graph` takes it.

    Returns ``(T_w_c (K, 4, 4), cost = sum w ||L r||^2)``.
    """
    L = None if information is None else sqrt_information(information, rotation_weight)
    T = np.asarray(T_w_c, float)
    K = len(T)
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    fixed_mask = np.zeros(K, bool)
    fixed_mask[np.asarray(fixed, np.int64)] = True
    free = np.flatnonzero(~fixed_mask)
    col_of = np.full(K, -1, np.int64)
    col_of[free] = np.arange(len(free))
    sqrt_w = np.sqrt(np.asarray(weights, float))
    R0, t0 = T[:, :3, :3], T[:, :3, 3]

    def poses(x):
        d = np.zeros((K, 6))
        d[free] = x.reshape(-1, 6)
        return Rotation.from_rotvec(d[:, :3]).as_matrix() @ R0, t0 + d[:, 3:]

    def fun(x):
        R, t = poses(x)
        return edge_residuals(R, t, edges, T_i_j, sqrt_w, rotation_weight, L).ravel()

    rows, cols = [], []
    base = (6 * np.arange(len(edges)))[:, None] + np.arange(6)
    for end in (0, 1):
        c = col_of[edges[:, end]]
        ok = c >= 0
        rows.append(np.repeat(base[ok], 6, axis=1).ravel())
        cols.append(np.tile(6 * c[ok][:, None] + np.arange(6), (1, 6)).ravel())
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    sparsity = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(6 * len(edges), 6 * len(free)))
    res = least_squares(fun, np.zeros(6 * len(free)), jac_sparsity=sparsity, method="trf", x_scale="jac",
                        tr_solver="lsmr", max_nfev=max_nfev, ftol=1e-10, xtol=1e-10, gtol=1e-10)
    R, t = poses(res.x)
    out = np.tile(np.eye(4), (K, 1, 1))
    out[:, :3, :3], out[:, :3, 3] = R, t
    return out, 2.0 * float(res.cost)
