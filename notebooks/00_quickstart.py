# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # 00 · Quickstart: SLAM with people walking through the picture
#
# **What you will learn**
# - what a synthetic dynamic RGB-D sequence holds: colour, depth, and the truth of which pixels move;
# - what a dynamic-feature filter does: keep the keypoints on walking people out of tracking;
# - how to score a trajectory: the absolute trajectory error (ATE) after aligning the estimate to the ground truth;
# - why an unfiltered run drifts while the people cross the view.
#
# The score is the **ATE** of the TUM RGB-D benchmark (Sturm et al. 2012, Sec. VI-B): with the
# estimated poses $P_i$, the ground truth $Q_i$ and the rigid motion $S$ that best aligns the
# two (least squares, Umeyama / Horn),
#
# $$\mathrm{ATE}_{\mathrm{RMSE}} = \Big(\frac{1}{n}\sum_{i=1}^{n} \big\lVert \operatorname{trans}(Q_i^{-1} S P_i) \big\rVert^2\Big)^{1/2}.$$
#
# The alignment matters: the estimate starts at the identity (the first camera *is* its world),
# while the ground truth lives in the room's frame, about a metre away.

# %%
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from dynslam_lab.config import Config
from dynslam_lab.datasets import TumSequence
from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.dynamic.oracle import truth_dynamic
from dynslam_lab.dynamic.screening import build_screener
from dynslam_lab.evaluation import compute_ate, read_tum_trajectory
from dynslam_lab.features.orb import extract_features
from dynslam_lab.pipeline import build_pipeline
from dynslam_lab.runs import run_sequence
from dynslam_lab.viz.exercises import check
from dynslam_lab.viz.plots import plot_ate_along_path, plot_keypoints, plot_rgbd_frame, plot_trajectories

seq = TumSequence(synthetic_sequence("walking_xyz", n_frames=30, seed=0))  # rendered once, then cached
print(seq)

# %% [markdown]
# ## The sequence: colour, depth, and who moves
#
# Every pixel of a synthetic frame knows which object it shows (the instance mask), and the
# renderer writes which instances move in each frame. That truth scores every filter later on.

# %% figures=1
frame = seq[20]
plot_rgbd_frame(frame, title=f"frame {frame.index} of {len(seq)}");

# %% [markdown]
# **What to look for**: the two walkers (saturated colours, right panel) cover a large part of
# the picture; everything else, desk, monitors, books, is grey because it does not move. The
# depth panel shows the walkers about a metre in front of the desk: depth alone separates them.

# %% [markdown]
# ## What a filter removes
#
# ORB keypoints of the same frame. Without a filter all of them feed tracking; the *oracle*
# filter (perfect masks from the renderer) drops those on a walker, and those within 4 px of one: a
# corner there is made partly by the walker's edge and moves with it (notebook 10, section 4d').

# %% figures=1
uv = extract_features(frame.gray).uv
on_walker = truth_dynamic(frame, uv)
dropped = build_screener("oracle").screen(frame, uv).dynamic
fig, axes = plt.subplots(1, 2, figsize=(13, 4.8), constrained_layout=True)
plot_keypoints(frame.rgb, uv, None, ax=axes[0], title="filter none: every keypoint is used")
plot_keypoints(frame.rgb, uv, dropped, ax=axes[1],
               title=f"filter oracle: {dropped.sum()} dropped ({on_walker.sum()} on walkers, {(dropped & ~on_walker).sum()} within 4 px)");

# %% [markdown]
# **What to look for**: about one keypoint in five lies on a walker, and one in ten more within 4 px of
# one: the perfect masks drop about three in ten (magenta, right). They
# move with the person, not with the camera: a tracker that uses them estimates a mixture of
# the camera's and the walkers' motion.

# %% [markdown]
# ## Run SLAM twice, then score
#
# One SLAM run per filter (`build_pipeline` builds the system from one `Config`; `run_sequence`
# writes the run folder: `trajectory.txt`, `summary.json`, ...), then the ATE of each.

# %% figures=1
out_root = Path(tempfile.mkdtemp(prefix="dynslam_quickstart_"))
ate = {}
raw = {}
for filters in ("none", "oracle"):
    system = build_pipeline(Config(), seq.camera, filters=filters)
    summary = run_sequence(seq, out_root / filters, system, progress=False)
    raw[filters] = read_tum_trajectory(out_root / filters / "trajectory.txt")
    ate[filters] = compute_ate(seq.groundtruth, raw[filters], align="se3")
    print(f"{filters:6s}: tracked {summary['tracked']} of {summary['frames']} frames, "
          f"ATE RMSE {1000 * ate[filters].stats.rmse:.1f} mm")

fig, axes = plt.subplots(1, 2, figsize=(13, 5), constrained_layout=True)
plot_trajectories({"ground truth": seq.groundtruth, **{f"{k} (as written)": v for k, v in raw.items()}},
                  plane="xy", ax=axes[0], title="as written: two different world frames")
plot_trajectories({"ground truth": ate["none"].gt_positions,
                   **{f"{k}: ATE {1000 * a.stats.rmse:.1f} mm": a.est_positions for k, a in ate.items()}},
                  plane="xy", ax=axes[1], title="after SE(3) alignment, seen from above (z up)");

# %% [markdown]
# **What to look for**: left, the estimates start at the origin (the first camera) and the
# ground truth a metre away: comparing them unaligned would say both runs failed. Right, after
# alignment, `oracle` lies on the ground truth (a few millimetres), while `none` wanders off
# by ten centimetres and more: the walkers' keypoints pulled its poses.

# %% [markdown]
# ## Where the error comes from
#
# The aligned `none` estimate, coloured by its error at each pose.

# %% figures=1
plot_ate_along_path(ate["none"], plane="xy");

# %% [markdown]
# **What to look for**: the error is not spread evenly: small at the start, largest where
# the walker fills the view, and it stays once made, because every pose is estimated from the
# previous ones. Exercise 2 asks at which moment it peaks.

# %% [markdown]
# ### Exercise 1: the ATE by hand
#
# `ate["none"]` holds the aligned positions (`est_positions`) and the ground truth
# (`gt_positions`), `(n, 3)` arrays in metres. Compute the ATE RMSE of the equation above.

# %% exercise="00.1"
answer = None  # your code: the RMSE of the position differences, in metres

# %% check="00.1"
check("00.1", answer, ate["none"].stats.rmse, hint="root of the mean of the squared distances")

# %% [markdown]
# ### Exercise 2: the worst moment
#
# At which timestamp (seconds, a value of `ate["none"].timestamps`) is the `none` error largest?
# Then look at that frame with `plot_rgbd_frame(seq[i])`: where are the walkers?

# %% exercise="00.2"
answer = None  # your code: the timestamp of the largest error

# %% check="00.2"
check("00.2", answer, ate["none"].timestamps[np.argmax(ate["none"].errors)])

# %% [markdown]
# ### Exercise 3: without alignment
#
# Compute the `none` run's ATE RMSE with `align="none"` (`compute_ate(gt, est, align="none")`).
# Why is it about a metre, although the run tracked every frame?

# %% exercise="00.3"
answer = None  # your code

# %% check="00.3"
check("00.3", answer, compute_ate(seq.groundtruth, raw["none"], align="none").stats.rmse)
