"""``dynslam sweep``: a parameter sweep (sequences x filters x detectors x a grid) on a process pool
or a Dask cluster, resumable, with a tidy table and sensitivity plots.

Example::

    dynslam sweep sweep.toml --out runs/sweep               # local pool, one worker per core
    dynslam sweep sweep.toml --out runs/sweep --workers 1
    dynslam sweep sweep.toml --out /shared/sweep --scheduler tcp://10.0.0.5:8786
    dynslam sweep sweep.toml --out runs/sweep --dry-run     # list the runs, run nothing

The spec format is in docs/sweeps.md (and :mod:`dynslam_lab.experiments.sweep_spec`).
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "sweep",
        help="run a parameter sweep (one SLAM run per sequence, seed, filter and grid point) and tabulate it",
        description=(
            "Run every combination of SPEC.toml's sequences, seeds, filters, detectors and parameter grid "
            "(dotted config keys) into OUTDIR/runs/RUN_ID (RUN_ID: a hash of the run's inputs), on a local "
            "process pool (--workers) or a Dask cluster (--scheduler or the spec's [dask] section). Runs "
            "finished earlier are skipped, so a killed sweep is resumed by running it again. Writes "
            "OUTDIR/results.csv (one row per run: parameters and every metric of summary.json, keypoint "
            "precision/recall on synthetic sequences) and OUTDIR/plots/METRIC__PARAM.png."
        ),
    )
    p.add_argument("spec", metavar="SPEC.toml", help="the sweep spec (docs/sweeps.md)")
    p.add_argument("--out", required=True, metavar="OUTDIR", help="sweep folder (an existing one is resumed)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="local worker processes (default: one per available core; 0 = in this process)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler, e.g. tcp://HOST:8786 (needs the sweeps extra; OUTDIR must be shared)")
    p.add_argument("--no-plots", action="store_true", help="write the table only")
    p.add_argument("--dry-run", action="store_true", help="list the runs and which are finished; run nothing")
    p.add_argument("--quiet", action="store_true", help="no progress bar or status lines")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import logging
    from pathlib import Path

    from ..experiments.sweep import is_finished, run_sweep
    from ..experiments.sweep_spec import load_spec

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    spec = load_spec(args.spec)
    if args.workers is not None and args.workers < 0:
        raise ValueError(f"--workers must be >= 0, got {args.workers}")
    if args.dry_run:
        tasks = spec.tasks(args.out)
        finished = 0
        for t in tasks:
            done = is_finished(t.run_dir)
            finished += done
            params = " ".join(f"{k}={v!r}" for k, v in t.params)
            seed = f" seed {t.sequence.seed}" if t.sequence.synthetic else ""
            print(f"{t.run_id}  {'done' if done else 'todo'}  {t.sequence.label}{seed}  {t.filters}  {t.detector}  {params}")
        print(f"{len(tasks)} runs, {finished} finished, {len(tasks) - finished} to do")
        return 0
    report = run_sweep(spec, args.out, workers=args.workers, scheduler=args.scheduler, progress=not args.quiet,
                       plots=not args.no_plots)
    out = Path(report.out)
    print(f"{report.total} runs: {report.executed - report.failed} done now, {report.skipped} done before, "
          f"{report.failed} failed ({report.seconds:.1f} s on a {report.engine})")
    print(f"wrote {out / 'results.csv'}" + (f" and {len(report.plots)} plots in {out / 'plots'}" if report.plots else ""))
    return 1 if report.failed else 0
