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
# # 07 · The whole screening chain and its ablation
#
# All stages together, chained by configuration, each writing its column into one table per frame:
# semantic prior → depth-RANSAC (box-only detections) → epipolar → multi-view → adaptive flow →
# motion-probability restoration. Then the ablation the papers print (YOLO-SLAM Table 3, Chang et al.
# Table I): one SLAM run per filter, ATE RMSE, and what the papers could not measure: per-keypoint
# precision and recall against the synthetic truth.
#
# This notebook runs short sequences to stay fast; `dynslam demo` and `dynslam ablation` run longer ones.

# %%
import dataclasses
import tempfile

import ipywidgets as widgets
import matplotlib.pyplot as plt
from IPython.display import Markdown, display

from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.datasets.tum import TumSequence
from dynslam_lab.detection import build_detector
from dynslam_lab.experiments.ablation import ablation_markdown, run_ablation
from dynslam_lab.dynamic.config import ScreeningConfig
from dynslam_lab.dynamic.epipolar import EpipolarConfig
from dynslam_lab.dynamic.multiview import MultiViewConfig
from dynslam_lab.dynamic.plots import draw_table
from dynslam_lab.dynamic.oracle import truth_dynamic
from dynslam_lab.experiments.scoring import score_keypoints
from dynslam_lab.dynamic.screening import build_screener
from dynslam_lab.features.orb import extract_features

N_FRAMES = 30  # the sequence the tests render too (one cache entry)
seqdir = synthetic_sequence("walking_xyz", n_frames=N_FRAMES, seed=0)
seq = TumSequence(seqdir)
detector = build_detector("oracle")
cache = []
for i in range(12):
    f = seq[i]
    cache.append((f, extract_features(f.gray).uv.astype(float), detector.detect(f)))

# %% [markdown]
# ## One frame, every stage
# Pick a frame and move the thresholds; the screener replays the frames before it (it needs the previous
# frame). Keypoints are coloured by the stage that judged them dynamic.

# %%
def show_frame(index=10, filters="full", mu=1.0, reprojection_px=4.0, depth_m=0.1):
    cfg = dataclasses.replace(ScreeningConfig(), epipolar=dataclasses.replace(EpipolarConfig(), threshold_px=mu),
                              multiview=dataclasses.replace(MultiViewConfig(), reprojection_px=reprojection_px, depth_m=depth_m))
    s = build_screener(filters, cfg)
    for f, uv, d in cache[max(index - 1, 0) : index]:
        s.screen(f, uv, d)
    f, uv, d = cache[index]
    table = s.screen(f, uv, d)
    sc = score_keypoints(table.dynamic, truth_dynamic(f, uv))
    fig, ax = plt.subplots(figsize=(9, 6.5))
    draw_table(ax, f.rgb, table, f"frame {index}, {filters}: precision {sc.precision:.2f}, recall {sc.recall:.2f}, "
               f"{table.timings_ms['total']:.1f} ms")
    plt.show()
    display(table.to_dataframe().groupby("reason").size().rename("keypoints").to_frame().T)


display(widgets.interactive(
    show_frame,
    index=widgets.IntSlider(value=10, min=1, max=len(cache) - 1, description="frame"),
    filters=widgets.Dropdown(options=["semantic", "depth_ransac", "geometry", "full", "oracle"], value="full"),
    mu=widgets.FloatSlider(value=1.0, min=0.1, max=10.0, step=0.1, description="epipolar μ"),
    reprojection_px=widgets.FloatSlider(value=4.0, min=0.5, max=15.0, step=0.5, description="reproj px"),
    depth_m=widgets.FloatSlider(value=0.1, min=0.01, max=0.5, step=0.01, description="depth m"),
))

# %% [markdown]
# ## The ablation
# One SLAM run per filter on the short synthetic walking sequence (oracle detections). ATE RMSE in metres,
# improvement over `none`, per-keypoint precision/recall, median screening time per frame.

# %%
out = tempfile.mkdtemp(prefix="dynslam_ablation_")
df = run_ablation([seqdir], out, ["none", "semantic", "depth_ransac", "geometry", "full", "oracle"],
                  detector="oracle", max_frames=N_FRAMES, progress=False)
display(Markdown(ablation_markdown(df)))

# %%
fig, axes = plt.subplots(1, 2, figsize=(12, 3.5))
axes[0].bar(df["filter"], df["ate_rmse_m"])
axes[0].set_ylabel("ATE RMSE (m)")
axes[0].set_yscale("log")
axes[1].bar(df["filter"], df["recall"], alpha=0.7, label="recall")
axes[1].bar(df["filter"], df["precision"], alpha=0.5, label="precision")
axes[1].set_ylim(0, 1.05)
axes[1].legend()
plt.show()
