"""Matplotlib figures shared by the notebooks and the command line.

* :func:`plot_trajectories` - camera paths seen from above (two chosen axes), like the
  trajectory figures of YOLO-SLAM (Fig. 8), Chang et al. 2021 (Fig. 10) and ASG-SLAM;
* :func:`plot_trajectory_axes` - x, y, z of each trajectory against time;
* :func:`plot_ate_along_path` - the aligned estimate coloured by its absolute error
  ``e_i = ||trans(Q_i) - trans(S P_i)||`` (Sturm et al. 2012, Sec. VI-B), with the ground truth;
* :func:`plot_rpe_over_time` - translational and rotational relative pose error per pair;
* :func:`plot_timing_bars` - median milliseconds per stage, like YOLO-SLAM Table 8 and
  Chang et al. Table IV (per-module time);
* :func:`plot_keypoints` - keypoints on an image coloured by their static/dynamic verdict;
* :func:`plot_keypoint_stages` - keypoints with one ring per screening stage that flagged them;
* :func:`plot_rgbd_frame` - colour, depth and instance mask of a frame, the movers in colour;
* :func:`plot_ablation` - ATE and keypoint precision/recall per filter, readable labels.

Colours come from :mod:`dynslam_lab.viz.colors` (the same as the 3D viewer's).

Every function returns the ``matplotlib.figure.Figure`` it drew (or draws into ``ax`` when
given one), never calls ``plt.show()``, and takes plain numpy arrays or the evaluation
results (:class:`~dynslam_lab.evaluation.AteResult`, :class:`~dynslam_lab.evaluation.RpeResult`).
"""

from __future__ import annotations

import re
from typing import Mapping

import numpy as np

from ..evaluation.trajectory import Trajectory
from .colors import FILTERS, MOVER_COLORS, STAGES, hex_color, instance_colors

__all__ = [
    "plot_trajectories",
    "plot_trajectory_axes",
    "plot_ate_along_path",
    "plot_rpe_over_time",
    "plot_timing_bars",
    "plot_keypoints",
    "plot_keypoint_stages",
    "plot_rgbd_frame",
    "plot_ablation",
    "VERDICT_COLORS",
    "trajectory_style",
]

_AXES = {"x": 0, "y": 1, "z": 2}
#: colours of keypoint verdicts (matplotlib form of the shared palette).
VERDICT_COLORS = {"static": hex_color("static"), "dynamic": hex_color("dynamic")}


def _is_ground_truth(name: str) -> bool:
    n = name.lower()
    return "ground" in n or n in ("gt", "groundtruth", "truth")


def trajectory_style(name: str) -> dict:
    """Line colour and style of a named trajectory: ground truth dashed near-black, a filter
    name (``none``, ``oracle`` ...) its filter colour, anything with "estimate" red, others the
    matplotlib cycle."""
    if _is_ground_truth(name):
        return {"color": hex_color("ground_truth"), "ls": "--"}
    key = re.split(r"[\s:(,]", name.strip())[0].lower()
    if key in FILTERS:
        return {"color": hex_color(FILTERS[key]), "ls": "-"}
    if "estimate" in name.lower():
        return {"color": hex_color("estimate"), "ls": "-"}
    return {"color": None, "ls": "-"}


def _new_axes(ax, figsize):
    import matplotlib.pyplot as plt  # heavy: imported on use (module docstring)

    if ax is not None:
        return ax.figure, ax
    fig, ax = plt.subplots(figsize=figsize, constrained_layout=True)
    return fig, ax


def _positions(t) -> np.ndarray:
    if isinstance(t, Trajectory):
        return t.positions
    P = np.asarray(t, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"expected a Trajectory or (N, 3) positions, got shape {P.shape}")
    return P


def plot_trajectories(trajectories: Mapping[str, Trajectory | np.ndarray], plane: str = "xy", ax=None,
                      title: str | None = None):
    """Camera paths projected on a plane of the world frame.

    Parameters
    ----------
    trajectories : name -> :class:`Trajectory` or ``(N, 3)`` positions (metres); drawn in order
        (a name containing ``"ground"`` or ``"gt"`` is drawn dashed black).
    plane : two of ``x y z``, e.g. ``"xy"`` (TUM's ground truth is roughly z-up: ``"xy"`` is the
        top view) or ``"xz"`` (camera-start frames are y-down: ``"xz"`` is the top view).
    ax : matplotlib axes to draw into, or None for a new figure.

    Returns
    -------
    matplotlib Figure; one ``Line2D`` per trajectory, labelled with its name.
    """
    if len(plane) != 2 or any(c not in _AXES for c in plane) or plane[0] == plane[1]:
        raise ValueError(f"plane must be two different letters of 'xyz', got {plane!r}")
    fig, ax = _new_axes(ax, (5, 5))
    a, b = _AXES[plane[0]], _AXES[plane[1]]
    for name, traj in trajectories.items():
        P = _positions(traj)
        st = trajectory_style(name)
        ax.plot(P[:, a], P[:, b], st["ls"], color=st["color"], lw=1.5, label=name)
        if len(P):
            ax.plot(P[:1, a], P[:1, b], "o", color=ax.lines[-1].get_color(), ms=4)
    ax.set_xlabel(f"{plane[0]} [m]")
    ax.set_ylabel(f"{plane[1]} [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    if title:
        ax.set_title(title)
    return fig


def plot_trajectory_axes(trajectories: Mapping[str, Trajectory], title: str | None = None):
    """x, y and z of each trajectory against time (seconds from the first pose of the first).

    Returns
    -------
    matplotlib Figure with three stacked axes sharing the time axis.
    """
    import matplotlib.pyplot as plt  # heavy: imported on use (module docstring)

    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(7, 5), constrained_layout=True)
    t0 = None
    for name, traj in trajectories.items():
        if not isinstance(traj, Trajectory):
            raise TypeError(f"plot_trajectory_axes: {name!r} must be a Trajectory (timestamps needed)")
        if t0 is None and len(traj):
            t0 = traj.timestamps[0]
        st = trajectory_style(name)
        for k, ax in enumerate(axes):
            ax.plot(traj.timestamps - (t0 or 0.0), traj.positions[:, k], st["ls"], color=st["color"], lw=1.0,
                    label=name)
    for k, ax in enumerate(axes):
        ax.set_ylabel(f"{'xyz'[k]} [m]")
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="best", fontsize="small")
    axes[-1].set_xlabel("time [s]")
    if title:
        fig.suptitle(title)
    return fig


def plot_ate_along_path(ate, plane: str = "xy", ax=None, cmap: str = "viridis"):
    """The aligned estimate coloured by its absolute trajectory error, over the ground truth.

    Parameters
    ----------
    ate : :class:`~dynslam_lab.evaluation.AteResult` (its ``est_positions`` are aligned).
    plane : two of ``x y z``.

    Returns
    -------
    matplotlib Figure; the coloured path is a ``LineCollection`` whose ``get_array()`` holds
    the error (metres) of each segment (mean of its two end poses).
    """
    from matplotlib.collections import LineCollection  # heavy: imported on use

    if len(plane) != 2 or any(c not in _AXES for c in plane) or plane[0] == plane[1]:
        raise ValueError(f"plane must be two different letters of 'xyz', got {plane!r}")
    fig, ax = _new_axes(ax, (6, 5))
    a, b = _AXES[plane[0]], _AXES[plane[1]]
    G, E, err = ate.gt_positions, ate.est_positions, np.asarray(ate.errors)
    ax.plot(G[:, a], G[:, b], "--", color=hex_color("ground_truth"), lw=1.0, label="ground truth")
    pts = E[:, [a, b]]
    segs = np.stack([pts[:-1], pts[1:]], axis=1)
    lc = LineCollection(segs, cmap=cmap, linewidths=2.0)
    lc.set_array(0.5 * (err[:-1] + err[1:]))
    ax.add_collection(lc)
    cb = fig.colorbar(lc, ax=ax)
    cb.set_label("ATE [m]")
    ax.set_xlabel(f"{plane[0]} [m]")
    ax.set_ylabel(f"{plane[1]} [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.grid(True, alpha=0.3)
    ax.set_title(f"ATE RMSE {ate.stats.rmse:.4f} m, median {ate.stats.median:.4f} m ({ate.stats.n} poses)")
    ax.legend(loc="best", fontsize="small")
    return fig


def plot_rpe_over_time(rpe, title: str | None = None):
    """Translational (m) and rotational (deg) relative pose error against time.

    Parameters
    ----------
    rpe : :class:`~dynslam_lab.evaluation.RpeResult`.

    Returns
    -------
    matplotlib Figure with two axes; a dotted line marks each RMSE.
    """
    import matplotlib.pyplot as plt  # heavy: imported on use (module docstring)

    fig, (ax_t, ax_r) = plt.subplots(2, 1, sharex=True, figsize=(7, 4.5), constrained_layout=True)
    t = np.asarray(rpe.timestamps) - (rpe.timestamps[0] if len(rpe.timestamps) else 0.0)
    c = hex_color("estimate")
    ax_t.plot(t, rpe.trans_errors, lw=1.0, color=c)
    ax_t.axhline(rpe.trans.rmse, ls=":", color=c, label=f"RMSE {_num(rpe.trans.rmse)} m")
    ax_r.plot(t, rpe.rot_errors, lw=1.0, color=c)
    ax_r.axhline(rpe.rot.rmse, ls=":", color=c, label=f"RMSE {_num(rpe.rot.rmse)} deg")
    ax_t.set_ylabel("RPE trans. [m]")
    ax_r.set_ylabel("RPE rot. [deg]")
    ax_r.set_xlabel("time [s]")
    for ax in (ax_t, ax_r):
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize="small")
    unit = "frame" if rpe.delta_unit == "frames" else "s"
    fig.suptitle(title or f"Relative pose error, delta = {rpe.delta:g} {unit}")
    return fig


def _num(x: float) -> str:
    """Three significant digits, never "0.000" for a small non-zero value (0.00042 deg)."""
    return f"{x:.3g}" if x != 0 else "0"


def plot_timing_bars(timings, ax=None, title: str = "Time per stage (median)", statistic: str = "median"):
    """Horizontal bars of milliseconds per stage, like the papers' time tables.

    Parameters
    ----------
    timings : stage -> milliseconds (one number each), or a ``pandas.DataFrame`` with one
        row per frame and one column per stage (``timing.csv``; columns ``frame`` and
        ``timestamp`` are ignored), reduced with ``statistic`` (``"median"`` or ``"mean"``).
    ax : axes to draw into, or None.

    Returns
    -------
    matplotlib Figure; bars in the given stage order, each labelled with its value.
    """
    if statistic not in ("median", "mean"):
        raise ValueError(f"statistic must be 'median' or 'mean', got {statistic!r}")
    if hasattr(timings, "columns"):
        cols = [c for c in timings.columns if c not in ("frame", "timestamp")]
        values = getattr(timings[cols], statistic)(skipna=True)
        names, ms = list(cols), [float(values[c]) for c in cols]
    else:
        names, ms = list(timings.keys()), [float(v) for v in timings.values()]
    if not names:
        raise ValueError("plot_timing_bars: no stages to draw")
    fig, ax = _new_axes(ax, (6, 0.4 * len(names) + 1.2))
    y = np.arange(len(names))
    bars = ax.barh(y, ms, color=hex_color("multiview"))
    ax.set_yticks(y, names)
    ax.invert_yaxis()
    ax.bar_label(bars, labels=[f"{v:.1f}" for v in ms], padding=3, fontsize="small")
    ax.set_xlabel("time [ms]")
    ax.set_xlim(0, max(ms) * 1.2 if max(ms) > 0 else 1.0)
    ax.set_title(title)
    ax.grid(True, axis="x", alpha=0.3)
    return fig


def plot_keypoints(image: np.ndarray, uv: np.ndarray, dynamic: np.ndarray | None = None, ax=None,
                   title: str | None = None, size: float = 24.0):
    """Keypoints on an image, green when static, magenta when judged dynamic.

    Parameters
    ----------
    image : ``(H, W, 3)`` uint8 RGB or ``(H, W)`` grey.
    uv : ``(N, 2)`` pixel coordinates (x right, y down).
    dynamic : ``(N,)`` bool verdicts (True = dynamic), or None (all drawn static).

    Returns
    -------
    matplotlib Figure; two scatter collections labelled ``static (n)`` and ``dynamic (n)``.
    """
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    dyn = np.zeros(len(uv), bool) if dynamic is None else np.asarray(dynamic, dtype=bool)
    if dyn.shape != (len(uv),):
        raise ValueError(f"plot_keypoints: dynamic must have shape ({len(uv)},), got {dyn.shape}")
    img = np.asarray(image)
    H, W = img.shape[:2]
    fig, ax = _new_axes(ax, (W / 100, H / 100))
    ax.imshow(img, cmap="gray" if img.ndim == 2 else None)
    for name, sel in (("static", ~dyn), ("dynamic", dyn)):
        ax.scatter(uv[sel, 0], uv[sel, 1], s=size, facecolors="none", edgecolors=VERDICT_COLORS[name],
                   linewidths=1.4, label=f"{name} ({int(sel.sum())})")
    ax.set_xlim(-0.5, W - 0.5)
    ax.set_ylim(H - 0.5, -0.5)
    ax.set_axis_off()
    ax.legend(loc="lower right", fontsize="small")
    if title:
        ax.set_title(title)
    return fig


def plot_keypoint_stages(image: np.ndarray, uv: np.ndarray, stages: Mapping[str, np.ndarray],
                         dynamic: np.ndarray | None = None, restored: np.ndarray | None = None,
                         region_mask: np.ndarray | None = None, ax=None, title: str | None = None,
                         size: float = 20.0):
    """Keypoints with one ring per screening stage that flagged them (several stages: nested rings).

    Parameters
    ----------
    image : ``(H, W, 3)`` RGB or ``(H, W)`` grey.
    uv : ``(N, 2)`` pixels.
    stages : stage name -> ``(N,)`` bool, the keypoints that stage flagged (a
        :class:`~dynslam_lab.dynamic.table.KeypointTable`'s ``stages``); drawn in the order of
        :data:`~dynslam_lab.viz.colors.STAGES`, the first stage innermost.
    dynamic : ``(N,)`` final verdicts; static keypoints get a small green dot (default: those
        flagged by no stage).
    restored : ``(N,)`` bool keypoints given back (cyan outer ring).
    region_mask : ``(H, W)`` bool pixels judged dynamic, tinted.

    Returns
    -------
    matplotlib Figure; one scatter collection per stage, labelled ``stage (n)``.
    """
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    n = len(uv)
    flags = {k: np.asarray(v, bool).reshape(-1) for k, v in stages.items()}
    for k, v in flags.items():
        if v.shape != (n,):
            raise ValueError(f"plot_keypoint_stages: stage {k!r} has {v.shape[0]} rows, uv has {n}")
    any_flag = np.zeros(n, bool)
    for v in flags.values():
        any_flag |= v
    dyn = any_flag if dynamic is None else np.asarray(dynamic, bool).reshape(-1)
    img = np.asarray(image)
    H, W = img.shape[:2]
    fig, ax = _new_axes(ax, (W / 80, H / 80))
    ax.imshow(img, cmap="gray" if img.ndim == 2 else None)
    if region_mask is not None and np.any(region_mask):
        tint = np.zeros((H, W, 4))
        tint[np.asarray(region_mask, bool)] = (*[c / 255 for c in (220, 0, 220)], 0.18)
        ax.imshow(tint)
    stat = ~dyn
    ax.scatter(uv[stat, 0], uv[stat, 1], s=size * 0.6, c=VERDICT_COLORS["static"], linewidths=0,
               label=f"static ({int(stat.sum())})")
    order = [k for k in STAGES if k in flags] + [k for k in flags if k not in STAGES]
    ring = 0
    for k in order:
        sel = flags[k]
        if k in ("restored", "restoration") or not sel.any():  # given back: the cyan squares below
            continue
        ax.scatter(uv[sel, 0], uv[sel, 1], s=2 * size * (1 + 0.7 * ring) ** 2, facecolors="none",
                   edgecolors=hex_color(k) if k in STAGES else "0.5", linewidths=1.5, label=f"{k} ({int(sel.sum())})")
        ring += 1
    if restored is not None and np.any(restored):
        r = np.asarray(restored, bool)
        ax.scatter(uv[r, 0], uv[r, 1], s=2 * size, marker="s", facecolors="none", edgecolors=hex_color("restored"),
                   linewidths=1.3, label=f"restored ({int(r.sum())})")
    ax.set_xlim(-0.5, W - 0.5)
    ax.set_ylim(H - 0.5, -0.5)
    ax.set_axis_off()
    ax.legend(loc="lower right", fontsize="small", framealpha=0.85)
    if title:
        ax.set_title(title, fontsize="medium")
    return fig


def plot_rgbd_frame(frame, title: str | None = None, max_depth: float | None = None):
    """Colour, depth (metres, holes blank, with a colour bar) and the instance mask of a frame.

    In the instance panel the instances that move in this frame (``frame.moving_ids``) are in
    saturated colours, people standing still in light purple-grey, other objects in greys
    (:func:`~dynslam_lab.viz.colors.instance_colors`); without a mask, two panels.

    Returns
    -------
    matplotlib Figure with two or three axes.
    """
    import matplotlib.pyplot as plt  # heavy: imported on use (module docstring)
    from matplotlib.patches import Patch  # heavy: imported on use

    has_mask = getattr(frame, "instance_mask", None) is not None
    fig, axes = plt.subplots(1, 3 if has_mask else 2, figsize=(14 if has_mask else 9.5, 3.6), constrained_layout=True)
    axes[0].imshow(frame.rgb)
    axes[0].set_title("colour")
    depth = np.asarray(frame.depth, dtype=float)
    im = axes[1].imshow(np.where(depth > 0, depth, np.nan), cmap="turbo", vmin=0,
                        vmax=max_depth or float(np.nanpercentile(np.where(depth > 0, depth, np.nan), 99)))
    fig.colorbar(im, ax=axes[1], fraction=0.04, label="depth [m]")
    axes[1].set_title(f"depth, {100 * np.mean(depth <= 0):.1f}% holes (blank)")
    if has_mask:
        present = set(np.unique(frame.instance_mask).tolist())
        movers = sorted(i for i in (frame.moving_ids or ()) if i in present)
        axes[2].imshow(instance_colors(frame.instance_mask, movers, frame.instance_classes), interpolation="nearest")
        axes[2].set_title(f"instances: {len(movers)} moving")
        handles = [Patch(color=np.array(MOVER_COLORS[k % len(MOVER_COLORS)]) / 255,
                         label=f"{frame.instance_classes.get(i, 'object')} {i} (moving)") for k, i in enumerate(movers)]
        if handles:
            axes[2].legend(handles=handles, loc="lower right", fontsize="x-small")
    for a in axes:
        a.set_axis_off()
    if title:
        fig.suptitle(title)
    return fig


def plot_ablation(df, title: str | None = None):
    """ATE RMSE and keypoint precision/recall per filter, like the papers' ablation tables.

    Parameters
    ----------
    df : one row per filter with columns ``filter``, ``ate_rmse_m``, ``precision``,
        ``recall`` (what :func:`~dynslam_lab.experiments.ablation.run_ablation` returns; with
        several sequences, the rows of one filter are averaged).

    Returns
    -------
    matplotlib Figure with two axes: horizontal ATE bars (one label per bar, its value at its
    end) and grouped precision/recall bars.
    """
    import matplotlib.pyplot as plt  # heavy: imported on use (module docstring)

    g = df.groupby("filter", sort=False)[["ate_rmse_m", "precision", "recall"]].mean()
    names = list(g.index)
    y = np.arange(len(names))
    fig, (a0, a1) = plt.subplots(1, 2, figsize=(12, 0.45 * len(names) + 1.6), constrained_layout=True)
    colors = [hex_color(FILTERS.get(n, (100, 100, 100))) for n in names]
    bars = a0.barh(y, g["ate_rmse_m"], color=colors)
    a0.bar_label(bars, labels=[f"{1000 * v:.1f} mm" if np.isfinite(v) else "lost" for v in g["ate_rmse_m"]],
                 padding=3, fontsize="small")
    a0.set_yticks(y, names)
    a0.invert_yaxis()
    a0.set_xlabel("ATE RMSE [m]")
    finite = g["ate_rmse_m"][np.isfinite(g["ate_rmse_m"])]
    a0.set_xlim(0, 1.3 * float(finite.max()) if len(finite) else 1.0)
    a0.grid(True, axis="x", alpha=0.3)
    h = 0.38
    a1.barh(y - h / 2, g["precision"], height=h, color=hex_color("static"), label="precision")
    a1.barh(y + h / 2, g["recall"], height=h, color=hex_color("dynamic"), label="recall")
    a1.set_yticks(y, names)
    a1.invert_yaxis()
    a1.set_xlim(0, 1.05)
    a1.set_xlabel("keypoints judged dynamic, against the truth")
    a1.legend(loc="upper right", fontsize="small")
    a1.grid(True, axis="x", alpha=0.3)
    if title:
        fig.suptitle(title)
    return fig
