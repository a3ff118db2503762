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
# # 05 · Geometry against motion: epipolar lines, multi-view RGB-D, adaptive flow
#
# **What you will learn**
# - what an epipolar line is, and why a static point must lie on it in the next frame;
# - the epipolar check (Zhang et al. 2023, eq. 17; also Chang et al. 2021 and Ge et al. 2024) and
#   the motion it cannot see;
# - the multi-view RGB-D check (Chang et al. 2021, eq. 2): reprojection and depth differences
#   under a rough camera pose;
# - adaptive-threshold dense flow (Chang et al. 2021, eq. 3): regions a person moves besides
#   the person.
#
# Semantics says what *may* move; geometry says what *did* move between two frames. A static
# point seen at $p_1$ in the previous frame lies, in the current frame, on the epipolar line
# $l_2 = F p_1$ of the fundamental matrix $F$; the distance of the observed $p_2 = (u, v, 1)^\top$
# to it,
#
# $$d = \frac{|p_2^\top F p_1|}{\sqrt{a^2 + b^2}}, \qquad (a, b, c)^\top = F p_1,$$
#
# is the test (Zhang et al. 2023 eq. 17): above $\mu$ pixels, the point moved. $F$ comes from RANSAC
# over the Lucas-Kanade pairs outside the people. Frames come from the synthetic `walking_xyz`
# sequence, where the truth is known.

# %%
import dataclasses

import matplotlib.pyplot as plt
import numpy as np

from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.datasets.tum import TumSequence
from dynslam_lab.detection import build_detector
from dynslam_lab.dynamic.epipolar import EpipolarConfig, LkConfig, epipolar_check, track_lk
from dynslam_lab.dynamic.flow import FlowConfig, flow_regions
from dynslam_lab.dynamic.multiview import MultiViewConfig, multiview_check
from dynslam_lab.dynamic.oracle import truth_dynamic
from dynslam_lab.dynamic.semantic import semantic_prior
from dynslam_lab.dynamic.table import depth_at
from dynslam_lab.experiments.scoring import score_keypoints
from dynslam_lab.features.orb import extract_features
from dynslam_lab.geometry.epipolar import epipolar_distance
from dynslam_lab.viz.colors import hex_color, rgb
from dynslam_lab.viz.exercises import check
from dynslam_lab.viz.plots import plot_keypoint_stages
from dynslam_lab.viz.widgets import checkbox, figure_explorer, float_slider, log_slider

seq = TumSequence(synthetic_sequence("walking_xyz", n_frames=30, seed=0))
prev, cur = seq[19], seq[20]
uv = extract_features(cur.gray).uv.astype(float)
dets = build_detector("oracle").detect(cur)
sem = semantic_prior(uv, dets)  # a-priori dynamic: left out of F and of the rough pose
truth = truth_dynamic(cur, uv)
uv_prev, matched = track_lk(prev.gray, cur.gray, uv, LkConfig())
z, z_prev = depth_at(cur.depth, uv), depth_at(prev.depth, np.nan_to_num(uv_prev, nan=-1.0))
ep = epipolar_check(uv, uv_prev, matched, sem.flagged, cur.shape, EpipolarConfig())
print(f"{len(uv)} keypoints, {matched.sum()} matched by LK, {truth.sum()} truly dynamic, "
      f"{sem.flagged.sum()} on a-priori dynamic detections, {ep.used.sum()} pairs used for F")

# %% [markdown]
# ## 1. Epipolar lines
#
# For a few keypoints, their epipolar line $F p_1$ in the current frame (drawn across the image)
# and the observed keypoint $p_2$ (dot), labelled with its distance $d$ to the line.

# %% figures=1
rng = np.random.default_rng(0)
pick_static = rng.choice(np.flatnonzero(matched & ~truth), 8, replace=False)
pick_moving = rng.choice(np.flatnonzero(matched & truth), 8, replace=False)
H, W = cur.shape
fig, ax = plt.subplots(figsize=(10, 7.5), constrained_layout=True)
ax.imshow(cur.rgb)
xs = np.array([0.0, W - 1.0])
for idx, color, name in ((pick_static, hex_color("static"), "static"), (pick_moving, hex_color("dynamic"), "on a walker")):
    for k, i in enumerate(idx):
        a, b, c = ep.F @ np.array([uv_prev[i, 0], uv_prev[i, 1], 1.0])
        ax.plot(xs, -(a * xs + c) / b, "-", color=color, lw=0.9, alpha=0.85)
        ax.plot(*uv[i], "o", color=color, ms=6, mec="white", label=name if k == 0 else None)
        ax.annotate(f"{ep.distance[i]:.1f}", uv[i], xytext=(4, -6), textcoords="offset points", color=color,
                    fontsize=8, fontweight="bold")
ax.set_xlim(0, W - 1)
ax.set_ylim(H - 1, 0)
ax.set_axis_off()
ax.legend(loc="lower right")
ax.set_title("epipolar lines of 16 keypoints and their distances d (px)");

# %% [markdown]
# **What to look for**: all lines meet in one point, the *epipole*, the image of the previous
# camera's centre: here inside the picture, because the camera also moves forward. The green
# keypoints sit on their lines (a fraction of a pixel); the magenta ones are off theirs by
# several pixels, because the walker moved between the frames. A walker's keypoint that moved
# *along* its line would sit on it too: the epipolar test is blind to that motion.

# %% [markdown]
# ## 2. Epipolar distances of all keypoints

# %% figures=1
fig, ax = plt.subplots(figsize=(7.5, 3.4), constrained_layout=True)
bins = np.logspace(-3, 2, 50)
ax.hist(ep.distance[matched & ~truth], bins=bins, color=hex_color("static"), alpha=0.7, label="static (truth)")
ax.hist(ep.distance[matched & truth], bins=bins, color=hex_color("dynamic"), alpha=0.7, label="moving (truth)")
ax.axvline(EpipolarConfig().threshold_px, color="black", ls=":", label=r"$\mu$ = 1 px")
ax.set_xscale("log")
ax.set_xlabel("distance to the epipolar line [px]")
ax.set_ylabel("keypoints")
ax.legend(fontsize="small");

# %% [markdown]
# **What to look for**: static keypoints pile up below 1 px; moving ones spread from 0.01 px to
# tens of pixels. Whatever the threshold, part of the walkers stays under it: the ones moving
# along their lines, or barely moving (a standing leg).

# %% [markdown]
# ## 3. Two checks, one frame: epipolar and multi-view
#
# The multi-view check (Chang et al. 2021 eq. 2) estimates a rough pose from the pairs outside
# the people (PnP), projects each previous 3D point into the current frame, and flags a keypoint
# when its reprojection error exceeds 4 px or its depth differs by more than 0.1 m (the paper's
# fixed threshold; ours by default also grows as $0.01 z^2$, the Kinect's depth noise). Each ring is
# one check that flagged the keypoint (purple: epipolar, blue: multi-view; two rings: both).
# Scores are against the truth over the matched keypoints.

# %% figures=1
def checks(mu, reprojection_px, depth_m, noise_aware=True):
    e = epipolar_check(uv, uv_prev, matched, sem.flagged, cur.shape, dataclasses.replace(EpipolarConfig(), threshold_px=mu))
    mcfg = MultiViewConfig()
    m = multiview_check(uv, z, uv_prev, z_prev, matched, sem.flagged, cur.camera,
                        dataclasses.replace(mcfg, reprojection_px=reprojection_px, depth_m=depth_m,
                                            depth_quadratic=mcfg.depth_quadratic if noise_aware else 0.0))
    return e, m


def draw_checks(mu=1.0, reprojection_px=4.0, depth_m=0.1, noise_aware=False):
    e, m = checks(mu, reprojection_px, depth_m, noise_aware)
    se = score_keypoints(e.dynamic[matched], truth[matched])
    sm = score_keypoints(m.dynamic[matched], truth[matched])
    fig, ax = plt.subplots(figsize=(10, 7.5), constrained_layout=True)
    plot_keypoint_stages(cur.rgb, uv[matched], {"epipolar": e.dynamic[matched], "multiview": m.dynamic[matched]}, ax=ax,
                         title=f"epipolar (mu {mu:.2g} px): P {se.precision:.2f} R {se.recall:.2f}   |   multi-view "
                               f"({reprojection_px:.1f} px / {depth_m:.2f} m): P {sm.precision:.2f} R {sm.recall:.2f}")
    return fig


figure_explorer(draw_checks, name="05 epipolar + multi-view", probes={"mu": [0.2, 10.0]},
                mu=log_slider("epipolar mu [px]", 1.0, -1, 1.3),
                reprojection_px=float_slider("reprojection [px]", 4.0, 0.5, 15.0, 0.5),
                depth_m=float_slider("depth [m]", 0.1, 0.01, 0.5, 0.01),
                noise_aware=checkbox("depth threshold grows with z² (ours)", False));

# %% [markdown]
# **What to look for**: the two checks agree on the walkers' fast parts (two rings) and each
# catches some the other misses. Lowering $\mu$ or the reprojection threshold adds rings on the
# static background (false alarms from matching noise); raising them loses the walkers. A depth
# threshold of 1 cm flags the far background everywhere: Kinect depth noise grows with the square
# of the distance, which is what the noise-aware threshold accounts for.

# %% [markdown]
# ## 4. Adaptive-threshold flow
#
# Flow runs at a quarter of the resolution; the camera's own motion is removed with the rough
# pose and the depth (`docs/epipolar_multiview_flow.md`). Chang et al. 2021 (eq. 3) threshold the
# flow at $k\,\bar p$, with $\bar p$ the mean flow inside the person mask: regions above it that
# touch the person are "human-driven" (a door the person pushes, a chair they drag). The paper's
# $k = 2$ leaves only the fastest parts; at $k = 1$ the regions grow around the walker.

# %% figures=1
mv = multiview_check(uv, z, uv_prev, z_prev, matched, sem.flagged, cur.camera)
person = dets.region_masks()[sem.dynamic_detections].any(axis=0)


def draw_flow(factor=1.0, compensate_ego_motion=True):
    cfg = dataclasses.replace(FlowConfig(), factor=factor, compensate_ego_motion=compensate_ego_motion)
    fr = flow_regions(cur.gray, prev.gray, person, cur.depth, cur.camera, mv.T_c_p, cfg)
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.6), constrained_layout=True)
    im = axes[0].imshow(fr.magnitude, cmap="magma", vmin=0, vmax=max(8.0, float(np.nanpercentile(fr.magnitude, 99))))
    fig.colorbar(im, ax=axes[0], label="residual flow [px, full resolution]")
    axes[0].set_title(f"flow magnitude; mean in the person mask p̄ = {fr.mean_flow_px:.2f} px")
    view = np.full((*person.shape, 3), 0.93)
    view[person] = 0.55
    view[fr.region & person] = np.array(rgb("dynamic")) / 255
    view[fr.region & ~person] = np.array(rgb("depth_ransac")) / 255
    axes[1].imshow(view)
    axes[1].set_title(f"threshold {fr.threshold_px:.2f} px: above it inside the mask (magenta), "
                      f"{(fr.region & ~person).sum()} px beyond it (orange)", fontsize="medium")
    for a in axes:
        a.set_axis_off()
    return fig


figure_explorer(draw_flow, name="05 flow", factor=float_slider("k (x p̄)", 1.0, 0.5, 5.0, 0.1),
                compensate_ego_motion=checkbox("remove camera motion", True));

# %% [markdown]
# **What to look for**: with the camera's motion removed, the background is dark (no residual
# flow; white: no depth, not judged) and the walker bright. At $k = 1$ the region covers the
# faster half of the walker (torso, swinging arm) and spills past the mask beside the arm
# (orange). At $k = 2$ almost nothing is left; without ego-motion removal the whole background
# flows, and the region changes with it.

# %% [markdown]
# ### Exercise 1: one epipolar distance by hand
#
# For the first matched keypoint `i = np.flatnonzero(matched)[0]`, compute the distance of
# `uv[i]` to the epipolar line of `uv_prev[i]` with `ep.F` (the equation at the top).

# %% exercise="05.1"
answer = None  # your code: d in pixels

# %% check="05.1"
i0 = np.flatnonzero(matched)[0]
check("05.1", answer, epipolar_distance(ep.F, uv_prev[i0:i0 + 1], uv[i0:i0 + 1])[0])

# %% [markdown]
# ### Exercise 2: where the checks disagree
#
# At the default thresholds, how many matched keypoints does exactly one of the two checks flag
# (epipolar or multi-view, not both)? Use `e, m = checks(1.0, 4.0, 0.1)`.

# %% exercise="05.2"
answer = None  # your code: an integer

# %% check="05.2"
e_chk, m_chk = checks(1.0, 4.0, 0.1)
check("05.2", answer, int((e_chk.dynamic ^ m_chk.dynamic)[matched].sum()))

# %% [markdown]
# ### Exercise 3: the adaptive threshold
#
# Run `flow_regions` with the default `FlowConfig()` (k = 2, floor 2 px) and compute the
# threshold the stage uses from its `mean_flow_px`: $\max(k\,\bar p, \text{floor})$.

# %% exercise="05.3"
answer = None  # your code: the threshold in pixels

# %% check="05.3"
check("05.3", answer, flow_regions(cur.gray, prev.gray, person, cur.depth, cur.camera, mv.T_c_p, FlowConfig()).threshold_px)
