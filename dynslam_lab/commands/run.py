"""``dynslam run``: the whole pipeline over one sequence, writing a run folder.

Example::

    dynslam run data/rgbd_dataset_freiburg3_walking_xyz --out runs/wxyz --filters full --detector oracle
    dynslam run SEQ --out runs/x --max-frames 300 --config my.toml --no-loop
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "run",
        help="run RGB-D SLAM over a TUM-layout sequence and write trajectory, map, timings, summary",
        description=(
            "Track SEQDIR (TUM / Bonn / synthetic layout) with the ORB-SLAM2-style system, the "
            "chosen dynamic-feature filters and detector, and write OUTDIR: trajectory.txt, "
            "timing.csv, summary.json (with ATE/RPE when ground truth exists), keyframes.npz, "
            "map_points.npz, dynamic_points.npz, thumbs/, map.ply."
        ),
    )
    p.add_argument("seqdir", metavar="SEQDIR", help="sequence folder (rgb.txt, depth.txt, rgb/, depth/)")
    p.add_argument("--out", required=True, metavar="OUTDIR", help="run folder to write")
    p.add_argument("--max-frames", type=int, default=None, metavar="N", help="process only the first N frames")
    p.add_argument("--config", default=None, metavar="FILE.toml", help="TOML overrides of any parameter")
    p.add_argument("--filters", default="none", metavar="NAME",
                   help="dynamic filters: none, semantic, depth_ransac, geometry, full, oracle (default none)")
    p.add_argument("--detector", default="none", metavar="SPEC", help="none, oracle, onnx:PATH, cache:DIR (default none)")
    p.add_argument("--no-loop", action="store_true", help="turn loop closing off")
    p.add_argument("--save-labels", action="store_true", help="write each frame's keypoint table to OUTDIR/labels/")
    p.add_argument("--camera", default=None, metavar="PRESET", help="camera preset (default: from the folder name)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json
    import logging

    from ..config import Config, load_config
    from ..datasets.tum import TumSequence
    from ..pipeline import build_pipeline
    from ..runs import run_sequence

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    config = Config()
    if args.config:
        config = load_config(args.config, config)
    if args.max_frames is not None and args.max_frames < 1:
        raise ValueError(f"--max-frames must be >= 1, got {args.max_frames}")
    seq = TumSequence(args.seqdir, camera=args.camera)
    system = build_pipeline(config, seq.camera, detector=args.detector, filters=args.filters, loop_closing=not args.no_loop)
    summary = run_sequence(seq, args.out, system, max_frames=args.max_frames, progress=not args.quiet,
                           save_labels=args.save_labels)
    short = {k: summary.get(k) for k in ("frames", "tracked", "lost", "keyframes", "map_points", "loops")}
    if summary.get("ate"):
        short["ate_rmse_m"] = summary["ate"].get("rmse")
    short["median_ms"] = {k: round(v, 1) for k, v in summary["timing_median_ms"].items() if v is not None}
    if summary.get("lost_frames"):
        short["lost_frames"] = summary["lost_frames"][:20]
    print(json.dumps(short))
    print(f"wrote {args.out}")
    return 0
