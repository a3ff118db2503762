"""``dynslam detect``: run an ONNX detector on images and print what it finds.

Example::

    dynslam detect frame.png --model yolov8n.onnx
    dynslam detect rgb/*.png --model yolox_nano.onnx --nms soft --classes person --json
    dynslam detect frame.png --model yolov8n-seg.onnx --save-dir dets/   # npz cache files too

``--save-dir`` is an output folder (``docs/reliability.md``): new or empty, or, with ``--force``,
a previous ``--save-dir`` folder replaced. ``--json`` prints strict JSON (no NaN/Infinity).
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "detect",
        help="detect COCO objects in images with an ONNX model (YOLOv8/YOLO11, YOLOv5, YOLOX, NanoDet)",
        description=(
            "Run an ONNX detector on each IMAGE and print its detections: class name, score "
            "and box (x1 y1 x2 y2, pixels of the image). The model's family is recognised from "
            "its inputs and outputs. With --json, one JSON object per image and line."
        ),
    )
    p.add_argument("images", nargs="+", metavar="IMAGE", help="colour image(s) (PNG/JPEG)")
    p.add_argument("--model", required=True, metavar="MODEL.onnx", help="ONNX detector file")
    p.add_argument("--score", type=float, default=None, metavar="S", help="score threshold (default 0.3)")
    p.add_argument("--nms", choices=("hard", "soft", "none"), default=None, help="suppression (default hard)")
    p.add_argument("--iou", type=float, default=None, metavar="T", help="hard-NMS IoU threshold (default 0.45)")
    p.add_argument("--sigma", type=float, default=None, help="soft-NMS Gaussian sigma (default 0.5)")
    p.add_argument("--classes", nargs="+", default=None, metavar="NAME", help="report only these COCO classes")
    p.add_argument("--config", default=None, metavar="TOML", help="TOML file with a [detection] table")
    p.add_argument("--save-dir", default=None, metavar="DIR",
                   help="also save each image's detections as DIR/STEM.npz (DIR new or empty)")
    p.add_argument("--force", action="store_true", help="replace a previous --save-dir folder")
    p.add_argument("--json", action="store_true", help="one JSON object per image instead of a table")
    p.set_defaults(func=run)


def _config(args: argparse.Namespace):
    """DetectionConfig from --config's [detection] table, then the command-line options."""
    import dataclasses

    from ..config import Config, load_config
    from ..errors import UsageError

    cfg = load_config(args.config, Config()).detection if args.config else Config().detection
    changes = {
        "score_threshold": args.score, "nms": args.nms, "nms_iou": args.iou, "soft_nms_sigma": args.sigma,
        "classes": tuple(args.classes) if args.classes else None,
    }
    try:
        return dataclasses.replace(cfg, **{k: v for k, v in changes.items() if v is not None})
    except ValueError as exc:  # an option out of range (e.g. --score 2)
        raise UsageError(str(exc)) from None


def run(args: argparse.Namespace) -> int:
    import contextlib
    from pathlib import Path

    from ..datasets.tum import load_rgb
    from ..detection import OnnxDetector, save_detections
    from ..errors import UsageError
    from ..jsonio import dumps
    from ..runs import OutputFolder

    stems = [Path(image).stem for image in args.images]
    twice = sorted({s for s in stems if stems.count(s) > 1})
    if args.save_dir and twice:
        raise UsageError(f"--save-dir: several images share the file name stem {twice[:3]}; their detections would "
                         "overwrite each other: run them separately")
    detector = OnnxDetector(args.model, _config(args))
    L = detector.layout
    if not args.json:
        print(f"{Path(args.model).name}: {L.family}, input {L.input_size[1]}x{L.input_size[0]}, "
              f"{L.num_classes} classes, NMS {detector.config.nms}")
    out = OutputFolder(args.save_dir, kind="detections", force=args.force) if args.save_dir else contextlib.nullcontext()
    with out as folder:
        for image in args.images:
            det = detector.detect_image(load_rgb(image))
            if folder is not None:
                stem = Path(image).stem
                folder.record(f"{stem}.npz.tmp.npz")  # save_detections' own temporary file
                folder.record(f"{stem}.npz")
                save_detections(folder.path / stem, det)
            items = [
                {"class": n, "class_id": int(c), "score": round(float(s), 4), "box": [round(float(v), 1) for v in b]}
                for n, c, s, b in zip(det.names, det.class_ids, det.scores, det.boxes)
            ]
            if args.json:
                print(dumps({
                    "image": str(image), "model": str(args.model), "family": L.family,
                    "image_size": list(det.image_size), "has_masks": det.masks is not None,
                    "detections": items, "timings_ms": {k: round(v, 2) for k, v in det.timings_ms.items()},
                }), flush=True)
                continue
            print(f"{image}: {len(det)} detections ({det.timings_ms['inference']:.1f} ms inference)")
            for it in items:
                x1, y1, x2, y2 = it["box"]
                print(f"  {it['class']:<14} {it['score']:.2f}  {x1:7.1f} {y1:7.1f} {x2:7.1f} {y2:7.1f}")
    return 0
