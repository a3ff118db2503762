"""``dynslam synth``: render a synthetic dynamic RGB-D sequence in the TUM layout.

Example::

    dynslam synth --list
    dynslam synth walking_xyz out/walking_xyz --frames 120 --seed 1
    dynslam synth boxes_xyz out/boxes_xyz                       # a named stress scene
    dynslam synth boxes_xyz out/boxes_xyz_ref --no-movers       # the same room and camera path, no movers
    dynslam synth random --seed 7 --motion rpy --kinds box,pushed --frames 60 out/r7
"""

from __future__ import annotations

import argparse


class _IntermixedParser(argparse.ArgumentParser):
    """Lets options come between PRESET and OUTDIR (``dynslam synth random --seed 7 OUT``).

    With two optional positionals argparse takes both from the first run of positional words, so the
    OUTDIR after the options would be "unrecognized"; intermixed parsing (argparse's own
    ``parse_known_intermixed_args``) parses the options first and the positionals from what is left.
    """

    _inside = False

    def parse_known_args(self, args=None, namespace=None):
        if self._inside:  # the two passes of the intermixed parse
            return super().parse_known_args(args, namespace)
        self._inside = True
        try:
            return self.parse_known_intermixed_args(args, namespace)
        finally:
            self._inside = False


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "synth",
        help="render a synthetic dynamic RGB-D sequence (TUM layout, with masks and ground truth)",
        description=(
            "Render the textured office with walking or sitting people, a named stress scene (other rooms, movers of "
            "no COCO class), or a random stress scene drawn from --seed, as seen by a moving Kinect-like camera, and "
            "write it in the TUM RGB-D layout (rgb/, depth/, rgb.txt, depth.txt, groundtruth.txt) plus camera.json, "
            "masks/, instances.json, moving.txt, coverage.csv and synthetic.json."
        ),
        epilog="PRESET 'random' draws a stress scene from --seed; the options below the seed fix parts of the draw.",
    )
    p.add_argument("preset", nargs="?", help="preset name (see --list), or 'random'")
    p.add_argument("outdir", nargs="?", help="output folder (created)")
    p.add_argument("--frames", type=int, default=None, metavar="N", help="number of frames (default: the preset's; random: 300)")
    p.add_argument("--seed", type=int, default=0, metavar="S",
                   help="seed of the sensor noise (and the office's textures); for 'random' also of the whole scene (default 0)")
    p.add_argument("--no-movers", action="store_true",
                   help="stress scenes: the same room and camera path without movers (bit-identical where no mover is seen)")
    p.add_argument("--list", action="store_true", help="print the presets and exit")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--force", action="store_true",
                   help="replace a sequence this command wrote before in OUTDIR (never a folder it did not make)")
    g = p.add_argument_group("random stress scenes (PRESET 'random')")
    # (values are checked by random_scene_preset: importing the renderer here would slow down `dynslam --help`)
    g.add_argument("--motion", help="camera motion: static, xyz, rpy, halfsphere or loop (default: drawn among the first four)")
    g.add_argument("--movers", type=int, default=None, metavar="K", help="number of movers 0..4 (default: drawn, 1..4)")
    g.add_argument("--kinds", default=None, metavar="K1,K2",
                   help="comma-separated kind of each mover, from person, box, cart, panel, door, carried, pushed "
                        "(sets the number of movers)")
    g.add_argument("--patterns", default=None, metavar="P1,P2",
                   help="motion pattern of every mover (one) or of each, from pace, stop_go, enter")
    g.add_argument("--style", help="room surfaces: noise, flat, pattern or photo (default: drawn)")
    g.add_argument("--lighting", help="lighting family: even, dim, lamp, bright or window (default: drawn)")
    g.add_argument("--distance", type=float, nargs=2, default=(0.8, 3.0), metavar=("LO", "HI"),
                   help="distance of the movers' paths from the camera, m (default 0.8 3.0)")
    g.add_argument("--speed", type=float, nargs=2, default=(0.4, 2.0), metavar=("LO", "HI"),
                   help="movers' cruise speeds, m/s (default 0.4 2.0)")
    g.add_argument("--max-coverage", type=float, default=0.6, metavar="F",
                   help="bound on a rough estimate of the image fraction the movers cover (default 0.6)")
    p.set_defaults(func=run)
    p.__class__ = _IntermixedParser  # the sub-command parser, made by the main parser, parses intermixed


def _split(value: str | None) -> tuple[str, ...] | None:
    return None if value is None else tuple(v.strip() for v in value.split(",") if v.strip())


def run(args: argparse.Namespace) -> int:
    from ..datasets import stress
    from ..datasets.synthetic import PRESETS, get_preset, preset_names, render_sequence
    from ..runs import OutputFolder

    if args.list:
        print(f"{'preset':<20} {'scene':<12} {'camera motion':<14} {'frames':>6}")
        for name, p in PRESETS.items():
            print(f"{name:<20} {p.scene:<12} {p.motion:<14} {p.n_frames:>6}")
        print("\nstress scenes (STRESS_SUITE, then STRESS_LOOPS; append _nomovers for the scene without movers):")
        print(f"{'preset':<20} {'room':<8} {'light':<7} {'camera motion':<14} {'frames':>6}  movers")
        for name, p in stress.STRESS_PRESETS.items():
            kinds = ", ".join(m.kind for m in p.movers) or "-"
            print(f"{name:<20} {p.style:<8} {p.lighting:<7} {p.motion:<14} {p.n_frames:>6}  {kinds}")
        print(f"{'random':<20} a stress scene drawn from --seed (see dynslam synth --help)")
        return 0
    if not args.preset or not args.outdir:
        raise ValueError("give PRESET and OUTDIR (or --list to see the presets)")
    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames must be at least 1, got {args.frames}")
    if args.preset == "random":
        preset = stress.random_scene_preset(
            args.seed, motion=args.motion, n_movers=args.movers, kinds=_split(args.kinds), patterns=_split(args.patterns),
            style=args.style, lighting=args.lighting, distance=tuple(args.distance), speed=tuple(args.speed),
            max_coverage=args.max_coverage, n_frames=args.frames or 300)
    else:
        random_only = [o for o, v in (("--motion", args.motion), ("--movers", args.movers), ("--kinds", args.kinds),
                                      ("--patterns", args.patterns), ("--style", args.style), ("--lighting", args.lighting))
                       if v is not None]
        if random_only:
            raise ValueError(f"{', '.join(random_only)} only apply to PRESET 'random'")
        if args.preset not in preset_names() and not args.preset.endswith("_nomovers"):
            raise ValueError(f"unknown preset {args.preset!r}; choose one of {', '.join(preset_names())} or 'random'")
        preset = get_preset(args.preset)
    if args.no_movers:
        if not isinstance(preset, stress.StressPreset):
            raise ValueError(f"--no-movers applies to stress scenes; for the office use the static_* presets, not {args.preset!r}")
        preset = preset.without_movers()
    if isinstance(preset, stress.StressPreset):
        print(stress.describe(preset))
    with OutputFolder(args.outdir, kind="synth", force=args.force) as folder:
        out = render_sequence(preset, folder.path, n_frames=args.frames, seed=args.seed, progress=not args.quiet)
    print(f"wrote {out}")
    return 0
