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
# Semantics says what *may* move; geometry says what *did* move between two frames.
#
# 1. **Epipolar check** (Zhang et al. 2023, Chang et al. 2021 and Ge et al. 2024): LK matches with the previous frame, RANSAC fundamental
#    matrix from the pairs outside people and away from the border, then the distance of each keypoint to
#    its epipolar line, $d = |p_2^\top F p_1| / \sqrt{a^2+b^2}$ (Zhang et al. 2023 eq. 17).
# 2. **Multi-view RGB-D check** (Chang et al. 2021 eq. 2): a rough PnP pose from the pairs outside people, then
#    reprojection error > 4 px or depth difference > 0.1 m → dynamic.
# 3. **Adaptive dense flow** (Chang et al. 2021 eq. 3): Farneback flow, threshold $2\bar p$ with $\bar p$ the mean flow
#    inside the person mask; regions above it touching the person are "human-driven".
#
# Frames come from the synthetic `walking_xyz` sequence (truth known).

# %%
import dataclasses

import ipywidgets as widgets
import matplotlib.pyplot as plt
import numpy as np
from IPython.display import display

from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.datasets.tum import TumSequence
from dynslam_lab.detection import build_detector
from dynslam_lab.dynamic.epipolar import EpipolarConfig, LkConfig, epipolar_check, track_lk
from dynslam_lab.dynamic.flow import FlowConfig, flow_regions
from dynslam_lab.dynamic.multiview import MultiViewConfig, multiview_check
from dynslam_lab.dynamic.plots import draw_keypoints
from dynslam_lab.dynamic.oracle import truth_dynamic
from dynslam_lab.experiments.scoring import score_keypoints
from dynslam_lab.dynamic.semantic import semantic_prior
from dynslam_lab.dynamic.table import depth_at
from dynslam_lab.features.orb import extract_features

seq = TumSequence(synthetic_sequence("walking_xyz", n_frames=30, seed=0))
prev, cur = seq[19], seq[20]
uv = extract_features(cur.gray).uv.astype(float)
dets = build_detector("oracle").detect(cur)
sem = semantic_prior(uv, dets)  # a-priori dynamic: left out of F and of the rough pose
truth = truth_dynamic(cur, uv)
uv_prev, matched = track_lk(prev.gray, cur.gray, uv, LkConfig())
z, z_prev = depth_at(cur.depth, uv), depth_at(prev.depth, np.nan_to_num(uv_prev, nan=-1.0))
print(f"{len(uv)} keypoints, {matched.sum()} matched by LK, {truth.sum()} truly dynamic, "
      f"{sem.flagged.sum()} on a-priori dynamic detections")

# %% [markdown]
# ## Epipolar distances
# Static keypoints sit near their epipolar line; keypoints on moving people scatter. A point that moves
# *along* its line stays close: the epipolar test cannot see it.

# %%
ep = epipolar_check(uv, uv_prev, matched, sem.flagged, cur.shape, EpipolarConfig())
fig, ax = plt.subplots(figsize=(7, 3))
bins = np.logspace(-3, 2, 50)
ax.hist(ep.distance[matched & ~truth], bins=bins, alpha=0.7, label="static (truth)")
ax.hist(ep.distance[matched & truth], bins=bins, alpha=0.7, label="moving (truth)")
ax.set_xscale("log")
ax.set_xlabel("distance to epipolar line (px)")
ax.legend()
plt.show()

# %% [markdown]
# ## Sliders: epipolar μ, the 4 px / 0.1 m of the multi-view check
# Left: epipolar verdict; right: multi-view verdict. Scores are against the renderer's truth over the
# matched keypoints (unmatched keypoints get no geometric verdict).

# %%
def show_geometry(mu=1.0, reprojection_px=4.0, depth_m=0.1):
    e = epipolar_check(uv, uv_prev, matched, sem.flagged, cur.shape, dataclasses.replace(EpipolarConfig(), threshold_px=mu))
    m = multiview_check(uv, z, uv_prev, z_prev, matched, sem.flagged, cur.camera,
                        dataclasses.replace(MultiViewConfig(), reprojection_px=reprojection_px, depth_m=depth_m))
    fig, axes = plt.subplots(1, 2, figsize=(13, 5))
    for ax, res, name in ((axes[0], e.dynamic, f"epipolar, μ = {mu:.2f} px"),
                          (axes[1], m.dynamic, f"multi-view, {reprojection_px:.1f} px / {depth_m:.2f} m")):
        s = score_keypoints(res[matched], truth[matched])
        draw_keypoints(ax, cur.rgb, uv[matched], res[matched], f"{name}: P {s.precision:.2f} R {s.recall:.2f}")
    plt.show()


display(widgets.interactive(
    show_geometry,
    mu=widgets.FloatLogSlider(value=1.0, base=10, min=-1, max=1.3, step=0.05, description="μ (px)"),
    reprojection_px=widgets.FloatSlider(value=4.0, min=0.5, max=15, step=0.5, description="reproj (px)"),
    depth_m=widgets.FloatSlider(value=0.1, min=0.01, max=0.5, step=0.01, description="depth (m)"),
))

# %% [markdown]
# ## Adaptive-threshold flow
# Flow runs at quarter resolution; the camera's own motion is removed with the rough pose and the depth
# (`docs/epipolar_multiview_flow.md`). Left: residual flow magnitude; right: the person mask (white) and
# the human-driven regions above $k\,\bar p$ (red).

# %%
mv = multiview_check(uv, z, uv_prev, z_prev, matched, sem.flagged, cur.camera)
person = dets.region_masks()[sem.dynamic_detections].any(axis=0)


def show_flow(factor=2.0, min_flow_px=2.0, compensate_ego_motion=True):
    cfg = dataclasses.replace(FlowConfig(), factor=factor, min_flow_px=min_flow_px,
                              compensate_ego_motion=compensate_ego_motion)
    fr = flow_regions(cur.gray, prev.gray, person, cur.depth, cur.camera, mv.T_c_p, cfg)
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.5))
    im = axes[0].imshow(fr.magnitude, cmap="magma")
    fig.colorbar(im, ax=axes[0], label="px (full resolution)")
    axes[0].set_title(f"flow magnitude, mean in mask p̄ = {fr.mean_flow_px:.2f} px")
    view = np.zeros((*person.shape, 3))
    view[person] = 1.0
    view[fr.region & ~person] = (1.0, 0.0, 0.0)
    axes[1].imshow(view)
    axes[1].set_title(f"threshold {fr.threshold_px:.2f} px: {(fr.region & ~person).sum()} px beyond the mask")
    for a in axes:
        a.set_axis_off()
    plt.show()


display(widgets.interactive(
    show_flow,
    factor=widgets.FloatSlider(value=2.0, min=0.5, max=5.0, step=0.1, description="k (× p̄)"),
    min_flow_px=widgets.FloatSlider(value=2.0, min=0.0, max=10.0, step=0.5, description="floor (px)"),
    compensate_ego_motion=widgets.Checkbox(value=True, description="remove camera motion"),
))
