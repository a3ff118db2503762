"""Camera effects benchmark: the filters on sequences as another camera would record them (auto-exposure, blur,
vignetting and another response, more noise, 15 and 10 frames a second, half and 1.5 times the resolution, a noisier
or misregistered depth), against the same filters on the unchanged sequences (docs/robustness.md, "Camera effects").

Usage::

    python benchmarks/camera_effects.py --sequences boxes_xyz,crowd_rpy,random_183 --frames 240
    python benchmarks/camera_effects.py --sequences random_190 --effects exposure,vignette --filters geometry
    python benchmarks/camera_effects.py --roots SEQDIR1,SEQDIR2 --filters none,geometry   # any TUM-layout folders

Writes OUTDIR/camera_effects.csv and camera_effects.md, the copies under OUTDIR/sequences/ and one run folder per
(sequence, effect, filter); an interrupted benchmark resumes from the runs already finished.
"""

from __future__ import annotations

import argparse
import time


def main(argv: list[str] | None = None) -> int:
    from dynslam_lab.datasets.camera_effects import EFFECT_PRESETS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", default=None, help="comma-separated synthetic names (stress scenes, random_N, office presets)")
    ap.add_argument("--roots", default=None, help="comma-separated folders of sequences in the TUM layout (with ground truth)")
    ap.add_argument("--frames", type=int, default=240, help="frames rendered per synthetic sequence (default 240)")
    ap.add_argument("--max-frames", type=int, default=None, help="frames run per sequence (default all)")
    ap.add_argument("--effects", default=",".join(EFFECT_PRESETS), help=f"comma-separated effects (default all: {', '.join(EFFECT_PRESETS)})")
    ap.add_argument("--filters", default="geometry,full+oracle", help="comma-separated filter labels (default geometry,full+oracle)")
    ap.add_argument("--model", default=None, help="an ONNX detector for the full+onnx filter")
    ap.add_argument("--loop", action="store_true", help="with loop closing (default without)")
    ap.add_argument("--fresh", action="store_true", help="rerun finished runs instead of resuming")
    ap.add_argument("--config", default=None, help="a TOML file of parameters for every run")
    ap.add_argument("--out", default="runs/camera_effects", help="output folder (default runs/camera_effects)")
    args = ap.parse_args(argv)

    from dynslam_lab.config import Config, load_config
    from dynslam_lab.experiments.camera_effects import camera_effects_markdown, run_camera_effects
    from dynslam_lab.experiments.robustness import root_specs, synthetic_specs

    if not args.sequences and not args.roots:
        ap.error("give --sequences or --roots")
    unknown = [e for e in args.effects.split(",") if e.strip() and e.strip() not in EFFECT_PRESETS]
    if unknown:
        ap.error(f"unknown effects {unknown}; choose from {list(EFFECT_PRESETS)}")
    effects = {e.strip(): EFFECT_PRESETS[e.strip()] for e in args.effects.split(",") if e.strip()}
    t0 = time.time()
    specs = synthetic_specs([n.strip() for n in args.sequences.split(",") if n.strip()], n_frames=args.frames) if args.sequences else []
    try:
        specs += root_specs(args.roots or "")
    except ValueError as exc:
        ap.error(str(exc))
    print(f"{len(specs)} sequences ready ({time.time() - t0:.0f} s)")

    def line(r: dict) -> None:
        print(f"{r['sequence']:<18} {r['effect']:<9} {r['filter']:<12} ATE {r['ate_rmse_m']:.4f} m  lost {r['lost']}  "
              f"{r['ms_per_frame']:.0f} ms/frame", flush=True)

    config = load_config(args.config, Config()) if args.config else None
    df = run_camera_effects(specs, args.out, effects, [f.strip() for f in args.filters.split(",") if f.strip()], config,
                            args.max_frames, loop_closing=args.loop, resume=not args.fresh, on_run=line, onnx_model=args.model)
    print(camera_effects_markdown(df))
    print(f"wrote {args.out}/camera_effects.csv, camera_effects.md ({time.time() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
