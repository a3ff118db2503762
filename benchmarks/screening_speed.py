"""Time every screening stage per frame inside the SLAM system on 640x480 synthetic frames; print a table
(and each filter's per-keypoint precision / recall against the renderer's truth).

Usage::

    python benchmarks/screening_speed.py [--preset walking_xyz[,boxes_xyz,...]] [--frames 60] [--filters full] [--threads 1] [--config FILE.toml]

Renders (cached) each synthetic sequence (office presets, stress scenes, ``random_N``) and runs the SLAM system
of each filter (``build_pipeline``, the oracle detector for the filters that need one, no loop closing) over it. Screening runs as in a real run: with the
system's context (prediction, local map, the poses of the earlier frames), which the ``screen`` column includes
building. Reported per stage: the median / 90th percentile milliseconds (wall clock) of the frames after the
first 16 (the multi-frame stages have their earlier frames then), the CPU time of screening alone (the number
to compare on a shared machine: wall clock grows with the load) and of the whole system per frame.
Detection and ORB are not part of the screening numbers. With ``oracle`` among the filters (perfect masks, no
screening work) a last table gives each filter's system CPU and wall time per frame as a ratio to it: issue 16 asks
``geometry`` (a failing configuration) for <= 1.5x the same run with masks.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="walking_xyz", help="office presets, stress scenes or random_N, comma-separated (default walking_xyz)")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--filters", default="semantic;depth_ransac;geometry;full", help="filters separated by ';'")
    ap.add_argument("--threads", type=int, default=None, help="OpenCV threads (default: OpenCV's choice)")
    ap.add_argument("--config", default=None, help="a TOML file of parameters for every run (e.g. [screening.reference] room_depth_gain = 0.0)")
    args = ap.parse_args(argv)

    import cv2

    from dynslam_lab.datasets.synthetic import synthetic_sequence
    from dynslam_lab.datasets.tum import TumSequence
    from dynslam_lab.config import Config, load_config
    from dynslam_lab.experiments.robustness import _stress_preset

    config = load_config(args.config, Config()) if args.config else Config()
    if args.threads is not None:
        cv2.setNumThreads(args.threads)
    filters = [f.strip() for f in args.filters.split(";") if f.strip()]
    summary: list[tuple[str, str, float, float, float]] = []  # preset, filter, system CPU, wall, screening CPU (medians)
    for name in [p.strip() for p in args.preset.split(",") if p.strip()]:
        stress_preset = _stress_preset(name, args.frames)
        seq = TumSequence(synthetic_sequence(stress_preset) if stress_preset is not None else synthetic_sequence(name, n_frames=args.frames))
        for row in _one_sequence(name, seq, filters, cv2, config):
            summary.append(row)
    if any(f == "oracle" for _, f, *_ in summary):
        print()
        print("per frame, median over the frames after the first 16: ratio to the same run with perfect masks (oracle)")
        print(f"{'sequence':20s} {'filter':10s} {'system CPU ms':>14s} {'/ oracle':>9s} {'wall ms':>9s} {'/ oracle':>9s} {'screening CPU ms':>17s}")
        base = {p: (c, wl) for p, f, c, wl, _ in summary if f == "oracle"}
        for p, f, c, wl, sc in summary:
            bc, bw = base.get(p, (np.nan, np.nan))
            print(f"{p:20s} {f:10s} {c:14.1f} {c / bc:9.2f} {wl:9.1f} {wl / bw:9.2f} {sc:17.1f}")
    return 0


def _one_sequence(preset: str, seq, filters: list[str], cv2, config) -> list[tuple[str, str, float, float, float]]:
    """Run every filter over one sequence with ``config``; print its stage table and quality; return the summary rows."""
    from dynslam_lab.dynamic.oracle import truth_dynamic
    from dynslam_lab.experiments.scoring import score_keypoints
    from dynslam_lab.pipeline import build_pipeline
    from dynslam_lab.threads import blas_single_thread

    frames = [seq[i] for i in range(len(seq))]
    h, w = frames[0].shape
    warm = min(16, len(frames) - 1)
    rows: dict[str, list[float]] = {}
    quality: dict[str, tuple[float, float, float, float, float]] = {}
    for name in filters:
        det = "none" if name in ("geometry", "oracle") or name.startswith("epipolar") else "oracle"
        system = build_pipeline(config, seq.camera, detector=det, filters=name, loop_closing=False)
        screen_cpu: list[float] = []
        if system.screener is not None:  # `none` screens nothing: only its system time is measured
            screen = system.screener.screen

            def cpu_timed(*a, _screen=screen, _out=screen_cpu, **k):  # CPU time of screening alone (load-proof)
                c0 = time.process_time()
                table = _screen(*a, **k)
                _out.append((time.process_time() - c0) * 1e3)
                return table

            system.screener.screen = cpu_timed
        timings: dict[str, list[float]] = {}
        tp = fp = fn = 0
        cpu, wall = [], []
        with blas_single_thread():
            for k, f in enumerate(frames):
                c0, w0 = time.process_time(), time.perf_counter()
                res = system.process(f)
                cpu.append((time.process_time() - c0) * 1e3)
                wall.append((time.perf_counter() - w0) * 1e3)
                if k < warm:
                    continue
                timings.setdefault("screen (in the system)", []).append(res.timings_ms.get("screen", np.nan))
                for key, v in (res.table.timings_ms if res.table is not None else {}).items():
                    timings.setdefault(key, []).append(v)
                s = score_keypoints(res.dynamic, truth_dynamic(f, res.uv))
                tp, fp, fn = tp + s.tp, fp + s.fp, fn + s.fn
        quality[name] = (tp / max(tp + fp, 1), tp / max(tp + fn, 1), float(np.median(cpu[warm:])),
                         float(np.median(screen_cpu[warm:])) if screen_cpu else float("nan"), float(np.median(wall[warm:])))
        for key, v in timings.items():
            rows[f"{name}:{key}"] = v
    print(f"screening speed, {preset}, {len(frames)} frames of {w}x{h} (first {warm} not counted); "
          f"{platform.processor() or platform.machine()}, OpenCV {cv2.__version__}, threads {cv2.getNumThreads()}")
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (wall-clock times grow with load)")
    print(f"{'filter:stage':44s} {'median ms':>10s} {'p90 ms':>10s} {'frames':>7s}")
    for key, v in rows.items():
        a = np.asarray(v, float)
        print(f"{key:44s} {np.nanmedian(a):10.2f} {np.nanpercentile(a, 90):10.2f} {len(a):7d}")
    print()
    print(f"{'filter':16s} {'precision':>10s} {'recall':>10s} {'screening CPU ms/frame':>23s} {'system CPU ms/frame':>20s}")
    for name, (p, r, c, sc, _) in quality.items():
        print(f"{name:16s} {p:10.3f} {r:10.3f} {sc:23.1f} {c:20.1f}")
    print()
    return [(preset, name, c, wl, sc) for name, (_, _, c, sc, wl) in quality.items()]


if __name__ == "__main__":
    raise SystemExit(main())
