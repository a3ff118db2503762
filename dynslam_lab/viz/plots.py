"""Matplotlib figures shared by the notebooks and the command line.

* :func:`plot_trajectories` - camera paths seen from above (two chosen axes), like the
  trajectory figures of YOLO-SLAM (Fig. 8), Chang et al. 2021 (Fig. 10) and ASG-SLAM;
* :func:`plot_trajectory_axes` - x, y, z of each trajectory against time;
* :func:`plot_ate_along_path` - the aligned estimate coloured by its absolute error
  ``e_i = ||trans(Q_i) - trans(S P_i)||`` (Sturm et al. 2012, Sec. VI-B), with the ground truth;
* :func:`plot_rpe_over_time` - translational and rotational relative pose error per pair;
* :func:`plot_timing_bars` - median milliseconds per stage, like YOLO-SLAM Table 8 and
  Chang et al. Table IV (per-module time);
* :func:`plot_keypoints` - keypoints on an image coloured by their static/dynamic verdict.

Every function returns the ``matplotlib.figure.Figure`` it drew (or draws into ``ax`` when
given one), never calls ``plt.show()``, and takes plain numpy arrays or the evaluation
results (:class:`~dynslam_lab.evaluation.AteResult`, :class:`~dynslam_lab.evaluation.RpeResult`).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ..evaluation.trajectory import Trajectory

__all__ = [
    "plot_trajectories",
    "plot_trajectory_axes",
    "plot_ate_along_path",
    "plot_rpe_over_time",
    "plot_timing_bars",
    "plot_keypoints",
    "VERDICT_COLORS",
]

_AXES = {"x": 0, "y": 1, "z": 2}
#: colours of keypoint verdicts (matplotlib names).
VERDICT_COLORS = {"static": "limegreen", "dynamic": "red"}


def _new_axes(ax, figsize):
    import matplotlib.pyplot as plt

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
        gt = "ground" in name.lower() or name.lower() in ("gt", "groundtruth")
        ax.plot(P[:, a], P[:, b], "--" if gt else "-", color="black" if gt else None, lw=1.2, label=name)
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
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(7, 5), constrained_layout=True)
    t0 = None
    for name, traj in trajectories.items():
        if not isinstance(traj, Trajectory):
            raise TypeError(f"plot_trajectory_axes: {name!r} must be a Trajectory (timestamps needed)")
        if t0 is None and len(traj):
            t0 = traj.timestamps[0]
        gt = "ground" in name.lower() or name.lower() in ("gt", "groundtruth")
        for k, ax in enumerate(axes):
            ax.plot(traj.timestamps - (t0 or 0.0), traj.positions[:, k], "--" if gt else "-",
                    color="black" if gt else None, lw=1.0, label=name)
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
    from matplotlib.collections import LineCollection

    if len(plane) != 2 or any(c not in _AXES for c in plane) or plane[0] == plane[1]:
        raise ValueError(f"plane must be two different letters of 'xyz', got {plane!r}")
    fig, ax = _new_axes(ax, (6, 5))
    a, b = _AXES[plane[0]], _AXES[plane[1]]
    G, E, err = ate.gt_positions, ate.est_positions, np.asarray(ate.errors)
    ax.plot(G[:, a], G[:, b], "--", color="black", lw=1.0, label="ground truth")
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
    import matplotlib.pyplot as plt

    fig, (ax_t, ax_r) = plt.subplots(2, 1, sharex=True, figsize=(7, 4.5), constrained_layout=True)
    t = np.asarray(rpe.timestamps) - (rpe.timestamps[0] if len(rpe.timestamps) else 0.0)
    ax_t.plot(t, rpe.trans_errors, lw=1.0, color="tab:blue")
    ax_t.axhline(rpe.trans.rmse, ls=":", color="tab:blue", label=f"RMSE {rpe.trans.rmse:.4f} m")
    ax_r.plot(t, rpe.rot_errors, lw=1.0, color="tab:orange")
    ax_r.axhline(rpe.rot.rmse, ls=":", color="tab:orange", label=f"RMSE {rpe.rot.rmse:.3f} deg")
    ax_t.set_ylabel("RPE trans. [m]")
    ax_r.set_ylabel("RPE rot. [deg]")
    ax_r.set_xlabel("time [s]")
    for ax in (ax_t, ax_r):
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize="small")
    unit = "frame" if rpe.delta_unit == "frames" else "s"
    fig.suptitle(title or f"Relative pose error, delta = {rpe.delta:g} {unit}")
    return fig


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
    bars = ax.barh(y, ms, color="tab:blue")
    ax.set_yticks(y, names)
    ax.invert_yaxis()
    ax.bar_label(bars, labels=[f"{v:.1f}" for v in ms], padding=3, fontsize="small")
    ax.set_xlabel("time [ms]")
    ax.set_xlim(0, max(ms) * 1.2 if max(ms) > 0 else 1.0)
    ax.set_title(title)
    ax.grid(True, axis="x", alpha=0.3)
    return fig


def plot_keypoints(image: np.ndarray, uv: np.ndarray, dynamic: np.ndarray | None = None, ax=None,
                   title: str | None = None, size: float = 12.0):
    """Keypoints on an image, green when static, red when judged dynamic.

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
                   linewidths=1.0, label=f"{name} ({int(sel.sum())})")
    ax.set_xlim(-0.5, W - 0.5)
    ax.set_ylim(H - 0.5, -0.5)
    ax.set_axis_off()
    ax.legend(loc="lower right", fontsize="small")
    if title:
        ax.set_title(title)
    return fig
