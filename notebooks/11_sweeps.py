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
# # 11 · Parameter sweeps: one threshold, many runs, sequences and seeds
#
# **What you will learn**
# - how a sweep spec names sequences, seeds, filters and a grid of config keys (`dynslam sweep SPEC.toml`);
# - why every run is named by a hash of its inputs, and how that makes a killed sweep resumable;
# - how to read the tidy table and the sensitivity plots, with the spread over seeds;
# - how the same spec runs on a Dask cluster.
#
# **The paper.** The epipolar check of Zhang et al. 2023 (improved YOLOv5 with geometric constraints) flags
# a keypoint whose distance to its epipolar line exceeds a threshold $\mu$:
#
# $$ l_2 = (a, b, c)^\top = F p_1 \quad (16), \qquad d = \frac{|p_2^\top l_2|}{\sqrt{a^2+b^2}} > \mu \quad (17)$$
#
# The paper does not give $\mu$ (we default to DS-SLAM's 1 px). A smaller $\mu$ flags more keypoints: more of
# the truly moving ones (recall up), more static ones too (precision down). How much, on which sequences,
# and how stable across seeds? One SLAM run per sequence, seed and value of $\mu$: a sweep. Here a tiny one
# (8-frame sequences, so that it runs in seconds); `docs/sweeps.md` has the whole spec format.

# %%
import importlib.util
import json
import tempfile
from pathlib import Path

import ipywidgets as widgets
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from IPython.display import display

from dynslam_lab.experiments.sweep import deterministic_columns, is_finished, run_sweep
from dynslam_lab.experiments.sweep_plots import plot_metric
from dynslam_lab.experiments.sweep_spec import expand_values, load_spec

# the solutions of the exercises (used by the checks when an exercise is not done yet)
_sol_path = next(p for p in (Path("solutions"), Path("notebooks/solutions")) if p.is_dir()) / "11_sweeps.py"
_spec = importlib.util.spec_from_file_location("solutions_11_sweeps", _sol_path)
solutions = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(solutions)

# %% [markdown]
# ## The spec
# Two synthetic presets: `walking_xyz` (the camera translates: the epipolar geometry is defined) and
# `walking_static` (the camera hardly moves: $F$ is undefined, the epipolar stage abstains and the multi-view
# check does the work), two seeds each (textures and sensor noise change with the seed), the `geometry` filter
# (epipolar + multi-view, Chang et al. 2021 "only with multi-view geometry"), and three values of $\mu$.
# Every key is checked before the first run; a misspelt key is named with the keys that exist.

# %%
work = Path(tempfile.mkdtemp(prefix="dynslam_sweep_"))
SPEC = """
[sweep]
name = "epipolar_mu"
filters = ["geometry"]
loop_closing = false

[[sequences]]
preset = "walking_xyz"
n_frames = 8
seeds = [0, 1]

[[sequences]]
preset = "walking_static"
n_frames = 8
seeds = [0, 1]

[grid]
"screening.epipolar.threshold_px" = [0.5, 1.0, 2.0]
"""
(work / "sweep.toml").write_text(SPEC)
spec = load_spec(work / "sweep.toml")
tasks = spec.tasks(work / "out")
print(f"{len(tasks)} runs = 2 presets x 2 seeds x 1 filter x 3 values")
for t in tasks[:3]:
    print(t.run_id, t.sequence.label, "seed", t.sequence.seed, t.filters, dict(t.params))

(work / "typo.toml").write_text(SPEC.replace("threshold_px", "threshhold_px"))
try:
    load_spec(work / "typo.toml")
except ValueError as exc:
    print("\n", str(exc)[:230], "...")

# %% [markdown]
# ## Run it on a process pool
# `run_sweep` (what `dynslam sweep sweep.toml --out out --workers 2` calls) starts 2 worker processes, one task
# per run; each worker renders its sequence (cached on disk) and runs the same pipeline as `dynslam run`,
# scoring each keypoint verdict against the renderer's truth. Each run writes `out/runs/RUN_ID/`; the table
# and the plots come last.

# %%
report = run_sweep(spec, work / "out", workers=2, progress=False, plots=False)
print(f"{report.executed} runs done on a {report.engine} in {report.seconds:.1f} s")
table = report.table
THR = "screening.epipolar.threshold_px"
cols = ["sequence", "seed", THR, "tracked", "ate.rmse", "keypoints.precision", "keypoints.recall"]
display(table[cols].round(4))

# %% [markdown]
# ## The sensitivity plots
# One line per sequence (the mean over seeds), the band from the lowest to the highest seed, a dot per seed.

# %%
fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
for ax, metric in zip(axes, ["keypoints.recall", "keypoints.precision"]):
    for i, (name, g) in enumerate(table.groupby("sequence", sort=False)):
        per = g.groupby(THR)[metric]
        x = np.array(sorted(g[THR].unique()))
        ax.plot(x, per.mean().loc[x], "-o", color=f"C{i}", label=name)
        ax.fill_between(x, per.min().loc[x], per.max().loc[x], color=f"C{i}", alpha=0.2)
    ax.set_xlabel("epipolar threshold μ (px)")
    ax.set_ylabel(metric)
    ax.grid(alpha=0.3)
axes[0].legend(title="sequence (band: seeds)")
plt.show()

# %% [markdown]
# **What to look for.** On `walking_xyz` recall falls as $\mu$ grows: the epipolar test lets more moving
# keypoints through; precision rises, since fewer static keypoints are flagged. On `walking_static` the lines
# are flat: with a camera at rest $F$ is undefined, the epipolar stage abstains whatever $\mu$ is, and the
# multi-view check alone decides. The band is the spread over two seeds: narrow here, so the trend is not
# one seed's accident.
#
# The same figures, saved by `dynslam sweep` as `out/plots/METRIC__AXIS.png`, come from `plot_metric`; pick
# a metric below (the first figure is static, so it also shows in an HTML export).

# %%
metrics = ["keypoints.recall", "keypoints.precision", "ate.rmse", "rpe.trans.rmse", "tracked"]
display(plot_metric(table, "ate.rmse", THR, [THR]))


def show(metric="ate.rmse"):
    display(plot_metric(table, metric, THR, [THR]))


display(widgets.interactive(show, metric=widgets.Dropdown(options=metrics, value="ate.rmse")))

# %% [markdown]
# **What to look for.** ATE over 8 frames is a few millimetres, and on `walking_xyz` the two seeds (the dots,
# the band) disagree more than the values of $\mu$ do: 8 frames cannot rank $\mu$ by ATE. The keypoint scores
# are the sensitive measure of such short runs; ranking by ATE needs longer sequences and more seeds.

# %% [markdown]
# ## Resume: a run is named by its inputs
# Each folder under `out/runs/` is named by the SHA-256 of everything that decides the run: the sequence (the
# renderer's cache key: preset, length, seed, renderer version), the filter, the detector, the whole config
# and the package version. Starting the sweep again finds every run finished (`summary.json` complete) and
# does nothing; a sweep killed half-way would redo only its unfinished runs.

# %%
again = run_sweep(spec, work / "out", workers=2, progress=False, plots=False)
print(f"again: {again.executed} runs done, {again.skipped} skipped, in {again.seconds:.1f} s")
same = again.table[deterministic_columns(again.table)].equals(table[deterministic_columns(table)])
print("same table (all but the timings):", same)

# %% [markdown]
# ## The same spec on a Dask cluster
# On a cluster, start a scheduler and workers (one thread each: SLAM is Python-heavy), in the same environment
# (`pip install 'dynslam_lab[sweeps]'`), with the output folder on a filesystem every worker sees:
#
# ```bash
# dask scheduler                                           # prints tcp://HOST:8786 and the dashboard :8787
# dask worker tcp://HOST:8786 --nworkers 2 --nthreads 1    # on each machine
# dynslam sweep sweep.toml --out /shared/sweeps/mu --scheduler tcp://HOST:8786
# ```
#
# or put `[dask] scheduler = "tcp://HOST:8786"` in the spec. Here a cluster inside this kernel stands in
# for it, on a smaller spec (one preset, one seed): its rows must equal the pool's.

# %%
from distributed import Client, LocalCluster  # the sweeps extra

SMALL = """
[sweep]
name = "epipolar_mu_small"
filters = ["geometry"]
loop_closing = false

[[sequences]]
preset = "walking_xyz"
n_frames = 8
seed = 0

[grid]
"screening.epipolar.threshold_px" = [0.5, 1.0, 2.0]
"""
(work / "small.toml").write_text(SMALL)
small = load_spec(work / "small.toml")
with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster, \
        Client(cluster) as client:
    print("dashboard:", client.dashboard_link)
    dask_report = run_sweep(small, work / "dask", scheduler=client, progress=False, plots=False)
print(f"{dask_report.executed} runs on a {dask_report.engine}")
det = [c for c in deterministic_columns(table) if c != "run_dir"]  # (the folders differ: two sweeps)
pool_rows = table[(table["sequence"] == "walking_xyz") & (table["seed"] == 0)][det].reset_index(drop=True)
dask_rows = dask_report.table[det].reset_index(drop=True)
pd.testing.assert_frame_equal(pool_rows, dask_rows)  # same run ids (same inputs), same numbers
print("the cluster's 3 runs equal the pool's, run ids included")

# %% [markdown]
# ## Exercises
#
# **Exercise 1: a log range.** In a spec, `{start = 0.25, stop = 4.0, num = 5, scale = "log"}` gives values
# evenly spaced in log between `start` and `stop` (both included). Write `log_range(start, stop, num)` with
# numpy and compare with the library's `expand_values`.

# %%
def log_range(start, stop, num):
    # your code here: return the num values as a list
    return None


answer = log_range(0.25, 4.0, 5)
if answer is None:
    print("exercise 1 not done yet: the check runs on the solution (solutions/11_sweeps.py)")
    answer = solutions.log_range(0.25, 4.0, 5)
assert np.allclose(answer, expand_values({"start": 0.25, "stop": 4.0, "num": 5, "scale": "log"}, "ex1"))
assert np.allclose(answer, [0.25, 0.5, 1.0, 2.0, 4.0])

# %% [markdown]
# **Exercise 2: pooled precision.** The plot averages each seed's precision. Pool the counts instead (a
# micro-average): for each sequence and $\mu$, sum TP and FP over the seeds, then TP / (TP + FP). Write
# `pooled_precision(table)` returning a pandas Series indexed by `(sequence, threshold)`. The check recomputes
# it from each run folder's `sweep_run.json`, not from the table.

# %%
def pooled_precision(table):
    # your code here
    return None


answer = pooled_precision(table)
if answer is None:
    print("exercise 2 not done yet: the check runs on the solution")
    answer = solutions.pooled_precision(table)
counts = {}
for t in tasks:
    kp = json.loads((Path(t.run_dir) / "sweep_run.json").read_text())["keypoints"]
    c = counts.setdefault((t.sequence.label, dict(t.params)[THR]), [0, 0])
    c[0] += kp["tp"]
    c[1] += kp["fp"]
for key, (tp, fp) in counts.items():
    assert np.isclose(answer.loc[key], tp / (tp + fp) if tp + fp else np.nan, equal_nan=True), key

# %% [markdown]
# **Exercise 3: what a changed spec redoes.** Add the value 4.0 to the grid and a third seed to `walking_xyz`.
# Predict how many runs the new spec has and how many of them are already finished in `work / "out"`, as
# `(total, finished)`. The check plans the new spec (no run is done) and asks each run folder.

# %%
def predict_extension():
    # your code here: return (total, finished)
    return None


answer = predict_extension()
if answer is None:
    print("exercise 3 not done yet: the check runs on the solution")
    answer = solutions.predict_extension()
bigger = SPEC.replace("[0.5, 1.0, 2.0]", "[0.5, 1.0, 2.0, 4.0]").replace("seeds = [0, 1]", "seeds = [0, 1, 2]", 1)
(work / "bigger.toml").write_text(bigger)
planned = load_spec(work / "bigger.toml").tasks(work / "out")
assert answer == (len(planned), sum(is_finished(t.run_dir) for t in planned)), (answer, len(planned))
print(f"{len(planned)} runs, {answer[1]} finished: `dynslam sweep bigger.toml --out out` would do {len(planned) - answer[1]}")
