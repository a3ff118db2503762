"""``dynslam run``: the whole pipeline over one sequence, writing a run folder.

Example::

    dynslam run data/rgbd_dataset_freiburg3_walking_xyz --out runs/wxyz --filters full --detector oracle
    dynslam run SEQ --out runs/x --max-frames 300 --config my.toml --no-loop
    dynslam run SEQ --out runs/x --force      # replace the previous run folder runs/x

OUTDIR must be new or empty; ``--force`` replaces a previous *run folder* (never a folder that
dynslam did not write). Exit codes: 0 done, 1 no frame tracked or unreadable data, 2 usage,
130 Ctrl-C (the partial run folder is consistent: ``summary.json`` says ``complete: false``).
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
    p.add_argument("--out", required=True, metavar="OUTDIR", help="run folder to write (new or empty)")
    p.add_argument("--force", action="store_true",
                   help="replace a previous run folder at OUTDIR (only files dynslam wrote there; never another folder)")
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
    import logging
    import sys

    from ..config import Config, load_config
    from ..datasets.tum import TumSequence
    from ..errors import UsageError
    from ..jsonio import dumps
    from ..pipeline import build_pipeline
    from ..runs import run_sequence

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    if args.max_frames is not None and args.max_frames < 1:
        raise UsageError(f"--max-frames must be >= 1, got {args.max_frames}")
    config = Config()
    if args.config:
        config = load_config(args.config, config)
    seq = TumSequence(args.seqdir, camera=args.camera)
    system = build_pipeline(config, seq.camera, detector=args.detector, filters=args.filters, loop_closing=not args.no_loop)
    summary = run_sequence(seq, args.out, system, max_frames=args.max_frames, progress=not args.quiet,
                           save_labels=args.save_labels, force=args.force)
    short = {k: summary.get(k) for k in ("frames", "tracked", "lost", "keyframes", "map_points", "loops")}
    if summary.get("ate"):
        short["ate_rmse_m"] = summary["ate"].get("rmse")
    short["median_ms"] = {k: round(v, 1) for k, v in summary["timing_median_ms"].items() if v is not None}
    if summary.get("lost_frames"):
        short["lost_frames"] = summary["lost_frames"][:20]
    if summary.get("depth_noise_ratio") is not None:  # the screener's measurement (docs/robustness.md "Another depth sensor")
        short["depth_noise_ratio"] = round(summary["depth_noise_ratio"], 2)
    print(dumps(short))
    if summary["tracked"] == 0:
        first = f"; first error: {summary['errors'][0]}" if summary.get("errors") else ""
        print(f"dynslam run: error: no frame of {args.seqdir} was tracked ({summary['processed']} processed){first}; "
              f"the run folder {args.out} records it", file=sys.stderr)
        return 1
    print(f"wrote {args.out}")
    return 0
