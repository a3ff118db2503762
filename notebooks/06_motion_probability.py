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
# # 06 · Motion probabilities: giving features back (ASG-SLAM) and Zhang et al.'s levels
#
# **What you will learn**
# - why removing everything that *might* move can leave too little to track;
# - the static ratio $\delta$ of ASG-SLAM (Ge et al. 2024, eq. 3) and how restoration gives back
#   excluded keypoints, least probable movers first;
# - Zhang et al. 2023's dynamic levels: which objects go at once and which only when geometry
#   says they moved;
# - how these rules sit in the screening chain, keypoint by keypoint.
#
# ASG-SLAM grades COCO classes into six categories of increasing motion probability and watches
# the share of keypoints left static,
#
# $$\delta = \frac{m}{n} \qquad (m \text{ static keypoints out of } n),$$
#
# and while $\delta < \delta_1$ it gives excluded keypoints back, the least probable movers first.
# Our readings (`docs/motion_probability.md`): restoration goes class group by group and never
# gives back a keypoint that a geometric test flagged; $\delta_1 = 0.3$ by default. The scene is
# the synthetic `sitting_xyz`: two people sitting at a desk full of objects, the case where
# excluding every object leaves less than a third of the keypoints.

# %%
import dataclasses

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from IPython.display import display

from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.datasets.tum import TumSequence
from dynslam_lab.detection import build_detector
from dynslam_lab.detection.coco import ASG_PROBABILITIES, COCO_CLASSES
from dynslam_lab.dynamic.config import ScreeningConfig
from dynslam_lab.dynamic.motion_probability import RestorationConfig, restore_by_motion_probability, static_ratio
from dynslam_lab.dynamic.screening import Screener
from dynslam_lab.dynamic.semantic import SemanticConfig, semantic_prior
from dynslam_lab.features.orb import extract_features
from dynslam_lab.viz.colors import hex_color
from dynslam_lab.viz.exercises import check
from dynslam_lab.viz.plots import plot_keypoint_stages
from dynslam_lab.viz.widgets import checkbox, figure_explorer, float_slider

print(pd.Series(ASG_PROBABILITIES, name="prior motion probability").to_string())
seq = TumSequence(synthetic_sequence("sitting_xyz", n_frames=20, seed=0))
frame = seq[10]
uv = extract_features(frame.gray).uv.astype(float)
dets = build_detector("oracle").detect(frame)
sem = semantic_prior(uv, dets, SemanticConfig())
on_object = sem.instance >= 0

# %% [markdown]
# ## 1. Every keypoint's class and motion probability
#
# Suppose we exclude every keypoint on *any* detected object (Zhang et al.'s levels with the
# low objects removed too): how many are left?

# %% figures=1
df = pd.DataFrame({"class": [COCO_CLASSES[c] if c >= 0 else "(none)" for c in sem.class_id],
                   "motion_prob": sem.motion_prob})
counts = df[on_object].groupby(["class", "motion_prob"]).size().rename("keypoints").reset_index()
counts = counts.sort_values(["motion_prob", "keypoints"])
print(f"static ratio if every object is excluded: delta = {static_ratio(on_object):.2f}")
fig, ax = plt.subplots(figsize=(8, 0.35 * len(counts) + 1.4), constrained_layout=True)
y = np.arange(len(counts))
ax.barh(y, counts["keypoints"], color=[hex_color("dynamic") if p >= 0.5 else hex_color("restored") for p in counts["motion_prob"]])
ax.set_yticks(y, [f"{c} (p = {p:g})" for c, p in zip(counts["class"], counts["motion_prob"])])
ax.bar_label(ax.containers[0], padding=3, fontsize="small")
ax.set_xlabel("keypoints on the class")
ax.set_title(f"{on_object.sum()} of {len(uv)} keypoints lie on a detected object");

# %% [markdown]
# **What to look for**: the people hold about a quarter of the keypoints; monitors, the table,
# books and the keyboard hold more than the people together. Excluding them all leaves
# $\delta \approx 0.3$: tracking on 300 keypoints, most of them on the walls, is fragile. Yet those
# objects have a low prior probability (0.2) of moving: they are the first to give back.

# %% [markdown]
# ## 2. Slide $\delta_1$
#
# Excluded: every keypoint on a detected object. Restored (cyan squares) group by group in
# increasing motion probability until $\delta \ge \delta_1$.

# %% figures=1
def restoration(delta_1):
    return restore_by_motion_probability(on_object, on_object, sem.motion_prob, None, RestorationConfig(delta_1=delta_1))


def draw_restoration(delta_1=0.3):
    r = restoration(delta_1)
    fig, ax = plt.subplots(figsize=(9, 6.8), constrained_layout=True)
    plot_keypoint_stages(frame.rgb, uv, {"semantic": on_object}, dynamic=on_object & ~r.restored, restored=r.restored,
                         ax=ax, title=f"delta_1 = {delta_1:.2f}: delta {r.delta_before:.2f} -> {r.delta_after:.2f}, "
                                      f"restored groups p = {r.groups}")
    return fig


figure_explorer(draw_restoration, name="06 restoration", delta_1=float_slider("delta_1", 0.3, 0.0, 1.0, 0.05));

# %% [markdown]
# **What to look for**: at $\delta_1 = 0.3$ the frame is just short ($\delta = 0.297$), so the
# whole 0.2 group comes back at once: monitors, table, books, four hundred keypoints, and
# $\delta$ jumps to 0.72. Restoration works by groups, so it overshoots; below 0.29 nothing comes
# back, and only $\delta_1 > 0.72$ gives back the people too (their $p = 0.9$).

# %% [markdown]
# ## 3. Zhang et al.'s rule in the chain
#
# The screener runs the semantic prior, the epipolar and multi-view checks on the previous frame
# and this one, Zhang et al.'s levels (high and medium removed at once, low only with geometric
# evidence) and restoration. Each ring is a stage that flagged the keypoint; cyan squares were
# given back. $\delta_1$ starts at 0.7, just above the $\delta$ the levels leave (below it nothing comes back;
# above it, more than 0.7 gives nothing more).

# %% figures=1
prev = seq[9]
prev_uv = extract_features(prev.gray).uv.astype(float)
prev_dets = build_detector("oracle").detect(prev)


def screen(delta_1, use_level_rule):
    stages = ("semantic", "epipolar", "multiview") + (("level_rule",) if use_level_rule else ()) + ("restoration",)
    cfg = dataclasses.replace(ScreeningConfig(), restoration=RestorationConfig(delta_1=delta_1))
    s = Screener(stages, cfg)
    s.screen(prev, prev_uv, prev_dets)
    return s.screen(frame, uv, dets)


def draw_rule(delta_1=0.7, use_level_rule=True):
    t = screen(delta_1, use_level_rule)
    fig, ax = plt.subplots(figsize=(9, 6.8), constrained_layout=True)
    plot_keypoint_stages(frame.rgb, t.uv, t.stages, dynamic=t.dynamic, restored=t.restored, region_mask=t.region_mask,
                         ax=ax, title=f"levels {'on' if use_level_rule else 'off'}, delta_1 = {delta_1:.2f}: "
                                      f"{t.n_dynamic} dynamic, {int(t.restored.sum())} restored")
    return fig


figure_explorer(draw_rule, name="06 level rule", probes={"delta_1": [0.0, 0.5]}, delta_1=float_slider("delta_1", 0.7, 0.0, 1.0, 0.05),
                use_level_rule=checkbox("Zhang et al. 2023 levels", True));

# %% [markdown]
# **What to look for**: with the levels on, the medium objects (books, bottle, cup, chairs) go
# with the people, $\delta$ falls to about 0.61, and at $\delta_1 = 0.7$ restoration gives them
# back. The sitting people barely move, so the epipolar and multi-view checks flag few keypoints:
# on this frame, semantics and priors decide almost everything. Turn the levels off: the medium
# objects are never excluded, and nothing needs restoring.

# %% [markdown]
# ### Exercise 1: the static ratio
#
# Compute $\delta$ of eq. 3 when every keypoint on a detected object is excluded (`on_object`
# is True for those), with numpy.

# %% exercise="06.1"
answer = None  # your code: delta

# %% check="06.1"
check("06.1", answer, static_ratio(on_object))

# %% [markdown]
# ### Exercise 2: the smallest restoration
#
# Restoration gives back whole class groups and overshoots. If keypoints could be given back
# one by one, how many would have to come back for $\delta$ to reach $\delta_1 = 0.5$?

# %% exercise="06.2"
answer = None  # your code: an integer

# %% check="06.2"
check("06.2", answer, int(np.ceil(0.5 * len(uv) - (~on_object).sum())))

# %% [markdown]
# ### Exercise 3: which groups come back?
#
# At $\delta_1 = 0.8$, which motion probabilities does restoration give back, in order? Predict,
# then check with `restoration(0.8).groups`. Why does the second group come back?

# %% exercise="06.3"
answer = None  # your code: a list of probabilities, e.g. [0.2]

# %% check="06.3"
check("06.3", answer, restoration(0.8).groups)
