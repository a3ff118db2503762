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
# Removing everything that *might* move can leave too little to track. ASG-SLAM (Ge et al. 2024, Sec. 2.4)
# grades COCO classes into six categories of increasing motion probability and watches the static ratio
# $\delta = m/n$ (eq. 3): while $\delta < \delta_1$, excluded keypoints come back, least probable movers
# first. Zhang et al. 2023 (Zhang et al. 2023) sorts objects into high / medium / low dynamic levels: high and
# medium are removed at once, low ones only when the epipolar test says they moved.
#
# Our readings (`docs/motion_probability.md`): restoration goes class group by group and never gives back
# a keypoint that a geometric test flagged; $\delta_1 = 0.3$ by default.

# %%
import dataclasses

import ipywidgets as widgets
import matplotlib.pyplot as plt
import pandas as pd
from IPython.display import display

from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.datasets.tum import TumSequence
from dynslam_lab.detection import build_detector
from dynslam_lab.detection.coco import ASG_PROBABILITIES, COCO_CLASSES
from dynslam_lab.dynamic.config import ScreeningConfig
from dynslam_lab.dynamic.motion_probability import RestorationConfig, restore_by_motion_probability, static_ratio
from dynslam_lab.dynamic.plots import draw_table
from dynslam_lab.dynamic.screening import Screener
from dynslam_lab.dynamic.semantic import SemanticConfig, semantic_prior
from dynslam_lab.features.orb import extract_features

print(pd.Series(ASG_PROBABILITIES, name="prior motion probability").to_string())
seq = TumSequence(synthetic_sequence("sitting_xyz", n_frames=20, seed=0))
frame = seq[10]
uv = extract_features(frame.gray).uv.astype(float)
dets = build_detector("oracle").detect(frame)
print("detections:", ", ".join(f"{COCO_CLASSES[c]} ({s:.2f})" for c, s in zip(dets.class_ids, dets.scores)))

# %% [markdown]
# ## Every keypoint's class and motion probability
# Suppose we exclude every keypoint on *any* detected object (Zhang et al.'s levels with low objects removed
# too): how many are left?

# %%
sem = semantic_prior(uv, dets, SemanticConfig())
on_object = sem.instance >= 0
df = pd.DataFrame({"class": [COCO_CLASSES[c] if c >= 0 else "(none)" for c in sem.class_id],
                   "motion_prob": sem.motion_prob, "level": sem.level})
print(df.groupby(["class", "motion_prob"]).size().rename("keypoints").to_string())
print(f"static ratio if every object is excluded: δ = {static_ratio(on_object):.2f}")

# %% [markdown]
# ## Slide δ₁
# Excluded: every keypoint on a detected object. Restored (cyan) group by group in increasing motion
# probability until $\delta \ge \delta_1$.

# %%
def show_restoration(delta_1=0.3):
    r = restore_by_motion_probability(on_object, on_object, sem.motion_prob, None, RestorationConfig(delta_1=delta_1))
    dyn = on_object & ~r.restored
    fig, ax = plt.subplots(figsize=(8, 6))
    ax.imshow(frame.rgb)
    for sel, c, lab in ((~on_object, "#2ca02c", "static"), (r.restored, "#17becf", "restored"), (dyn, "#d62728", "excluded")):
        ax.scatter(uv[sel, 0], uv[sel, 1], s=9, c=c, label=f"{lab} ({sel.sum()})")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(f"δ {r.delta_before:.2f} → {r.delta_after:.2f}; restored groups p = {r.groups}")
    ax.set_axis_off()
    plt.show()


display(widgets.interactive(show_restoration, delta_1=widgets.FloatSlider(value=0.3, min=0.0, max=1.0, step=0.05,
                                                                          description="δ₁")))

# %% [markdown]
# ## Zhang et al.'s rule in the pipeline
# Semantic levels plus the epipolar and multi-view checks on the next frame: people (high) go at once;
# low-level objects (monitor, keyboard) only when geometry flags them. Colours give the reason.

# %%
def show_rule(delta_1=0.3, use_level_rule=True):
    stages = ("semantic", "epipolar", "multiview") + (("level_rule",) if use_level_rule else ()) + ("restoration",)
    cfg = dataclasses.replace(ScreeningConfig(), restoration=RestorationConfig(delta_1=delta_1))
    s = Screener(stages, cfg)
    prev = seq[9]
    s.screen(prev, extract_features(prev.gray).uv.astype(float), build_detector("oracle").detect(prev))
    table = s.screen(frame, uv, dets)
    fig, ax = plt.subplots(figsize=(8, 6))
    draw_table(ax, frame.rgb, table, f"{'+'.join(stages)}: {table.n_dynamic} dynamic")
    plt.show()


display(widgets.interactive(show_rule, delta_1=widgets.FloatSlider(value=0.3, min=0.0, max=1.0, step=0.05, description="δ₁"),
                            use_level_rule=widgets.Checkbox(value=True, description="Zhang et al. 2023 levels")))
