"""``dynslam synth``: render a synthetic dynamic RGB-D sequence in the TUM layout.

Example::

    dynslam synth --list
    dynslam synth walking_xyz out/walking_xyz --frames 120 --seed 1
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "synth",
        help="render a synthetic dynamic RGB-D sequence (TUM layout, with masks and ground truth)",
        description=(
            "Render the textured office with walking or sitting people as seen by a moving "
            "Kinect-like camera, and write it in the TUM RGB-D layout (rgb/, depth/, rgb.txt, "
            "depth.txt, groundtruth.txt) plus camera.json, masks/, instances.json and moving.txt."
        ),
    )
    p.add_argument("preset", nargs="?", help="preset name (see --list)")
    p.add_argument("outdir", nargs="?", help="output folder (created)")
    p.add_argument("--frames", type=int, default=None, metavar="N", help="number of frames (default: the preset's)")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="seed of textures and sensor noise (default 0)")
    p.add_argument("--list", action="store_true", help="print the presets and exit")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..datasets.synthetic import PRESETS, render_sequence

    if args.list:
        print(f"{'preset':<20} {'scene':<12} {'camera motion':<14} {'frames':>6}")
        for name, p in PRESETS.items():
            print(f"{name:<20} {p.scene:<12} {p.motion:<14} {p.n_frames:>6}")
        return 0
    if not args.preset or not args.outdir:
        raise ValueError("give PRESET and OUTDIR (or --list to see the presets)")
    if args.preset not in PRESETS:
        raise ValueError(f"unknown preset {args.preset!r}; choose one of {', '.join(PRESETS)}")
    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames must be at least 1, got {args.frames}")
    out = render_sequence(args.preset, args.outdir, n_frames=args.frames, seed=args.seed, progress=not args.quiet)
    print(f"wrote {out}")
    return 0
