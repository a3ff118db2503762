"""``dynslam eval``: ATE and RPE of an estimated trajectory against ground truth.

Example::

    dynslam eval --gt groundtruth.txt --est run/trajectory.txt
    dynslam eval --gt groundtruth.txt --est traj.txt --align sim3 --delta 1 --delta-unit seconds --json
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "eval",
        help="ATE/RPE of an estimated trajectory against ground truth (TUM format)",
        description=(
            "Associate the poses of EST with GT by nearest timestamp, align EST to GT "
            "(Umeyama), and print the absolute trajectory error and the relative pose error "
            "(RMSE, mean, median, S.D., min, max)."
        ),
    )
    p.add_argument("--gt", required=True, help="ground-truth trajectory (TUM format: t tx ty tz qx qy qz qw)")
    p.add_argument("--est", required=True, help="estimated trajectory (TUM format)")
    p.add_argument(
        "--align", choices=("se3", "sim3", "none"), default="se3",
        help="alignment of EST to GT: rigid (default, RGB-D), with scale (monocular), or none",
    )
    p.add_argument(
        "--max-diff", type=float, default=0.02, metavar="S",
        help="largest time difference of associated poses in seconds (default 0.02, as TUM's scripts)",
    )
    p.add_argument("--delta", type=float, default=1, metavar="N", help="RPE interval (default 1)")
    p.add_argument(
        "--delta-unit", choices=("frames", "seconds"), default="frames",
        help="unit of --delta (default frames)",
    )
    p.add_argument("--all-pairs", action="store_true", help="RPE over all overlapping pairs, not consecutive ones")
    p.add_argument("--dedupe", choices=("error", "first"), default="error",
                   help="rows sharing a timestamp (in GT or EST): an error naming their lines (default), or keep the first")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import math

    from ..errors import UsageError
    from ..evaluation import evaluate, format_report, read_tum_trajectory
    from ..jsonio import dumps

    if not (math.isfinite(args.max_diff) and args.max_diff >= 0):
        raise UsageError(f"--max-diff must be a number >= 0 seconds, got {args.max_diff}")
    if not (math.isfinite(args.delta) and args.delta > 0):
        raise UsageError(f"--delta must be > 0, got {args.delta}")
    if args.delta_unit == "frames" and float(args.delta) != int(args.delta):
        raise UsageError(f"--delta must be a whole number of frames, got {args.delta}")
    delta = int(args.delta) if args.delta_unit == "frames" else float(args.delta)
    gt = read_tum_trajectory(args.gt, duplicates=args.dedupe)
    est = read_tum_trajectory(args.est, duplicates=args.dedupe)
    result = evaluate(
        gt, est, align=args.align, max_diff=args.max_diff, delta=delta, delta_unit=args.delta_unit,
        all_pairs=args.all_pairs, gt_name=args.gt, est_name=args.est,
    )
    if args.json:
        print(dumps(result))
    else:
        print(format_report(result))
    return 0
