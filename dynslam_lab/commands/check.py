"""``dynslam check``: what a run would take from a sequence folder, said before the run.

Example::

    dynslam check rgbd_dataset_freiburg3_walking_xyz
    dynslam check my_scene --camera default --json
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "check",
        help="check a sequence folder before a run: frames, camera, image size, depth scale, ground truth",
        description=(
            "Read SEQDIR as `dynslam run` would (the lists, the first frame, five depth images, the ground truth) and "
            "report each part: how many colour/depth pairs and at what rate, where the camera's intrinsics come from "
            "(camera.json, the folder's name, or a guess), the image size against the camera, the depth's median in "
            "metres at the camera's depth_scale, how much of the run the ground truth covers, and the synthetic "
            "renderer's masks. Exit code 1 when `dynslam run` would refuse the folder, else 0 (warnings included)."
        ),
    )
    p.add_argument("seqdir", metavar="SEQDIR", help="sequence folder (rgb.txt, depth.txt, rgb/, depth/)")
    p.add_argument("--camera", metavar="PRESET", default=None, help="camera preset, as for `dynslam run`")
    p.add_argument("--config", metavar="FILE.toml", default=None,
                   help="TOML overrides, as for `dynslam run` (tracking.min_depth and max_depth bound the depth)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the report")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..config import Config, load_config
    from ..datasets.check import check_sequence
    from ..jsonio import dumps

    cfg = load_config(args.config, Config()) if args.config else Config()
    rep = check_sequence(args.seqdir, camera=args.camera, min_depth=cfg.tracking.min_depth,
                         max_depth=cfg.tracking.max_depth)
    print(dumps(rep.to_dict()) if args.json else rep.format())
    return 0 if rep.ok else 1
