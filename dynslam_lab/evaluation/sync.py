"""Timestamp association of two trajectories (nearest time within ``max_diff``).

Ground truth from a motion-capture system (TUM: 100 Hz) and a SLAM estimate (one pose per
tracked colour frame, ~30 Hz, possibly only part of the sequence) are sampled at different
times. Before poses can be compared, each pose of the *shorter* trajectory is paired with
the pose of the longer one whose timestamp is closest, and the pair is kept only if

.. math::

    |t^{short}_i - t^{long}_{j(i)}| \\le \\text{max\\_diff}.

This is the rule of evo's ``sync.associate_trajectories`` (nearest neighbour for each pose of
the shorter trajectory, ties to the earlier stamp), so our numbers match evo's on the same
inputs. TUM's ``associate.py`` (Sturm et al. 2012) instead matches greedily one-to-one; both
agree whenever the shorter trajectory is sampled more coarsely than ``2 * max_diff``, which
is the case for ~30 Hz estimates against 100 Hz ground truth. The default ``max_diff`` of
0.02 s is the one of TUM's ``evaluate_ate.py`` / ``evaluate_rpe.py``.
"""

from __future__ import annotations

import numpy as np

from .trajectory import Trajectory, TrajectoryError

__all__ = ["match_timestamps", "associate_trajectories", "DEFAULT_MAX_DIFF"]

#: Largest accepted time difference between associated poses (s); TUM's evaluate_ate.py default.
DEFAULT_MAX_DIFF = 0.02


def match_timestamps(
    query: np.ndarray, reference: np.ndarray, max_diff: float = DEFAULT_MAX_DIFF
) -> tuple[np.ndarray, np.ndarray]:
    """For each query stamp, the index of the nearest reference stamp within ``max_diff``.

    Parameters
    ----------
    query : ``(N,)`` timestamps (s), any order.
    reference : ``(M,)`` timestamps (s), increasing (sorted internally if not).
    max_diff : largest accepted ``|query - reference|`` (s), ``>= 0``.

    Returns
    -------
    index_query, index_reference : ``(K,)`` int arrays of matched indices, in query order.
        A reference index may appear twice when two query stamps share a nearest neighbour.
        On equal distance the earlier reference stamp wins.
    """
    if not np.isfinite(max_diff) or max_diff < 0:
        raise ValueError(f"max_diff must be a finite number >= 0 (seconds), got {max_diff}")
    q = np.asarray(query, dtype=np.float64).reshape(-1)
    r = np.asarray(reference, dtype=np.float64).reshape(-1)
    if len(q) == 0 or len(r) == 0:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    order = None
    if np.any(np.diff(r) < 0):
        order = np.argsort(r, kind="stable")
        r = r[order]
    upper = np.minimum(np.searchsorted(r, q, side="right"), len(r) - 1)
    lower = upper - 1
    d_upper = np.abs(r[upper] - q)
    d_lower = np.where(lower >= 0, q - r[np.maximum(lower, 0)], np.inf)
    d_lower = np.abs(d_lower)
    take_upper = d_upper < d_lower
    best = np.where(take_upper, upper, lower)
    d_best = np.where(take_upper, d_upper, d_lower)
    ok = d_best <= max_diff
    index_q = np.flatnonzero(ok)
    index_r = best[ok]
    if order is not None:
        index_r = order[index_r]
    return index_q.astype(int), index_r.astype(int)


def associate_trajectories(
    gt: Trajectory,
    est: Trajectory,
    max_diff: float = DEFAULT_MAX_DIFF,
    gt_name: str = "ground truth",
    est_name: str = "estimate",
) -> tuple[Trajectory, Trajectory]:
    """Pair the poses of ``gt`` and ``est`` by nearest timestamp.

    The shorter trajectory (fewer poses; ``est`` on a tie) is the query: each of its poses is
    kept if a pose of the other lies within ``max_diff``. Partial estimates (tracking started
    late or was lost) are fine: only the matched part is returned.

    Parameters
    ----------
    gt, est : the two trajectories.
    max_diff : largest accepted time difference (s).
    gt_name, est_name : names (file paths) used in the error message.

    Returns
    -------
    gt_matched, est_matched : trajectories of equal length ``K``, pose ``k`` of one paired
        with pose ``k`` of the other.

    Raises
    ------
    TrajectoryError
        No pair of timestamps lies within ``max_diff`` (message names both trajectories and
        their time ranges).
    """
    if len(gt) == 0 or len(est) == 0:
        raise TrajectoryError(
            f"cannot associate {gt_name} ({len(gt)} poses) with {est_name} ({len(est)} poses): empty trajectory"
        )
    if len(est) <= len(gt):
        i_est, i_gt = match_timestamps(est.timestamps, gt.timestamps, max_diff)
    else:
        i_gt, i_est = match_timestamps(gt.timestamps, est.timestamps, max_diff)
    if len(i_gt) == 0:
        raise TrajectoryError(
            f"no matching timestamps between {gt_name} "
            f"[{gt.timestamps.min():.6f}, {gt.timestamps.max():.6f}] s and {est_name} "
            f"[{est.timestamps.min():.6f}, {est.timestamps.max():.6f}] s with max_diff={max_diff} s"
        )
    return gt.subset(i_gt), est.subset(i_est)
