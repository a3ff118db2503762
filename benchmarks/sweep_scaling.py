"""Scaling of ``dynslam sweep``: the same 24-run sweep on 1 and 2 local workers and on a Dask LocalCluster.

Run::

    python benchmarks/sweep_scaling.py [--frames 30] [--repeats 1] [--out /tmp/sweep_scaling]

The sweep: 3 epipolar thresholds x 2 filters (geometry, full) x 4 short synthetic presets
(walking_xyz, walking_static, walking_rpy, walking_halfsphere; seed 0, ``--frames`` frames).
The sequences are rendered first (the cache is warm for every measurement), then each engine runs
the whole sweep into a fresh folder, back to back (1 worker, 2 workers, ..., ``--repeats`` times,
alternating). Prints one row per sweep: engine, wall seconds, CPU seconds of the workers
(children's user + system time; the in-process Dask cluster's is this process's), the speed-up
over the median 1-worker wall time, and whether its table equals the first 1-worker table on
every column that is not a timing. The target: 2 workers take about half the time of 1 on an
idle 2-core machine. On a shared machine the ratio tells more than the seconds; the load average
is printed with each row, and ``others_cores``: the cores the machine's other processes kept busy
on average during that sweep (from ``/proc/stat``): what was left for the sweep.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.experiments.sweep import deterministic_columns, run_sweep
from dynslam_lab.experiments.sweep_spec import load_spec

PRESETS = ("walking_xyz", "walking_static", "walking_rpy", "walking_halfsphere")

SPEC = """
[sweep]
name = "scaling"
filters = ["geometry", "full"]
loop_closing = false
{sequences}
[grid]
"screening.epipolar.threshold_px" = [0.5, 1.0, 2.0]
"""


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _self_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _machine_busy() -> float:
    """CPU seconds the whole machine has been busy (all processes, all cores; Linux /proc/stat)."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]
    except OSError:  # not Linux
        return float("nan")
    user, nice, system, idle, iowait, irq, softirq, steal = (int(v) for v in fields[:8])
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=30, help="frames per sequence (default 30)")
    ap.add_argument("--repeats", type=int, default=1, help="rounds of (1 worker, 2 workers) (default 1)")
    ap.add_argument("--out", default=None, help="folder for the sweeps (default: a temporary folder)")
    ap.add_argument("--no-dask", action="store_true", help="skip the LocalCluster sweep")
    args = ap.parse_args()
    root = Path(args.out or tempfile.mkdtemp(prefix="sweep_scaling_"))
    root.mkdir(parents=True, exist_ok=True)
    seqs = "".join(f'\n[[sequences]]\npreset = "{p}"\nn_frames = {args.frames}\nseed = 0\n' for p in PRESETS)
    (root / "scaling.toml").write_text(SPEC.format(sequences=seqs))
    spec = load_spec(root / "scaling.toml")
    for p in PRESETS:  # a warm cache for every measurement
        synthetic_sequence(p, n_frames=args.frames, seed=0)
    n = len(spec.tasks(root / "x"))
    print(f"sweep: {n} runs (3 thresholds x 2 filters x {len(PRESETS)} presets x {args.frames} frames); "
          f"{os.cpu_count()} cores; folder {root}")
    rows = []
    reference = None
    plan = [("pool", w) for _ in range(args.repeats) for w in (1, 2)] + ([] if args.no_dask else [("dask", 2)])
    for i, (engine, workers) in enumerate(plan):
        out = root / f"{i:02d}_{engine}{workers}"
        shutil.rmtree(out, ignore_errors=True)
        load = os.getloadavg()[0]
        c0, s0, m0 = _children_cpu(), _self_cpu(), _machine_busy()
        t0 = time.perf_counter()
        if engine == "pool":
            report = run_sweep(spec, out, workers=workers, progress=False, plots=False)
            wall = time.perf_counter() - t0
            label = f"process pool, {workers} worker{'s' if workers > 1 else ''}"
        else:
            from distributed import Client, LocalCluster  # optional: the sweeps extra

            with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
                    Client(cluster) as client:
                t0 = time.perf_counter()  # the cluster's start-up is not the sweep's
                report = run_sweep(spec, out, scheduler=client, progress=False, plots=False)
                wall = time.perf_counter() - t0
            label = f"Dask LocalCluster, {workers} processes"
        cpu = (_children_cpu() - c0) + (_self_cpu() - s0)
        others = (_machine_busy() - m0 - cpu) / wall
        table = pd.read_csv(out / "results.csv")
        cols = deterministic_columns(table)
        if reference is None:
            reference = table
        same = table[cols].reset_index(drop=True).equals(reference[cols].reset_index(drop=True))
        rows.append({"engine": label, "workers": workers, "wall_s": wall, "cpu_s": cpu, "failed": report.failed,
                     "same_table": same, "load_1min": load, "others_cores": others})
        print(f"  {label}: {wall:.1f} s wall, {cpu:.1f} s CPU, load {load:.1f}, other processes used {others:.2f} cores",
              flush=True)
    df = pd.DataFrame(rows)
    one = float(np.median(df.loc[(df["workers"] == 1), "wall_s"]))
    df["speed_up"] = one / df["wall_s"]
    print()
    print(df.to_string(index=False, float_format=lambda v: f"{v:.2f}"))


if __name__ == "__main__":
    main()
