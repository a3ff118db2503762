"""Sensitivity plots of a sweep: each metric against each swept parameter.

One figure per (metric, parameter): the parameter on the x axis, one line per sequence (the mean
over its seeds) with the spread over seeds as a band (min to max) and each seed's value as a dot.
The other axes of the sweep (other parameters, filters, detectors) become panels, one per
combination; beyond :data:`MAX_PANELS` combinations they are pooled into one panel whose line is
the median over them. Like the papers' sensitivity figures (e.g. ATE against the epipolar
threshold), but with the seeds' spread, which the papers do not show.

The figures are :class:`matplotlib.figure.Figure` objects made without pyplot, so they can be
drawn in worker processes and saved headless; a notebook displays them as they are.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from ..runs.layout import atomic_write

__all__ = ["DEFAULT_METRICS", "MAX_PANELS", "plot_axes", "plot_metric", "save_plots"]

#: Metrics plotted by default (those present in the table with a finite value).
DEFAULT_METRICS = ("ate.rmse", "rpe.trans.rmse", "keypoints.precision", "keypoints.recall", "lost")
#: Most panels of one figure before the other axes are pooled.
MAX_PANELS = 6


def plot_axes(table: pd.DataFrame, params) -> list[str]:
    """The swept axes with more than one value: the parameters, then ``filter``, and ``detector``
    when it varies for one filter (it is ``none`` for the filters that use no detection)."""
    axes = [p for p in params if p in table.columns and table[p].nunique(dropna=False) > 1]
    if table["filter"].nunique() > 1:
        axes.append("filter")
    if (table.groupby("filter")["detector"].nunique() > 1).any():
        axes.append("detector")
    return axes


def _numeric(values) -> bool:
    return all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
               for v in values)


def _panel_title(keys, combo) -> str:
    return ", ".join(f"{k.split('.')[-1]}={v}" for k, v in zip(keys, combo))


def plot_metric(table: pd.DataFrame, metric: str, x: str, others=()) -> Figure:
    """``metric`` against ``x``: one line per sequence (mean over seeds, band min-max, dots per seed),
    one panel per combination of the ``others`` axes (pooled by median beyond :data:`MAX_PANELS`).

    Only rows with ``status == "done"`` are drawn.
    """
    df = table[table["status"] == "done"] if "status" in table.columns else table
    others = [o for o in others if o != x]
    combos = list(dict.fromkeys(map(tuple, df[others].itertuples(index=False, name=None)))) if others else [()]
    pooled = len(combos) > MAX_PANELS
    if pooled:
        combos = [()]
    xs = list(dict.fromkeys(df[x]))
    numeric = _numeric(xs)
    if numeric:
        xs = sorted(xs)
    pos = {v: (float(v) if numeric else i) for i, v in enumerate(xs)}
    ncols = min(3, len(combos))
    nrows = math.ceil(len(combos) / ncols)
    fig = Figure(figsize=(4.6 * ncols, 3.4 * nrows), layout="constrained")
    axs = fig.subplots(nrows, ncols, squeeze=False)
    sequences = list(dict.fromkeys(df["sequence"]))
    colours = [f"C{i % 10}" for i in range(len(sequences))]
    for i, combo in enumerate(combos):
        ax = axs[i // ncols][i % ncols]
        sub = df
        for k, v in zip(others if not pooled else (), combo):
            sub = sub[sub[k] == v]
        for seq, colour in zip(sequences, colours):
            s = sub[sub["sequence"] == seq]
            px, mid, lo, hi = [], [], [], []
            for v in xs:
                vals = s.loc[s[x] == v, metric].to_numpy(float)
                vals = vals[np.isfinite(vals)]
                if not len(vals):
                    continue
                if pooled:  # the median over the pooled settings of each seed's mean, spread over everything
                    per = s[s[x] == v].groupby(others, dropna=False)[metric].mean().to_numpy(float)
                    centre = float(np.nanmedian(per))
                else:
                    centre = float(vals.mean())
                px.append(pos[v])
                mid.append(centre)
                lo.append(vals.min())
                hi.append(vals.max())
                ax.scatter(np.full(len(vals), pos[v]), vals, s=9, color=colour, alpha=0.5, linewidths=0)
            if px:
                ax.plot(px, mid, "-o", color=colour, ms=4, label=seq)
                ax.fill_between(px, lo, hi, color=colour, alpha=0.15, linewidth=0)
        if numeric:
            finite = [float(v) for v in xs]
            if min(finite) > 0 and max(finite) / min(finite) >= 20:
                ax.set_xscale("log")
        else:
            ax.set_xticks(range(len(xs)), [str(v) for v in xs], rotation=20 if len(xs) > 3 else 0)
        ax.set_xlabel(x)
        ax.set_ylabel(metric)
        ax.grid(alpha=0.3)
        title = "pooled over " + ", ".join(others) + " (median)" if pooled else _panel_title(others, combo)
        if title:
            ax.set_title(title, fontsize=9)
    for j in range(len(combos), nrows * ncols):
        axs[j // ncols][j % ncols].set_visible(False)
    axs[0][0].legend(fontsize=8, title="sequence (band: seeds)", title_fontsize=8)
    return fig


def save_plots(table: pd.DataFrame, spec_or_params, outdir: str | Path, metrics=DEFAULT_METRICS) -> list[Path]:
    """Write ``outdir/METRIC__AXIS.png`` for every metric with a finite value and every swept axis
    (:func:`plot_axes`); returns the files. ``spec_or_params``: a
    :class:`~.sweep_spec.SweepSpec` or the list of swept parameter keys."""
    params = getattr(spec_or_params, "params", spec_or_params)
    done = table[table["status"] == "done"] if "status" in table.columns else table
    axes = plot_axes(done, params) if len(done) else []
    written: list[Path] = []
    if not axes:
        return written
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    for metric in metrics:
        if metric not in done.columns or not np.isfinite(done[metric].to_numpy(float)).any():
            continue
        for x in axes:
            fig = plot_metric(done, metric, x, axes)
            path = outdir / f"{metric}__{x}.png"
            atomic_write(path, lambda tmp, fig=fig: fig.savefig(tmp, format="png", dpi=110))
            written.append(path)
    return written
