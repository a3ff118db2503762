"""Pose-only optimisation and bundle adjustment with a robust kernel
(ORB-SLAM2, Mur-Artal and Tardos, T-RO 2017, Sec. III-C, eqs. 2-4), solved by Levenberg-Marquardt
on the normal equations with analytic Jacobians and, for bundle adjustment, the Schur complement.

**Measurement.** A keypoint observed at ``(u, v)`` with depth ``z`` gives the "stereo" measurement
``x = (u, v, u_R)`` with ``u_R = u - bf / z`` (eq. 1; without depth only ``(u, v)``). The
projection of a world point ``X_w`` into a camera with pose ``T_c_w = (R, t)`` is::

    X_c = R X_w + t,    pi(X_c) = ( fx x/z + cx,  fy y/z + cy,  fx x/z + cx - bf / z )

and the whitened residual of one observation is ``e = (pi(X_c) - x) / sigma`` with
``sigma = scale_factor ** octave`` (``Sigma = sigma^2 I``, one pixel at level 0), so that
``chi^2 = ||e||^2``. An observation whose ``chi^2`` exceeds the 95 % quantile (5.991 for 2, 7.815
for 3 degrees of freedom) is an outlier.

**Motion-only BA** (eq. 2) optimises one pose over its matched points; **local BA** (eqs. 3-4)
the poses of the covisible keyframes ``K_L`` and all the points ``P_L`` they see, keyframes ``K_F``
that see those points entering with fixed poses::

    {R, t} = argmin  sum_i  rho( chi^2_i )          rho = Huber, delta^2 = 7.815 (g2o in ORB-SLAM2)

**The Jacobian.** A step ``(omega, tau)`` moves a pose on the left, ``R <- Exp(omega) R``,
``t <- t + tau``, and a point by ``X_w <- X_w + delta``. At the current estimate::

    dX_c / d omega = -[R X_w]_x,     dX_c / d tau = I,     dX_c / d X_w = R

    d pi / d X_c = [[ fx/z,    0,  -fx x / z^2         ],
                    [    0, fy/z,  -fy y / z^2         ],
                    [ fx/z,    0,  -fx x / z^2 + bf/z^2 ]]

and ``J = (1 / sigma) (d pi / d X_c) (d X_c / d parameters)`` (the third row zero without depth).

**Metric depth row** (ours, for motion-only BA; ``Observations.z_sigma`` set). The ``u_R`` row weighs
a depth error ``dz`` as ``bf dz / z^2`` pixels: with ``bf = 40`` a 5 cm error at 3 m is 0.2 px, so the
depth of a keypoint is worth almost nothing beside its ``(u, v)``, and on a flat wall a small rotation
and a lateral translation explain the pixels equally well. The metric row replaces ``u_R`` by the
depth itself, whitened by the sensor's depth noise::

    e_3 = (z_c - z) / sigma_z(z),     d e_3 / d X_c = (0, 0, 1 / sigma_z)

with ``z_c`` the predicted depth (third coordinate of ``X_c``) and ``sigma_z`` from the caller
(tracking: Nguyen et al. 2012's Kinect model, ``TrackingConfig.depth_sigma_*``). The chi^2 test
keeps 3 degrees of freedom.

**Robust kernel** by iteratively re-weighted least squares: at each linearisation an observation
gets the weight ``w = rho'(chi^2) = min(1, delta / sqrt(chi^2))`` (as g2o re-evaluates its kernel at
every iteration), so the fixed point of the iteration is the Huber minimum.

**Levenberg-Marquardt.** One step solves ``(H + lambda D) dx = -g`` with ``H = sum J^T w J``,
``g = sum J^T w e`` and ``D = diag(H)``; it is kept when the robust cost falls (``lambda / 10``),
otherwise undone (``lambda x 10``). Iterations stop early when the cost stops falling (relative
change below ``1e-6``) or the step is below ``1e-9``.

**Schur complement** (bundle adjustment). With the camera parameters ``c`` and the points ``p`` the
normal equations are ``[[H_cc, H_cp], [H_pc, H_pp]] [dc; dp] = -[g_c; g_p]``. ``H_pp`` is
block-diagonal (one 3x3 block per point), so the points are eliminated::

    (H_cc - H_cp H_pp^-1 H_pc) dc = -g_c + H_cp H_pp^-1 g_p,      dp = -H_pp^-1 (g_p + H_pc dc)

``H_cc`` is block-diagonal too (6x6 per free keyframe), ``H_cp`` has one 6x3 block per observation;
the reduced camera system is ``6 x (free keyframes)`` square, small and dense.

As in ORB-SLAM2, motion-only BA runs in rounds that re-classify outliers, the last one without the
robust kernel, and local BA runs one robust round, drops the chi^2 outliers and runs a plain one.
The same problems with scipy's general ``least_squares`` are in :mod:`.scipy_reference` (tests and
``benchmarks/solver_speed.py`` compare the two).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.linalg import LinAlgError, cho_factor, cho_solve
from scipy.sparse.linalg import spsolve

from ..camera import PinholeCamera
from ..geometry.se3 import nearest_rotation, skew, so3_log

__all__ = [
    "pose_information",
    "pose_uncertainty",
    "pose_step_mahalanobis",
    "CHI2_2DOF",
    "CHI2_3DOF",
    "Observations",
    "project_stereo",
    "observation_chi2",
    "huber_weight",
    "huber_cost",
    "stereo_jacobian",
    "optimize_pose",
    "pose_observation_chi2",
    "local_bundle_adjustment",
    "solve_spd",
    "BAResult",
]

CHI2_2DOF = 5.991  # chi^2 95 % quantile, 2 dof (ORB-SLAM2)
CHI2_3DOF = 7.815  # chi^2 95 % quantile, 3 dof (ORB-SLAM2)
HUBER_DELTA2 = CHI2_3DOF  # Huber threshold on chi^2; g2o's robust kernel in ORB-SLAM2: sqrt(7.815)
_REL_TOL = 1e-6  # stop when the cost falls by less than this fraction in an iteration
_STEP_TOL = 1e-9  # ... or the step is this small (rad, m)
_MIN_DEPTH = 1e-6  # camera points closer than this (m) are left out of an iteration (behind the camera)


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
    z: np.ndarray | None = None
    z_sigma: np.ndarray | None = None

    @classmethod
    def from_keypoints(cls, uv: np.ndarray, depth: np.ndarray, octave: np.ndarray, bf: float, scale_factor: float,
                       z_sigma: np.ndarray | None = None) -> "Observations":
        """``z_sigma (K,)`` (m, the standard deviation of each keypoint's depth) switches motion-only BA
        to the metric depth row (:func:`optimize_pose`); None keeps ORB-SLAM2's ``u_R`` row."""
        uv = np.asarray(uv, float).reshape(-1, 2)
        z = np.asarray(depth, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            ur = np.where(z > 0, uv[:, 0] - bf / z, np.nan)
        if z_sigma is None:
            return cls(uv, ur, scale_factor ** np.asarray(octave, float))
        z_sigma = np.asarray(z_sigma, float).reshape(-1)
        if len(z_sigma) != len(z) or not np.all((z_sigma > 0) | ~np.isfinite(ur)):
            raise ValueError(f"Observations: z_sigma must be > 0 for each of the {len(z)} keypoints with depth")
        return cls(uv, ur, scale_factor ** np.asarray(octave, float), z, z_sigma)

    def __len__(self) -> int:
        return len(self.uv)

    def subset(self, idx: np.ndarray) -> "Observations":
        """The observations at indices / boolean mask ``idx``."""
        if self.z_sigma is None:
            return Observations(self.uv[idx], self.ur[idx], self.sigma[idx])
        return Observations(self.uv[idx], self.ur[idx], self.sigma[idx], self.z[idx], self.z_sigma[idx])


def _rodrigues(omega: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` -> matrices ``(..., 3, 3)``: ``Exp(omega)`` (Rodrigues' formula)."""
    omega = np.asarray(omega, float)
    th = np.linalg.norm(omega, axis=-1)[..., None, None]
    W = np.zeros(omega.shape[:-1] + (3, 3))
    W[..., 0, 1], W[..., 0, 2], W[..., 1, 2] = -omega[..., 2], omega[..., 1], -omega[..., 0]
    W[..., 1, 0], W[..., 2, 0], W[..., 2, 1] = omega[..., 2], -omega[..., 1], omega[..., 0]
    small = th < 1e-8
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0, np.sin(ths) / ths)
    b = np.where(small, 0.5, (1.0 - np.cos(ths)) / ths**2)
    return np.eye(3) + a * W + b * (W @ W)


def project_stereo(X_c: np.ndarray, camera: PinholeCamera, bf: float) -> np.ndarray:
    """``(K, 3)`` camera points -> ``(K, 3)`` predicted ``(u, v, u_R)``."""
    z = X_c[:, 2]
    u = camera.fx * X_c[:, 0] / z + camera.cx
    v = camera.fy * X_c[:, 1] / z + camera.cy
    return np.stack([u, v, u - bf / z], axis=1)


def stereo_jacobian(X_c: np.ndarray, camera: PinholeCamera, bf: float) -> np.ndarray:
    """``(K, 3, 3)`` Jacobian ``d(u, v, u_R) / d X_c`` (module docstring)."""
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
    with np.errstate(divide="ignore", invalid="ignore"):
        r, has_d = _residuals(X_c, obs, camera, bf)
    chi2 = np.sum(r**2, axis=1)
    bad = ~(chi2 <= np.where(has_d, CHI2_3DOF, CHI2_2DOF)) | ~(X_c[:, 2] > 0)
    return chi2, bad


def huber_weight(chi2: np.ndarray, delta2: float | None) -> np.ndarray:
    """IRLS weight ``rho'(chi^2)`` of the Huber kernel: 1 inside, ``delta / sqrt(chi^2)`` beyond
    ``delta^2``; all ones for ``delta2 = None`` (no kernel)."""
    if delta2 is None:
        return np.ones_like(chi2)
    return np.sqrt(delta2 / np.maximum(chi2, delta2))


def huber_cost(chi2: np.ndarray, delta2: float | None) -> np.ndarray:
    """Huber cost ``rho(chi^2)``: ``chi^2`` inside, ``2 delta sqrt(chi^2) - delta^2`` beyond ``delta^2``."""
    if delta2 is None:
        return chi2
    return np.where(chi2 <= delta2, chi2, 2.0 * np.sqrt(delta2 * chi2) - delta2)


def _whitened_jacobian(X_c: np.ndarray, obs: Observations, camera: PinholeCamera, bf: float) -> np.ndarray:
    """``(K, 3, 3)`` ``(1 / sigma) d pi / d X_c``, third row zero without depth."""
    Jp = stereo_jacobian(X_c, camera, bf) / obs.sigma[:, None, None]
    Jp[~np.isfinite(obs.ur), 2, :] = 0.0
    return Jp


def _pose_columns(Jp: np.ndarray, RX: np.ndarray) -> np.ndarray:
    """``(K, 3, 6)`` Jacobian of the residuals in the pose step ``(omega, tau)``:
    ``Jp [-[R X]_x, I]``; row ``a`` of ``Jp -[v]_x`` is ``v x a``."""
    v = RX[:, None, :]
    J = np.empty(Jp.shape[:2] + (6,))
    J[..., 0] = v[..., 1] * Jp[..., 2] - v[..., 2] * Jp[..., 1]
    J[..., 1] = v[..., 2] * Jp[..., 0] - v[..., 0] * Jp[..., 2]
    J[..., 2] = v[..., 0] * Jp[..., 1] - v[..., 1] * Jp[..., 0]
    J[..., 3:] = Jp
    return J


# ------------------------------------------------------------------------------------ pose only
def _pose_residuals(X_c: np.ndarray, obs: Observations, camera: PinholeCamera, bf: float) -> tuple[np.ndarray, np.ndarray]:
    """Whitened residuals of motion-only BA ``(K, 3)`` and the ``has_depth`` mask: ORB-SLAM2's
    ``(u, v, u_R)`` (:func:`_residuals`), or with ``obs.z_sigma`` the metric depth row
    ``(z_c - z) / sigma_z`` in place of the ``u_R`` row (module docstring, "Metric depth row"). Written as
    the equations read; the solver uses :class:`_PoseTerms`, which the tests compare with this and with
    :func:`_pose_point_jacobian`."""
    r, has_d = _residuals(X_c, obs, camera, bf)
    if obs.z_sigma is not None:
        r[has_d, 2] = (X_c[has_d, 2] - obs.z[has_d]) / obs.z_sigma[has_d]
    return r, has_d


def _pose_point_jacobian(X_c: np.ndarray, obs: Observations, camera: PinholeCamera, bf: float) -> np.ndarray:
    """``(K, 3, 3)`` derivative of :func:`_pose_residuals` in ``X_c``; the metric depth row is
    ``(0, 0, 1 / sigma_z)``."""
    Jp = _whitened_jacobian(X_c, obs, camera, bf)
    if obs.z_sigma is not None:
        has_d = np.isfinite(obs.ur)
        Jp[has_d, 2, :2] = 0.0
        Jp[has_d, 2, 2] = 1.0 / obs.z_sigma[has_d]
    return Jp


def pose_observation_chi2(X_c: np.ndarray, obs: Observations, camera: PinholeCamera, bf: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`observation_chi2` of motion-only BA (with the metric depth row where ``obs.z_sigma`` is set)."""
    return _PoseTerms(X_c, obs, camera, bf).classify(X_c)


def _rotation_step(omega: np.ndarray) -> np.ndarray:
    """``Exp(omega)`` of one rotation vector ``(3,)``: :func:`_rodrigues` in scalar arithmetic (the LM
    step of motion-only BA takes one per trial, where numpy's per-call overhead would dominate)."""
    wx, wy, wz = float(omega[0]), float(omega[1]), float(omega[2])
    th2 = wx * wx + wy * wy + wz * wz
    if th2 < 1e-16:
        a, b = 1.0, 0.5
    else:
        th = math.sqrt(th2)
        a, b = math.sin(th) / th, (1.0 - math.cos(th)) / th2
    return np.array([
        [1.0 - b * (wy * wy + wz * wz), b * wx * wy - a * wz, b * wx * wz + a * wy],
        [b * wx * wy + a * wz, 1.0 - b * (wx * wx + wz * wz), b * wy * wz - a * wx],
        [b * wx * wz - a * wy, b * wy * wz + a * wx, 1.0 - b * (wx * wx + wy * wy)],
    ])


class _PoseTerms:
    """The observations of motion-only BA with what does not depend on the pose computed once:
    the measurements, ``1 / sigma``, and the third row's weight and measurement (``1 / sigma`` and
    ``u_R``, or ``1 / sigma_z`` and ``z`` for the metric depth row; zero without depth). The residuals
    and Jacobian are those of :func:`_pose_residuals` and :func:`_pose_point_jacobian` (tested equal);
    the LM loop evaluates them several times per iteration, so the constant parts are not redone."""

    __slots__ = ("X", "mu", "mv", "inv_s", "w3", "m3", "metric", "fx", "fy", "cx", "cy", "bf")

    def __init__(self, X_w: np.ndarray, obs: Observations, camera: PinholeCamera, bf: float) -> None:
        self.X = np.ascontiguousarray(X_w, float)
        self.mu, self.mv = obs.uv[:, 0], obs.uv[:, 1]
        self.inv_s = 1.0 / obs.sigma
        has_d = np.isfinite(obs.ur)
        self.metric = obs.z_sigma is not None
        if self.metric:
            with np.errstate(divide="ignore", invalid="ignore"):
                self.w3 = np.where(has_d, 1.0 / obs.z_sigma, 0.0)
            self.m3 = np.where(has_d, obs.z, 0.0)
        else:
            self.w3 = np.where(has_d, self.inv_s, 0.0)
            self.m3 = np.where(has_d, obs.ur, 0.0)
        self.fx, self.fy, self.cx, self.cy, self.bf = camera.fx, camera.fy, camera.cx, camera.cy, float(bf)

    def subset(self, keep: np.ndarray) -> "_PoseTerms":
        out = object.__new__(_PoseTerms)
        for name in ("X", "mu", "mv", "inv_s", "w3", "m3"):
            setattr(out, name, getattr(self, name)[keep])
        out.metric, out.fx, out.fy, out.cx, out.cy, out.bf = self.metric, self.fx, self.fy, self.cx, self.cy, self.bf
        return out

    def residuals(self, X_c: np.ndarray) -> np.ndarray:
        """Whitened residuals ``(K, 3)`` at the camera points ``X_c``."""
        iz = 1.0 / X_c[:, 2]
        r = np.empty((len(X_c), 3))
        pu = self.fx * X_c[:, 0] * iz + self.cx
        r[:, 0] = (pu - self.mu) * self.inv_s
        r[:, 1] = (self.fy * X_c[:, 1] * iz + self.cy - self.mv) * self.inv_s
        if self.metric:
            r[:, 2] = (X_c[:, 2] - self.m3) * self.w3
        else:
            r[:, 2] = (pu - self.bf * iz - self.m3) * self.w3
        return r

    def classify(self, X_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``chi^2 (K,)`` at the camera points ``X_c`` and whether each is an outlier (95 % quantile by
        degrees of freedom: 3 with depth, 2 without); points behind the camera are outliers."""
        with np.errstate(divide="ignore", invalid="ignore"):
            r = self.residuals(X_c)
        chi2 = np.einsum("ij,ij->i", r, r)
        bad = ~(chi2 <= np.where(self.w3 > 0, CHI2_3DOF, CHI2_2DOF)) | ~(X_c[:, 2] > 0)
        return chi2, bad

    def jacobian(self, X_c: np.ndarray, RX: np.ndarray) -> np.ndarray:
        """``(3K, 6)`` Jacobian of :meth:`residuals` in the pose step ``(omega, tau)``."""
        K = len(X_c)
        iz = 1.0 / X_c[:, 2]
        Jp = np.zeros((K, 3, 3))
        a = self.fx * iz
        c = -self.fx * X_c[:, 0] * iz * iz
        Jp[:, 0, 0] = a * self.inv_s
        Jp[:, 0, 2] = c * self.inv_s
        Jp[:, 1, 1] = self.fy * iz * self.inv_s
        Jp[:, 1, 2] = -self.fy * X_c[:, 1] * iz * iz * self.inv_s
        if self.metric:
            Jp[:, 2, 2] = self.w3
        else:
            Jp[:, 2, 0] = a * self.w3
            Jp[:, 2, 2] = (c + self.bf * iz * iz) * self.w3
        return _pose_columns(Jp, RX).reshape(-1, 6)


def _evaluate_pose(R: np.ndarray, t: np.ndarray, terms: _PoseTerms, delta2: float | None, dense=None) -> tuple[float, tuple]:
    """Robust cost of the pose ``(R, t)`` and what its linearisation needs (points behind the camera
    left out); with ``dense`` (a :class:`~dynslam_lab.geometry.depth_alignment.DenseTerm`) its point-to-plane residuals
    are added, each point it cannot associate costing as much as one at the association gate (so
    that losing points never lowers the cost)."""
    RX = terms.X @ R.T
    X_c = RX + t
    front = X_c[:, 2] > _MIN_DEPTH
    if not front.all():
        RX, X_c, terms = RX[front], X_c[front], terms.subset(front)
    r = terms.residuals(X_c)
    chi2 = np.einsum("ij,ij->i", r, r)
    cost = float(huber_cost(chi2, delta2).sum())
    dense_state = None
    if dense is not None:
        e, Jd, unmatched = dense.residuals(R, t)
        cost += float(huber_cost(e * e, delta2).sum()) + float(huber_cost(unmatched, delta2).sum())
        dense_state = (e, Jd, huber_weight(e * e, delta2))
    return cost, (RX, X_c, terms, r, huber_weight(chi2, delta2), dense_state)


def _lm_pose(R: np.ndarray, t: np.ndarray, X_w: np.ndarray, obs: Observations, camera: PinholeCamera, bf: float,
             delta2: float | None, iterations: int, dense=None) -> tuple[np.ndarray, np.ndarray, float]:
    """Levenberg-Marquardt on one pose ``T_c_w = (R, t)`` (robust kernel ``delta2`` or None; optional
    dense term, :func:`_evaluate_pose`); returns ``(R, t, cost)``."""
    return _lm_pose_terms(R, t, _PoseTerms(X_w, obs, camera, bf), delta2, iterations, dense)


def _lm_pose_terms(R: np.ndarray, t: np.ndarray, terms: _PoseTerms, delta2: float | None, iterations: int,
                   dense=None, damped: bool = True) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`_lm_pose` on observations already gathered in a :class:`_PoseTerms`. ``damped`` False: plain
    Gauss-Newton, every step taken and the pose not evaluated after the last (``iterations`` evaluations in
    all; the cost returned is the one before the last step): a refinement from a pose already close."""
    lam = 1e-4
    cost, (RX, X_c, o, r, w, ds) = _evaluate_pose(R, t, terms, delta2, dense)
    for it in range(iterations):
        J = o.jacobian(X_c, RX)
        Jw = J * np.repeat(w, 3)[:, None]
        H = J.T @ Jw
        g = Jw.T @ r.ravel()
        if ds is not None:
            e, Jd, wd = ds
            H += Jd.T @ (Jd * wd[:, None])
            g += Jd.T @ (wd * e)
        if not damped:
            try:
                dx = -np.linalg.solve(H + 1e-12 * np.eye(6), g)
            except np.linalg.LinAlgError:
                break
            R, t = _rotation_step(dx[:3]) @ R, t + dx[3:]
            if it == iterations - 1 or np.abs(dx).max() < _STEP_TOL:
                break
            cost, (RX, X_c, o, r, w, ds) = _evaluate_pose(R, t, terms, delta2, dense)
            continue
        diag = np.diag(H)
        while True:
            try:
                dx = -np.linalg.solve(H + np.diag(lam * diag + 1e-12), g)
            except np.linalg.LinAlgError:
                dx = np.zeros(6)
            R_new, t_new = _rotation_step(dx[:3]) @ R, t + dx[3:]
            new, state = _evaluate_pose(R_new, t_new, terms, delta2, dense)
            if new <= cost or lam > 1e8:
                break
            lam *= 10.0
        if new > cost:  # no step lowers the cost: converged
            break
        R, t, lam = R_new, t_new, max(lam / 10.0, 1e-9)
        RX, X_c, o, r, w, ds = state
        done = cost - new <= _REL_TOL * cost or np.abs(dx).max() < _STEP_TOL
        cost = new
        if done:
            break
    return R, t, cost


def optimize_pose(
    T_c_w: np.ndarray,
    X_w: np.ndarray,
    obs: Observations,
    camera: PinholeCamera,
    bf: float,
    rounds: int = 4,
    max_iterations: int = 10,
    dense=None,
    damped: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Motion-only bundle adjustment (ORB-SLAM2 eq. 2).

    Parameters
    ----------
    T_c_w : ``(4, 4)`` initial world-to-camera pose.
    X_w : ``(K, 3)`` world points (metres); obs : their measurements.
    rounds : outlier re-classification rounds (ORB-SLAM2: 4); the last without the Huber kernel.
    max_iterations : Levenberg-Marquardt iterations per round at most (ORB-SLAM2: 10).
    dense : optional :class:`~dynslam_lab.geometry.depth_alignment.DenseTerm`, point-to-plane residuals of the frame's
        depth added to the cost (ours, for frames with few features); its points are re-associated
        at every evaluation. Or a :class:`~dynslam_lab.geometry.depth_alignment.HybridTerm` (image edges too).
    damped : Levenberg-Marquardt (True, ORB-SLAM2's g2o); False: plain Gauss-Newton, ``max_iterations``
        steps each taken (tracking's refinement of a pose already close, ``TrackingConfig.joint_gn_iterations``).

    Returns
    -------
    ``(T_c_w (4, 4), outlier (K,) bool)``: after each round every observation (also the outliers of
    the round before) is classified again by its chi^2.
    """
    X_w = np.asarray(X_w, float).reshape(-1, 3)
    if len(X_w) != len(obs):
        raise ValueError(f"optimize_pose: {len(X_w)} points but {len(obs)} observations")
    if len(X_w) < 3 and dense is None:
        return np.asarray(T_c_w, float).copy(), np.ones(len(X_w), bool)
    R = nearest_rotation(np.asarray(T_c_w, float)[:3, :3])
    t = np.asarray(T_c_w, float)[:3, 3].copy()
    outlier = np.zeros(len(X_w), bool)
    terms = _PoseTerms(X_w, obs, camera, bf)
    for rnd in range(rounds):
        use = ~outlier
        if use.sum() < 3 and dense is None:
            break
        delta2 = HUBER_DELTA2 if rnd < rounds - 1 else None
        R, t, _ = _lm_pose_terms(R, t, terms if use.all() else terms.subset(use), delta2, max_iterations, dense, damped)
        _, outlier = terms.classify(X_w @ R.T + t)  # every observation classified again
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T, outlier


def pose_information(T_c_w: np.ndarray, X_w: np.ndarray, obs: Observations, camera: PinholeCamera,
                     bf: float, per_observation: bool = False) -> np.ndarray:
    """``(6, 6)`` Gauss-Newton information ``H = J^T J`` of one pose under the observations of motion-only
    BA (eq. 2, no robust kernel, whitened rows: one pixel at level 0), in its step ``(omega, tau)``
    (``R <- Exp(omega) R``, ``t <- t + tau``); points behind the camera are left out. It does not
    depend on the measured pixels, only on where the points are and which have depth. With
    ``per_observation``, ``(K, 6, 6)``: each observation's share (zero behind the camera), summing to ``H``.

    At ``T_c_w = I`` (points given in the camera) the step moves a point by ``[omega]_x X + tau``, minus
    the right perturbation ``T_w_c Exp(eps)`` of the camera's pose to first order, so ``H`` is also the
    information of that perturbation (the pose graph's edge residual, :mod:`.loop_closing.correction`)."""
    X_w = np.asarray(X_w, float).reshape(-1, 3)
    if len(X_w) != len(obs):
        raise ValueError(f"pose_information: {len(X_w)} points but {len(obs)} observations")
    R, t = np.asarray(T_c_w, float)[:3, :3], np.asarray(T_c_w, float)[:3, 3]
    terms = _PoseTerms(X_w, obs, camera, bf)
    RX = terms.X @ R.T
    X_c = RX + t
    front = X_c[:, 2] > _MIN_DEPTH
    J = terms.subset(front).jacobian(X_c[front], RX[front])
    if not per_observation:
        return J.T @ J
    out = np.zeros((len(X_w), 6, 6))
    Jk = J.reshape(-1, 3, 6)
    out[front] = np.einsum("kia,kib->kab", Jk, Jk)
    return out


def pose_uncertainty(T_c_w: np.ndarray, X_w: np.ndarray, obs: Observations, camera: PinholeCamera,
                     bf: float) -> tuple[float, float]:
    """How well the observations fix one pose: the largest standard deviation of the camera centre (m)
    and of its orientation (deg) that motion-only BA (eq. 2, no robust kernel) has at ``T_c_w`` if each
    whitened residual has unit variance (one pixel at level 0): the inverse of the Gauss-Newton
    information ``H = J^T J`` (:func:`pose_information`; the Cramer-Rao bound of the least-squares pose).

    With the step ``R <- Exp(omega) R``, ``t <- t + tau`` the centre ``c = -R^T t`` moves by
    ``dc = -R^T [t]_x omega - R^T tau`` to first order, so ``Cov(c) = J_c H^-1 J_c^T``; the orientation's is
    the ``omega`` block of ``H^-1``. Points clustered in a small part of the image leave a lateral
    translation and a rotation that explain them alike (large values); ``(inf, inf)`` when ``H`` is
    singular (fewer than 3 observations, or a degenerate set). Ours, to tell a weak feature pose."""
    X_w = np.asarray(X_w, float).reshape(-1, 3)
    if len(X_w) != len(obs):
        raise ValueError(f"pose_uncertainty: {len(X_w)} points but {len(obs)} observations")
    R, t = np.asarray(T_c_w, float)[:3, :3], np.asarray(T_c_w, float)[:3, 3]
    if int(((X_w @ R[2]) + t[2] > _MIN_DEPTH).sum()) < 3:
        return float("inf"), float("inf")
    H = pose_information(T_c_w, X_w, obs, camera, bf)
    if np.linalg.cond(H) > 1e12:
        return float("inf"), float("inf")
    C = np.linalg.inv(H)
    J_c = -R.T @ np.hstack([skew(t), np.eye(3)])
    cov_c = J_c @ C @ J_c.T
    sigma_c = np.sqrt(max(float(np.linalg.eigvalsh(cov_c)[-1]), 0.0))
    sigma_r = np.degrees(np.sqrt(max(float(np.linalg.eigvalsh(C[:3, :3])[-1]), 0.0)))
    return float(sigma_c), float(sigma_r)


def pose_step_mahalanobis(T_from: np.ndarray, T_to: np.ndarray, X_w: np.ndarray, obs: Observations,
                          camera: PinholeCamera, bf: float) -> float:
    """``d^2 = xi^T H xi``: the squared Mahalanobis length of the step ``xi = (omega, tau)`` from the pose ``T_from``
    to ``T_to`` (both ``T_c_w``; ``R_to = Exp(omega) R_from``, ``t_to = t_from + tau``) under the Gauss-Newton
    information ``H`` of the observations at ``T_from`` (:func:`pose_information`, one pixel a unit). To second
    order it is what the step adds to the least-squares cost of observations that ``T_from`` fits exactly: how far
    the observations themselves let the pose go (a chi^2 value with 6 degrees of freedom when ``T_to`` is a
    draw from their uncertainty). Ours, the bound on tracking's joint refinement
    (:attr:`~.tracking.TrackingConfig.joint_gate_chi2`)."""
    T_from, T_to = np.asarray(T_from, float), np.asarray(T_to, float)
    H = pose_information(T_from, X_w, obs, camera, bf)
    xi = np.concatenate([so3_log(T_to[:3, :3] @ T_from[:3, :3].T), T_to[:3, 3] - T_from[:3, 3]])
    return float(xi @ H @ xi)


# ----------------------------------------------------------------------------- bundle adjustment
@dataclass
class BAResult:
    """Result of bundle adjustment: optimised poses ``T_c_w`` per keyframe id, points ``(P, 3)`` in the
    order given, and ``outlier (K,)`` per observation (chi^2 test after optimisation)."""

    T_c_w: dict[int, np.ndarray]
    points: np.ndarray
    outlier: np.ndarray
    cost_before: float
    cost_after: float
    iterations: int = 0


@dataclass
class _BAProblem:
    """The arrays of one bundle adjustment.

    ``R (C, 3, 3)``, ``t (C, 3)``: every camera's ``T_c_w``; ``X (P, 3)`` the points; per
    observation its camera row ``cam (K,)`` and point ``pt (K,)``; ``free_cam (F,)`` the camera rows
    that move and ``slot (K,)`` each observation's index into them (-1 for a fixed camera).
    """

    R: np.ndarray
    t: np.ndarray
    X: np.ndarray
    cam: np.ndarray
    pt: np.ndarray
    free_cam: np.ndarray
    slot: np.ndarray
    obs: Observations
    camera: PinholeCamera
    bf: float
    unique_pairs: bool = True  # no free camera observes a point twice

    def camera_points(self, R=None, t=None, X=None) -> tuple[np.ndarray, np.ndarray]:
        """``(R X_w, X_c)`` of every observation, ``(K, 3)`` each."""
        R = self.R if R is None else R
        t = self.t if t is None else t
        X = self.X if X is None else X
        RX = np.einsum("kij,kj->ki", R[self.cam], X[self.pt])
        return RX, RX + t[self.cam]

    def cost(self, weight: np.ndarray, delta2: float | None, R=None, t=None, X=None) -> float:
        """Robust cost ``sum weight rho(chi^2)`` (observations behind a camera left out)."""
        _, X_c = self.camera_points(R, t, X)
        use = (X_c[:, 2] > _MIN_DEPTH) & (weight > 0)
        r, _ = _residuals(X_c[use], self.obs.subset(use), self.camera, self.bf)
        return float((weight[use] * huber_cost(np.einsum("ij,ij->i", r, r), delta2)).sum())

    def moved(self, dc: np.ndarray, dp: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(R, t, X)`` after the step ``dc (F, 6)``, ``dp (P, 3)``."""
        R, t = self.R.copy(), self.t.copy()
        R[self.free_cam] = _rodrigues(dc[:, :3]) @ self.R[self.free_cam]
        t[self.free_cam] += dc[:, 3:]
        return R, t, self.X + dp


@dataclass
class _NormalEquations:
    """The blocks of ``H = J^T W J`` and ``g = J^T W e`` of a bundle adjustment: ``H_cc (F, 6, 6)`` per
    free camera, ``H_pp (P, 3, 3)`` per point, ``H_cp (Kf, 6, 3)`` per observation by a free camera
    (its slot ``s (Kf,)`` and point ``p (Kf,)``), ``g_c (F, 6)``, ``g_p (P, 3)``."""

    H_cc: np.ndarray
    H_pp: np.ndarray
    H_cp: np.ndarray
    s: np.ndarray
    p: np.ndarray
    g_c: np.ndarray
    g_p: np.ndarray
    unique_pairs: bool


def _ba_normal_equations(pb: _BAProblem, weight: np.ndarray, delta2: float | None) -> _NormalEquations:
    """Linearise at the current estimate and accumulate the normal equations' blocks.

    Per observation ``k`` (camera ``c``, point ``p``): the whitened residual ``e_k (3,)``, the IRLS
    weight ``w_k = rho'(chi^2_k) weight_k`` (zero behind the camera), the point columns
    ``J_p = (1/sigma) dpi/dX_c R`` and the pose columns ``J_c = (1/sigma) dpi/dX_c [-[R X]_x, I]``;
    ``H_pp += J_p^T w J_p``, ``H_cc += J_c^T w J_c``, ``H_cp = J_c^T w J_p``, ``g += J^T w e``.
    """
    RX, X_c = pb.camera_points()
    front = X_c[:, 2] > _MIN_DEPTH
    X_c = np.where(front[:, None], X_c, [0.0, 0.0, 1.0])  # placeholder depth: their weight is zero
    r, _ = _residuals(X_c, pb.obs, pb.camera, pb.bf)
    w = huber_weight(np.einsum("ij,ij->i", r, r), delta2) * weight * front
    Jx = _whitened_jacobian(X_c, pb.obs, pb.camera, pb.bf)
    J_pt = Jx @ pb.R[pb.cam]
    JptT_w = (J_pt * w[:, None, None]).transpose(0, 2, 1)
    n_pts = len(pb.X)
    H_pp = _block_sum(JptT_w @ J_pt, pb.pt, n_pts)
    g_p = _block_sum((JptT_w @ r[:, :, None])[..., 0], pb.pt, n_pts)
    free = pb.slot >= 0
    s, p = pb.slot[free], pb.pt[free]
    J_cam = _pose_columns(Jx[free], RX[free])
    JcT_w = (J_cam * w[free, None, None]).transpose(0, 2, 1)
    F = len(pb.free_cam)
    H_cc = _block_sum(JcT_w @ J_cam, s, F)
    g_c = _block_sum((JcT_w @ r[free][:, :, None])[..., 0], s, F)
    return _NormalEquations(H_cc, H_pp, JcT_w @ J_pt[free], s, p, g_c, g_p, pb.unique_pairs)


def _block_sum(values: np.ndarray, index: np.ndarray, n: int) -> np.ndarray:
    """Sum the blocks ``values (K, ...)`` into ``n`` bins by ``index (K,)`` (one bincount per entry)."""
    flat = values.reshape(len(values), int(np.prod(values.shape[1:])))  # (0, ...) too: no free camera
    out = np.empty((n, flat.shape[1]))
    for i in range(flat.shape[1]):  # loop over the entries of a block (at most 36)
        out[:, i] = np.bincount(index, weights=flat[:, i], minlength=n)
    return out.reshape((n,) + values.shape[1:])


def _damped(H: np.ndarray, lam: float) -> np.ndarray:
    """``H + lambda diag(H)`` for a stack of square blocks (plus a tiny ridge for empty blocks)."""
    d = np.einsum("...ii->...i", H)
    return H + (lam * d + 1e-9)[..., :, None] * np.eye(H.shape[-1])


_DENSE_SCHUR_MAX = 4_000_000  # entries of the dense (6F, 3P) H_cp above which the sparse product is used


def _schur_step(ne: _NormalEquations, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """One damped Gauss-Newton step ``(dc (F, 6), dp (P, 3))``, the points eliminated by the Schur
    complement (module docstring)."""
    F, n_pts = len(ne.H_cc), len(ne.H_pp)
    H_pp_inv = np.linalg.inv(_damped(ne.H_pp, lam))
    if F == 0:
        return np.zeros((0, 6)), -(H_pp_inv @ ne.g_p[:, :, None])[..., 0]
    W = ne.H_cp
    Y = W @ H_pp_inv[ne.p]  # the blocks of H_cp H_pp^-1
    if 18 * F * n_pts <= _DENSE_SCHUR_MAX:  # few free cameras (local BA): dense (6F, 3P) matrices
        Yd = np.zeros((F, 6, n_pts, 3))
        Wd = np.zeros((F, 6, n_pts, 3))
        if ne.unique_pairs:
            Yd[ne.s, :, ne.p], Wd[ne.s, :, ne.p] = Y, W
        else:  # a keyframe observing a point twice
            np.add.at(Yd, (ne.s, slice(None), ne.p), Y)
            np.add.at(Wd, (ne.s, slice(None), ne.p), W)
        Y_m, W_m = Yd.reshape(6 * F, 3 * n_pts), Wd.reshape(6 * F, 3 * n_pts)
    else:  # many (global BA): the same products with sparse matrices
        rows = np.broadcast_to(6 * ne.s[:, None, None] + np.arange(6)[None, :, None], W.shape).ravel()
        cols = np.broadcast_to(3 * ne.p[:, None, None] + np.arange(3)[None, None, :], W.shape).ravel()
        Y_m = sp.csr_matrix((Y.ravel(), (rows, cols)), shape=(6 * F, 3 * n_pts))
        W_m = sp.csr_matrix((W.ravel(), (rows, cols)), shape=(6 * F, 3 * n_pts))
    S = Y_m @ W_m.T  # H_cp H_pp^-1 H_pc
    S = -(S.toarray() if sp.issparse(S) else S)
    S.reshape(F, 6, F, 6)[np.arange(F), :, np.arange(F), :] += _damped(ne.H_cc, lam)
    dc = solve_spd(S, -ne.g_c.ravel() + Y_m @ ne.g_p.ravel()).reshape(F, 6)
    H_pc_dc = _block_sum((W.transpose(0, 2, 1) @ dc[ne.s][:, :, None])[..., 0], ne.p, n_pts)
    return dc, -(H_pp_inv @ (ne.g_p + H_pc_dc)[:, :, None])[..., 0]


def solve_spd(S, b: np.ndarray) -> np.ndarray:
    """Solve a symmetric positive-definite system ``S x = b`` (dense Cholesky; sparse LU when ``S`` is
    large or given sparse). Shared with :mod:`.pose_graph`."""
    if S.shape[0] > 1200:
        return spsolve(sp.csc_matrix(S), b)
    if sp.issparse(S):
        S = S.toarray()
    try:
        return cho_solve(cho_factor(S, check_finite=False), b, check_finite=False)
    except LinAlgError:
        return np.linalg.lstsq(S, b, rcond=None)[0]


def _lm_ba(pb: _BAProblem, weight: np.ndarray, delta2: float | None, iterations: int) -> int:
    """Levenberg-Marquardt on ``pb`` (in place) with observation weights ``weight (K,)``; returns the
    iterations run."""
    lam = 1e-4
    cost = pb.cost(weight, delta2)
    it = 0
    for it in range(1, iterations + 1):
        ne = _ba_normal_equations(pb, weight, delta2)
        while True:
            dc, dp = _schur_step(ne, lam)
            R, t, X = pb.moved(dc, dp)
            new = pb.cost(weight, delta2, R, t, X)
            if new <= cost or lam > 1e8:
                break
            lam *= 10.0
        if new > cost:  # no step lowers the cost: converged
            break
        step = max(np.abs(dc).max(initial=0.0), np.abs(dp).max(initial=0.0))
        pb.R, pb.t, pb.X, lam = R, t, X, max(lam / 10.0, 1e-9)
        done = cost - new <= _REL_TOL * cost or step < _STEP_TOL
        cost = new
        if done:
            break
    return it


def _ba_problem(poses: dict[int, np.ndarray], fixed: set[int], points: np.ndarray, obs_cam: np.ndarray,
                obs_pt: np.ndarray, obs: Observations, camera: PinholeCamera, bf: float) -> tuple[_BAProblem, np.ndarray]:
    """Gather the arrays of a bundle adjustment; also returns the keyframe ids of the camera rows."""
    cam_ids = np.array(sorted(poses), np.int64)
    T = np.stack([np.asarray(poses[int(k)], float) for k in cam_ids]) if len(cam_ids) else np.zeros((0, 4, 4))
    R = np.stack([nearest_rotation(M[:3, :3]) for M in T]) if len(T) else np.zeros((0, 3, 3))
    cam = np.searchsorted(cam_ids, np.asarray(obs_cam, np.int64))
    is_free = ~np.isin(cam_ids, np.array(sorted(fixed), np.int64))
    free_cam = np.flatnonzero(is_free)
    slot_of = np.full(len(cam_ids), -1, np.int64)
    slot_of[free_cam] = np.arange(len(free_cam))
    X = np.asarray(points, float).reshape(-1, 3).copy()
    pt, slot = np.asarray(obs_pt, np.int64), slot_of[cam]
    pair = (slot * len(X) + pt)[slot >= 0]
    pb = _BAProblem(R, T[:, :3, 3].copy(), X, cam, pt, free_cam, slot, obs, camera, bf,
                    unique_pairs=len(np.unique(pair)) == len(pair))
    return pb, cam_ids


def local_bundle_adjustment(
    poses: dict[int, np.ndarray],
    fixed: set[int],
    points: np.ndarray,
    obs_cam: np.ndarray,
    obs_pt: np.ndarray,
    obs: Observations,
    camera: PinholeCamera,
    bf: float,
    max_iterations: int = 10,
    second_round: bool = True,
) -> BAResult:
    """Bundle adjustment (ORB-SLAM2 eqs. 3-4): Levenberg-Marquardt with the Schur complement.

    Parameters
    ----------
    poses : keyframe id -> ``T_c_w (4, 4)`` of every keyframe in the problem.
    fixed : ids whose poses stay fixed (``K_F``; include the map origin).
    points : ``(P, 3)`` world points to optimise.
    obs_cam : ``(K,)`` keyframe id of each observation; obs_pt : ``(K,)`` index into ``points``.
    obs : the measurements ``(K)``.
    max_iterations : Levenberg-Marquardt iterations per round at most.
    second_round : after the Huber round, drop chi^2 outliers and optimise again without the
        robust kernel (ORB-SLAM2 does 5 + 10 iterations).

    Returns
    -------
    BAResult; ``cost_before`` / ``cost_after`` are ``0.5 sum chi^2`` over all observations.
    """
    pb, cam_ids = _ba_problem(poses, fixed, points, obs_cam, obs_pt, obs, camera, bf)
    k_obs = len(pb.pt)
    everything = np.ones(k_obs)
    cost_before = 0.5 * pb.cost(everything, None)
    iterations = 0
    if k_obs and (len(pb.free_cam) or len(pb.X)):
        iterations = _lm_ba(pb, everything, HUBER_DELTA2, max_iterations)
        if second_round:
            _, bad = observation_chi2(pb.camera_points()[1], obs, camera, bf)
            iterations += _lm_ba(pb, (~bad).astype(float), None, max_iterations)
    out = {}
    for i, k in enumerate(cam_ids):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = pb.R[i], pb.t[i]
        out[int(k)] = T
    _, outlier = observation_chi2(pb.camera_points()[1], obs, camera, bf)
    return BAResult(out, pb.X.copy(), outlier, cost_before, 0.5 * pb.cost(everything, None), iterations)
