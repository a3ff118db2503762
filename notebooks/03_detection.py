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
# Every paper this toolkit follows starts the same way: a CNN finds the *a-priori dynamic*
# objects, people first. YOLO-SLAM draws person boxes with a Darknet19-YOLOv3; Zhang et al.
# add a segmentation head to YOLOv5; Chang et al. use YOLACT instance masks; ASG-SLAM uses
# YOLOv8 instance segmentation. Here we
#
# 1. run four small real detectors (YOLOX-Nano, NanoDet-m, YOLOv8n, YOLOv8n-seg) on a real
#    TUM frame and draw their boxes and masks,
# 2. compare hard NMS with the Gaussian soft-NMS of the improved YOLOv5,
# 3. look at the motion priors the papers attach to COCO classes,
# 4. degrade a perfect *oracle* detector (misses, jitter, false positives) on a synthetic frame,
# 5. time every backend, and cache detections so later notebooks do not rerun the network.
#
# The real models and frames live in `../shared/data/`; without them (a fresh clone) the
# notebook runs the oracle sections only.

# %%
import dataclasses
import tempfile
import time
from pathlib import Path

import ipywidgets as widgets
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from IPython.display import display

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.datasets import load_rgb
from dynslam_lab.datasets.frame import Frame
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

SHARED = Path("..").resolve().parent / "shared" / "data"
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

# %%
detectors = {p.stem: OnnxDetector(p) for p in MODELS}
for name, det in detectors.items():
    print(f"{name:<26} {det.layout.family:<11} input {det.layout.input_size}  preprocessing: {det.preprocess_kind}")

# %%
if detectors and FRAMES:
    first = next(f for f in FRAMES if "xyz" in f.name)
    rgb = load_rgb(first)
    results = {name: det.detect_image(rgb) for name, det in detectors.items()}
    fig, axes = plt.subplots(2, 2, figsize=(12, 9))
    for ax, (name, d) in zip(axes.ravel(), results.items()):
        ax.imshow(draw_detections(rgb, d))
        ax.set_title(f"{name}: {len(d)} detections, {d.timings_ms['inference']:.0f} ms")
        ax.axis("off")
    plt.tight_layout()
    plt.show()
    rows = [
        {"model": name, "class": n, "score": round(float(s), 2), "box": np.round(b).astype(int).tolist()}
        for name, d in results.items() for n, s, b in zip(d.names, d.scores, d.boxes)
    ]
    display(pd.DataFrame(rows))

# %% [markdown]
# The segmentation model also returns one mask per instance: the mask coefficients `c` of a
# box combine the 32 prototypes `P` into `sigmoid(c^T P)`, which we sample at every image
# pixel and crop to the box. Against the YOLACT person mask of the same frame (the network of
# Chang et al.) the two people overlap with IoU:

# %%
seg = next((n for n in detectors if "seg" in n), None)
yolact = SHARED / "tum" / "frames" / "fr3_walking_xyz_1341846313.553992_person_mask_yolact.png"
if seg and yolact.is_file():
    d = results[seg]
    ours = d.masks[d.class_ids == 0].any(axis=0)
    ref = load_rgb(yolact)[:, :, 0] > 0
    print(f"person-mask IoU, YOLOv8n-seg vs YOLACT: {(ours & ref).sum() / (ours | ref).sum():.3f}")
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for ax, img, title in zip(axes, [ours, ref, ours ^ ref], ["YOLOv8n-seg", "YOLACT", "disagreement"]):
        ax.imshow(img, cmap="gray")
        ax.set_title(title)
        ax.axis("off")
    plt.show()

# %% [markdown]
# ## 2. Hard NMS versus Gaussian soft-NMS
#
# A detector proposes many overlapping boxes per object. *Hard* NMS (Zhang et al., eq. 5)
# keeps the best box `M` and sets the score of every box with `IoU(M, b_i) >= N_t` to zero.
# The improved YOLOv5 of the same paper instead *re-ranks*: each overlapping score decays as
# `s_i exp(-IoU(M, b_i)^2 / sigma)`, so a person half hidden behind another keeps a lowered
# score instead of vanishing. Move the sliders: a low score threshold shows the extra boxes
# soft-NMS keeps, a small `sigma` makes it behave like hard NMS.

# %%
nms_model = next((p for p in MODELS if "yolox" in p.name), MODELS[0] if MODELS else None)
if nms_model is not None:
    nms_frames = [load_rgb(f) for f in FRAMES]
    base = OnnxDetector(nms_model)
    # the network runs once per frame; the sliders only re-run decoding and suppression
    raw = [(base.infer(x), tf) for x, tf in (base.preprocess(img) for img in nms_frames)]

    def compare_nms(frame=0, score_threshold=0.3, nms_iou=0.45, sigma=0.5):
        fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
        img = nms_frames[frame]
        for ax, kind in zip(axes, ["none", "hard", "soft"]):
            cfg = DetectionConfig(score_threshold=score_threshold, nms=kind, nms_iou=nms_iou, soft_nms_sigma=sigma)
            d = base.with_config(cfg).postprocess(*raw[frame])
            ax.imshow(draw_detections(img, d, labels=False, thickness=1))
            ax.set_title(f"NMS {kind}: {len(d)} boxes, {int((d.class_ids == 0).sum())} person")
            ax.axis("off")
        plt.tight_layout()
        plt.show()

    controls = dict(
        frame=widgets.IntSlider(0, 0, len(nms_frames) - 1, description="frame"),
        score_threshold=widgets.FloatSlider(0.3, min=0.05, max=0.9, step=0.05, description="score"),
        nms_iou=widgets.FloatSlider(0.45, min=0.1, max=0.9, step=0.05, description="N_t"),
        sigma=widgets.FloatSlider(0.5, min=0.05, max=2.0, step=0.05, description="sigma"),
    )
    display(widgets.VBox([widgets.HBox(list(controls.values())), widgets.interactive_output(compare_nms, controls)]))

# %% [markdown]
# The same comparison as numbers over all five frames, at a low score threshold where the
# difference shows:

# %%
if nms_model is not None:
    rows = []
    for kind in ["none", "hard", "soft"]:
        det = base.with_config(DetectionConfig(score_threshold=0.1, nms=kind))
        t0 = time.perf_counter()
        ds = [det.postprocess(*r) for r in raw]
        ms = (time.perf_counter() - t0) * 1e3 / len(raw)
        rows.append({
            "nms": kind,
            "boxes per frame": np.mean([len(d) for d in ds]),
            "person boxes per frame": np.mean([(d.class_ids == 0).sum() for d in ds]),
            "decode + NMS ms": ms,
        })
    display(pd.DataFrame(rows).set_index("nms").round(2))

# %% [markdown]
# ## 3. Which classes may move? The papers' motion priors
#
# A box says *what* is there; whether it may move is a prior attached to the class.
# Chang et al. drop everything in 19 *a-priori dynamic* classes (people, vehicles, animals).
# ASG-SLAM grades six categories by motion probability and restores features of the least
# likely ones first when too few static features remain. Zhang et al. sort objects into
# high, medium and low dynamic levels: high and medium are removed at once, low ones go to
# the epipolar test. All three tables live in `DetectionConfig.priors` and can be edited.

# %%
if detectors and FRAMES:  # the classes the four models found in the frame
    ids = np.unique(np.concatenate([r.class_ids for r in results.values()]))
else:
    ids = np.array([0, 2, 15, 24, 39, 56, 62, 66])
prior_table = pd.DataFrame({
    "class": [COCO_CLASSES[i] for i in ids],
    "a-priori dynamic (Chang)": is_apriori_dynamic(ids),
    "ASG category": [ASG_CATEGORY_OF[COCO_CLASSES[i]] for i in ids],
    "motion probability (ASG)": motion_probability(ids),
    "level (Zhang)": dynamic_level(ids),
})
prior_table

# %% [markdown]
# ## 4. An imperfect oracle on a synthetic frame
#
# Synthetic frames carry the true instance mask of every object, so an *oracle* detector can
# return perfect boxes and masks. Real networks miss people, place boxes loosely and see
# people where there are none; the oracle can do all three, with a seed, so the later
# notebooks can ask how each dynamic filter copes with a given detector quality.

# %%
def synthetic_frame() -> Frame:
    """A synthetic frame from the renderer when it is available, else a hand-drawn one."""
    try:
        from dynslam_lab.datasets import TumSequence
        from dynslam_lab.datasets.synthetic import synthetic_sequence

        seq = TumSequence(synthetic_sequence("walking_xyz", n_frames=5, seed=0))
        return seq[2]
    except ImportError:
        h, w = 480, 640
        yy, xx = np.mgrid[0:h, 0:w]
        mask = np.zeros((h, w), np.int32)
        mask[((xx - 200) / 60) ** 2 + ((yy - 300) / 150) ** 2 < 1] = 1  # a standing person
        mask[((xx - 470) / 55) ** 2 + ((yy - 330) / 120) ** 2 < 1] = 2  # another one
        mask[380:470, 300:400] = 3  # a chair
        rgb = np.full((h, w, 3), 180, np.uint8)
        rgb[mask > 0] = [90, 60, 40]
        return Frame(0, 0.0, rgb, np.full((h, w), 2.0, np.float32), CAMERA_PRESETS["tum_fr3"],
                     instance_mask=mask, instance_classes={1: "person", 2: "person", 3: "chair"})


syn = synthetic_frame()


def show_oracle(miss_rate=0.0, jitter=0.0, false_positives=0.0, seed=0):
    cfg = DetectionConfig(oracle=OracleConfig(miss_rate=miss_rate, jitter=jitter,
                                              false_positives=false_positives, seed=seed))
    d = OracleDetector(cfg).detect(syn)
    truth = syn.instance_mask > 0
    found = d.masks.any(axis=0) if len(d) else np.zeros_like(truth)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    axes[0].imshow(draw_detections(syn.rgb, d))
    axes[0].set_title(f"oracle: {len(d)} detections")
    axes[1].imshow(found.astype(int) - (truth & ~found).astype(int), cmap="RdYlGn", vmin=-1, vmax=1)
    axes[1].set_title(f"covered {(found & truth).sum() / max(truth.sum(), 1):.0%} of the true pixels (red: missed)")
    for ax in axes:
        ax.axis("off")
    plt.show()


oracle_controls = dict(
    miss_rate=widgets.FloatSlider(0.0, min=0, max=1, step=0.05, description="miss rate"),
    jitter=widgets.FloatSlider(0.0, min=0, max=0.3, step=0.01, description="jitter"),
    false_positives=widgets.FloatSlider(0.0, min=0, max=5, step=0.5, description="false pos."),
    seed=widgets.IntSlider(0, 0, 20, description="seed"),
)
display(widgets.VBox([widgets.HBox(list(oracle_controls.values())),
                      widgets.interactive_output(show_oracle, oracle_controls)]))

# %% [markdown]
# The rates are what they claim to be: over 200 frames, the share of missed people and the
# number of false positives per frame.

# %%
cfg = DetectionConfig(oracle=OracleConfig(miss_rate=0.25, false_positives=1.0, seed=3))
oracle = OracleDetector(cfg)
n_true = len(OracleDetector().detect(syn))
counts = []
for i in range(200):
    f = dataclasses.replace(syn, index=i)
    d = oracle.detect(f)
    counts.append(((d.scores == 1).sum(), (d.scores < 1).sum()))
counts = np.array(counts)
print(f"missed: {1 - counts[:, 0].mean() / n_true:.2f} (set 0.25); false positives per frame: {counts[:, 1].mean():.2f} (set 1.0)")

# %% [markdown]
# ## 5. Speed of each backend, and the cache
#
# Each `Detections` carries its timings: preprocessing (letterbox, channel order), the network,
# and our decoding + NMS (+ masks). Decoding should cost a small fraction of the network.
# A cache (`cache:DIR`) stores each frame's detections as a small npz file; reading one back is
# far cheaper than running any network. (`benchmarks/detection_speed.py` measures the same
# with more repetitions.)

# %%
def median_ms(det, frame, n=3):
    t = []
    for _ in range(n):
        t0 = time.perf_counter()
        d = det.detect(frame)
        t.append((time.perf_counter() - t0) * 1e3)
    return np.median(t), d


rows = []
real = Frame(0, 1341846313.553992, rgb, np.zeros(rgb.shape[:2], np.float32), CAMERA_PRESETS["tum_fr3"]) if FRAMES else None
for name, det in detectors.items():
    total, d = median_ms(det, real)
    rows.append({"backend": name, "total ms": total, **{f"{k} ms": v for k, v in d.timings_ms.items()}})
total, _ = median_ms(OracleDetector(), syn)
rows.append({"backend": "oracle", "total ms": total})
with tempfile.TemporaryDirectory() as tmp:
    source = next(iter(detectors.values()), OracleDetector())
    frame = real if detectors else syn
    CacheDetector(tmp, fallback=source).detect(frame)  # the first pass fills the cache
    total, d = median_ms(build_detector(f"cache:{tmp}"), frame)  # later passes read it
    rows.append({"backend": f"cache ({source.source})", "total ms": total})
timing = pd.DataFrame(rows).set_index("backend").round(2)
if "decode ms" in timing:
    timing["decode / inference"] = (timing["decode ms"] / timing["inference ms"]).map("{:.1%}".format)
timing
