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
# # 09 · Maps and 3D views
#
# **What you will learn**
# - how every keyframe becomes a small 3D scan, and which pixels must stay out of it in a
#   dynamic scene;
# - how fusing the scans with a voxel filter and a statistical outlier filter gives a clean
#   static map, and why the dynamic masks are grown before use;
# - how an occupancy octree (OctoMap, Hornung et al. 2013) stores free and occupied space;
# - what a run folder holds, how `dynslam view` shows it in 3D, and the shared evaluation plots.
#
# Chang et al. 2021 (IEEE TIM, Sec. III-D, Fig. 9) build the point cloud from the *static*
# pixels only, clean it with a voxel filter and a statistical outlier filter, and convert it into
# an octree map. A pixel $(u, v)$ with depth $z$ back-projects to the world point
#
# $$X_w = R_{wc}\, z \left(\frac{u - c_x}{f_x},\ \frac{v - c_y}{f_y},\ 1\right)^{\!\top} + t_{wc}.$$
#
# Poses come from the ground truth and masks from the renderer, so what you see is the mapping
# alone; `dynslam run` uses the tracker's poses and the screener's masks.

# %%
import dataclasses
import tempfile
import time
from pathlib import Path

import cv2
import matplotlib.pyplot as plt
import numpy as np

from dynslam_lab.datasets import TumSequence
from dynslam_lab.datasets.synthetic import moving_instances, synthetic_sequence, truth_views
from dynslam_lab.evaluation import Trajectory, compute_ate, compute_rpe, write_tum_trajectory
from dynslam_lab.features.orb import extract_features
from dynslam_lab.geometry.se3 import so3_exp
from dynslam_lab.mapping.dense import DenseMapConfig, build_dense_map, map_quality, static_exclusion_mask, write_dense_map
from dynslam_lab.mapping.octree import OctreeConfig, OctreeMap
from dynslam_lab.mapping.pointcloud import backproject_frame, voxel_downsample
from dynslam_lab.viz.colors import hex_color
from dynslam_lab.viz.exercises import check
from dynslam_lab.viz.plots import (plot_ate_along_path, plot_keypoints, plot_rpe_over_time, plot_timing_bars,
                                   plot_trajectories)
from dynslam_lab.viz.viser_scene import load_run, show_inline
from dynslam_lab.viz.widgets import figure_explorer, float_slider, int_slider

N = 30  # frames of the synthetic walking_xyz preset (two people walking, camera translating)
root = synthetic_sequence("walking_xyz", n_frames=N, seed=0)
seq = TumSequence(root)
movers = moving_instances(root)
keyframes = list(range(0, N, 3))
print(seq, "| moving instances:", movers, "| keyframes:", keyframes)


def moving_mask(frame, short_px=0):
    """Truth mask of the walkers; ``short_px`` > 0 shrinks it like a segmentation network's
    mask, which stops a few pixels short of the outline."""
    m = np.isin(frame.instance_mask, movers)
    if short_px > 0:
        disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * short_px + 1, 2 * short_px + 1))
        m = cv2.erode(m.astype(np.uint8), disk).astype(bool)
    return m


def top_view(xyz, rgb, ax, title, size=4.0):
    """Map points seen from above (the synthetic world is z-up), highest drawn last."""
    order = np.argsort(xyz[:, 2])
    ax.scatter(xyz[order, 0], xyz[order, 1], c=rgb[order] / 255.0, s=size, marker=".", linewidths=0)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize="small")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")


# %% [markdown]
# ## 1. One keyframe as a point cloud
#
# Three kinds of pixels stay out: no depth reading, the dynamic mask **grown by a few pixels**
# (masks stop short of the outline, and the outline is where depth jumps), and **flying pixels**
# at depth edges, where the sensor mixes foreground and background.

# %% figures=1
cfg = DenseMapConfig()
f0 = seq[keyframes[4]]
excl = static_exclusion_mask(f0.depth, moving_mask(f0), cfg)
fig, axes = plt.subplots(1, 3, figsize=(14, 3.6), constrained_layout=True)
axes[0].imshow(f0.rgb)
axes[0].set_title(f"keyframe {f0.index}")
im = axes[1].imshow(np.where(f0.depth > 0, f0.depth, np.nan), cmap="turbo", vmin=0, vmax=5)
fig.colorbar(im, ax=axes[1], fraction=0.04, label="depth [m]")
axes[1].set_title("depth (blank: no reading)")
axes[2].imshow(np.where(excl[..., None], np.array([220, 0, 220]), f0.rgb).astype(np.uint8))
axes[2].set_title("left out (magenta): grown dynamic mask + depth edges")
for a in axes:
    a.set_axis_off()
xyz0, rgb0 = backproject_frame(f0.depth, f0.camera, seq.gt_pose(f0.index), f0.rgb, excl, cfg.stride,
                               cfg.min_depth, cfg.max_depth)
print(f"{len(xyz0)} static points from one keyframe (every {cfg.stride}nd pixel)")

# %% [markdown]
# **What to look for**: the walker and a thin band around it are out, and so are the outlines
# of every object standing in front of another (monitor edges, chair legs): flying pixels would
# smear into the gap between foreground and background.

# %% [markdown]
# ## 2. Fusing the keyframes, with and without masks
#
# All keyframes go into one voxel grid: each voxel of side `voxel_size` keeps the centroid and
# mean colour of its points (PCL's `VoxelGrid`). Voxels seen by fewer than `min_observations`
# keyframes go (a walker rarely stays in a voxel), and the statistical filter drops points whose
# mean distance to their `k` neighbours exceeds $\mu + \alpha\sigma$. To score a map we render
# *exact* depth from the true poses: a point is **on a person** when it projects into a walker's
# mask at the walker's depth, and its **surface error** is its depth difference to the true surface.

# %% figures=1
views = truth_views(root, keyframes)  # (frame with exact depth, true T_w_c, moving mask) per keyframe


def keyframe_stream(mask=True, short_px=0, every=1):
    for i in keyframes[::every]:
        f = seq[i]
        yield f, seq.gt_pose(i), (moving_mask(f, short_px) if mask else None)


maps = {}
no_filters = dataclasses.replace(cfg, min_observations=1, sor_k=0)
for name, use_masks, c in (("with dynamic masks", True, cfg), ("without masks", False, cfg),
                           ("without masks or filters", False, no_filters)):
    maps[name] = build_dense_map(keyframe_stream(use_masks), c)
    q = map_quality(maps[name].xyz, views)
    print(f"{name:>26}: {len(maps[name].xyz):6d} points, {100 * q.dynamic_fraction:5.2f} % on people, "
          f"median surface error {100 * q.median_surface_error:.2f} cm")
fig, axes = plt.subplots(1, 3, figsize=(15, 5), constrained_layout=True, sharex=True, sharey=True)
for ax, (name, m) in zip(axes, maps.items()):
    top_view(m.xyz, m.rgb, ax, f"{name}: {len(m.xyz)} points")

# %% [markdown]
# **What to look for**: without masks or filters the walkers leave smeared trails in front of
# the desk (the band near y = 0) and by the desk (y = 2.2); the multi-view filter
# (`min_observations`) removes most of them even without masks, since a walker rarely occupies
# the same voxel twice; with masks they are gone.

# %% [markdown]
# ## 3. The filters, by hand
#
# Real segmentation masks stop short of the outline. Here every mask is shrunk by 8 pixels
# (a network's mask), every other keyframe is used (a quicker redraw), the voxel filter is at
# 2 cm and the multi-view filter is *off*
# (`min_observations` = 1). Right: the corridor in front of the desk seen from the camera's side
# (points with y < 0.9 m), where the walkers passed. Grow the masks (dilation) or turn the
# multi-view filter on, and watch the walkers' ghosts disappear.

# %% figures=1
def draw_filters(voxel_size=0.02, sor_std_ratio=2.0, dilate_px=3, min_observations=1):
    c = dataclasses.replace(cfg, voxel_size=voxel_size, sor_std_ratio=sor_std_ratio, dilate_px=dilate_px,
                            min_observations=min_observations)
    m = build_dense_map(keyframe_stream(True, short_px=8, every=2), c)  # every other keyframe: a quick redraw
    q = map_quality(m.xyz, views)
    fig, axes = plt.subplots(1, 2, figsize=(14, 4.8), constrained_layout=True, gridspec_kw={"width_ratios": [1, 1.15]})
    top_view(m.xyz, m.rgb, axes[0], f"{len(m.xyz)} points, {100 * q.dynamic_fraction:.2f} % on people, "
                                    f"median error {100 * q.median_surface_error:.2f} cm")
    near = m.xyz[:, 1] < 0.9
    axes[1].scatter(m.xyz[near, 0], m.xyz[near, 2], c=m.rgb[near] / 255.0, s=6, linewidths=0)
    axes[1].set_xlim(-1.6, 1.7)
    axes[1].set_ylim(-0.1, 1.9)
    axes[1].set_aspect("equal")
    axes[1].set_xlabel("x [m]")
    axes[1].set_ylabel("z [m]")
    axes[1].set_title(f"the corridor (y < 0.9 m) from the front: {near.sum()} points", fontsize="small")
    return fig


figure_explorer(draw_filters, name="09 dense-map filters",
                voxel_size=float_slider("voxel [m]", 0.02, 0.005, 0.08, 0.005),
                sor_std_ratio=float_slider("SOR alpha", 2.0, 0.25, 4.0, 0.25),
                dilate_px=int_slider("mask dilation [px]", 3, 0, 15),
                min_observations=int_slider("min keyframes per voxel", 1, 1, 5));

# %% [markdown]
# **What to look for**: at 3 px of dilation the walkers' outlines still stand in the corridor
# as ghost figures (right), about one percent of the map; at 8 px or more they are gone, at the
# price of the floor next to the walkers. `min_observations` = 2 removes them too, without
# growing any mask. A larger voxel thins the map; a small $\alpha$ eats into thin structures.

# %% [markdown]
# ## 4. The octree map
#
# OctoMap (Hornung et al. 2013) stores occupancy as log-odds per voxel. Each keyframe casts rays
# from the camera centre to its static points: the end voxel gets $\operatorname{logit}(0.7)$,
# every voxel crossed gets $\operatorname{logit}(0.4)$, clamped to
# $[\operatorname{logit}(0.12), \operatorname{logit}(0.97)]$. Free space is known too, and a person
# who stood somewhere is *erased* by later rays through that place. Inner nodes hold the maximum
# of their children, so the same tree answers at 5, 10, 20, 40 cm.

# %% figures=1
octree = OctreeMap(OctreeConfig(resolution=0.05))
t = time.perf_counter()
for f, T, mask in keyframe_stream(True):
    pts, _ = backproject_frame(f.depth, f.camera, T, None, static_exclusion_mask(f.depth, mask, cfg), 4,
                               cfg.min_depth, cfg.max_depth)
    octree.insert_scan(voxel_downsample(pts, 0.025)[0], T[:3, 3])
print(octree.stats(), f"built in {time.perf_counter() - t:.2f} s")


def draw_octree(level=1):
    centres, side = octree.occupied(level)
    fig = plt.figure(figsize=(7, 5.5), constrained_layout=True)
    ax = fig.add_subplot(projection="3d")
    ax.scatter(centres[:, 0], centres[:, 1], centres[:, 2], c=centres[:, 2], cmap="viridis", s=4 * 2**level,
               marker="s", depthshade=False)
    ax.set_title(f"level {level}: {len(centres)} occupied nodes of {100 * side:.0f} cm")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    return fig


figure_explorer(draw_octree, name="09 octree", level=int_slider("levels above the leaves", 1, 0, 4));

# %% [markdown]
# **What to look for**: at 10 cm the room's walls, desk and shelves are recognisable with a few
# thousand nodes; each level up divides the count by about four (surfaces, not volumes), and at
# 80 cm only the room's outline is left: a planner would choose its level by the robot's size.

# %% [markdown]
# ## 5. A run folder in the 3D viewer
#
# `dynslam run` writes its results in one folder (see `docs/architecture.md`). We write the
# same files here from the truth: the trajectory (with a little noise, so that the errors below
# are not zero), the keyframes, ORB keypoints of the keyframes as the sparse map (static ones,
# and the dynamic ones apart), thumbnails and `map.ply`. `dynslam view OUTDIR` serves this in the
# browser; the figure first shows the same layers from above, in the viewer's colours.

# %% figures=1
out = Path(tempfile.mkdtemp(prefix="dynslam_view_"))
rng = np.random.default_rng(0)
gt = Trajectory(seq.timestamps, np.stack([seq.gt_pose(i) for i in range(N)]))
est_poses = gt.poses.copy()
est_poses[:, :3, 3] += np.cumsum(rng.normal(scale=0.002, size=(N, 3)), axis=0)
est_poses[:, :3, :3] = est_poses[:, :3, :3] @ np.stack([so3_exp(rng.normal(scale=np.radians(0.2), size=3))
                                                        for _ in range(N)])
write_tum_trajectory(Trajectory(gt.timestamps, est_poses), out / "trajectory.txt")
write_tum_trajectory(gt, out / "groundtruth.txt")
kf = np.array(keyframes)
np.savez(out / "keyframes.npz", ids=np.arange(len(kf)), frame_index=kf, timestamps=seq.timestamps[kf],
         poses=est_poses[kf], loop_edges=np.zeros((0, 2), np.int64))
static_xyz, static_rgb, dyn_xyz, dyn_frame = [], [], [], []
(out / "thumbs").mkdir()
for k, i in enumerate(kf):
    f = seq[int(i)]
    feats = extract_features(f.gray)
    px = np.round(feats.uv).astype(int)
    z = f.depth[px[:, 1], px[:, 0]]
    ok = z > 0
    X = f.camera.backproject(feats.uv[ok].astype(float), z[ok].astype(float)) @ est_poses[i][:3, :3].T + est_poses[i][:3, 3]
    dyn = moving_mask(f)[px[ok, 1], px[ok, 0]]
    static_xyz.append(X[~dyn])
    static_rgb.append(f.rgb[px[ok, 1], px[ok, 0]][~dyn])
    dyn_xyz.append(X[dyn])
    dyn_frame.append(np.full(dyn.sum(), i))
    cv2.imwrite(str(out / "thumbs" / f"{k}.jpg"), cv2.cvtColor(cv2.resize(f.rgb, (160, 120)), cv2.COLOR_RGB2BGR))
np.savez(out / "map_points.npz", xyz=np.concatenate(static_xyz), rgb=np.concatenate(static_rgb),
         n_obs=np.ones(sum(len(x) for x in static_xyz), int))
np.savez(out / "dynamic_points.npz", xyz=np.concatenate(dyn_xyz), frame=np.concatenate(dyn_frame))
write_dense_map(seq, out, {int(i): moving_mask(seq[int(i)]) for i in kf}, cfg)
print("run folder:", out, sorted(p.name for p in out.iterdir()))
print(f"in a terminal: dynslam view {out}")

run = load_run(out)
fig, ax = plt.subplots(figsize=(8, 6.5), constrained_layout=True)
sx = np.concatenate(static_xyz)
dx = np.concatenate(dyn_xyz)
ax.scatter(sx[:, 0], sx[:, 1], s=5, c=hex_color("static"), linewidths=0, label=f"sparse map, static ({len(sx)})")
ax.scatter(dx[:, 0], dx[:, 1], s=7, c=hex_color("dynamic"), linewidths=0, label=f"keypoints judged dynamic ({len(dx)})")
ax.plot(run.kf_poses[:, 0, 3], run.kf_poses[:, 1, 3], "s", color=hex_color("keyframe"), ms=4, label="keyframes")
plot_trajectories({"ground truth": run.ground_truth, "estimate": run.trajectory}, plane="xy", ax=ax)
ax.legend(loc="upper left", fontsize="small")
ax.set_title("the run from above, in the viewer's colours");

# %% [markdown]
# **What to look for**: the estimate (red) follows the dashed ground truth within millimetres;
# the keyframes (orange) sit on it every third frame. The magenta points are the walkers'
# keypoints, between the camera and the desk: in the 3D viewer they are shown only for the
# frames near the playback position, not all at once.
#
# The same scene in 3D, embedded (drag to turn it; `dynslam view` adds the playback slider,
# layer toggles and a legend):

# %%
show_inline(run, height=450);

# %% [markdown]
# ## 6. The shared plots
#
# The same figures appear in the other notebooks and in the command line: the paths from above,
# the absolute trajectory error along the path (Sturm et al. 2012), the relative pose error
# over time, time per stage, and keypoints coloured by their verdict.

# %% figures=2
ate = compute_ate(gt, run.trajectory)
rpe = compute_rpe(gt, run.trajectory)
fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), constrained_layout=True)
plot_trajectories({"ground truth": gt, "estimate": run.trajectory}, plane="xy", ax=axes[0])
plot_ate_along_path(ate, plane="xy", ax=axes[1])
plt.show()
plot_rpe_over_time(rpe);

# %% [markdown]
# **What to look for**: the absolute error grows along the path (the noise of the made-up
# estimate is a random walk), while the relative error per frame stays flat: RPE measures drift
# per step, ATE the accumulated result. The rotational RPE is a fraction of a degree, printed
# with its significant digits.

# %% figures=2
# Time per mapping step on one keyframe, measured here (milliseconds).
f = seq[keyframes[0]]
T = seq.gt_pose(keyframes[0])
timings = {}
t = time.perf_counter(); ex = static_exclusion_mask(f.depth, moving_mask(f), cfg); timings["exclusion mask"] = 1e3 * (time.perf_counter() - t)
t = time.perf_counter(); P, C = backproject_frame(f.depth, f.camera, T, f.rgb, ex, cfg.stride); timings["back-projection"] = 1e3 * (time.perf_counter() - t)
t = time.perf_counter(); Pv, Cv = voxel_downsample(P, cfg.voxel_size, C); timings["voxel filter"] = 1e3 * (time.perf_counter() - t)
t = time.perf_counter(); octree.insert_scan(voxel_downsample(P, 0.025)[0], T[:3, 3]); timings["octree update"] = 1e3 * (time.perf_counter() - t)
plot_timing_bars(timings, title="Mapping, one keyframe (ms)")
plt.show()
f = seq[keyframes[4]]
feats = extract_features(f.gray)
px = np.round(feats.uv).astype(int)
plot_keypoints(f.rgb, feats.uv, moving_mask(f)[px[:, 1], px[:, 0]], title="ORB keypoints: on a walker (magenta) or static (green)");

# %% [markdown]
# **What to look for**: the octree update dominates the mapping time (it walks every ray
# through the grid); the voxel filter is cheap. The keypoints on the walker are the ones the
# screening stage must find: a fifth of the frame's keypoints here.

# %% [markdown]
# ### Exercise 1: a voxel filter by hand
#
# How many voxels of side 5 cm hold at least one point of the keyframe cloud `xyz0` (section 1)?
# Voxel index: $\lfloor X / 0.05 \rfloor$ per axis; count the distinct triples.

# %% exercise="09.1"
answer = None  # your code: an integer

# %% check="09.1"
check("09.1", answer, len(voxel_downsample(xyz0, 0.05)[0]))

# %% [markdown]
# ### Exercise 2: three hits
#
# A voxel starts unknown (log-odds 0, probability 0.5) and is hit by three rays (each adds
# $\operatorname{logit}(0.7)$). What is its occupancy probability $1 / (1 + e^{-L})$? Then check on a
# fresh `OctreeMap`: insert the scan `np.array([[1.02, 0.02, 0.02]])` from the origin three times
# and read `occupancy`.

# %% exercise="09.2"
answer = None  # your code: the probability

# %% check="09.2"
tree = OctreeMap(OctreeConfig(resolution=0.05))
for _ in range(3):
    tree.insert_scan(np.array([[1.02, 0.02, 0.02]]), np.zeros(3))
check("09.2", answer, tree.occupancy(np.array([[1.02, 0.02, 0.02]]))[0], rtol=1e-6)

# %% [markdown]
# ### Exercise 3: how much do the masks remove?
#
# From the maps of section 2, what share of the points of the map "without masks or filters"
# lies on people (`map_quality(...).dynamic_fraction`)? Compare with the masked map.

# %% exercise="09.3"
answer = None  # your code: a fraction in [0, 1]

# %% check="09.3"
check("09.3", answer, map_quality(maps["without masks or filters"].xyz, views).dynamic_fraction)
