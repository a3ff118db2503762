"""Relative pose error (RPE): local accuracy (drift) of an estimated trajectory.

Sturm et al., "A benchmark for the evaluation of RGB-D SLAM systems", IROS 2012,
Section VI-A: for associated ground-truth poses ``Q_i`` and estimated poses ``P_i``, and a
pair of indices ``(i, j)`` a fixed interval apart, the relative pose error is

.. math::

    E_{ij} = \\left(Q_i^{-1} Q_j\\right)^{-1} \\left(P_i^{-1} P_j\\right),

the mismatch between how far the camera really moved from ``i`` to ``j`` and how far the
estimate says it moved. We report its translation ``||trans(E_ij)||`` (m) and rotation
angle ``angle(E_ij)`` (deg), each summarised by RMSE, mean, median, S.D., min, max (YOLO-SLAM
Tables 5-6, ASG-SLAM Tables 2-3). ``E_ij`` does not change under a rigid alignment of the
estimate; a Sim(3) alignment rescales its translation.

Pairs ``(i, j)``:

* ``delta_unit="frames"`` (evo's ``Unit.frames``): consecutive pairs ``(0, d), (d, 2d), ...``
  or, with ``all_pairs``, every ``(i, i + d)``.
* ``delta_unit="seconds"`` (TUM ``evaluate_rpe.py`` with ``--delta_unit s``): for a start
  pose ``i``, ``j`` is the later pose whose timestamp is closest to ``t_i + delta``; the pair
  is kept when ``|t_j - t_i - delta| <= delta_tol`` (default ``0.1 * delta``, so a gap in a
  partial trajectory does not yield a pair spanning much more than ``delta``). With
  ``all_pairs`` every pose starts a pair; otherwise pairs are chained without overlap,
  ``i_0 = 0, i_{k+1} = j_k``. TUM's script (``--fixed_delta``) also starts a pair at every
  pose and takes the closest stamp to ``t_i + delta``, but with no tolerance (it only drops
  pairs ending at the last pose) and then draws a random subset of at most 10000 pairs; we
  keep all pairs, deterministically, and reject pairs that miss ``delta`` by more than
  ``delta_tol``.

The rotation angle is taken from the rotation vector (``|log R|``), not from
``arccos((tr R - 1)/2)``, which loses precision for the small angles RPE deals with.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.align import Alignment
from ..geometry.se3 import se3_inv
from .ate import ALIGN_METHODS, ErrorStats, align_trajectory, error_statistics
from .sync import DEFAULT_MAX_DIFF, associate_trajectories
from .trajectory import Trajectory, TrajectoryError

__all__ = ["RpeResult", "rpe_pairs", "relative_errors", "compute_rpe", "DELTA_UNITS"]

#: Accepted values of ``delta_unit``.
DELTA_UNITS = ("frames", "seconds")


def rpe_pairs(
    timestamps: np.ndarray,
    delta: float = 1,
    delta_unit: str = "frames",
    all_pairs: bool = False,
    delta_tol: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(i, j)`` a fixed interval apart.

    Parameters
    ----------
    timestamps : ``(N,)`` increasing timestamps (s) of the associated poses.
    delta : interval: a positive integer number of frames, or seconds ``> 0``.
    delta_unit : ``"frames"`` or ``"seconds"`` (see the module docstring).
    all_pairs : every pose starts a pair (overlapping) instead of consecutive pairs.
    delta_tol : for seconds, largest accepted ``|t_j - t_i - delta|`` (s); default ``0.1 * delta``.

    Returns
    -------
    i, j : ``(P,)`` int arrays with ``i < j``.
    """
    t = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    n = len(t)
    if delta_unit not in DELTA_UNITS:
        raise ValueError(f"delta_unit must be one of {DELTA_UNITS}, got {delta_unit!r}")
    if not np.isfinite(delta) or delta <= 0:
        raise ValueError(f"delta must be > 0, got {delta}")
    if delta_unit == "frames":
        if float(delta) != int(delta):
            raise ValueError(f"delta must be a whole number of frames, got {delta}")
        d = int(delta)
        if all_pairs:
            i = np.arange(max(n - d, 0))
            return i, i + d
        starts = np.arange(0, n, d)
        return starts[:-1], starts[1:]
    # seconds
    if np.any(np.diff(t) < 0):
        raise ValueError("rpe_pairs: timestamps must be increasing for delta in seconds")
    tol = 0.1 * delta if delta_tol is None else float(delta_tol)
    if tol < 0:
        raise ValueError(f"delta_tol must be >= 0, got {delta_tol}")
    target = t + delta
    upper = np.minimum(np.searchsorted(t, target, side="left"), n - 1)
    lower = np.maximum(upper - 1, 0)
    use_lower = np.abs(t[lower] - target) <= np.abs(t[upper] - target)
    j_all = np.where(use_lower, lower, upper)
    ok = (j_all > np.arange(n)) & (np.abs(t[j_all] - target) <= tol)
    if all_pairs:
        i = np.flatnonzero(ok)
        return i, j_all[i]
    # Chain non-overlapping pairs: a walk over the poses (not a per-pixel hot path).
    pairs_i: list[int] = []
    k = 0
    while k < n:
        if ok[k]:
            pairs_i.append(k)
            k = int(j_all[k])
        else:
            k += 1
    i = np.asarray(pairs_i, dtype=int)
    return i, j_all[i] if len(i) else np.zeros(0, dtype=int)


def relative_errors(
    gt_poses: np.ndarray, est_poses: np.ndarray, i: np.ndarray, j: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Translation (m) and rotation (deg) of ``E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)``.

    Parameters
    ----------
    gt_poses, est_poses : ``(N, 4, 4)`` associated poses ``Q`` and ``P``.
    i, j : ``(P,)`` index pairs.

    Returns
    -------
    trans : ``(P,)`` metres.
    rot : ``(P,)`` degrees, in ``[0, 180]``.
    """
    Q_rel = se3_inv(gt_poses[i]) @ gt_poses[j]
    P_rel = se3_inv(est_poses[i]) @ est_poses[j]
    E = se3_inv(Q_rel) @ P_rel
    trans = np.linalg.norm(E[:, :3, 3], axis=1)
    from scipy.spatial.transform import Rotation  # imported here: trajectory I/O alone does not need scipy

    rot = np.degrees(Rotation.from_matrix(E[:, :3, :3]).magnitude()) if len(E) else np.zeros(0)
    return trans, np.asarray(rot, dtype=np.float64)


@dataclass(frozen=True)
class RpeResult:
    """Relative pose error of one estimate.

    Attributes
    ----------
    trans_errors : ``(P,)`` translational error per pair (m).
    rot_errors : ``(P,)`` rotational error per pair (deg).
    trans : statistics of ``trans_errors``.
    rot : statistics of ``rot_errors``.
    pairs : ``(P, 2)`` index pairs into the associated trajectories.
    timestamps : ``(P,)`` timestamp of the end pose ``j`` of each pair (s).
    delta, delta_unit, all_pairs : the pairing used.
    alignment : the transform applied to the estimate before computing ``E_ij``.
    """

    trans_errors: np.ndarray
    rot_errors: np.ndarray
    trans: ErrorStats
    rot: ErrorStats
    pairs: np.ndarray
    timestamps: np.ndarray
    delta: float
    delta_unit: str
    all_pairs: bool
    alignment: Alignment


def compute_rpe(
    gt: Trajectory,
    est: Trajectory,
    delta: float = 1,
    delta_unit: str = "frames",
    all_pairs: bool = False,
    align: str = "se3",
    max_diff: float = DEFAULT_MAX_DIFF,
    associate: bool = True,
    delta_tol: float | None = None,
    gt_name: str = "ground truth",
    est_name: str = "estimate",
) -> RpeResult:
    """Relative pose error of ``est`` against ``gt``.

    Parameters
    ----------
    gt, est : ground truth and estimate (``T_w_c`` poses).
    delta, delta_unit, all_pairs, delta_tol : the pairing, see :func:`rpe_pairs`.
        Pairs are formed on the estimate's associated timestamps.
    align : alignment applied first (``"se3"``, ``"sim3"``, ``"none"``); only a Sim(3)
        scale changes the result.
    max_diff : timestamp association tolerance (s).
    associate : if False, ``gt`` and ``est`` are already paired pose by pose.
    gt_name, est_name : names used in error messages.

    Returns
    -------
    RpeResult

    Raises
    ------
    TrajectoryError
        No pair of poses ``delta`` apart exists (trajectory too short for ``delta``).
    """
    if align not in ALIGN_METHODS:
        raise ValueError(f"align must be one of {ALIGN_METHODS}, got {align!r}")
    if associate:
        gt, est = associate_trajectories(gt, est, max_diff, gt_name=gt_name, est_name=est_name)
    elif len(gt) != len(est):
        raise TrajectoryError(f"compute_rpe: {len(gt)} ground-truth vs {len(est)} estimated poses (associate=False)")
    aligned, alignment = align_trajectory(est, gt, align, gt_name=gt_name, est_name=est_name)
    i, j = rpe_pairs(aligned.timestamps, delta, delta_unit, all_pairs, delta_tol)
    if len(i) == 0:
        raise TrajectoryError(
            f"RPE: no pose pairs {delta} {delta_unit} apart in {est_name} "
            f"({len(est)} associated poses over {aligned.timestamps[-1] - aligned.timestamps[0]:.3f} s)"
        )
    trans, rot = relative_errors(gt.poses, aligned.poses, i, j)
    return RpeResult(
        trans_errors=trans,
        rot_errors=rot,
        trans=error_statistics(trans),
        rot=error_statistics(rot),
        pairs=np.stack([i, j], axis=1),
        timestamps=aligned.timestamps[j],
        delta=delta,
        delta_unit=delta_unit,
        all_pairs=all_pairs,
        alignment=alignment,
    )
