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
# # 03 · Semantic detection: finding the objects that may move
#
# **What you will learn**
# - how four small real detectors (YOLOX-Nano, NanoDet-m, YOLOv8n, YOLOv8n-seg) see a real TUM frame,
#   and how their output tensors are decoded;
# - what hard NMS and Gaussian soft-NMS do with overlapping boxes;
# - which classes the papers treat as moving, and with which prior;
# - how an *oracle* detector with misses, jitter and false positives stands in for a real
#   network on synthetic frames, and what each backend costs.
#
# Every paper this toolkit follows starts the same way: a CNN finds the *a-priori dynamic*
# objects, people first. Wu et al. 2022 (YOLO-SLAM) draw person boxes with a Darknet19-YOLOv3;
# Zhang et al. 2023 add a segmentation head to YOLOv5 and replace hard NMS by Gaussian soft-NMS,
# which lowers the score $s_i$ of a box $b_i$ overlapping the best box $M$ instead of removing it:
#
# $$s_i \leftarrow s_i \, e^{-\mathrm{IoU}(M, b_i)^2 / \sigma}.$$
#
# Chang et al. 2021 use YOLACT instance masks; Ge et al. 2024 (ASG-SLAM) YOLOv8 instance
# segmentation. The real models and frames live in `../shared/data/`; without them (a fresh
# clone) the notebook runs the oracle sections only.

# %%
import dataclasses
import os
import tempfile
import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from IPython.display import display

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.datasets import TumSequence, load_rgb
from dynslam_lab.datasets.frame import Frame
from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.detection import (
    CacheDetector,
    DetectionConfig,
    OnnxDetector,
    OracleConfig,
    OracleDetector,
    build_detector,
    draw_detections,
    dynamic_level,
    is_apriori_dynamic,
    motion_probability,
)
from dynslam_lab.detection.coco import ASG_CATEGORY_OF, COCO_CLASSES
from dynslam_lab.detection.nms import box_iou, soft_nms
from dynslam_lab.viz.colors import hex_color
from dynslam_lab.viz.exercises import check
from dynslam_lab.viz.plots import plot_timing_bars
from dynslam_lab.viz.widgets import figure_explorer, float_slider, int_slider

SHARED = Path(os.environ.get("DYNSLAM_SHARED_DATA", Path("..").resolve().parent / "shared" / "data"))
MODELS = sorted((SHARED / "models").glob("*.onnx")) if SHARED.is_dir() else []
FRAMES = sorted((SHARED / "tum" / "frames").glob("*_rgb.png")) if SHARED.is_dir() else []
print(f"{len(MODELS)} ONNX models, {len(FRAMES)} real frames")

# %% [markdown]
# ## 1. Four detectors, one frame
#
# `OnnxDetector` reads a model's inputs and outputs and recognises its family from their
# shapes alone: YOLOv8 gives `[1, 4+80, N]`, YOLOv8-seg adds 32 mask coefficients and a
# `[1, 32, H/4, W/4]` prototype tensor, YOLOX gives raw grid offsets `[1, N, 85]`, NanoDet six
# per-stride tensors (class scores and box *distributions*). With `N` the number of anchor
# points over strides 8/16/32 (3,549 at 416 x 416), the shapes are unambiguous.

# %% figures=1 needs_shared=true
detectors = {p.stem: OnnxDetector(p) for p in MODELS}
for name, det in detectors.items():
    print(f"{name:<26} {det.layout.family:<11} input {det.layout.input_size}  preprocessing: {det.preprocess_kind}")
if detectors and FRAMES:
    first = next(f for f in FRAMES if "xyz" in f.name)
    rgb = load_rgb(first)
    results = {name: det.detect_image(rgb) for name, det in detectors.items()}
    fig, axes = plt.subplots(2, 2, figsize=(12, 9), constrained_layout=True)
    for ax, (name, d) in zip(axes.ravel(), results.items()):
        ax.imshow(draw_detections(rgb, d))
        ax.set_title(f"{name}: {len(d)} detections, {d.timings_ms['inference']:.0f} ms")
        ax.set_axis_off()
    plt.show()
    display(pd.DataFrame([
        {"model": name, "class": n, "score": round(float(s), 2), "box": np.round(b).astype(int).tolist()}
        for name, d in results.items() for n, s, b in zip(d.names, d.scores, d.boxes)]))

# %% [markdown]
# **What to look for**: all four find the two people, with boxes that agree within a few
# pixels; they differ on the small things (a cup, a keyboard, a chair half hidden by a person).
# The person boxes hold a lot of background (wall, desk): the next notebook's depth-RANSAC keeps
# those keypoints.
#
# The segmentation model also returns one mask per instance: the mask coefficients $c$ of a box
# combine the 32 prototypes $P$ into $\sigma(c^\top P)$, sampled at every image pixel and cropped
# to the box. Against the YOLACT person mask of the same frame (the network of Chang et al.
# 2021):

# %% figures=1 needs_shared=true
seg = next((n for n in detectors if "seg" in n), None)
yolact = SHARED / "tum" / "frames" / "fr3_walking_xyz_1341846313.553992_person_mask_yolact.png"
if seg and yolact.is_file():
    d = results[seg]
    ours = d.masks[d.class_ids == 0].any(axis=0)
    ref = load_rgb(yolact)[:, :, 0] > 0
    print(f"person-mask IoU, YOLOv8n-seg vs YOLACT: {(ours & ref).sum() / (ours | ref).sum():.3f}")
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6), constrained_layout=True)
    for ax, img, title in zip(axes, [ours, ref, ours ^ ref], ["YOLOv8n-seg", "YOLACT", "disagreement"]):
        ax.imshow(img, cmap="gray")
        ax.set_title(title)
        ax.set_axis_off()
    plt.show()

# %% [markdown]
# **What to look for**: the two masks disagree along the outlines (a band a few pixels wide)
# and on the arms and legs; the YOLOv8n-seg mask, computed at a quarter of the resolution, is
# blobbier. Keypoints sit on exactly those outlines (corners), so a mask's edge matters more
# than its area.

# %% [markdown]
# ## 2. Hard NMS versus Gaussian soft-NMS
#
# A detector proposes many overlapping boxes per object. *Hard* NMS keeps the best box $M$ and
# sets the score of every box with $\mathrm{IoU}(M, b_i) \ge N_t$ to zero. Soft-NMS instead
# decays the overlapping scores (equation above), so a person half hidden behind another keeps
# a lowered score instead of vanishing. The network runs once per frame; the sliders only re-run
# decoding and suppression.

# %% figures=1 needs_shared=true
nms_model = next((p for p in MODELS if "yolox" in p.name), MODELS[0] if MODELS else None)
if nms_model is not None:
    nms_frames = [load_rgb(f) for f in FRAMES]
    base = OnnxDetector(nms_model)
    raw = [(base.infer(x), tf) for x, tf in (base.preprocess(img) for img in nms_frames)]

    def draw_nms(frame=4, score_threshold=0.15, nms_iou=0.45, sigma=0.5):
        fig, axes = plt.subplots(1, 3, figsize=(15, 4.2), constrained_layout=True)
        img = nms_frames[frame]
        for ax, kind in zip(axes, ["none", "hard", "soft"]):
            cfg = DetectionConfig(score_threshold=score_threshold, nms=kind, nms_iou=nms_iou, soft_nms_sigma=sigma)
            d = base.with_config(cfg).postprocess(*raw[frame])
            ax.imshow(draw_detections(img, d, labels=False, thickness=1))
            ax.set_title(f"NMS {kind}: {len(d)} boxes, {int((d.class_ids == 0).sum())} person")
            ax.set_axis_off()
        return fig

    # frame 4 at a low score threshold: several overlapping person boxes, where N_t and sigma matter
    figure_explorer(draw_nms, name="03 NMS", frame=int_slider("frame", 4, 0, len(nms_frames) - 1),
                    score_threshold=float_slider("score", 0.15, 0.05, 0.9, 0.05),
                    nms_iou=float_slider("N_t (hard)", 0.45, 0.1, 0.9, 0.05),
                    sigma=float_slider("sigma (soft)", 0.5, 0.05, 2.0, 0.05))

# %% [markdown]
# **What to look for**: without NMS every person carries a stack of boxes; hard NMS leaves one
# each; soft-NMS keeps some of the stack with lowered scores, visible once the score threshold
# is low. A small $\sigma$ makes soft-NMS behave like hard NMS. The same as numbers over the
# frames, at a low score threshold:

# %%
if nms_model is not None:
    rows = []
    for kind in ["none", "hard", "soft"]:
        det = base.with_config(DetectionConfig(score_threshold=0.1, nms=kind))
        t0 = time.perf_counter()
        ds = [det.postprocess(*r) for r in raw]
        rows.append({"nms": kind, "boxes per frame": np.mean([len(d) for d in ds]),
                     "person boxes per frame": np.mean([(d.class_ids == 0).sum() for d in ds]),
                     "decode + NMS ms": (time.perf_counter() - t0) * 1e3 / len(raw)})
    display(pd.DataFrame(rows).set_index("nms").round(2))

# %% [markdown]
# ## 3. Which classes may move? The papers' motion priors
#
# A box says *what* is there; whether it may move is a prior attached to the class.
# Chang et al. 2021 drop everything in 19 *a-priori dynamic* classes (people, vehicles,
# animals). ASG-SLAM (Ge et al. 2024) grades six categories by motion probability and restores
# features of the least likely movers first when too few static features remain. Zhang et al.
# 2023 sort objects into high, medium and low dynamic levels: high and medium are removed at
# once, low ones go to the epipolar test. All three tables live in `DetectionConfig.priors`.

# %% figures=1
if detectors and FRAMES:  # the classes the four models found in the frame
    ids = np.unique(np.concatenate([r.class_ids for r in results.values()]))
else:
    ids = np.array([0, 2, 15, 24, 39, 41, 56, 62, 63, 66, 73])
prior_table = pd.DataFrame({
    "class": [COCO_CLASSES[i] for i in ids],
    "a-priori dynamic (Chang)": is_apriori_dynamic(ids),
    "ASG category": [ASG_CATEGORY_OF[COCO_CLASSES[i]] for i in ids],
    "motion probability (ASG)": motion_probability(ids),
    "level (Zhang)": dynamic_level(ids),
}).sort_values("motion probability (ASG)")
display(prior_table.set_index("class"))
level_color = {"high": hex_color("dynamic"), "medium": hex_color("keyframe"), "low": hex_color("static")}
fig, ax = plt.subplots(figsize=(8, 0.35 * len(prior_table) + 1.2), constrained_layout=True)
y = np.arange(len(prior_table))
ax.barh(y, prior_table["motion probability (ASG)"], color=[level_color.get(l, "0.6") for l in prior_table["level (Zhang)"]])
ax.set_yticks(y, [f"{c}{' *' if a else ''}" for c, a in zip(prior_table["class"], prior_table["a-priori dynamic (Chang)"])])
ax.set_xlabel("prior motion probability (ASG-SLAM)")
ax.set_xlim(0, 1)
ax.legend(handles=[plt.Rectangle((0, 0), 1, 1, color=c, label=f"level {k} (Zhang)") for k, c in level_color.items()],
          loc="lower right", fontsize="small")
ax.set_title("motion priors of the classes (* = a-priori dynamic for Chang et al.)");

# %% [markdown]
# **What to look for**: the papers agree on a person (a-priori dynamic, level high, the
# highest probability). In between they differ: a chair or a bottle is "medium" for Zhang et
# al. 2023 (removed at once), yet shares the lowest probability with a monitor for ASG-SLAM,
# which gives such keypoints back first when a frame runs short of static features.

# %% [markdown]
# ## 4. An imperfect oracle on a synthetic frame
#
# Synthetic frames carry the true instance mask of every object, so an *oracle* detector can
# return perfect boxes and masks. Real networks miss people, place boxes loosely and see people
# where there are none; the oracle can do all three, with a seed, so the later notebooks ask how
# each filter copes with a given detector quality. It starts degraded here (30% misses, jittered
# boxes, one false positive per frame on average).

# %% figures=1
syn = TumSequence(synthetic_sequence("walking_xyz", n_frames=30, seed=0))[20]


def draw_oracle(miss_rate=0.3, jitter=0.08, false_positives=1.0, seed=0):
    cfg = DetectionConfig(oracle=OracleConfig(miss_rate=miss_rate, jitter=jitter, false_positives=false_positives,
                                              seed=seed))
    d = OracleDetector(cfg).detect(dataclasses.replace(syn, index=seed))
    truth = np.isin(syn.instance_mask, sorted(syn.moving_ids))
    found = d.masks.any(axis=0) if len(d) else np.zeros_like(truth)
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.6), constrained_layout=True)
    axes[0].imshow(draw_detections(syn.rgb, d))
    axes[0].set_title(f"oracle: {len(d)} detections")
    view = np.full((*truth.shape, 3), 245, np.uint8)
    view[found] = (190, 190, 190)
    view[found & truth] = (44, 160, 44)
    view[truth & ~found] = (220, 0, 220)
    axes[1].imshow(view)
    axes[1].set_title(f"walker pixels covered: {(found & truth).sum() / max(truth.sum(), 1):.0%} "
                      "(green covered, magenta missed, grey other detections)")
    for ax in axes:
        ax.set_axis_off()
    return fig


figure_explorer(draw_oracle, name="03 oracle", miss_rate=float_slider("miss rate", 0.3, 0.0, 1.0, 0.05),
                jitter=float_slider("jitter", 0.08, 0.0, 0.3, 0.01),
                false_positives=float_slider("false pos. / frame", 1.0, 0.0, 5.0, 0.5),
                seed=int_slider("seed", 0, 0, 20));

# %% [markdown]
# **What to look for**: the seed decides which person is missed and where the false positives
# land; jitter shifts and scales the boxes and masks, so part of the walker falls outside
# (magenta) while background falls inside. The rates are what they claim to be, over 200 frames:

# %%
oracle = OracleDetector(DetectionConfig(oracle=OracleConfig(miss_rate=0.25, false_positives=1.0, seed=3)))
n_true = len(OracleDetector().detect(syn))
counts = np.array([((d.scores == 1).sum(), (d.scores < 1).sum())
                   for d in (oracle.detect(dataclasses.replace(syn, index=i)) for i in range(200))])
print(f"missed: {1 - counts[:, 0].mean() / n_true:.2f} (set 0.25); false positives per frame: "
      f"{counts[:, 1].mean():.2f} (set 1.0)")

# %% [markdown]
# ## 5. Speed of each backend, and the cache
#
# Each `Detections` carries its timings: preprocessing (letterbox, channel order), the network,
# and our decoding + NMS (+ masks). A cache (`cache:DIR`) stores each frame's detections as a
# small npz file; reading one back is far cheaper than running any network.
# (`benchmarks/detection_speed.py` measures the same with more repetitions.)

# %% figures=1
def median_ms(det, frame, n=3):
    t = []
    for _ in range(n):
        t0 = time.perf_counter()
        d = det.detect(frame)
        t.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(t)), d


totals = {}
real = Frame(0, 1341846313.553992, rgb, np.zeros(rgb.shape[:2], np.float32), CAMERA_PRESETS["tum_fr3"]) if FRAMES else None
for name, det in detectors.items():
    totals[name], _ = median_ms(det, real)
totals["oracle"], _ = median_ms(OracleDetector(), syn)
with tempfile.TemporaryDirectory() as tmp:
    source = next(iter(detectors.values()), OracleDetector())
    frame = real if detectors else syn
    CacheDetector(tmp, fallback=source).detect(frame)  # the first pass fills the cache
    totals[f"cache ({source.source})"], _ = median_ms(build_detector(f"cache:{tmp}"), frame)
plot_timing_bars(totals, title="detection time per frame (median of 3)");

# %% [markdown]
# **What to look for**: on a laptop CPU the networks cost from about a hundred milliseconds to
# a second per frame (the segmentation model is the slowest: it also decodes masks), the oracle
# tens of milliseconds (it draws masks), the cache under a millisecond: run a network once over
# a sequence (`dynslam detect ... --save-dir`), then every filter experiment reads the cache.

# %% [markdown]
# ### Exercise 1: intersection over union
#
# Compute the IoU of the boxes `[0, 0, 10, 10]` and `[5, 5, 15, 15]` (x1, y1, x2, y2 in pixels,
# continuous coordinates: the first box has area 100) by hand, then compare with
# `box_iou(np.array([[0, 0, 10, 10]]), np.array([[5, 5, 15, 15]]))`.

# %% exercise="03.1"
answer = None  # your code: a number in [0, 1]

# %% check="03.1"
check("03.1", answer, box_iou(np.array([[0.0, 0, 10, 10]]), np.array([[5.0, 5, 15, 15]]))[0, 0])

# %% [markdown]
# ### Exercise 2: one step of soft-NMS
#
# Box A `[0, 0, 10, 10]` scores 0.9, box B `[2, 0, 12, 10]` scores 0.8. Soft-NMS keeps A first;
# what is B's score after the decay with $\sigma = 0.5$? Use the equation at the top.

# %% exercise="03.2"
answer = None  # your code: B's decayed score

# %% check="03.2"
keep, new_scores = soft_nms(np.array([[0.0, 0, 10, 10], [2.0, 0, 12, 10]]), np.array([0.9, 0.8]), sigma=0.5)
check("03.2", answer, new_scores[list(keep).index(1)])

# %% [markdown]
# ### Exercise 3: measure a miss rate
#
# Build an oracle with `miss_rate=0.5` (and no jitter or false positives), run it on 100
# copies of `syn` with different indices (`dataclasses.replace(syn, index=i)`: the index seeds
# the draw) and give the share of true detections missed. It should be near 0.5, not exactly.

# %% exercise="03.3"
answer = None  # your code: the measured miss rate

# %% check="03.3"
check("03.3", answer, test=lambda a: abs(float(a) - 0.5) < 0.1, hint="within 0.1 of the rate set")
