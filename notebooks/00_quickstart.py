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
# # 00 · Quickstart
#
# Render a short synthetic sequence in which two people walk in front of a moving camera,
# look at its colour, depth and ground-truth masks, run the SLAM system on it with and
# without a dynamic-feature filter, and score both trajectories against the ground truth
# (ATE and RPE, the numbers of the papers' tables).

# %%
from pathlib import Path
import tempfile

import matplotlib.pyplot as plt
import numpy as np

from dynslam_lab.datasets import TumSequence
from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.evaluation import evaluate

seq_dir = synthetic_sequence("walking_xyz", n_frames=40, seed=0)
seq = TumSequence(seq_dir)
print(seq)

# %% [markdown]
# ## The sequence: colour, depth, instance masks
# Every pixel of a synthetic frame knows which object it shows; `moving.txt` says which
# objects move in each frame. That truth scores every filter later on.

# %%
frame = seq[20]
fig, ax = plt.subplots(1, 3, figsize=(13, 3.4))
ax[0].imshow(frame.rgb); ax[0].set_title("colour")
ax[1].imshow(np.where(frame.depth > 0, frame.depth, np.nan), cmap="turbo"); ax[1].set_title("depth (m)")
ax[2].imshow(frame.instance_mask, cmap="tab20", interpolation="nearest"); ax[2].set_title("instances")
for a in ax:
    a.axis("off")
plt.show()

# %% [markdown]
# ## Run SLAM twice: no filter, and the oracle (perfect masks)

# %%
from dynslam_lab.config import Config
from dynslam_lab.pipeline import build_pipeline
from dynslam_lab.runs import run_sequence

out_root = Path(tempfile.mkdtemp(prefix="dynslam_quickstart_"))
summaries = {}
for filters in ("none", "oracle"):
    system = build_pipeline(Config(), seq.camera, filters=filters)
    summaries[filters] = run_sequence(seq, out_root / filters, system, progress=False)
    print(filters, "tracked", summaries[filters]["tracked"], "of", summaries[filters]["frames"])

# %% [markdown]
# ## Evaluate: ATE after SE(3) alignment, RPE over one frame

# %%
from dynslam_lab.evaluation import read_tum_trajectory

for filters in summaries:
    est = read_tum_trajectory(out_root / filters / "trajectory.txt")
    res = evaluate(seq.groundtruth, est, align="se3")
    print(f"{filters:7s} ATE RMSE {res['ate']['rmse']:.4f} m   RPE trans RMSE {res['rpe']['trans']['rmse']:.4f} m")
    plt.plot(est.positions[:, 0], est.positions[:, 1], label=filters)
gt = seq.groundtruth
plt.plot(gt.positions[:, 0], gt.positions[:, 1], "k--", label="ground truth")
plt.axis("equal"); plt.legend(); plt.xlabel("x (m)"); plt.ylabel("y (m)")
plt.show()
