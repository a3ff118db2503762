"""Absolute trajectory error (ATE): global consistency of an estimated trajectory.

Sturm et al., "A benchmark for the evaluation of RGB-D SLAM systems", IROS 2012,
Section VI-B: after associating estimated poses ``P_i`` with ground-truth poses ``Q_i`` by
timestamp, the estimate is aligned to the ground truth by the least-squares transform ``S``
of the camera centres (Horn 1987 / Umeyama 1991: rigid SE(3), or Sim(3) with scale for
monocular systems), and the error at time ``i`` is

.. math::

    F_i = Q_i^{-1} S P_i, \\qquad e_i = \\lVert \\operatorname{trans}(F_i) \\rVert
        = \\lVert \\operatorname{trans}(Q_i) - \\operatorname{trans}(S P_i) \\rVert ,

summarised as ``RMSE = sqrt(mean e_i^2)``. The four papers of this toolkit (YOLO-SLAM Table
4, Zhang 2023, Chang 2021 Table II, ASG-SLAM Table 1) report the RMSE, mean, median, S.D.
of ``e_i`` in metres, which :func:`error_statistics` computes (S.D. with ``1/n``, like
evo and TUM's ``evaluate_ate.py``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..geometry.align import Alignment, AlignmentError, umeyama_alignment
from .sync import DEFAULT_MAX_DIFF, associate_trajectories
from .trajectory import Trajectory, TrajectoryError

__all__ = ["ErrorStats", "AteResult", "error_statistics", "align_trajectory", "compute_ate", "ALIGN_METHODS"]

#: Accepted values of ``align``: rigid (6 DoF), similarity (7 DoF, monocular), or none.
ALIGN_METHODS = ("se3", "sim3", "none")


@dataclass(frozen=True)
class ErrorStats:
    """Summary statistics of a vector of errors, as the papers' tables report them.

    Attributes
    ----------
    rmse, mean, median, std, min, max : in the unit of the errors (m or deg);
        ``std`` is the population standard deviation (``1/n``), as in evo and TUM's scripts.
    n : number of errors.
    """

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    n: int

    def to_dict(self) -> dict:
        """Plain ``dict`` (JSON-serialisable)."""
        return asdict(self)


def error_statistics(errors: np.ndarray) -> ErrorStats:
    """RMSE, mean, median, S.D., min, max of ``errors (N,)``.

    Raises
    ------
    ValueError
        ``errors`` is empty or contains NaN/inf.
    """
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    if e.size == 0:
        raise ValueError("error_statistics: no errors to summarise (empty array)")
    if not np.all(np.isfinite(e)):
        raise ValueError("error_statistics: errors contain NaN or inf")
    return ErrorStats(
        rmse=float(np.sqrt(np.mean(e * e))),
        mean=float(np.mean(e)),
        median=float(np.median(e)),
        std=float(np.std(e)),
        min=float(np.min(e)),
        max=float(np.max(e)),
        n=int(e.size),
    )


def align_trajectory(
    est: Trajectory, gt: Trajectory, align: str = "se3", gt_name: str = "ground truth", est_name: str = "estimate"
) -> tuple[Trajectory, Alignment]:
    """Align ``est`` onto ``gt`` (already associated, pose ``i`` with pose ``i``).

    Parameters
    ----------
    est, gt : trajectories of equal length.
    align : ``"se3"`` (rotation + translation), ``"sim3"`` (also scale) or ``"none"``.

    Returns
    -------
    aligned : ``est`` with every pose replaced by ``S P_i``: positions ``c R p + t`` and
        orientations ``R R_i`` (the scale acts on positions only).
    alignment : the transform ``S`` (identity for ``"none"``).

    Raises
    ------
    TrajectoryError
        Too few associated poses, or poses on a line (rotation undetermined); names both.
    """
    if align not in ALIGN_METHODS:
        raise ValueError(f"align must be one of {ALIGN_METHODS}, got {align!r}")
    if len(est) != len(gt):
        raise TrajectoryError(f"align_trajectory: {len(est)} estimated vs {len(gt)} ground-truth poses")
    if align == "none":
        return Trajectory(est.timestamps.copy(), est.poses.copy()), Alignment.identity()
    try:
        a = umeyama_alignment(est.positions, gt.positions, with_scale=(align == "sim3"))
    except AlignmentError as exc:
        raise TrajectoryError(f"cannot align {est_name} to {gt_name} ({align}): {exc}") from None
    T = np.eye(4)
    T[:3, :3] = a.R
    T[:3, 3] = a.t
    return est.transformed(T, scale=a.scale), a


@dataclass(frozen=True)
class AteResult:
    """Absolute trajectory error of one estimate.

    Attributes
    ----------
    errors : ``(K,)`` translational error per associated pose (m).
    stats : summary of ``errors``.
    timestamps : ``(K,)`` timestamps of the estimate's associated poses (s).
    gt_positions : ``(K, 3)`` ground-truth camera centres (m).
    est_positions : ``(K, 3)`` aligned estimated camera centres (m).
    alignment : the transform applied to the estimate.
    align : ``"se3"``, ``"sim3"`` or ``"none"``.
    """

    errors: np.ndarray
    stats: ErrorStats
    timestamps: np.ndarray
    gt_positions: np.ndarray
    est_positions: np.ndarray
    alignment: Alignment
    align: str


def compute_ate(
    gt: Trajectory,
    est: Trajectory,
    align: str = "se3",
    max_diff: float = DEFAULT_MAX_DIFF,
    associate: bool = True,
    gt_name: str = "ground truth",
    est_name: str = "estimate",
) -> AteResult:
    """Absolute trajectory error (translation part) of ``est`` against ``gt``.

    Parameters
    ----------
    gt, est : ground truth and estimate (``T_w_c`` poses, metres, seconds).
    align : ``"se3"`` (default, RGB-D), ``"sim3"`` (monocular) or ``"none"``.
    max_diff : timestamp association tolerance (s), see :mod:`.sync`.
    associate : if False, ``gt`` and ``est`` must already be paired pose by pose.
    gt_name, est_name : names used in error messages (file paths).

    Returns
    -------
    AteResult

    Examples
    --------
    >>> import numpy as np
    >>> from dynslam_lab.evaluation import Trajectory
    >>> P = np.tile(np.eye(4), (4, 1, 1)); P[:, :3, 3] = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
    >>> gt = Trajectory(np.arange(4.0), P)
    >>> round(compute_ate(gt, gt).stats.rmse, 12)
    0.0
    """
    if associate:
        gt, est = associate_trajectories(gt, est, max_diff, gt_name=gt_name, est_name=est_name)
    elif len(gt) != len(est):
        raise TrajectoryError(f"compute_ate: {len(gt)} ground-truth vs {len(est)} estimated poses (associate=False)")
    aligned, alignment = align_trajectory(est, gt, align, gt_name=gt_name, est_name=est_name)
    errors = np.linalg.norm(gt.positions - aligned.positions, axis=1)
    return AteResult(
        errors=errors,
        stats=error_statistics(errors),
        timestamps=est.timestamps.copy(),
        gt_positions=gt.positions.copy(),
        est_positions=aligned.positions.copy(),
        alignment=alignment,
        align=align,
    )
