"""Time every screening stage per frame on 640x480 synthetic frames; print a table (and each filter's
per-keypoint precision / recall against the renderer's truth).

Usage::

    python benchmarks/screening_speed.py [--preset walking_xyz] [--frames 40] [--filters full]

Renders (cached) a synthetic sequence, extracts ORB keypoints (1000 per frame), runs the oracle
detector, then screens every frame and reports the median / 90th percentile milliseconds of each
stage and of the whole screening (``total``). Detection and ORB are not part of the numbers.
Dense flow runs at quarter resolution (``FlowConfig.scale = 0.25``: 160x120).
The target of the issue: all screening stages together <= 25 ms per frame (median).
"""

from __future__ import annotations

import argparse
import platform

import numpy as np


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="walking_xyz")
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--filters", default="semantic;depth_ransac;geometry;full", help="filters separated by ';'")
    ap.add_argument("--threads", type=int, default=None, help="OpenCV threads (default: OpenCV's choice)")
    args = ap.parse_args(argv)

    import cv2

    from dynslam_lab.datasets.synthetic import synthetic_sequence
    from dynslam_lab.datasets.tum import TumSequence
    from dynslam_lab.detection import build_detector
    from dynslam_lab.experiments.scoring import ScoringScreener
    from dynslam_lab.dynamic.screening import build_screener
    from dynslam_lab.features.orb import extract_features

    if args.threads is not None:
        cv2.setNumThreads(args.threads)
    seq = TumSequence(synthetic_sequence(args.preset, n_frames=args.frames, seed=0))
    det = build_detector("oracle")
    frames = []
    for i in range(len(seq)):
        f = seq[i]
        frames.append((f, extract_features(f.gray).uv.astype(float), det.detect(f)))
    h, w = frames[0][0].shape
    import time

    rows: dict[str, list[float]] = {}
    quality: dict[str, tuple[float, float]] = {}
    for name in [s.strip() for s in args.filters.split(";")]:
        screener = ScoringScreener(build_screener(name))
        timings: dict[str, list[float]] = {}
        for f, uv, d in frames:
            c0 = time.process_time()
            t = screener.screen(f, uv, d)
            timings.setdefault("total CPU (all threads)", []).append((time.process_time() - c0) * 1e3)
            for k, v in t.timings_ms.items():
                timings.setdefault(k, []).append(v)
        quality[name] = (screener.score.precision, screener.score.recall)
        for k, v in timings.items():
            rows[f"{name}:{k}"] = v[1:] if len(v) > 1 else v  # the first frame has no history
    print(f"screening speed, {args.preset}, {len(frames)} frames of {w}x{h}, ~{len(frames[0][1])} keypoints; "
          f"{platform.processor() or platform.machine()}, OpenCV {cv2.__version__}, threads {cv2.getNumThreads()}")
    import os

    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (wall-clock times grow with load; CPU time less so)")
    print(f"{'filter:stage':40s} {'median ms':>10s} {'p90 ms':>10s} {'frames':>7s}")
    for k, v in rows.items():
        a = np.asarray(v)
        print(f"{k:40s} {np.median(a):10.2f} {np.percentile(a, 90):10.2f} {len(a):7d}")
    print()
    print(f"{'filter':16s} {'precision':>10s} {'recall':>10s}   (per keypoint, against the renderer's moving instances)")
    for name, (p, r) in quality.items():
        print(f"{name:16s} {p:10.3f} {r:10.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
