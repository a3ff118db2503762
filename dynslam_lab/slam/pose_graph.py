"""Pose graph optimisation in SE(3) over the essential graph, and map point correction.

When a loop is closed, the error accumulated along the loop must be spread over the keyframes.
ORB-SLAM2 (Mur-Artal and Tardos, T-RO 2017, Sec. V-B; ORB-SLAM, T-RO 2015, Sec. VII-D,
``Optimizer::OptimizeEssentialGraph``) optimises the poses of the *essential graph*: the
spanning tree (each keyframe to its parent), the strong covisibility edges (``>= 100`` shared
map points), and the loop edges. Each edge ``(i, j)`` carries the relative pose measured
*before* the correction, ``Z_ij = T_w_i^-1 T_w_j``, except the new loop edges, which carry the
loop's relative pose; the cost is

.. math::

    \\min_{\\{T_k\\}} \\sum_{(i, j)} w_{ij} \\left\\lVert \\log\\!\\left(Z_{ij}^{-1}\\, T_i^{-1} T_j\\right)^\\vee \\right\\rVert^2

with ``log(.)^v`` the 6-vector (rotation vector, translation) of the error pose, its rotation part
multiplied by ``PoseGraphConfig.rotation_weight`` (metres; ours): a rotation error ``phi`` then costs as
much as the displacement ``rotation_weight * phi`` it gives a point that far away, so rotation and
translation are compared in one unit (ORB-SLAM2's identity information mixes radians and metres as
if every point were 1 m away). ORB-SLAM2
works in Sim(3) because monocular scale drifts; RGB-D has metric scale, so SE(3) here. The
loop keyframe is held fixed (gauge). ORB-SLAM2 runs 20 Levenberg-Marquardt iterations.

Afterwards every map point moves with the keyframe that created it (ORB-SLAM2's reference
keyframe): ``X_new = T_w_r^new (T_w_r^old)^-1 X_old``.

Our reading: the poses are stepped around the current estimate, ``R_k <- Exp(dw_k) R_k``,
``t_k <- t_k + dt_k``, and the problem is solved by Levenberg-Marquardt on the block-sparse normal
equations with the analytic Jacobian of each edge. With ``R_e = Z_R^T R_i^T R_j`` and
``t_e = Z_R^T (R_i^T (t_j - t_i) - Z_t)``, the residual ``r = (log(R_e), t_e)`` has::

    d log(R_e) / d dw_j =  J_r^-1(phi) R_j^T        d log(R_e) / d dw_i = -J_r^-1(phi) R_j^T
    d t_e / d dt_j      =  Z_R^T R_i^T              d t_e / d dt_i      = -Z_R^T R_i^T
    d t_e / d dw_i      =  Z_R^T R_i^T [t_j - t_i]_x                  (d t_e / d dw_j = 0)

with ``phi = log(R_e)`` and ``J_r^-1`` the inverse right Jacobian of SO(3). Each edge touches the 12
parameters of its two poses, so ``H = J^T W J`` is block-sparse (``6 x 6`` blocks on the diagonal
and at every edge); it is built as a scipy sparse matrix and solved by Cholesky (or sparse LU for
thousands of keyframes). A robust loss (``PoseGraphConfig.loss``) re-weights each edge by
``rho'(||r_e||^2)`` (scipy's loss functions with scale 1, applied to the edge's squared norm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

from ..geometry.se3 import skew
from .optimize import solve_spd

__all__ = ["PoseGraphConfig", "PoseGraphResult", "optimize_pose_graph", "edge_residuals", "sqrt_information",
           "correct_points"]


@dataclass(frozen=True)
class PoseGraphConfig:
    """Parameters of essential graph optimisation (ORB-SLAM2 ``OptimizeEssentialGraph``)."""

    max_iterations: int = 20  # Levenberg-Marquardt iterations at most; ORB-SLAM2: 20
    min_covisibility_weight: int = 100  # shared map points for a covisibility edge; ORB-SLAM2 minFeat: 100
    rotation_weight: float = 3.0  # m: the rotation residual (rad) times this, so that it counts as the displacement of a point this far
    # away (a room 2-4 m deep; translation residuals in m); ours, ORB-SLAM2 uses identity (1); docs/loop_closing.md "Where the
    # correction puts a plain room's drift": 3 lowered `loop_flat`'s worst ATE 29.4 -> 24.6 mm, other rooms unchanged
    information: str = "points"  # each edge's information matrix: "points" (from the map points the edge's keyframes share, the loop's from its matches; loop_closing.correction.edge_information; ours, docs/loop_closing.md "Information per edge") or "identity" (ORB-SLAM2; rotation counted rotation_weight times)
    floor_rotation_deg: float = 1.0  # "points": a prior of this rotation sigma added to every edge (an edge with no shared point, tracked by depth); ours, as tracking.dense_prior_rotation_deg
    floor_translation: float = 0.02  # m, the same for the translation; ours, as tracking.dense_prior_translation
    dense_scale: float = 0.01  # "points": every odometry edge measured by its keyframes' reduced depth too (loop_closing.dense_factor; j's depth, every other cell, aligned to i's from the edge's measurement, held to it with the floor sigmas): the aligned relative pose becomes the measurement, and this times the alignment's information is added; 0 = off; ours, docs/loop_closing.md "Odometry edges measured by depth"
    dense_max_edges: int = 300  # at most this many edges are measured by depth per correction (~7 ms each), the weakest first (smallest eigenvalue of their information in units of the floor); bounds the worker's time on large maps; ours
    loss: str = "linear"  # robust loss on an edge's squared residual (scipy's names); ORB-SLAM2 uses none here (a robust loss would mute the loop edge)

    def __post_init__(self) -> None:
        if self.max_iterations < 1:
            raise ValueError(f"PoseGraphConfig.max_iterations must be >= 1, got {self.max_iterations}")
        if self.min_covisibility_weight < 0:
            raise ValueError(f"PoseGraphConfig.min_covisibility_weight must be >= 0, got {self.min_covisibility_weight}")
        if self.rotation_weight <= 0:
            raise ValueError(f"PoseGraphConfig.rotation_weight must be > 0, got {self.rotation_weight}")
        if self.information not in ("identity", "points"):
            raise ValueError(f"PoseGraphConfig.information must be 'identity' or 'points', got {self.information!r}")
        if self.dense_max_edges < 0:
            raise ValueError(f"PoseGraphConfig.dense_max_edges must be >= 0, got {self.dense_max_edges}")
        if not self.dense_scale >= 0:
            raise ValueError(f"PoseGraphConfig.dense_scale must be >= 0, got {self.dense_scale}")
        if not (self.floor_rotation_deg > 0 and self.floor_translation > 0):
            raise ValueError("PoseGraphConfig.floor_rotation_deg and floor_translation must be > 0")
        if self.loss not in ("linear", "soft_l1", "huber", "cauchy", "arctan"):
            raise ValueError(f"PoseGraphConfig.loss must be a scipy least_squares loss, got {self.loss!r}")


@dataclass(frozen=True)
class PoseGraphResult:
    """Optimised poses ``(K, 4, 4)`` T_w_c, the cost ``0.5 sum w rho(||r||^2)`` before and after, and the
    Levenberg-Marquardt iterations run (``n_evaluations``)."""

    poses: np.ndarray
    initial_cost: float
    final_cost: float
    n_evaluations: int


def _apply_update(R0: np.ndarray, t0: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = x.reshape(-1, 6)
    R = Rotation.from_rotvec(d[:, :3]).as_matrix() @ R0
    return R, t0 + d[:, 3:]


def _inv_right_jacobian(phi: np.ndarray) -> np.ndarray:
    """Inverse right Jacobian of SO(3) ``(E, 3)`` -> ``(E, 3, 3)``:
    ``I + [phi]_x / 2 + (1 / th^2 - (1 + cos th) / (2 th sin th)) [phi]_x^2``."""
    th = np.linalg.norm(phi, axis=1)[:, None, None]
    W = skew(phi)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    c = np.where(small, 1.0 / 12.0, 1.0 / ths**2 - (1.0 + np.cos(ths)) / (2.0 * ths * np.sin(ths)))
    return np.eye(3) + 0.5 * W + c * (W @ W)


_LOSS_WEIGHT = {  # rho'(z) of scipy's losses (scale 1), z = squared norm of an edge's residual
    "linear": lambda z: np.ones_like(z),
    "soft_l1": lambda z: 1.0 / np.sqrt(1.0 + z),
    "huber": lambda z: np.where(z <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(z, 1.0))),
    "cauchy": lambda z: 1.0 / (1.0 + z),
    "arctan": lambda z: 1.0 / (1.0 + z**2),
}
_LOSS = {  # rho(z)
    "linear": lambda z: z,
    "soft_l1": lambda z: 2.0 * (np.sqrt(1.0 + z) - 1.0),
    "huber": lambda z: np.where(z <= 1.0, z, 2.0 * np.sqrt(np.maximum(z, 1.0)) - 1.0),
    "cauchy": np.log1p,
    "arctan": np.arctan,
}


def edge_residuals(
    R: np.ndarray, t: np.ndarray, edges: np.ndarray, Z: np.ndarray, sqrt_w: np.ndarray, rotation_weight: float,
    sqrt_info: np.ndarray | None = None,
) -> np.ndarray:
    """Residuals ``(E, 6)``: ``log(Z_ij^-1 T_i^-1 T_j)`` (rotation vector in rad, translation in m), weighted.

    ``R (K, 3, 3)``, ``t (K, 3)`` are the poses T_w_c; ``edges (E, 2)`` index them; ``Z (E, 4, 4)``
    the measured ``T_i_j``; ``sqrt_w (E,)`` square roots of the edge weights; ``rotation_weight`` (m) multiplies
    the rotation part (``PoseGraphConfig.rotation_weight``; no default here, so that every caller states which
    problem it solves); ``sqrt_info (E, 6, 6)``, when given, multiplies each edge's residual on the left
    (:func:`sqrt_information`).
    """
    i, j = edges[:, 0], edges[:, 1]
    Ri_T = np.swapaxes(R[i], 1, 2)
    R_ij = Ri_T @ R[j]
    t_ij = np.einsum("eab,eb->ea", Ri_T, t[j] - t[i])
    Rz_T = np.swapaxes(Z[:, :3, :3], 1, 2)
    R_e = Rz_T @ R_ij
    t_e = np.einsum("eab,eb->ea", Rz_T, t_ij - Z[:, :3, 3])
    r = np.concatenate([rotation_weight * Rotation.from_matrix(R_e).as_rotvec(), t_e], axis=1)
    if sqrt_info is not None:
        r = np.einsum("eab,eb->ea", sqrt_info, r)
    return r * sqrt_w[:, None]


def sqrt_information(information: np.ndarray, rotation_weight: float) -> np.ndarray:
    """``L (E, 6, 6)`` with ``L^T L`` the information of each edge's residual as :func:`edge_residuals`
    weights it (rotation scaled by ``rotation_weight``), from ``information (E, 6, 6)`` of the plain
    residual ``(rotation vector in rad, translation in m)`` (symmetric positive definite)."""
    s = np.array([1.0 / rotation_weight] * 3 + [1.0] * 3)
    info = np.asarray(information, float) * s[:, None] * s[None, :]
    info = 0.5 * (info + np.swapaxes(info, 1, 2))
    try:
        return np.swapaxes(np.linalg.cholesky(info), 1, 2)
    except np.linalg.LinAlgError as exc:
        raise ValueError("optimize_pose_graph: every information matrix must be symmetric positive definite") from exc


def optimize_pose_graph(
    T_w_c: np.ndarray,
    edges: np.ndarray,
    T_i_j: np.ndarray,
    fixed: np.ndarray | list[int] = (0,),
    weights: np.ndarray | None = None,
    config: PoseGraphConfig = PoseGraphConfig(),
    information: np.ndarray | None = None,
) -> PoseGraphResult:
    """Optimise poses so that their relative poses agree with the edge measurements.

    Parameters
    ----------
    T_w_c : ``(K, 4, 4)`` initial camera-to-world poses (metres).
    edges : ``(E, 2)`` int pose indices ``(i, j)``.
    T_i_j : ``(E, 4, 4)`` measured relative poses ``T_w_i^-1 T_w_j``.
    fixed : indices of poses held at their initial value (at least one: the gauge).
    weights : ``(E,)`` positive edge weights (default 1).
    config : iterations, rotation weight, loss.
    information : ``(E, 6, 6)`` information matrix of each edge's residual ``(rotation vector (rad),
        translation (m))``, symmetric positive definite, multiplied by the edge's weight (default: the
        identity, with the rotation counted ``rotation_weight`` times; with it, ``rotation_weight`` only
        changes the numerical scaling, not the solution).

    Returns
    -------
    PoseGraphResult with the optimised ``(K, 4, 4)`` poses.

    Raises
    ------
    ValueError
        Shapes disagree, an index is out of range, or no pose is fixed.
    """
    T = np.asarray(T_w_c, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValueError(f"optimize_pose_graph: T_w_c must be (K, 4, 4), got {T.shape}")
    K = len(T)
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    Z = np.asarray(T_i_j, dtype=np.float64).reshape(-1, 4, 4)
    if len(Z) != len(edges):
        raise ValueError(f"optimize_pose_graph: {len(edges)} edges but {len(Z)} measurements")
    if len(edges) and (edges.min() < 0 or edges.max() >= K):
        raise ValueError(f"optimize_pose_graph: edge indices must be in [0, {K}), got range [{edges.min()}, {edges.max()}]")
    fixed_mask = np.zeros(K, bool)
    fixed_idx = np.asarray(fixed, dtype=np.int64).reshape(-1)
    if len(fixed_idx) == 0:
        raise ValueError("optimize_pose_graph: at least one pose must be fixed (gauge freedom)")
    if fixed_idx.min() < 0 or fixed_idx.max() >= K:
        raise ValueError(f"optimize_pose_graph: fixed indices must be in [0, {K}), got {fixed_idx.tolist()}")
    fixed_mask[fixed_idx] = True
    w = np.ones(len(edges)) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    if len(w) != len(edges) or np.any(~(w > 0)):
        raise ValueError(f"optimize_pose_graph: weights must be {len(edges)} positive numbers")
    sqrt_w = np.sqrt(w)
    L = None
    if information is not None:
        info = np.asarray(information, dtype=np.float64)
        if info.shape != (len(edges), 6, 6):
            raise ValueError(f"optimize_pose_graph: information must be ({len(edges)}, 6, 6), got {info.shape}")
        L = sqrt_information(info, config.rotation_weight)
    R0, t0 = T[:, :3, :3].copy(), T[:, :3, 3].copy()
    free = np.flatnonzero(~fixed_mask)
    if len(edges) == 0 or len(free) == 0:
        return PoseGraphResult(T.copy(), 0.0, 0.0, 0)
    cost0, sol = _lm_pose_graph(R0, t0, free, edges, Z, sqrt_w, config, L)
    out = np.tile(np.eye(4), (K, 1, 1))
    out[:, :3, :3], out[:, :3, 3] = sol[0], sol[1]
    return PoseGraphResult(out, cost0, sol[2], sol[3])


def _edge_jacobian(R: np.ndarray, t: np.ndarray, edges: np.ndarray, Z: np.ndarray, r: np.ndarray,
                   rotation_weight: float) -> tuple[np.ndarray, np.ndarray]:
    """Unweighted Jacobian blocks ``(E, 6, 6)`` of each edge's residual in the steps of its poses
    ``i`` and ``j`` (module docstring); ``r (E, 6)`` the unweighted residuals."""
    i, j = edges[:, 0], edges[:, 1]
    ZR_T = np.swapaxes(Z[:, :3, :3], 1, 2)
    A = ZR_T @ np.swapaxes(R[i], 1, 2)  # Z_R^T R_i^T
    Jr_inv_Rj = _inv_right_jacobian(r[:, :3] / rotation_weight) @ np.swapaxes(R[j], 1, 2)
    Ji = np.zeros((len(edges), 6, 6))
    Jj = np.zeros((len(edges), 6, 6))
    Ji[:, :3, :3] = -rotation_weight * Jr_inv_Rj
    Jj[:, :3, :3] = rotation_weight * Jr_inv_Rj
    Ji[:, 3:, :3] = A @ skew(t[j] - t[i])
    Ji[:, 3:, 3:] = -A
    Jj[:, 3:, 3:] = A
    return Ji, Jj


def _lm_pose_graph(R: np.ndarray, t: np.ndarray, free: np.ndarray, edges: np.ndarray, Z: np.ndarray,
                   sqrt_w: np.ndarray, config: PoseGraphConfig, L: np.ndarray | None = None):
    """Levenberg-Marquardt over the free poses; returns ``(initial cost, (R, t, final cost, iterations))``
    with ``cost = 0.5 sum w rho(||L_e r_e||^2)`` (``L (E, 6, 6)`` square roots of the information, identity
    when None)."""
    K = len(R)
    col_of = np.full(K, -1, np.int64)
    col_of[free] = np.arange(len(free))
    loss, dloss = _LOSS[config.loss], _LOSS_WEIGHT[config.loss]
    n = 6 * len(free)

    def evaluate(R, t):
        r = edge_residuals(R, t, edges, Z, np.ones(len(edges)), config.rotation_weight)
        rw = r if L is None else np.einsum("eab,eb->ea", L, r)
        z = sqrt_w**2 * np.einsum("ij,ij->i", rw, rw)
        return 0.5 * float(loss(z).sum()), r, z

    cost, r, z = evaluate(R, t)
    cost0, lam, it = cost, 1e-4, 0
    for it in range(1, config.max_iterations + 1):
        w = sqrt_w**2 * dloss(z)  # IRLS weight of each edge
        Ji, Jj = _edge_jacobian(R, t, edges, Z, r, config.rotation_weight)
        if L is not None:  # whitened: L r and L J
            Ji, Jj = L @ Ji, L @ Jj
        blocks, rows, cols = [], [], []
        for end, J in ((0, Ji), (1, Jj)):
            c = col_of[edges[:, end]]
            ok = c >= 0
            blocks.append(J[ok] * np.sqrt(w[ok])[:, None, None])
            rows.append(np.broadcast_to((6 * np.flatnonzero(ok))[:, None, None] + np.arange(6)[:, None], J[ok].shape))
            cols.append(np.broadcast_to(6 * c[ok][:, None, None] + np.arange(6), J[ok].shape))
        Jw = sp.csr_matrix((np.concatenate([b.ravel() for b in blocks]),
                            (np.concatenate([x.ravel() for x in rows]), np.concatenate([x.ravel() for x in cols]))),
                           shape=(6 * len(edges), n))
        H = (Jw.T @ Jw).tocsr()
        rw = r if L is None else np.einsum("eab,eb->ea", L, r)
        g = Jw.T @ (rw * np.sqrt(w)[:, None]).ravel()
        diag = H.diagonal()
        while True:
            dx = solve_spd(H + sp.diags(lam * diag + 1e-12), -g)
            full = np.zeros((K, 6))
            full[free] = dx.reshape(-1, 6)
            R_new, t_new = _apply_update(R, t, full)
            new, r_new, z_new = evaluate(R_new, t_new)
            if new <= cost or lam > 1e8:
                break
            lam *= 10.0
        if new > cost:  # no step lowers the cost: converged
            break
        done = cost - new <= 1e-10 * max(cost, 1e-300) or np.abs(dx).max() < 1e-12
        R, t, cost, r, z, lam = R_new, t_new, new, r_new, z_new, max(lam / 10.0, 1e-12)
        if done:
            break
    return cost0, (R, t, cost, it)


def correct_points(points_w: np.ndarray, ref_index: np.ndarray, T_old: np.ndarray, T_new: np.ndarray) -> np.ndarray:
    """Move map points with their reference keyframes: ``X_new = T_new[r] T_old[r]^-1 X_old``.

    Parameters
    ----------
    points_w : ``(M, 3)`` world points (metres).
    ref_index : ``(M,)`` index of each point's reference keyframe into the pose stacks.
    T_old, T_new : ``(K, 4, 4)`` poses T_w_c before and after the correction.

    Returns
    -------
    ``(M, 3)`` corrected world points.
    """
    X = np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
    r = np.asarray(ref_index, dtype=np.int64).reshape(-1)
    if len(r) != len(X):
        raise ValueError(f"correct_points: {len(X)} points but {len(r)} reference indices")
    T_old = np.asarray(T_old, dtype=np.float64)
    T_new = np.asarray(T_new, dtype=np.float64)
    if T_old.shape != T_new.shape or T_old.ndim != 3:
        raise ValueError(f"correct_points: pose stacks must be equal (K, 4, 4), got {T_old.shape} and {T_new.shape}")
    if len(r) and (r.min() < 0 or r.max() >= len(T_old)):
        raise ValueError(f"correct_points: reference indices must be in [0, {len(T_old)})")
    # camera-frame coordinates in the old reference pose, then back to the world with the new one
    Ro, to = T_old[r, :3, :3], T_old[r, :3, 3]
    Xc = np.einsum("mba,mb->ma", Ro, X - to)
    return np.einsum("mab,mb->ma", T_new[r, :3, :3], Xc) + T_new[r, :3, 3]
