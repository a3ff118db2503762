"""``dynslam demo``: the ablation on the built-in synthetic walking sequence (renders it once, cached).

Example::

    dynslam demo                 # 120 frames of walking_xyz, all filters, tables in runs/demo
    dynslam demo --frames 60 --out /tmp/demo

OUTDIR is an output folder (``docs/reliability.md``): a previous demo there is replaced (it is
recognised by its marker, and only the files the demo wrote are deleted); any other non-empty
folder is refused.
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "demo",
        help="render the synthetic walking_xyz sequence and run the filter ablation on it",
        description=(
            "Render (once, cached) the built-in synthetic walking_xyz sequence: two people walking "
            "in front of a moving RGB-D camera, with ground-truth poses and instance masks. Then run "
            "SLAM with every dynamic filter (none, semantic, depth_ransac, geometry, full, oracle) and "
            "print the ATE RMSE table and per-keypoint precision/recall; files in OUTDIR."
        ),
    )
    p.add_argument("--frames", type=int, default=120, metavar="N", help="frames to render and run (default 120)")
    p.add_argument("--out", default="runs/demo", metavar="DIR",
                   help="output folder (default runs/demo; a previous demo there is replaced)")
    p.add_argument("--preset", default="walking_xyz", metavar="NAME", help="synthetic preset (default walking_xyz)")
    p.add_argument("--seed", type=int, default=0, help="renderer seed (default 0)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..errors import UsageError
    from ..experiments.ablation import DEFAULT_FILTERS, run_ablation
    from ..runs import OutputFolder

    if args.frames < 10:
        raise UsageError(f"--frames must be at least 10, got {args.frames}")
    try:
        from ..datasets.synthetic import synthetic_sequence
    except ImportError as exc:
        raise RuntimeError(f"the synthetic renderer is not available ({exc})") from exc
    with OutputFolder(args.out, kind="demo", force=True, option="a new demo") as folder:
        if folder.replaced:
            print(f"replaced the previous demo in {args.out}")
        print(f"rendering synthetic {args.preset} ({args.frames} frames, cached) ...")
        seqdir = synthetic_sequence(args.preset, n_frames=args.frames, seed=args.seed)
        run_ablation([seqdir], args.out, DEFAULT_FILTERS, detector="oracle", max_frames=args.frames,
                     progress=not args.quiet)
    print((Path(args.out) / "ablation.md").read_text())
    print(f"wrote {args.out}/ablation.csv and ablation.md")
    return 0
