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

with ``log(.)^v`` the 6-vector (rotation vector, translation) of the error pose. ORB-SLAM2
works in Sim(3) because monocular scale drifts; RGB-D has metric scale, so SE(3) here. The
loop keyframe is held fixed (gauge). ORB-SLAM2 runs 20 Levenberg-Marquardt iterations.

Afterwards every map point moves with the keyframe that created it (ORB-SLAM2's reference
keyframe): ``X_new = T_w_r^new (T_w_r^old)^-1 X_old``.

Our reading: the poses are parametrised by a small update around the initial guess,
``R_k = Exp(dw_k) R_k^0, t_k = t_k^0 + dt_k``; residuals of all edges are computed at once
(batched rotations), and ``scipy.optimize.least_squares`` (trust region) gets the sparsity of
the Jacobian (each 6-row residual depends on the 12 parameters of its two poses only), so the
finite-difference Jacobian costs a few residual evaluations per iteration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix
from scipy.spatial.transform import Rotation

__all__ = ["PoseGraphConfig", "PoseGraphResult", "optimize_pose_graph", "edge_residuals", "correct_points"]


@dataclass(frozen=True)
class PoseGraphConfig:
    """Parameters of essential graph optimisation (ORB-SLAM2 ``OptimizeEssentialGraph``)."""

    max_iterations: int = 20  # solver iterations; ORB-SLAM2: 20 Levenberg-Marquardt iterations
    min_covisibility_weight: int = 100  # shared map points for a covisibility edge; ORB-SLAM2 minFeat: 100
    rotation_weight: float = 1.0  # weight of the rotation residual (rad vs m; ours, ORB-SLAM2 uses identity)
    loss: str = "linear"  # scipy robust loss; ORB-SLAM2 uses none here (a robust loss would mute the loop edge)

    def __post_init__(self) -> None:
        if self.max_iterations < 1:
            raise ValueError(f"PoseGraphConfig.max_iterations must be >= 1, got {self.max_iterations}")
        if self.min_covisibility_weight < 0:
            raise ValueError(f"PoseGraphConfig.min_covisibility_weight must be >= 0, got {self.min_covisibility_weight}")
        if self.rotation_weight <= 0:
            raise ValueError(f"PoseGraphConfig.rotation_weight must be > 0, got {self.rotation_weight}")
        if self.loss not in ("linear", "soft_l1", "huber", "cauchy", "arctan"):
            raise ValueError(f"PoseGraphConfig.loss must be a scipy least_squares loss, got {self.loss!r}")


@dataclass(frozen=True)
class PoseGraphResult:
    """Optimised poses ``(K, 4, 4)`` T_w_c, the cost before and after, and the solver's evaluations."""

    poses: np.ndarray
    initial_cost: float
    final_cost: float
    n_evaluations: int


def _apply_update(R0: np.ndarray, t0: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = x.reshape(-1, 6)
    R = Rotation.from_rotvec(d[:, :3]).as_matrix() @ R0
    return R, t0 + d[:, 3:]


def edge_residuals(
    R: np.ndarray, t: np.ndarray, edges: np.ndarray, Z: np.ndarray, sqrt_w: np.ndarray, rotation_weight: float = 1.0
) -> np.ndarray:
    """Residuals ``(E, 6)``: ``log(Z_ij^-1 T_i^-1 T_j)`` (rotation vector in rad, translation in m), weighted.

    ``R (K, 3, 3)``, ``t (K, 3)`` are the poses T_w_c; ``edges (E, 2)`` index them; ``Z (E, 4, 4)``
    the measured ``T_i_j``; ``sqrt_w (E,)`` square roots of the edge weights.
    """
    i, j = edges[:, 0], edges[:, 1]
    Ri_T = np.swapaxes(R[i], 1, 2)
    R_ij = Ri_T @ R[j]
    t_ij = np.einsum("eab,eb->ea", Ri_T, t[j] - t[i])
    Rz_T = np.swapaxes(Z[:, :3, :3], 1, 2)
    R_e = Rz_T @ R_ij
    t_e = np.einsum("eab,eb->ea", Rz_T, t_ij - Z[:, :3, 3])
    r = np.concatenate([rotation_weight * Rotation.from_matrix(R_e).as_rotvec(), t_e], axis=1)
    return r * sqrt_w[:, None]


def optimize_pose_graph(
    T_w_c: np.ndarray,
    edges: np.ndarray,
    T_i_j: np.ndarray,
    fixed: np.ndarray | list[int] = (0,),
    weights: np.ndarray | None = None,
    config: PoseGraphConfig = PoseGraphConfig(),
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
    R0, t0 = T[:, :3, :3].copy(), T[:, :3, 3].copy()
    free = np.flatnonzero(~fixed_mask)
    if len(edges) == 0 or len(free) == 0:
        return PoseGraphResult(T.copy(), 0.0, 0.0, 0)
    col_of = np.full(K, -1, np.int64)
    col_of[free] = np.arange(len(free))

    def fun(x: np.ndarray) -> np.ndarray:
        full = np.zeros((K, 6))
        full[free] = x.reshape(-1, 6)
        R, t = _apply_update(R0, t0, full)
        return edge_residuals(R, t, edges, Z, sqrt_w, config.rotation_weight).ravel()

    # Jacobian sparsity: rows 6e..6e+5 depend on the 6 parameters of each free end of edge e.
    sparsity = lil_matrix((6 * len(edges), 6 * len(free)), dtype=np.int8)
    rows = (6 * np.arange(len(edges)))[:, None] + np.arange(6)[None, :]
    for end in (0, 1):
        c = col_of[edges[:, end]]
        ok = c >= 0
        rr = np.repeat(rows[ok], 6, axis=1)  # (e, 36)
        cc = np.tile(6 * c[ok][:, None] + np.arange(6)[None, :], (1, 6))
        sparsity[rr.ravel(), cc.ravel()] = 1
    x0 = np.zeros(6 * len(free))
    r0 = fun(x0)
    sol = least_squares(
        fun,
        x0,
        jac_sparsity=sparsity.tocsr(),
        method="trf",
        loss=config.loss,
        max_nfev=config.max_iterations,  # trust-region steps (each one residual evaluation)
        x_scale="jac",
        tr_solver="lsmr",
    )
    full = np.zeros((K, 6))
    full[free] = sol.x.reshape(-1, 6)
    R, t = _apply_update(R0, t0, full)
    out = np.tile(np.eye(4), (K, 1, 1))
    out[:, :3, :3] = R
    out[:, :3, 3] = t
    return PoseGraphResult(out, 0.5 * float(r0 @ r0), 0.5 * float(sol.fun @ sol.fun), int(sol.nfev))


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
