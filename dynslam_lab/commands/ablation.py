"""``dynslam ablation``: every screening filter on one or more sequences, ATE table like the papers.

Example::

    dynslam ablation data/synthetic/walking_xyz --out runs/ablation
    dynslam ablation SEQ1 SEQ2 --detector onnx:models/yolov8n-seg.onnx --filters none,semantic,full

OUTDIR is an output folder like a run's (``docs/reliability.md``): new or empty, or, with
``--force``, a previous ablation folder replaced.
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "ablation",
        help="run SLAM once per dynamic filter and tabulate ATE RMSE and keypoint precision/recall",
        description=(
            "Run the SLAM system on each SEQDIR once per filter (none, semantic, depth_ransac, geometry, "
            "full, oracle) and write OUTDIR/ablation.csv and OUTDIR/ablation.md: ATE RMSE per filter "
            "like YOLO-SLAM Table 3 / Chang et al. Table I, improvement over 'none', and per-keypoint "
            "precision/recall of the dynamic verdict on synthetic sequences."
        ),
    )
    p.add_argument("seqdirs", nargs="+", metavar="SEQDIR", help="sequence folder(s) in TUM layout")
    p.add_argument("--out", default="runs/ablation", metavar="OUTDIR", help="output folder, new or empty (default runs/ablation)")
    p.add_argument("--force", action="store_true", help="replace a previous ablation folder at OUTDIR")
    p.add_argument("--filters", default="none;semantic;depth_ransac;geometry;full;oracle", metavar="LIST",
                   help="filters separated by ';' (a filter may itself be a comma-separated stage list); "
                        "default none;semantic;depth_ransac;geometry;full;oracle (oracle on synthetic only)")
    p.add_argument("--detector", default="auto", metavar="SPEC",
                   help="oracle, onnx:PATH or cache:DIR; default auto = oracle on synthetic sequences")
    p.add_argument("--max-frames", type=int, default=None, metavar="N", help="frames per run (default all)")
    p.add_argument("--config", default=None, metavar="FILE.toml", help="TOML overrides of any parameter")
    p.add_argument("--loop", action="store_true", help="also run loop closing (off by default)")
    p.add_argument("--camera", default=None, metavar="PRESET", help="camera preset (default: from the folder name)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def split_filters(text: str) -> list[str]:
    """``"none;semantic;full"`` -> list; a plain comma list of *filter names* is accepted too."""
    from ..dynamic.screening import FILTERS

    text = text.strip()
    if ";" in text:
        return [t.strip() for t in text.split(";") if t.strip()]
    parts = [t.strip() for t in text.split(",") if t.strip()]
    if all(p in FILTERS for p in parts):
        return parts
    return [text]  # one comma-separated stage list


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..config import Config, load_config
    from ..errors import UsageError
    from ..experiments.ablation import run_ablation
    from ..runs import OutputFolder

    if args.max_frames is not None and args.max_frames < 2:
        raise UsageError(f"--max-frames must be >= 2, got {args.max_frames}")
    config = Config()
    if args.config:
        config = load_config(args.config, config)
    with OutputFolder(args.out, kind="ablation", force=args.force):
        run_ablation(args.seqdirs, args.out, split_filters(args.filters), detector=args.detector, config=config,
                     max_frames=args.max_frames, loop_closing=args.loop, progress=not args.quiet, camera=args.camera)
    print((Path(args.out) / "ablation.md").read_text())
    print(f"wrote {args.out}/ablation.csv and ablation.md")
    return 0
