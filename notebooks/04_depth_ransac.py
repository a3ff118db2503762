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
# # 04 · Depth-RANSAC: keeping the wall behind a person (YOLO-SLAM)
#
# A person box also holds the wall, desk and monitor behind the person. YOLO-SLAM (Wu et al. 2022,
# Sec. 3.3) keeps them: inside each box, RANSAC looks for the largest set of keypoints of consistent
# depth. That set is the person; the rest of the box is static background.
#
# * Model (Algorithm 1, eq. 5): two sampled keypoints plus a candidate; the candidate is an inlier
#   when the variance of the three depths $s^2 = \frac{1}{3}\sum (x_i-\bar x)^2$ is below `nThre` = 0.43.
# * Adaptive iterations (eq. 8): $k = \log(1-P) / \log(1-\omega^2)$ with the inlier ratio $\omega$.
#
# The paper gives `nThre` no unit; `docs/depth_ransac.md` explains our reading (raw TUM value / 1000, so
# 0.43 units² = 0.0172 m², a tolerance of 0.28 m). We try it on a synthetic walking frame, where the truth
# is known, and on a real TUM frame.

# %%
import dataclasses
import math

import ipywidgets as widgets
import matplotlib.pyplot as plt
import numpy as np
from IPython.display import display

from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.datasets.tum import TumSequence
from dynslam_lab.detection import build_detector
from dynslam_lab.detection.coco import is_apriori_dynamic
from dynslam_lab.dynamic.depth_ransac import DepthRansacConfig, adaptive_iterations, screen_boxes
from dynslam_lab.dynamic.plots import draw_keypoints
from dynslam_lab.dynamic.oracle import truth_dynamic
from dynslam_lab.experiments.scoring import score_keypoints
from dynslam_lab.dynamic.table import depth_at
from dynslam_lab.features.orb import extract_features

seq = TumSequence(synthetic_sequence("walking_xyz", n_frames=30, seed=0))
frame = seq[20]
uv = extract_features(frame.gray).uv.astype(float)
dets = build_detector("oracle").detect(frame)
people = dets.select(is_apriori_dynamic(dets.class_ids))
z = depth_at(frame.depth, uv)
truth = truth_dynamic(frame, uv)
print(f"{len(uv)} keypoints, {len(people)} person boxes, {truth.sum()} keypoints truly on a moving person")

# %% [markdown]
# ## Depths inside the boxes
# Keypoints on the person (truth) and on the background of the same box, by depth. Assumption 3 of the
# paper: the person stands out in depth.

# %%
inside = np.zeros(len(uv), bool)
for x1, y1, x2, y2 in people.boxes:
    inside |= (uv[:, 0] >= x1) & (uv[:, 0] <= x2) & (uv[:, 1] >= y1) & (uv[:, 1] <= y2)
fig, ax = plt.subplots(figsize=(7, 3))
bins = np.linspace(np.nanmin(z[inside]) - 0.1, np.nanmax(z[inside]) + 0.1, 40)
ax.hist(z[inside & truth], bins=bins, alpha=0.7, label="on a moving person")
ax.hist(z[inside & ~truth], bins=bins, alpha=0.7, label="background in the box")
ax.set_xlabel("keypoint depth (m)")
ax.legend()
plt.show()

# %% [markdown]
# ## The adaptive iteration count (eq. 8)
# With a sample of two points, a box that is 60% person needs about 10 hypotheses for $P = 0.99$.

# %%
w = np.linspace(0.05, 0.95, 50)
fig, ax = plt.subplots(figsize=(6, 3))
for P in (0.9, 0.99, 0.999):
    ax.semilogy(w, [adaptive_iterations(x, 2, P) for x in w], label=f"P = {P}")
ax.set_xlabel("inlier ratio ω")
ax.set_ylabel("iterations k")
ax.legend()
plt.show()

# %% [markdown]
# ## Move the threshold
# Red: the consensus set (judged person, dynamic); green: static. `select="largest"` is the paper's rule;
# `"front"` (our default) takes the nearest set with at least a quarter of the box's keypoints.
# Precision and recall are against the renderer's truth.

# %%
def show(var_threshold=0.43, depth_unit_m=0.2, select="front", confidence=0.99):
    cfg = dataclasses.replace(DepthRansacConfig(), var_threshold=var_threshold, depth_unit_m=depth_unit_m,
                              select=select, confidence=confidence)
    dyn, results = screen_boxes(uv, z, people.boxes, cfg, rng=0)
    s = score_keypoints(dyn, truth)
    tol = math.sqrt(cfg.var_threshold_m2 * 9 / 2)
    fig, ax = plt.subplots(figsize=(8, 6))
    draw_keypoints(ax, frame.rgb, uv, dyn, f"nThre = {var_threshold} units² = {cfg.var_threshold_m2:.4f} m² "
                   f"(tolerance {tol:.2f} m): precision {s.precision:.2f}, recall {s.recall:.2f}")
    for x1, y1, x2, y2 in people.boxes:
        ax.add_patch(plt.Rectangle((x1, y1), x2 - x1, y2 - y1, fill=False, ec="yellow", lw=1.5))
    plt.show()
    for k, r in enumerate(results):
        if r is not None:
            print(f"box {k}: {r.iterations} hypotheses (k = {r.k:.1f}), person depth {r.depth_range[0]:.2f}-{r.depth_range[1]:.2f} m")


display(widgets.interactive(
    show,
    var_threshold=widgets.FloatLogSlider(value=0.43, base=10, min=-2, max=1, step=0.05, description="nThre"),
    depth_unit_m=widgets.FloatSlider(value=0.2, min=0.01, max=1.0, step=0.01, description="unit (m)"),
    select=widgets.Dropdown(options=["front", "largest"], value="front"),
    confidence=widgets.FloatSlider(value=0.99, min=0.5, max=0.999, step=0.001, description="P"),
))

# %% [markdown]
# ## The real TUM frame
# fr3/walking_xyz with the YOLACT person mask from `../shared/data` (skipped without it). The boxes are the
# mask's connected components. On this frame the paper's "largest set" picks the wall behind the left
# person: it holds more keypoints than the person.

# %%
from pathlib import Path

import cv2

shared = Path("../../shared/data/tum/frames")
if not shared.is_dir():
    shared = Path("../shared/data/tum/frames")
if (shared / "fr3_walking_xyz_1341846313.553992_rgb.png").is_file():
    from dynslam_lab.datasets.tum import load_depth, load_rgb
    from dynslam_lab.dynamic.table import values_at

    rgb = load_rgb(shared / "fr3_walking_xyz_1341846313.553992_rgb.png")
    depth = load_depth(shared / "fr3_walking_xyz_1341846313.592088_depth.png")
    mask = cv2.imread(str(shared / "fr3_walking_xyz_1341846313.553992_person_mask_yolact.png"), cv2.IMREAD_UNCHANGED) > 0
    ruv = extract_features(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)).uv.astype(float)
    _, _, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8))
    boxes = np.array([[x, y, x + w - 1, y + h - 1] for x, y, w, h, a in stats[1:] if a > 500], float)
    rz = depth_at(depth, ruv)
    in_mask = values_at(mask, ruv).astype(bool)
    fig, axes = plt.subplots(1, 2, figsize=(13, 5))
    for ax, sel in zip(axes, ("front", "largest")):
        dyn, _ = screen_boxes(ruv, rz, boxes, DepthRansacConfig(select=sel), rng=0)
        draw_keypoints(ax, rgb, ruv, dyn, f"{sel}: {dyn[in_mask].mean():.0%} of the person's keypoints dynamic")
        for x1, y1, x2, y2 in boxes:
            ax.add_patch(plt.Rectangle((x1, y1), x2 - x1, y2 - y1, fill=False, ec="yellow", lw=1.5))
    plt.show()
else:
    print("real TUM frame not found (../shared/data): skipped")
