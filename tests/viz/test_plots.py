"""The shared matplotlib figures draw exactly the data they are given."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pytest  # noqa: E402

from dynslam_lab.evaluation import Trajectory, compute_ate, compute_rpe  # noqa: E402
from dynslam_lab.geometry.se3 import make_pose, so3_exp  # noqa: E402
from dynslam_lab.viz.plots import (  # noqa: E402
    VERDICT_COLORS,
    plot_ate_along_path,
    plot_keypoints,
    plot_rpe_over_time,
    plot_timing_bars,
    plot_trajectories,
    plot_trajectory_axes,
)


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


@pytest.fixture
def trajs():
    t = np.arange(50) / 10.0
    gt = np.stack([make_pose(so3_exp(np.array([0, 0.02 * k, 0])), np.array([np.cos(k / 8), np.sin(k / 8), 0.01 * k]))
                   for k in range(50)])
    est = gt.copy()
    est[:, :3, 3] += np.random.default_rng(0).normal(scale=0.01, size=(50, 3))
    return Trajectory(t, gt), Trajectory(t, est)


def test_trajectories_top_view_draws_the_positions(trajs):
    gt, est = trajs
    fig = plot_trajectories({"ground truth": gt, "estimate": est}, plane="xz")
    ax = fig.axes[0]
    lines = {ln.get_label(): ln for ln in ax.lines}
    np.testing.assert_allclose(lines["estimate"].get_xdata(), est.positions[:, 0])
    np.testing.assert_allclose(lines["estimate"].get_ydata(), est.positions[:, 2])
    assert lines["ground truth"].get_linestyle() == "--"
    assert ax.get_xlabel() == "x [m]" and ax.get_ylabel() == "z [m]"
    with pytest.raises(ValueError, match="plane"):
        plot_trajectories({"a": gt}, plane="xx")


def test_per_axis_plot(trajs):
    gt, est = trajs
    fig = plot_trajectory_axes({"ground truth": gt, "estimate": est})
    assert len(fig.axes) == 3
    for k, ax in enumerate(fig.axes):
        est_line = [ln for ln in ax.lines if ln.get_label() == "estimate"][0]
        np.testing.assert_allclose(est_line.get_xdata(), est.timestamps - est.timestamps[0])
        np.testing.assert_allclose(est_line.get_ydata(), est.positions[:, k])


def test_ate_colours_are_the_errors(trajs):
    gt, est = trajs
    ate = compute_ate(gt, est)
    fig = plot_ate_along_path(ate)
    from matplotlib.collections import LineCollection

    lc = [c for c in fig.axes[0].collections if isinstance(c, LineCollection)][0]
    np.testing.assert_allclose(lc.get_array(), 0.5 * (ate.errors[:-1] + ate.errors[1:]))
    assert f"{ate.stats.rmse:.4f}" in fig.axes[0].get_title()


def test_rpe_over_time(trajs):
    gt, est = trajs
    rpe = compute_rpe(gt, est)
    fig = plot_rpe_over_time(rpe)
    ax_t, ax_r = fig.axes
    np.testing.assert_allclose(ax_t.lines[0].get_ydata(), rpe.trans_errors)
    np.testing.assert_allclose(ax_r.lines[0].get_ydata(), rpe.rot_errors)
    assert ax_t.lines[1].get_ydata()[0] == pytest.approx(rpe.trans.rmse)


def test_timing_bars_from_dict_and_timing_csv():
    fig = plot_timing_bars({"ORB": 12.0, "detection": 40.0, "tracking": 8.5})
    bars = fig.axes[0].patches
    assert [b.get_width() for b in bars] == [12.0, 40.0, 8.5]
    df = pd.DataFrame({"frame": [0, 1, 2], "timestamp": [0.0, 0.1, 0.2], "orb": [10.0, 12.0, 30.0],
                       "screening": [1.0, 2.0, np.nan]})
    fig = plot_timing_bars(df)
    assert [b.get_width() for b in fig.axes[0].patches] == [12.0, 1.5]  # medians, NaN skipped
    assert [t.get_text() for t in fig.axes[0].get_yticklabels()] == ["orb", "screening"]


def test_keypoints_coloured_by_verdict():
    img = np.zeros((48, 64, 3), np.uint8)
    uv = np.array([[5.0, 5.0], [10.0, 20.0], [30.0, 40.0], [60.0, 2.0]])
    dyn = np.array([False, True, True, False])
    fig = plot_keypoints(img, uv, dyn)
    ax = fig.axes[0]
    by_label = {c.get_label(): c for c in ax.collections}
    np.testing.assert_allclose(by_label["dynamic (2)"].get_offsets(), uv[dyn])
    np.testing.assert_allclose(by_label["static (2)"].get_offsets(), uv[~dyn])
    red = matplotlib.colors.to_rgba(VERDICT_COLORS["dynamic"])
    np.testing.assert_allclose(by_label["dynamic (2)"].get_edgecolor()[0], red)
    with pytest.raises(ValueError, match="dynamic must have shape"):
        plot_keypoints(img, uv, dyn[:2])
