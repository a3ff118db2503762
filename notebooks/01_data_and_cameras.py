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
# # 01 · Data and cameras
#
# **What you will learn**
# - the layout every sequence here shares (TUM RGB-D, Bonn RGB-D Dynamic, our synthetic scenes):
#   `rgb.txt`, `depth.txt` and `groundtruth.txt` list timestamped images and poses;
# - how colour and depth frames recorded a few milliseconds apart are *associated*;
# - the pinhole camera, and how a depth image becomes a 3D point cloud (back-projection);
# - what real Kinect depth looks like next to the synthetic one.
#
# The layout, the association rule and the camera intrinsics are those of the TUM RGB-D
# benchmark (Sturm et al. 2012). A point $X_c = (x, y, z)$ in the camera frame (x right, y down,
# z forward) projects to the pixel
#
# $$u = f_x \frac{x}{z} + c_x, \qquad v = f_y \frac{y}{z} + c_y,$$
#
# and back-projection inverts it with the pixel's depth: $X_c = z\,\big((u - c_x)/f_x,\ (v - c_y)/f_y,\ 1\big)$.

# %%
import os
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from IPython.display import display

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.datasets import TumSequence, associate, load_depth, load_rgb, read_file_list
from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.geometry.se3 import se3_inv, transform_points
from dynslam_lab.viz.colors import hex_color
from dynslam_lab.viz.exercises import check
from dynslam_lab.viz.plots import plot_rgbd_frame
from dynslam_lab.viz.widgets import figure_explorer, float_slider, int_slider

SHARED = Path(os.environ.get("DYNSLAM_SHARED_DATA", Path("..").resolve().parent / "shared" / "data"))
print("real data present:", SHARED.is_dir())
seq_dir = synthetic_sequence("walking_xyz", n_frames=30, seed=0)  # written in the TUM layout
seq = TumSequence(seq_dir)
print(seq, "|", sorted(p.name for p in seq_dir.iterdir()))

# %% [markdown]
# ## 1. A frame: colour, depth, instances
#
# `TumSequence` loads frames lazily: `seq[i]` reads the images of frame `i` only. Depth comes
# back in metres (16-bit PNG / 5000), 0 where the sensor gave no reading. Synthetic frames also
# carry a per-pixel instance mask with COCO class names, and which instances move.

# %% figures=1
frame = seq[10]
visible = pd.Series([frame.instance_classes[i] for i in np.unique(frame.instance_mask) if i in frame.instance_classes])
print("visible instances per class:", visible.value_counts().to_dict(), "| moving ids:", sorted(frame.moving_ids))
plot_rgbd_frame(frame, title=f"synthetic walking_xyz, frame {frame.index}");

# %% [markdown]
# **What to look for**: the depth holes (blank) sit on object edges and on dark, shiny
# surfaces, where a real Kinect loses its pattern too; the renderer imitates that. In the
# instance panel only the walker is in colour: the books and chairs have ids as well, but they
# never move.

# %% [markdown]
# ## 2. Association by timestamp
#
# The Kinect streams colour and depth separately, so their timestamps differ by a few
# milliseconds. TUM's `associate.py` pairs each colour frame with the nearest depth frame,
# greedily, keeping pairs closer than `max_diff` (0.02 s by default). Our synthetic sequences
# offset the depth stamps by up to 9 ms on purpose.

# %% figures=1
rgb_ts, _ = read_file_list(seq_dir / "rgb.txt")
depth_ts, _ = read_file_list(seq_dir / "depth.txt")


def draw_pairs(max_diff_ms=6.0):
    pairs = associate(rgb_ts, depth_ts, max_diff=max_diff_ms / 1000)
    t0 = rgb_ts[0]
    fig, ax = plt.subplots(figsize=(12, 2.8), constrained_layout=True)
    ax.plot(rgb_ts - t0, np.ones_like(rgb_ts), "o", color=hex_color("estimate"), ms=5, label="colour stamps")
    ax.plot(depth_ts - t0, np.zeros_like(depth_ts), "s", color=hex_color("multiview"), ms=5, label="depth stamps")
    for i, j in pairs:
        ax.plot([rgb_ts[i] - t0, depth_ts[j] - t0], [1, 0], "-", color=hex_color("static"), lw=1.5)
    lone = np.setdiff1d(np.arange(len(rgb_ts)), pairs[:, 0])
    ax.plot(rgb_ts[lone] - t0, np.ones(len(lone)), "x", color=hex_color("dynamic"), ms=11, mew=2,
            label=f"unpaired colour frames ({len(lone)})")
    ax.set_yticks([0, 1], ["depth", "colour"])
    ax.set_ylim(-0.5, 1.6)
    ax.set_xlabel("time since the first colour frame [s]")
    ax.set_title(f"max_diff = {max_diff_ms:.1f} ms: {len(pairs)} of {len(rgb_ts)} colour frames paired (green)")
    ax.legend(loc="upper right", ncol=3, fontsize="small")
    return fig


figure_explorer(draw_pairs, name="01 association", max_diff_ms=float_slider("max_diff [ms]", 6.0, 0.5, 40.0, 0.5));

# %% [markdown]
# **What to look for**: at 6 ms two colour frames in three pair; below the offsets (1 ms)
# none does, and from 10 ms on all do. Pairs never cross: the offsets are far below the 30 ms
# between frames, so the nearest depth frame is always the right one. With no pair at all, the
# loader refuses the sequence with a message naming the folder, rather than using no frames.

# %% [markdown]
# ## 3. The pinhole camera and back-projection
#
# TUM publishes one set of intrinsics per Kinect (freiburg 1, 2, 3); the loader picks it from
# the folder name. The synthetic sequences use the `default` camera (525 px focal length).

# %%
display(pd.DataFrame(
    [{"preset": k, "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy, "distorted": c.has_distortion}
     for k, c in CAMERA_PRESETS.items()]).set_index("preset"))

# %% [markdown]
# Back-projecting every pixel with the frame's ground-truth pose $T_{wc}$ puts it in the world
# frame, $X_w = R_{wc} X_c + t_{wc}$. The synthetic world is z-up (the floor is $z = 0$), so
# "from above" means x against y. The slider sets the pixel stride (fewer points, faster plot).

# %% figures=1
T = frame.T_w_c_gt


def draw_cloud(stride=6):
    pts = frame.camera.backproject_depth(frame.depth, stride=stride).reshape(-1, 3)
    cols = frame.rgb[::stride, ::stride].reshape(-1, 3) / 255.0
    ok = np.isfinite(pts).all(axis=1) & (pts[:, 2] > 0)
    Pw = transform_points(T, pts[ok])
    fig, axes = plt.subplots(1, 2, figsize=(13, 5), constrained_layout=True)
    for ax, (a, b), name in ((axes[0], (0, 1), "from above (x, y)"), (axes[1], (1, 2), "from the side (y, z)")):
        order = np.argsort(Pw[:, 2 if a == 0 else 0])  # draw the highest (or nearest) points last
        ax.scatter(Pw[order, a], Pw[order, b], c=cols[ok][order], s=max(1.0, stride / 2), linewidths=0)
        look = T[:3, 2] * 0.6
        ax.annotate("", xy=(T[a, 3] + look[a], T[b, 3] + look[b]), xytext=(T[a, 3], T[b, 3]),
                    arrowprops=dict(arrowstyle="->", color=hex_color("estimate"), lw=2))
        ax.plot(T[a, 3], T[b, 3], "o", color=hex_color("estimate"), ms=8, label="camera, looking along the arrow")
        ax.set_xlabel(f"{'xyz'[a]} [m]")
        ax.set_ylabel(f"{'xyz'[b]} [m]")
        ax.set_aspect("equal")
        ax.grid(True, alpha=0.3)
        ax.set_title(name)
    axes[0].legend(loc="lower right", fontsize="small")
    fig.suptitle(f"{ok.sum()} back-projected points, every {stride}th pixel")
    return fig


figure_explorer(draw_cloud, name="01 back-projection", stride=int_slider("pixel stride", 6, 2, 16));

# %% [markdown]
# **What to look for**: from above, the back wall and the bookshelves are straight lines and
# the walker is a small blob between the camera and the desk; from the side, the floor is flat
# at $z = 0$ and the desk top a horizontal line. Straight walls and a flat floor say the
# intrinsics and the depth scale are right: a wrong $f_x$ bends the walls into a fan.

# %% [markdown]
# ## 3b. Metres or not: the depth scale
#
# A depth PNG holds integers, and the camera's `depth_scale` says how many make a metre: 5000 for
# TUM and Bonn, 1000 (millimetres) for many other sensors. Nothing in the images says which, and
# geometry cannot tell either: a world scaled by $s$, seen from a path scaled by $s$, projects to
# the same pixels. So a wrong scale runs without a complaint and returns a path of the wrong size.
# `dynslam run` checks it twice (`dynslam_lab.datasets.depth_scale`, docs/datasets.md "The depth
# scale"): before the run, the median depth of five frames must lie inside the range tracking uses
# (`tracking.min_depth`-`max_depth`, 0.1-8 m); after it, where there is ground truth, the path is
# aligned with a similarity and a scale far from 1 is reported in `summary.json`. Below, this
# sequence read at several scales (the right one is 5000).

# %% figures=1
from dynslam_lab.datasets.depth_scale import check_depth_range, sample_depth
from dynslam_lab.datasets.tum import DatasetError

rows = []
for scale in (1000, 2500, 5000, 10000, 25000):
    read_so = TumSequence(seq_dir, camera=seq.camera.with_(depth_scale=float(scale)))
    try:
        check_depth_range(read_so, None, 0.1, 8.0)
        verdict = "accepted"
    except DatasetError:
        verdict = "refused before the run"
    rows.append({"depth_scale": scale, "median depth [m]": round(sample_depth(read_so).median_m, 2), "check": verdict})
table = pd.DataFrame(rows).set_index("depth_scale")
display(table)
fig, ax = plt.subplots(figsize=(8, 3.2), constrained_layout=True)
ax.axhspan(0.1, 8.0, color=hex_color("static"), alpha=0.15, label="tracking.min_depth - max_depth")
ax.bar([str(k) for k in table.index], table["median depth [m]"], label="median depth of five frames",
       color=[hex_color("static") if v == "accepted" else hex_color("dynamic") for v in table["check"]])
ax.set_xlabel("depth_scale read with [units per metre]")
ax.set_ylabel("depth [m]")
ax.legend(fontsize="small")
ax.set_title("the same depth images read at five scales (red: refused)");

# %% [markdown]
# **What to look for**: at 5000 the room reads 2.7 m (the median of five frames). Read as
# millimetres (1000) it would be 13.5 m, above the shaded band of depths tracking uses, and the run
# is refused (the red bar) with a message naming the file and the scale. A factor of two (2500:
# 5.4 m) and scales too fine (10000, 25000: 1.35 m and 0.54 m, plausible close-ups) pass: only the
# ground truth can catch those, after the run (`trajectory_scale` and `warnings` in `summary.json`).

# %% [markdown]
# Before running a folder of your own, `dynslam check SEQDIR` (or `check_sequence` here) says what a run
# would take from it: the pairs and their rate, where the camera's intrinsics come from, the image size,
# this depth median, how much of the run the ground truth covers. `!` marks a warning, `X` what
# `dynslam run` would refuse. Here the sequence above, then the same folder read as millimetres.

# %%
from dynslam_lab.datasets.check import check_sequence

print(check_sequence(seq_dir).format())
print()
print(check_sequence(seq_dir, camera=seq.camera.with_(depth_scale=1000.0)).format())

# %% [markdown]
# ## 4. Real TUM frames
#
# With `../shared/data` beside the clone, a real fr3/walking_xyz colour frame, the depth frame
# recorded 38 ms later and a YOLACT person mask (the network of Chang et al. 2021). Real depth
# has holes at edges and on dark or shiny surfaces, and its noise grows with the square of the
# distance.

# %% figures=1 needs_shared=true
frames = SHARED / "tum" / "frames"
if frames.is_dir():
    cam = CAMERA_PRESETS["tum_fr3"]
    rgb = load_rgb(frames / "fr3_walking_xyz_1341846313.553992_rgb.png")
    depth = load_depth(frames / "fr3_walking_xyz_1341846313.592088_depth.png", cam.depth_scale)
    person = load_rgb(frames / "fr3_walking_xyz_1341846313.553992_person_mask_yolact.png")[..., 0] > 127
    fig, ax = plt.subplots(1, 3, figsize=(14, 3.6), constrained_layout=True)
    ax[0].imshow(rgb)
    ax[0].contour(person, colors=[hex_color("dynamic")], linewidths=1.0)
    ax[0].set_title("fr3/walking_xyz + YOLACT person mask")
    ax[1].imshow(np.where(depth > 0, depth, np.nan), cmap="turbo")
    ax[1].set_title(f"depth, {100 * (depth == 0).mean():.1f}% holes (blank)")
    bins = np.linspace(0, 5, 60)
    ax[2].hist(depth[(depth > 0) & ~person], bins=bins, color=hex_color("static"), alpha=0.6, label="rest of the image")
    ax[2].hist(depth[(depth > 0) & person], bins=bins, color=hex_color("dynamic"), alpha=0.7, label="inside the person mask")
    ax[2].set_xlabel("depth [m]")
    ax[2].set_ylabel("pixels")
    ax[2].legend(fontsize="small")
    for a in ax[:2]:
        a.set_axis_off()
    plt.show()
else:
    print("../shared/data not found: skipping the real frames")

# %% [markdown]
# **What to look for**: most pixels inside the mask lie between 1 and 2 m and the rest of the
# image behind 2 m, the separation depth-RANSAC (notebook 04) relies on; but the mask also holds
# a tail of background depths, where YOLACT's outline spills over the person's edges.
#
# The association lists of the eight fr3 dynamic sequences are there too.

# %%
assoc = SHARED / "tum" / "associations"
if assoc.is_dir():
    rows = []
    for p in sorted(assoc.glob("*.txt")):
        ts, r = read_file_list(p, min_fields=4)
        d = np.array([float(x[1]) for x in r])
        rows.append({"sequence": p.stem, "frames": len(ts), "seconds": ts[-1] - ts[0],
                     "median |dt| ms": 1000 * np.median(np.abs(d - ts))})
    display(pd.DataFrame(rows).set_index("sequence").round(2))

# %% [markdown]
# ### Exercise 1: back-project one pixel
#
# Back-project the pixel $(u, v) = (400, 300)$ of `frame` with its depth `frame.depth[300, 400]`
# using the equation at the top and `frame.camera.fx, fy, cx, cy`. Give $X_c$ as an array of 3.

# %% exercise="01.1"
answer = None  # your code: np.array([x, y, z]) in metres

# %% check="01.1"
check("01.1", answer, frame.camera.backproject(np.array([[400.0, 300.0]]), np.array([frame.depth[300, 400]]))[0])

# %% [markdown]
# ### Exercise 2: how many pairs at 5 ms?
#
# Predict from the figure of section 2, then compute with `associate`: how many colour frames
# pair with `max_diff` = 5 ms?

# %% exercise="01.2"
answer = None  # your code

# %% check="01.2"
check("01.2", answer, len(associate(rgb_ts, depth_ts, max_diff=0.005)))

# %% [markdown]
# ### Exercise 3: project a world point
#
# The world point `X_w = np.array([0.5, 0.8, 0.9])` (metres) lies on the desk. Where does it
# appear in `frame`? Move it into the camera frame with $X_c = R_{wc}^\top (X_w - t_{wc})$
# (`T = frame.T_w_c_gt`), then apply the projection. Give $(u, v)$ as an array of 2.

# %% exercise="01.3"
X_w = np.array([0.5, 0.8, 0.9])
answer = None  # your code: np.array([u, v])

# %% check="01.3"
check("01.3", answer, frame.camera.project(transform_points(se3_inv(T), X_w[None]))[0][0], atol=1e-6)
