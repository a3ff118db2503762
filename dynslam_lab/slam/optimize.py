"""Pose-only optimisation and local bundle adjustment with robust loss
(ORB-SLAM2, Mur-Artal and Tardos, T-RO 2017, Sec. III-C, eqs. 2-4).

A keypoint observed at ``(u, v)`` with depth ``z`` gives the "stereo" measurement
``x = (u, v, u_R)`` with ``u_R = u - bf / z`` (eq. 1; without depth only ``(u, v)``).
The projection of a world point ``X_w`` into a camera with pose ``T_c_w = (R, t)`` is::

    X_c = R X_w + t,    pi(X_c) = ( fx x/z + cx,  fy y/z + cy,  fx x/z + cx - bf / z )

**Motion-only BA** (eq. 2) optimises one pose over its matched points::

    {R, t} = argmin  sum_i  rho( || x_i - pi(R X_i + t) ||^2_Sigma )

**Local BA** (eq. 3-4) optimises the poses of the covisible keyframes ``K_L`` and all the points
``P_L`` they see; keyframes ``K_F`` that see those points but are not in ``K_L`` enter the cost
with fixed poses. ``Sigma = sigma_s^2 I`` with ``sigma_s = scale_factor ** octave`` (one pixel at
level 0), ``rho`` the Huber cost. An observation whose ``chi^2`` exceeds the 95 % quantile
(5.991 for 2, 7.815 for 3 degrees of freedom) is an outlier.

Our reading: both problems go to ``scipy.optimize.least_squares`` with an analytic Jacobian
(sparse for local BA). The Huber kernel (``delta^2 = 7.815`` on an observation's chi^2, as g2o in
ORB-SLAM2) is applied by iteratively re-weighted least squares: each round fixes the weights
``sqrt(rho'(chi^2))`` from the residuals at its start. (``least_squares(loss="huber")`` itself
rescales the problem in a way that converged slowly here: 3x lower cost after 10 evaluations
where re-weighting gives 200x.) A pose is parametrised around its current value as
``R = exp(omega) R0, t = t0 + tau`` so the rotation Jacobian is
``dX_c / d omega = -[R X_w]_x J_l(omega)`` (left Jacobian of SO(3)). As in ORB-SLAM2, motion-only BA
runs in rounds that re-classify outliers, the last round without the robust kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares

from ..camera import PinholeCamera
from ..geometry.se3 import nearest_rotation, so3_exp

__all__ = [
    "CHI2_2DOF",
    "CHI2_3DOF",
    "Observations",
    "project_stereo",
    "observation_chi2",
    "optimize_pose",
    "local_bundle_adjustment",
    "BAResult",
]

CHI2_2DOF = 5.991  # chi^2 95 % quantile, 2 dof (ORB-SLAM2)
CHI2_3DOF = 7.815  # chi^2 95 % quantile, 3 dof (ORB-SLAM2)


@dataclass
class Observations:
    """Measurements of points by cameras.

    Attributes
    ----------
    uv : ``(K, 2)`` undistorted pixels.
    ur : ``(K,)`` virtual right coordinate ``u - bf / z``; ``nan`` where no depth.
    sigma : ``(K,)`` pixel standard deviation ``scale_factor ** octave``.
    """

    uv: np.ndarray
    ur: np.ndarray
    sigma: np.ndarray

    @classmethod
    def from_keypoints(cls, uv: np.ndarray, depth: np.ndarray, octave: np.ndarray, bf: float, scale_factor: float) -> "Observations":
        uv = np.asarray(uv, float).reshape(-1, 2)
        z = np.asarray(depth, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            ur = np.where(z > 0, uv[:, 0] - bf / z, np.nan)
        return cls(uv, ur, scale_factor ** np.asarray(octave, float))

    def __len__(self) -> int:
        return len(self.uv)


def _skew(v: np.ndarray) -> np.ndarray:
    """``(K, 3)`` -> ``(K, 3, 3)`` cross-product matrices."""
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def _left_jacobian(omega: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3), ``(..., 3)`` -> ``(..., 3, 3)``."""
    omega = np.asarray(omega, float)
    th = np.linalg.norm(omega, axis=-1)[..., None, None]
    W = _skew(omega)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    a = np.where(small, 0.5, (1 - np.cos(ths)) / ths**2)
    b = np.where(small, 1.0 / 6.0, (ths - np.sin(ths)) / ths**3)
    return np.eye(3) + a * W + b * (W @ W)


def project_stereo(X_c: np.ndarray, camera: PinholeCamera, bf: float) -> np.ndarray:
    """``(K, 3)`` camera points -> ``(K, 3)`` predicted ``(u, v, u_R)``."""
    z = X_c[:, 2]
    u = camera.fx * X_c[:, 0] / z + camera.cx
    v = camera.fy * X_c[:, 1] / z + camera.cy
    return np.stack([u, v, u - bf / z], axis=1)


def _proj_jac(X_c: np.ndarray, camera: PinholeCamera, bf: float) -> np.ndarray:
    """``(K, 3, 3)`` Jacobian of ``(u, v, u_R)`` with respect to ``X_c``."""
    x, y, z = X_c[:, 0], X_c[:, 1], X_c[:, 2]
    iz = 1.0 / z
    iz2 = iz * iz
    J = np.zeros((len(X_c), 3, 3))
    J[:, 0, 0] = camera.fx * iz
    J[:, 0, 2] = -camera.fx * x * iz2
    J[:, 1, 1] = camera.fy * iz
    J[:, 1, 2] = -camera.fy * y * iz2
    J[:, 2] = J[:, 0]
    J[:, 2, 2] += bf * iz2
    return J


def _residuals(X_c: np.ndarray, obs: Observations, camera: PinholeCamera, bf: float) -> tuple[np.ndarray, np.ndarray]:
    """Whitened residuals ``(K, 3)`` (third zero without depth) and the ``has_depth`` mask."""
    pred = project_stereo(X_c, camera, bf)
    has_d = np.isfinite(obs.ur)
    meas = np.column_stack([obs.uv, np.where(has_d, obs.ur, 0.0)])
    r = (pred - meas) / obs.sigma[:, None]
    r[~has_d, 2] = 0.0
    return r, has_d


def observation_chi2(X_c: np.ndarray, obs: Observations, camera: PinholeCamera, bf: float) -> tuple[np.ndarray, np.ndarray]:
    """``chi^2 (K,)`` of each observation and whether it is an outlier (95 % quantile by dof);
    points behind the camera are outliers."""
    r, has_d = _residuals(X_c, obs, camera, bf)
    chi2 = np.sum(r**2, axis=1)
    bad = (chi2 > np.where(has_d, CHI2_3DOF, CHI2_2DOF)) | ~(X_c[:, 2] > 0)
    return chi2, bad


def optimize_pose(
    T_c_w: np.ndarray,
    X_w: np.ndarray,
    obs: Observations,
    camera: PinholeCamera,
    bf: float,
    rounds: int = 4,
    max_nfev: int = 10,
) -> tuple[np.ndarray, np.ndarray]:
    """Motion-only bundle adjustment (ORB-SLAM2 eq. 2).

    Parameters
    ----------
    T_c_w : ``(4, 4)`` initial world-to-camera pose.
    X_w : ``(K, 3)`` world points (metres); obs : their measurements.
    rounds : outlier re-classification rounds (ORB-SLAM2: 4); the last without Huber.
    max_nfev : iterations per round (ORB-SLAM2: 10).

    Returns
    -------
    ``(T_c_w (4, 4), outlier (K,) bool)``.
    """
    X_w = np.asarray(X_w, float).reshape(-1, 3)
    if len(X_w) != len(obs):
        raise ValueError(f"optimize_pose: {len(X_w)} points but {len(obs)} observations")
    R0 = nearest_rotation(np.asarray(T_c_w, float)[:3, :3])
    t0 = np.asarray(T_c_w, float)[:3, 3].copy()
    outlier = np.zeros(len(X_w), bool)
    if len(X_w) < 3:
        return np.asarray(T_c_w, float).copy(), np.ones(len(X_w), bool)
    delta2 = CHI2_3DOF
    for rnd in range(rounds):
        use = ~outlier
        if use.sum() < 3:
            break
        Xu = X_w[use]
        ou = Observations(obs.uv[use], obs.ur[use], obs.sigma[use])
        # Huber kernel by re-weighting (IRLS): weight sqrt(rho'(chi^2)) per observation from the
        # residuals at the start of the round; the last round has no kernel (ORB-SLAM2).
        if rnd < rounds - 1:
            chi2, _ = observation_chi2(Xu @ R0.T + t0, ou, camera, bf)
            w = np.sqrt(np.where(chi2 <= delta2, 1.0, np.sqrt(delta2 / np.maximum(chi2, 1e-12))))
        else:
            w = np.ones(len(Xu))
        w3 = np.repeat(w, 3)
        no_depth = ~np.isfinite(ou.ur)

        def fun(p):
            X_c = Xu @ (so3_exp(p[:3]) @ R0).T + t0 + p[3:]
            r, _ = _residuals(X_c, ou, camera, bf)
            return r.ravel() * w3

        def jac(p):
            R = so3_exp(p[:3]) @ R0
            RX = Xu @ R.T
            X_c = RX + t0 + p[3:]
            Jp = _proj_jac(X_c, camera, bf) / ou.sigma[:, None, None]
            Jp[no_depth, 2, :] = 0.0
            Jrot = -_skew(RX) @ _left_jacobian(p[:3])
            J = np.concatenate([Jp @ Jrot, Jp], axis=2)  # (K, 3, 6)
            return J.reshape(-1, 6) * w3[:, None]

        res = least_squares(fun, np.zeros(6), jac=jac, method="lm", max_nfev=max_nfev)
        p = res.x
        R0 = so3_exp(p[:3]) @ R0
        t0 = t0 + p[3:]
        X_c = X_w @ R0.T + t0
        _, outlier = observation_chi2(X_c, obs, camera, bf)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R0, t0
    return T, outlier


@dataclass
class BAResult:
    """Result of local BA: optimised poses ``T_c_w`` per keyframe id, points ``(P, 3)`` in the
    order given, and ``outlier (K,)`` per observation (chi^2 test after optimisation)."""

    T_c_w: dict[int, np.ndarray]
    points: np.ndarray
    outlier: np.ndarray
    cost_before: float
    cost_after: float


def local_bundle_adjustment(
    poses: dict[int, np.ndarray],
    fixed: set[int],
    points: np.ndarray,
    obs_cam: np.ndarray,
    obs_pt: np.ndarray,
    obs: Observations,
    camera: PinholeCamera,
    bf: float,
    max_nfev: int = 10,
    second_round: bool = True,
    lsmr_iterations: int = 30,
) -> BAResult:
    """Local bundle adjustment (ORB-SLAM2 eqs. 3-4) with a sparse Jacobian.

    Parameters
    ----------
    poses : keyframe id -> ``T_c_w (4, 4)`` of every keyframe in the problem.
    fixed : ids whose poses stay fixed (``K_F``; include the map origin).
    points : ``(P, 3)`` world points to optimise.
    obs_cam : ``(K,)`` keyframe id of each observation; obs_pt : ``(K,)`` index into ``points``.
    obs : the measurements ``(K)``.
    max_nfev : evaluations of ``least_squares`` per round.
    second_round : after the Huber round, drop chi^2 outliers and optimise again without the
        robust kernel (ORB-SLAM2 does 5 + 10 iterations).
    lsmr_iterations : inner LSMR iterations per trust-region step.

    The Huber cost is minimised by re-weighting (IRLS) rather than ``least_squares(loss="huber")``,
    whose rescaling converges slowly from residuals of a few sigma (measured: cost 3x lower after 10
    evaluations instead of 200x).
    """
    points = np.asarray(points, float).reshape(-1, 3)
    obs_cam = np.asarray(obs_cam, np.int64)
    obs_pt = np.asarray(obs_pt, np.int64)
    free_ids = sorted(k for k in poses if k not in fixed)
    col_of = {k: i for i, k in enumerate(free_ids)}
    n_free, n_pts = len(free_ids), len(points)
    cam_ids = np.array(sorted(poses), np.int64)
    R0 = np.stack([nearest_rotation(np.asarray(poses[k], float)[:3, :3]) for k in cam_ids])
    t0 = np.stack([np.asarray(poses[k], float)[:3, 3] for k in cam_ids])
    cam_row = np.searchsorted(cam_ids, obs_cam)
    free_slot = np.array([col_of.get(int(k), -1) for k in cam_ids], np.int64)[cam_row]  # (K,)
    is_free = free_slot >= 0
    has_d = np.isfinite(obs.ur)
    n_par = 6 * n_free + 3 * n_pts

    def unpack(p):
        om = np.zeros((len(cam_ids), 3))
        tau = np.zeros((len(cam_ids), 3))
        fr = np.array([col_of.get(int(k), -1) for k in cam_ids])
        f = fr >= 0
        pp = p[: 6 * n_free].reshape(n_free, 6)
        om[f] = pp[fr[f], :3]
        tau[f] = pp[fr[f], 3:]
        R = so3_exp(om) @ R0 if len(cam_ids) else R0
        return om, R, t0 + tau, p[6 * n_free :].reshape(n_pts, 3)

    def camera_points(p):
        om, R, t, X = unpack(p)
        Xw = X[obs_pt]
        RX = np.einsum("kij,kj->ki", R[cam_row], Xw)
        return om, R, RX, RX + t[cam_row]

    def fun(p):
        _, _, _, X_c = camera_points(p)
        r, _ = _residuals(X_c, obs, camera, bf)
        return r.ravel()

    k_obs = len(obs_pt)
    rows = np.arange(3 * k_obs).reshape(k_obs, 3)

    def jac(p):
        om, R, RX, X_c = camera_points(p)
        Jp = _proj_jac(X_c, camera, bf) / obs.sigma[:, None, None]
        Jp[~has_d, 2, :] = 0.0
        Jpt = Jp @ R[cam_row]  # (K, 3, 3)
        r_idx = np.repeat(rows, 3, axis=1).reshape(k_obs, 3, 3)
        c_pt = 6 * n_free + 3 * obs_pt[:, None, None] + np.arange(3)[None, None, :]
        data = [Jpt.ravel()]
        ri = [r_idx.ravel()]
        ci = [np.broadcast_to(c_pt, (k_obs, 3, 3)).ravel()]
        if is_free.any():
            Jl = _left_jacobian(om)[cam_row[is_free]]
            Jrot = -_skew(RX[is_free]) @ Jl
            Jf = np.concatenate([Jp[is_free] @ Jrot, Jp[is_free]], axis=2)  # (F, 3, 6)
            rr = np.repeat(rows[is_free], 6, axis=1).reshape(-1, 3, 6)
            cc = 6 * free_slot[is_free][:, None, None] + np.arange(6)[None, None, :]
            data.append(Jf.ravel())
            ri.append(rr.ravel())
            ci.append(np.broadcast_to(cc, Jf.shape).ravel())
        return sp.csr_matrix((np.concatenate(data), (np.concatenate(ri), np.concatenate(ci))), shape=(3 * k_obs, n_par))

    p0 = np.concatenate([np.zeros(6 * n_free), points.ravel()])
    r0 = fun(p0)
    cost_before = 0.5 * float(r0 @ r0)
    if k_obs == 0 or n_par == 0:
        return BAResult({k: np.asarray(v, float).copy() for k, v in poses.items()}, points.copy(), np.zeros(k_obs, bool), cost_before, cost_before)
    def weighted(w_obs):
        w = np.repeat(w_obs, 3)
        return (lambda p: fun(p) * w), (lambda p: sp.diags(w) @ jac(p))

    # Round 1: Huber cost by iteratively re-weighted least squares, the weight of an
    # observation sqrt(rho'(chi^2)) fixed from the residuals at the start (delta^2 = 7.815, as
    # g2o's robust kernel in ORB-SLAM2). Round 2: chi^2 outliers dropped, plain least squares.
    _, _, _, X_c = camera_points(p0)
    chi2, _ = observation_chi2(X_c, obs, camera, bf)
    delta = np.sqrt(CHI2_3DOF)
    w1 = np.sqrt(np.where(chi2 <= delta**2, 1.0, delta / np.sqrt(np.maximum(chi2, 1e-12))))
    f1, j1 = weighted(w1)
    # x_scale="jac" scales the columns (a Jacobi preconditioner for LSMR); LSMR stops after
    # lsmr_iterations inner steps: an inexact step is enough inside the trust region.
    opts = dict(method="trf", tr_solver="lsmr", x_scale="jac", tr_options={"maxiter": lsmr_iterations})
    res = least_squares(f1, p0, jac=j1, max_nfev=max_nfev, **opts)
    if second_round:
        _, _, _, X_c = camera_points(res.x)
        _, bad = observation_chi2(X_c, obs, camera, bf)
        f2, j2 = weighted((~bad).astype(float))
        res = least_squares(f2, res.x, jac=j2, max_nfev=max_nfev, **opts)
    om, R, t, X = unpack(res.x)
    out = {}
    for i, k in enumerate(cam_ids):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R[i], t[i]
        out[int(k)] = T
    _, _, _, X_c = camera_points(res.x)
    _, outlier = observation_chi2(X_c, obs, camera, bf)
    r1 = fun(res.x)
    return BAResult(out, X.copy(), outlier, cost_before, 0.5 * float(r1 @ r1))
