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
# A SLAM run leaves camera poses and keyframes behind. With depth, every keyframe is a
# small 3D scan, and fusing the scans gives a **dense map** of the room. In a dynamic scene
# the people walk through those scans: Chang et al. (IEEE TIM 2021, Sec. III-D, Fig. 9)
# build the point cloud from the *static* pixels only, clean it with a **voxel filter** and
# a **statistical outlier filter**, and convert it into an **octree map** (OctoMap) for
# navigation. This notebook
#
# 1. back-projects one keyframe and shows which pixels are left out,
# 2. fuses ten keyframes with and without the dynamic masks and scores both maps against
#    the renderer's truth (share of points on people, distance to the true surfaces),
# 3. lets you move the filter parameters with sliders,
# 4. builds the occupancy octree and looks at it level by level,
# 5. writes a run folder and shows it in the 3D viewer (`dynslam view` in a browser; here
#    embedded), and draws the shared evaluation plots.
#
# Poses come from the ground truth and masks from the renderer, so what you see is the
# mapping alone; `dynslam run` uses the tracker's poses and the screener's masks.

# %%
import dataclasses
import tempfile
import time
from pathlib import Path

import cv2
import matplotlib.pyplot as plt
import numpy as np
from IPython.display import display

from dynslam_lab.datasets import TumSequence
from dynslam_lab.datasets.synthetic import moving_instances, synthetic_sequence, truth_views
from dynslam_lab.evaluation import Trajectory, compute_ate, compute_rpe, write_tum_trajectory
from dynslam_lab.features.orb import extract_features
from dynslam_lab.mapping.dense import DenseMapConfig, build_dense_map, map_quality, static_exclusion_mask, write_dense_map
from dynslam_lab.mapping.octree import OctreeConfig, OctreeMap
from dynslam_lab.mapping.pointcloud import backproject_frame, voxel_downsample
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


def moving_mask(frame):
    """Truth mask of the people who walk (the screener's region_mask in a real run)."""
    return np.isin(frame.instance_mask, movers)


# %% [markdown]
# ## 1. One keyframe as a point cloud
#
# A pixel $(u, v)$ with depth $z$ back-projects to $X_c = z\,((u-c_x)/f_x,\ (v-c_y)/f_y,\ 1)$
# and, with the keyframe pose, to $X_w = R_{wc} X_c + t_{wc}$. Three kinds of pixels stay out:
# no depth reading, the dynamic mask **grown by a few pixels** (masks stop short of the
# outline, and the outline is where depth jumps), and **flying pixels** at depth edges, where
# the sensor mixes foreground and background.

# %%
cfg = DenseMapConfig()
f0 = seq[keyframes[4]]
excl = static_exclusion_mask(f0.depth, moving_mask(f0), cfg)
fig, axes = plt.subplots(1, 3, figsize=(13, 3.4), constrained_layout=True)
axes[0].imshow(f0.rgb)
axes[0].set_title(f"keyframe {f0.index}")
axes[1].imshow(f0.depth, cmap="turbo", vmin=0, vmax=5)
axes[1].set_title("depth [m] (0 = no reading)")
axes[2].imshow(np.where(excl[..., None], [255, 0, 255], f0.rgb).astype(np.uint8))
axes[2].set_title("left out: dilated dynamic mask + depth edges")
for a in axes:
    a.set_axis_off()
xyz0, rgb0 = backproject_frame(f0.depth, f0.camera, seq.gt_pose(f0.index), f0.rgb, excl, cfg.stride,
                               cfg.min_depth, cfg.max_depth)
print(f"{len(xyz0)} static points from one keyframe (every {cfg.stride}nd pixel)")

# %% [markdown]
# ## 2. Fusing the keyframes, with and without masks
#
# All keyframes go into one voxel grid: each voxel of side `voxel_size` keeps the centroid
# and mean colour of its points (PCL's `VoxelGrid`). Then voxels seen by fewer than
# `min_observations` keyframes go (a walker rarely stays in a voxel), and the statistical
# filter drops points whose mean distance to their `k` neighbours exceeds
# $\mu + \alpha\sigma$. To score a map we render *exact* depth from the true poses at the
# keyframes' moments: a point is **on a person** when it projects into a walker's mask at the
# walker's depth, and its **surface error** is its depth difference to the true surface.
# (In these first frames the walkers are about 1 m away and cover 18-24 % of the image.)

# %%
views = truth_views(root, keyframes)  # (frame with exact depth, true T_w_c, moving mask) per keyframe


def keyframe_stream(use_masks):
    for i in keyframes:
        f = seq[i]
        yield f, seq.gt_pose(i), (moving_mask(f) if use_masks else None)


maps = {}
no_filters = dataclasses.replace(cfg, min_observations=1, sor_k=0)
for name, use_masks, c in (("with dynamic masks", True, cfg), ("without masks", False, cfg),
                           ("without masks or filters", False, no_filters)):
    maps[name] = build_dense_map(keyframe_stream(use_masks), c)
    q = map_quality(maps[name].xyz, views)
    print(f"{name:>26}: {len(maps[name].xyz):6d} points, {100 * q.dynamic_fraction:5.2f} % on people, "
          f"median surface error {100 * q.median_surface_error:.2f} cm")


# %%
def top_view(xyz, rgb, ax, title):
    """Map seen from above (the synthetic world is z-up)."""
    order = np.argsort(xyz[:, 2])
    ax.scatter(xyz[order, 0], xyz[order, 1], c=rgb[order] / 255.0, s=0.3, marker=".", linewidths=0)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize="small")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")


fig, axes = plt.subplots(1, 3, figsize=(15, 5), constrained_layout=True, sharex=True, sharey=True)
for ax, (name, m) in zip(axes, maps.items()):
    top_view(m.xyz, m.rgb, ax, f"{name}: {len(m.xyz)} points")

# %% [markdown]
# ## 3. The filters, by hand
#
# Move the voxel size, the statistical filter's $\alpha$ and the mask dilation and watch the
# point count, the share of points on people and the surface error change. A larger voxel
# averages more noise away but blurs edges; a small $\alpha$ eats into thin structures.

# %%
def explore(voxel_size, sor_std_ratio, dilate_px, min_observations):
    c = dataclasses.replace(cfg, voxel_size=voxel_size, sor_std_ratio=sor_std_ratio, dilate_px=dilate_px,
                            min_observations=min_observations)
    m = build_dense_map(keyframe_stream(True), c)
    q = map_quality(m.xyz, views)
    fig, ax = plt.subplots(figsize=(6, 5), constrained_layout=True)
    top_view(m.xyz, m.rgb, ax, f"{len(m.xyz)} points, {100 * q.dynamic_fraction:.2f} % on people, "
                                f"median error {100 * q.median_surface_error:.2f} cm")
    return fig


display(figure_explorer(
    explore,
    voxel_size=float_slider("voxel [m]", cfg.voxel_size, 0.005, 0.08, 0.005),
    sor_std_ratio=float_slider("SOR alpha", cfg.sor_std_ratio, 0.25, 4.0, 0.25),
    dilate_px=int_slider("mask dilation [px]", cfg.dilate_px, 0, 15),
    min_observations=int_slider("min keyframes per voxel", cfg.min_observations, 1, 5),
))

# %% [markdown]
# ## 4. The octree map
#
# OctoMap (Hornung et al. 2013) stores occupancy as log-odds per voxel. Each keyframe casts
# rays from the camera centre to its static points: the end voxel gets
# $\operatorname{logit}(0.7)$, every voxel crossed gets $\operatorname{logit}(0.4)$, clamped
# to $[\operatorname{logit}(0.12), \operatorname{logit}(0.97)]$. Free space is known too, and
# a person who stood somewhere is *erased* by later rays through that place. Inner nodes
# hold the maximum of their children, so the same tree answers at 5, 10, 20, 40 cm.

# %%
octree = OctreeMap(OctreeConfig(resolution=0.05))
t = time.perf_counter()
for f, T, mask in keyframe_stream(True):
    pts, _ = backproject_frame(f.depth, f.camera, T, None, static_exclusion_mask(f.depth, mask, cfg), 4,
                               cfg.min_depth, cfg.max_depth)
    pts, _ = voxel_downsample(pts, 0.025)
    octree.insert_scan(pts, T[:3, 3])
print(octree.stats(), f"built in {time.perf_counter() - t:.2f} s")


def draw_octree(level):
    centres, side = octree.occupied(level)
    fig = plt.figure(figsize=(6, 5), constrained_layout=True)
    ax = fig.add_subplot(projection="3d")
    ax.scatter(centres[:, 0], centres[:, 1], centres[:, 2], c=centres[:, 2], cmap="viridis", s=4 * 2**level,
               marker="s", depthshade=False)
    ax.set_title(f"level {level}: {len(centres)} occupied nodes of {100 * side:.0f} cm")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")
    return fig


display(figure_explorer(draw_octree, level=int_slider("levels above the leaves", 1, 0, 4)))

# %% [markdown]
# ## 5. A run folder in the 3D viewer
#
# `dynslam run` writes its results in one folder (see `docs/architecture.md`). We write the
# same files here from the truth: the trajectory (with a little noise, so that the errors
# below are not zero), the keyframes, ORB keypoints of the keyframes as the sparse map
# (static ones, and the dynamic ones apart), thumbnails and `map.ply`. `dynslam view OUTDIR`
# serves this in the browser with a playback slider; below, the same scene is embedded.

# %%
out = Path(tempfile.mkdtemp(prefix="dynslam_view_"))
rng = np.random.default_rng(0)
gt = Trajectory(seq.timestamps, np.stack([seq.gt_pose(i) for i in range(N)]))
est_poses = gt.poses.copy()
est_poses[:, :3, 3] += np.cumsum(rng.normal(scale=0.002, size=(N, 3)), axis=0)
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

# %%
run = load_run(out)
show_inline(run, height=450)

# %% [markdown]
# ## 6. The shared plots
#
# The same figures appear in the other notebooks and in the command line: the paths from
# above, the absolute trajectory error along the path, the relative pose error over time,
# time per stage, and keypoints coloured by their verdict.

# %%
ate = compute_ate(gt, run.trajectory)
rpe = compute_rpe(gt, run.trajectory)
fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), constrained_layout=True)
plot_trajectories({"ground truth": gt, "estimate": run.trajectory}, plane="xy", ax=axes[0])
plot_ate_along_path(ate, plane="xy", ax=axes[1])
plot_rpe_over_time(rpe)

# %%
# Time per mapping step on one keyframe, measured here (milliseconds).
f = seq[keyframes[0]]
T = seq.gt_pose(keyframes[0])
timings = {}
t = time.perf_counter(); ex = static_exclusion_mask(f.depth, moving_mask(f), cfg); timings["exclusion mask"] = 1e3 * (time.perf_counter() - t)
t = time.perf_counter(); P, C = backproject_frame(f.depth, f.camera, T, f.rgb, ex, cfg.stride); timings["back-projection"] = 1e3 * (time.perf_counter() - t)
t = time.perf_counter(); Pv, Cv = voxel_downsample(P, cfg.voxel_size, C); timings["voxel filter"] = 1e3 * (time.perf_counter() - t)
t = time.perf_counter(); octree.insert_scan(voxel_downsample(P, 0.025)[0], T[:3, 3]); timings["octree update"] = 1e3 * (time.perf_counter() - t)
plot_timing_bars(timings, title="Mapping, one keyframe (ms)")

# %%
dyn_truth = moving_mask(f)
feats = extract_features(f.gray)
px = np.round(feats.uv).astype(int)
plot_keypoints(f.rgb, feats.uv, dyn_truth[px[:, 1], px[:, 0]], title="ORB keypoints: on a walker (red) or static (green)")
