"""Tracking speed of the SLAM core: milliseconds per frame and stage, at 640x480.

Targets (issue 3): median tracking time per frame (ORB extraction + tracking, local mapping
excluded) <= 40 ms; the whole frame including local mapping <= 80 ms on average.
ORB-SLAM2 (C++, laptop CPU) reports 36 ms per frame for tracking.

Frames are loaded before timing (disk and PNG decoding are not SLAM). Usage::

    python benchmarks/tracking_speed.py                     # synthetic static_xyz, 300 frames
    python benchmarks/tracking_speed.py --preset static_halfsphere --frames 150
    python benchmarks/tracking_speed.py --seq path/to/tum_sequence --frames 300
    python benchmarks/tracking_speed.py --preset walking_xyz --frames 120 --filters full \
        --detector onnx:/work/shared/data/models/yolox_nano.onnx [--no-overlap]

With a detector, detection runs beside ORB extraction (``tracking.overlap_detection``) unless
``--no-overlap``; the table then shows the sum of the stages beside the frame's wall time.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="static_xyz", help="synthetic preset (default static_xyz)")
    ap.add_argument("--seq", default=None, help="a TUM-layout sequence folder instead of a synthetic preset")
    ap.add_argument("--frames", type=int, default=300, help="frames to run (default 300)")
    ap.add_argument("--detector", default="none", help="detector spec (none, oracle, onnx:PATH)")
    ap.add_argument("--filters", default="none", help="dynamic filters (none, geometry, full, ...)")
    ap.add_argument("--no-overlap", action="store_true", help="detection after ORB, not beside it")
    ap.add_argument("--detect-threads", type=int, default=None, help="onnxruntime intra-op threads (detection.num_threads)")
    args = ap.parse_args()

    from dataclasses import replace

    from dynslam_lab.config import Config
    from dynslam_lab.datasets.tum import TumSequence
    from dynslam_lab.pipeline import build_pipeline
    from dynslam_lab.threads import blas_single_thread

    if args.seq:
        seq = TumSequence(args.seq, max_frames=args.frames)
    else:
        from dynslam_lab.datasets.synthetic import synthetic_sequence

        seq = TumSequence(synthetic_sequence(args.preset, n_frames=args.frames))
    frames = [seq[i] for i in range(min(args.frames, len(seq)))]
    for f in frames:
        _ = f.gray  # colour conversion is the dataset's, not the tracker's
    cfg = Config()
    cfg = replace(cfg, tracking=replace(cfg.tracking, overlap_detection=not args.no_overlap))
    if args.detect_threads is not None:
        cfg = replace(cfg, detection=replace(cfg.detection, num_threads=args.detect_threads))
    system = build_pipeline(cfg, seq.camera, detector=args.detector, filters=args.filters, loop_closing=False)
    rows = []
    t0 = time.perf_counter()
    with blas_single_thread():
        for f in frames:
            r = system.process(f)
            rows.append({**r.timings_ms, "kf": r.is_keyframe, "ok": r.tracked})
    wall = time.perf_counter() - t0
    stages = ["orb", "detect", "screen", "track", "local_mapping", "loop", "total"]
    T = {s: np.array([r.get(s, 0.0) for r in rows]) for s in stages}
    tracking = T["orb"] + T["track"]
    kf = np.array([r["kf"] for r in rows])
    print(f"detector: {args.detector}  filters: {args.filters}  overlap: {not args.no_overlap}  "
          f"detection.num_threads: {cfg.detection.num_threads}")
    print(f"sequence: {seq.root.name}  frames: {len(rows)}  tracked: {sum(r['ok'] for r in rows)}  "
          f"keyframes made: {int(kf.sum())}  wall: {wall:.1f} s")
    print()
    print(f"| {'stage':<28} | {'median ms':>9} | {'mean ms':>8} | {'p90 ms':>7} |")
    print(f"|{'-' * 30}|{'-' * 11}|{'-' * 10}|{'-' * 9}|")
    stage_sum = sum(T[s] for s in stages[:-1])
    for name, v in [("ORB extraction", T["orb"]), ("detection", T["detect"]), ("screening", T["screen"]),
                    ("tracking", T["track"]), ("ORB + tracking", tracking),
                    ("local mapping (keyframes)", T["local_mapping"][kf] if kf.any() else np.zeros(1)),
                    ("sum of stages", stage_sum), ("whole frame (wall)", T["total"])]:
        print(f"| {name:<28} | {np.median(v):9.1f} | {np.mean(v):8.1f} | {np.percentile(v, 90):7.1f} |")
    print()
    med, mean = float(np.median(tracking)), float(np.mean(T["total"]))
    print(f"median ORB + tracking: {med:.1f} ms (target 40 ms, ratio {med / 40:.2f}; ORB-SLAM2 C++ 36 ms)")
    print(f"mean whole frame incl. local mapping: {mean:.1f} ms (target 80 ms, ratio {mean / 80:.2f})")


if __name__ == "__main__":
    main()
