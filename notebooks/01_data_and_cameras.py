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
# Every sequence this toolkit reads, TUM RGB-D, Bonn RGB-D Dynamic or our own synthetic
# scenes, has the same layout: `rgb.txt` and `depth.txt` list timestamped images, and
# `groundtruth.txt` lists timestamped poses. This notebook shows
#
# 1. the pinhole camera and its presets,
# 2. how colour and depth frames are *associated* by timestamp,
# 3. how a depth image becomes a 3D point cloud (back-projection),
# 4. the real TUM frames in `../shared/data/` when they are present.

# %%
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import ipywidgets as widgets
from IPython.display import display

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.datasets import TumSequence, associate, load_depth, load_rgb, read_file_list
from dynslam_lab.datasets.synthetic import synthetic_sequence

SHARED = Path("..").resolve().parent / "shared" / "data"
print("real data present:", SHARED.is_dir())

# %% [markdown]
# ## 1. The pinhole camera
#
# A point $X_c = (x, y, z)$ in the camera frame projects to the pixel
# $u = f_x x / z + c_x$, $v = f_y y / z + c_y$. The inverse, *back-projection*, needs the
# depth $z$ of the pixel: $X_c = z\,((u - c_x)/f_x,\ (v - c_y)/f_y,\ 1)$. TUM publishes one set
# of intrinsics per Kinect (freiburg 1, 2, 3); the loader picks it from the folder name.

# %%
import pandas as pd

pd.DataFrame(
    [{"preset": k, "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy, "distorted": c.has_distortion} for k, c in CAMERA_PRESETS.items()]
).set_index("preset")

# %% [markdown]
# ## 2. Association by timestamp
#
# The Kinect streams colour and depth separately, so their timestamps differ by a few
# milliseconds. TUM's `associate.py` pairs each colour frame with the nearest depth frame,
# greedily, keeping pairs closer than `max_diff` (0.02 s). We render a short synthetic
# sequence (written in the TUM layout, depth stamps deliberately offset) and associate it.

# %%
seq_dir = synthetic_sequence("walking_xyz", n_frames=30, seed=0)
rgb_ts, _ = read_file_list(seq_dir / "rgb.txt")
depth_ts, _ = read_file_list(seq_dir / "depth.txt")
pairs = associate(rgb_ts, depth_ts, max_diff=0.02)
dt_ms = (depth_ts[pairs[:, 1]] - rgb_ts[pairs[:, 0]]) * 1000
print(f"{len(rgb_ts)} colour, {len(depth_ts)} depth stamps -> {len(pairs)} pairs; depth - colour: {dt_ms.mean():.1f} ms on average")


# %% [markdown]
# Move `max_diff` below the real offset and frames stop pairing: the loader then refuses the
# sequence with a message that names the folder, rather than silently using no frames.

# %%
def show_pairs(max_diff_ms=20.0):
    n = len(associate(rgb_ts, depth_ts, max_diff=max_diff_ms / 1000))
    print(f"max_diff = {max_diff_ms:.1f} ms -> {n} of {len(rgb_ts)} colour frames paired")


widgets.interact(show_pairs, max_diff_ms=widgets.FloatSlider(value=20.0, min=0.5, max=40, step=0.5));

# %% [markdown]
# ## 3. A frame, its depth and its ground truth
#
# `TumSequence` loads frames lazily: `seq[i]` reads the images of frame `i` only. Depth comes
# back in metres (16-bit PNG / 5000), with 0 where the sensor gave no reading. Synthetic
# frames also carry per-pixel instance masks with COCO class names.

# %%
seq = TumSequence(seq_dir)
frame = seq[10]
print(seq, "| instances:", frame.instance_classes)
fig, ax = plt.subplots(1, 3, figsize=(13, 3.4))
ax[0].imshow(frame.rgb); ax[0].set_title("colour")
im = ax[1].imshow(np.where(frame.depth > 0, frame.depth, np.nan), cmap="turbo"); ax[1].set_title("depth (m), holes blank")
fig.colorbar(im, ax=ax[1], fraction=0.035)
ax[2].imshow(frame.instance_mask, cmap="tab20", interpolation="nearest"); ax[2].set_title("instance ids")
for a in ax:
    a.axis("off")
plt.show()


# %% [markdown]
# Back-projecting every pixel with the frame's ground-truth pose puts it in the world frame.
# The slider sets the pixel stride (fewer points, faster plot).

# %%
def show_cloud(stride=6):
    pts = frame.camera.backproject_depth(frame.depth, stride=stride).reshape(-1, 3)
    cols = frame.rgb[::stride, ::stride].reshape(-1, 3) / 255.0
    ok = np.isfinite(pts).all(axis=1)
    T = frame.T_w_c_gt
    Pw = pts[ok] @ T[:3, :3].T + T[:3, 3]
    fig, ax = plt.subplots(figsize=(6, 5))
    ax.scatter(Pw[:, 0], Pw[:, 2], c=cols[ok], s=1)
    ax.plot(*T[[0, 2], 3], "k^", ms=10, label="camera")
    ax.set_xlabel("x (m)"); ax.set_ylabel("z (m)"); ax.set_aspect("equal"); ax.legend()
    ax.set_title(f"top view of {ok.sum()} back-projected points")
    plt.show()


widgets.interact(show_cloud, stride=widgets.IntSlider(value=6, min=2, max=16));

# %% [markdown]
# ## 4. Real TUM frames
#
# With `../shared/data` beside the clone, we load a real fr3/walking_xyz colour frame, the
# depth frame after it and a YOLACT person mask, and look at the depth inside the person.
# Real depth has holes at edges and on dark or shiny surfaces, and its noise grows with the
# square of the distance: the synthetic renderer imitates both.

# %%
frames = SHARED / "tum" / "frames"
if frames.is_dir():
    cam = CAMERA_PRESETS["tum_fr3"]
    rgb = load_rgb(frames / "fr3_walking_xyz_1341846313.553992_rgb.png")
    depth = load_depth(frames / "fr3_walking_xyz_1341846313.592088_depth.png", cam.depth_scale)
    person = load_rgb(frames / "fr3_walking_xyz_1341846313.553992_person_mask_yolact.png")[..., 0] > 127
    fig, ax = plt.subplots(1, 3, figsize=(13, 3.4))
    ax[0].imshow(rgb); ax[0].contour(person, colors="r", linewidths=0.8); ax[0].set_title("fr3/walking_xyz + YOLACT mask")
    ax[1].imshow(np.where(depth > 0, depth, np.nan), cmap="turbo"); ax[1].set_title(f"depth, {100 * (depth == 0).mean():.1f}% holes")
    ax[2].hist(depth[(depth > 0) & person], bins=60, alpha=0.7, label="person")
    ax[2].hist(depth[(depth > 0) & ~person], bins=60, alpha=0.5, label="rest")
    ax[2].set_xlabel("depth (m)"); ax[2].legend()
    for a in ax[:2]:
        a.axis("off")
    plt.show()
    pts = cam.backproject_depth(depth, stride=4)
    print("back-projected", np.isfinite(pts[..., 2]).sum(), "points; median depth", np.nanmedian(pts[..., 2]).round(2), "m")
else:
    print("../shared/data not found: skipping the real frames")

# %% [markdown]
# The association lists of the eight fr3 dynamic sequences are there too: each pairs colour and
# depth frames recorded a few milliseconds apart.

# %%
assoc = SHARED / "tum" / "associations"
if assoc.is_dir():
    rows = []
    for p in sorted(assoc.glob("*.txt")):
        ts, r = read_file_list(p, min_fields=4)
        d = np.array([float(x[1]) for x in r])
        rows.append({"sequence": p.stem, "frames": len(ts), "seconds": ts[-1] - ts[0], "median |dt| ms": 1000 * np.median(np.abs(d - ts))})
    display(pd.DataFrame(rows).set_index("sequence").round(2))
