"""The robustness benchmark: every dynamic filter on the stress scenes and the office presets, each
beside the same camera path without movers; worst case and typical per filter (docs/robustness.md).

Usage::

    python benchmarks/robustness.py                        # STRESS_SUITE + office walking presets, 300 frames
    python benchmarks/robustness.py --max-frames 150 --sequences boxes_xyz,walking_rpy
    python benchmarks/robustness.py --frames 240 --sequences random_101,random_102,random_103   # scenes drawn from seeds
    python benchmarks/robustness.py --model /work/shared/data/models/yolox_nano.onnx   # adds full+onnx

Writes OUTDIR/robustness.csv, robustness.md (the tables) and robustness.png (ATE per sequence and
filter), one run folder per (sequence, filter), and resumes an interrupted benchmark from the runs
already finished. Rendering the scenes the first time takes a few minutes (cached afterwards).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

OFFICE = ("walking_xyz", "walking_rpy", "walking_halfsphere", "walking_static", "sitting_xyz", "sitting_halfsphere")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", default=None, help="comma-separated names: stress scenes, random_N (the scene of `dynslam synth random --seed N`), "
                    "office presets (default: STRESS_SUITE + office presets)")
    ap.add_argument("--frames", type=int, default=300, help="frames rendered per sequence (default 300)")
    ap.add_argument("--max-frames", type=int, default=None, help="frames run per sequence (default all rendered)")
    ap.add_argument("--out", default="runs/robustness", help="output folder (default runs/robustness)")
    ap.add_argument("--model", default=None, help="an ONNX detector for the full+onnx filter")
    ap.add_argument("--filters", default=None, help="comma-separated filter labels (default all)")
    ap.add_argument("--no-loop", action="store_true", help="without loop closing")
    ap.add_argument("--fresh", action="store_true", help="rerun finished runs instead of resuming")
    ap.add_argument("--config", default=None, help="a TOML file of parameters for every run (e.g. [orb] truth_region_share = 1.0)")
    args = ap.parse_args(argv)

    from dynslam_lab.config import Config, load_config
    from dynslam_lab.datasets import stress
    from dynslam_lab.experiments.robustness import run_robustness, synthetic_specs

    names = args.sequences.split(",") if args.sequences else [*stress.STRESS_SUITE, *OFFICE]
    t0 = time.time()
    specs = synthetic_specs([n.strip() for n in names if n.strip()], n_frames=args.frames)
    print(f"{len(specs)} sequences ready ({time.time() - t0:.0f} s)")
    only = [f.strip() for f in args.filters.split(",")] if args.filters else None
    def line(r: dict) -> None:
        print(f"{r['sequence']:<20} {r['filter']:<14} ATE {r['ate_rmse_m']:.4f} m  P {r['precision']:.3f} R {r['recall']:.3f}  "
              f"lost {r['lost']} loops {r['loops']}  {r['ms_per_frame']:.0f} ms/frame", flush=True)

    config = load_config(args.config, Config()) if args.config else None
    run_robustness(specs, args.out, config=config, onnx_model=args.model, filters=only, loop_closing=not args.no_loop,
                   resume=not args.fresh, on_run=line, max_frames=args.max_frames)
    print((Path(args.out) / "robustness.md").read_text())
    print(f"wrote {args.out}/robustness.csv, robustness.md, robustness.png ({time.time() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
