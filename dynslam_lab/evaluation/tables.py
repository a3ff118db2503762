"""One-call evaluation and paper-style tables (pandas).

:func:`evaluate` runs association, alignment, ATE and RPE on one estimate and returns a
plain, JSON-serialisable ``dict`` (``dynslam eval --json``, ``summary.json`` of
``dynslam run``). :func:`stats_table` lays several such results side by side like the
papers' tables (YOLO-SLAM Tables 4-6, ASG-SLAM Tables 1-3: RMSE, Mean, Median, S.D. per
method), and :func:`improvement` computes the papers' improvement over a baseline
(YOLO-SLAM Section 4.3, Chang 2021 Table III):

.. math::

    \\eta = \\frac{o - r}{o} \\times 100\\%,

with ``o`` the baseline's value (ORB-SLAM2) and ``r`` the improved system's value.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import pandas as pd

from .ate import compute_ate
from .rpe import compute_rpe, rpe_pairs
from .sync import DEFAULT_MAX_DIFF, associate_trajectories
from .trajectory import Trajectory

__all__ = ["evaluate", "improvement", "stats_table", "comparison_table", "format_report", "METRICS", "STAT_COLUMNS"]

#: Metric keys of an :func:`evaluate` result and their display names / units.
METRICS = {"ate": "ATE (m)", "rpe_trans": "RPE trans. (m)", "rpe_rot": "RPE rot. (deg)"}

#: Statistic keys and the column titles the papers use.
STAT_COLUMNS = {"rmse": "RMSE", "mean": "Mean", "median": "Median", "std": "S.D.", "min": "Min", "max": "Max"}


def evaluate(
    gt: Trajectory,
    est: Trajectory,
    align: str = "se3",
    max_diff: float = DEFAULT_MAX_DIFF,
    delta: float = 1,
    delta_unit: str = "frames",
    all_pairs: bool = False,
    gt_name: str = "ground truth",
    est_name: str = "estimate",
) -> dict:
    """ATE and RPE of ``est`` against ``gt`` as one JSON-serialisable ``dict``.

    Parameters
    ----------
    gt, est : ground truth and estimated trajectories (``T_w_c``).
    align : ``"se3"``, ``"sim3"`` or ``"none"``; applied before ATE and RPE.
    max_diff : timestamp association tolerance (s).
    delta, delta_unit, all_pairs : RPE pairing (see :func:`.rpe.rpe_pairs`).
    gt_name, est_name : names (paths) used in messages and stored in the result.

    Returns
    -------
    dict
        ``{"gt", "est", "n_gt", "n_est", "n_matched", "coverage", "max_diff",
        "align": {"method", "scale", "R", "t"},
        "ate": {rmse, mean, median, std, min, max, n},
        "rpe": {"delta", "delta_unit", "all_pairs", "trans": {...}, "rot": {...}}}``;
        ``coverage`` is the time span of the matched poses over the span of the ground truth
        (below 1 for a partial estimate). ``rpe`` is None when the trajectory is too short
        for ``delta``.
    """
    gt_m, est_m = associate_trajectories(gt, est, max_diff, gt_name=gt_name, est_name=est_name)
    ate = compute_ate(gt_m, est_m, align=align, associate=False, gt_name=gt_name, est_name=est_name)
    i, _ = rpe_pairs(est_m.timestamps, delta, delta_unit, all_pairs)
    rpe_dict: dict | None = None
    if len(i) > 0:
        rpe = compute_rpe(
            gt_m, est_m, delta=delta, delta_unit=delta_unit, all_pairs=all_pairs, align=align,
            associate=False, gt_name=gt_name, est_name=est_name,
        )
        rpe_dict = {
            "delta": float(delta) if delta_unit == "seconds" else int(delta),
            "delta_unit": delta_unit,
            "all_pairs": bool(all_pairs),
            "trans": rpe.trans.to_dict(),
            "rot": rpe.rot.to_dict(),
        }
    a = ate.alignment
    return {
        "gt": str(gt_name),
        "est": str(est_name),
        "n_gt": len(gt),
        "n_est": len(est),
        "n_matched": len(est_m),
        "coverage": _span(est_m.timestamps) / _span(gt.timestamps) if _span(gt.timestamps) > 0 else 1.0,
        "max_diff": float(max_diff),
        "align": {"method": align, "scale": float(a.scale), "R": a.R.tolist(), "t": a.t.tolist()},
        "ate": ate.stats.to_dict(),
        "rpe": rpe_dict,
    }


def _span(t: np.ndarray) -> float:
    return float(t[-1] - t[0]) if len(t) else 0.0


def _metric_stats(result: Mapping, metric: str) -> Mapping | None:
    if metric == "ate":
        return result.get("ate")
    rpe = result.get("rpe")
    if rpe is None:
        return None
    return rpe["trans" if metric == "rpe_trans" else "rot"]


def stats_table(
    results: Mapping[str, Mapping], metric: str = "ate", stats: tuple[str, ...] = ("rmse", "mean", "median", "std")
) -> pd.DataFrame:
    """Rows = methods (or sequences), columns = statistics, like the papers' tables.

    Parameters
    ----------
    results : ``{name: evaluate(...) result}``.
    metric : ``"ate"``, ``"rpe_trans"`` or ``"rpe_rot"``.
    stats : statistic keys among ``rmse, mean, median, std, min, max``.

    Returns
    -------
    pandas.DataFrame
        Index ``name``, columns titled ``RMSE, Mean, Median, S.D., ...``; NaN where a result
        has no RPE.
    """
    if metric not in METRICS:
        raise ValueError(f"metric must be one of {tuple(METRICS)}, got {metric!r}")
    bad = [s for s in stats if s not in STAT_COLUMNS]
    if bad:
        raise ValueError(f"unknown statistics {bad}; choose from {tuple(STAT_COLUMNS)}")
    rows = {}
    for name, res in results.items():
        st = _metric_stats(res, metric)
        rows[name] = [np.nan if st is None else float(st[s]) for s in stats]
    df = pd.DataFrame.from_dict(rows, orient="index", columns=[STAT_COLUMNS[s] for s in stats])
    df.index.name = "method"
    df.columns.name = METRICS[metric]
    return df


def improvement(baseline: float | np.ndarray, ours: float | np.ndarray) -> float | np.ndarray:
    """Improvement over a baseline in percent, ``(o - r) / o * 100`` (YOLO-SLAM Sec. 4.3).

    Positive when ``ours`` has the smaller error; NaN where the baseline is zero.
    """
    o = np.asarray(baseline, dtype=np.float64)
    r = np.asarray(ours, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        eta = np.where(o != 0, (o - r) / np.where(o != 0, o, 1.0) * 100.0, np.nan)
    return float(eta) if eta.ndim == 0 else eta


def comparison_table(
    baseline: Mapping[str, Mapping],
    ours: Mapping[str, Mapping],
    metric: str = "ate",
    stats: tuple[str, ...] = ("rmse", "std"),
    baseline_label: str = "baseline",
    ours_label: str = "ours",
) -> pd.DataFrame:
    """Per-sequence comparison with improvement columns (YOLO-SLAM Table 4 layout).

    Parameters
    ----------
    baseline, ours : ``{sequence: evaluate(...) result}`` with the same keys.
    metric : ``"ate"``, ``"rpe_trans"`` or ``"rpe_rot"``.
    stats : statistics to compare (the papers use RMSE and S.D.).

    Returns
    -------
    pandas.DataFrame
        Columns are a two-level index ``(label, stat)``: the baseline's values, ours, and
        ``Improvement (%)`` per statistic.
    """
    missing = sorted(set(baseline) ^ set(ours))
    if missing:
        raise ValueError(f"comparison_table: sequences not in both result sets: {missing}")
    b = stats_table(baseline, metric, stats)
    o = stats_table(ours, metric, stats).loc[b.index]
    imp = pd.DataFrame(improvement(b.to_numpy(), o.to_numpy()), index=b.index, columns=b.columns)
    out = pd.concat({baseline_label: b, ours_label: o, "Improvement (%)": imp}, axis=1)
    out.index.name = "sequence"
    return out


def format_report(result: Mapping, digits: int = 4) -> str:
    """Readable text table of one :func:`evaluate` result (``dynslam eval``)."""
    names = {k: v for k, v in METRICS.items() if _metric_stats(result, k) is not None}
    cols = list(STAT_COLUMNS)
    lines = [
        f"ground truth: {result['gt']} ({result['n_gt']} poses)",
        f"estimate:     {result['est']} ({result['n_est']} poses)",
        f"matched:      {result['n_matched']} poses (max_diff {result['max_diff']} s, "
        f"covering {100 * result['coverage']:.1f}% of the ground truth's time span)",
        f"alignment:    {result['align']['method']}"
        + (f" (scale {result['align']['scale']:.6f})" if result["align"]["method"] == "sim3" else ""),
    ]
    rpe = result.get("rpe")
    if rpe is not None:
        lines.append(
            f"RPE pairs:    delta {rpe['delta']} {rpe['delta_unit']}, "
            f"{'all' if rpe['all_pairs'] else 'consecutive'} pairs"
        )
    else:
        lines.append("RPE:          not computed (too few poses for delta)")
    width = max(len(v) for v in names.values())
    header = " " * width + "".join(f"{STAT_COLUMNS[c]:>11}" for c in cols) + f"{'n':>7}"
    lines += ["", header]
    for key, title in names.items():
        st = _metric_stats(result, key)
        lines.append(f"{title:<{width}}" + "".join(f"{st[c]:>11.{digits}f}" for c in cols) + f"{st['n']:>7d}")
    return "\n".join(lines)
