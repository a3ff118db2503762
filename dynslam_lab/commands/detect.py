"""``dynslam detect``: run an ONNX detector on images and print what it finds.

Example::

    dynslam detect frame.png --model yolov8n.onnx
    dynslam detect rgb/*.png --model yolox_nano.onnx --nms soft --classes person --json
    dynslam detect frame.png --model yolov8n-seg.onnx --save-dir dets/   # npz cache files too
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
    p.add_argument("--save-dir", default=None, metavar="DIR", help="also save each image's detections as DIR/STEM.npz")
    p.add_argument("--json", action="store_true", help="one JSON object per image instead of a table")
    p.set_defaults(func=run)


def _config(args: argparse.Namespace):
    """DetectionConfig from --config's [detection] table, then the command-line options."""
    import dataclasses
    import sys
    from pathlib import Path

    from ..config import with_overrides
    from ..detection import DetectionConfig

    cfg = DetectionConfig()
    if args.config:
        if sys.version_info >= (3, 11):
            import tomllib
        else:  # pragma: no cover - Python 3.10
            import tomli as tomllib  # type: ignore[no-redef]
        path = Path(args.config)
        if not path.is_file():
            raise ValueError(f"{path}: config file not found")
        try:
            data = tomllib.loads(path.read_text())
            cfg = with_overrides(cfg, data.get("detection", {}), "detection")
        except (tomllib.TOMLDecodeError, ValueError) as exc:
            raise ValueError(f"{path}: {exc}") from exc
    changes = {
        "score_threshold": args.score, "nms": args.nms, "nms_iou": args.iou, "soft_nms_sigma": args.sigma,
        "classes": tuple(args.classes) if args.classes else None,
    }
    return dataclasses.replace(cfg, **{k: v for k, v in changes.items() if v is not None})


def run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from ..datasets.tum import load_rgb
    from ..detection import OnnxDetector, save_detections

    detector = OnnxDetector(args.model, _config(args))
    L = detector.layout
    if not args.json:
        print(f"{Path(args.model).name}: {L.family}, input {L.input_size[1]}x{L.input_size[0]}, "
              f"{L.num_classes} classes, NMS {detector.config.nms}")
    for image in args.images:
        det = detector.detect_image(load_rgb(image))
        if args.save_dir:
            save_detections(Path(args.save_dir) / Path(image).stem, det)
        items = [
            {"class": n, "class_id": int(c), "score": round(float(s), 4), "box": [round(float(v), 1) for v in b]}
            for n, c, s, b in zip(det.names, det.class_ids, det.scores, det.boxes)
        ]
        if args.json:
            print(json.dumps({
                "image": str(image), "model": str(args.model), "family": L.family,
                "image_size": list(det.image_size), "has_masks": det.masks is not None,
                "detections": items, "timings_ms": {k: round(v, 2) for k, v in det.timings_ms.items()},
            }))
            continue
        print(f"{image}: {len(det)} detections ({det.timings_ms['inference']:.1f} ms inference)")
        for it in items:
            x1, y1, x2, y2 = it["box"]
            print(f"  {it['class']:<14} {it['score']:.2f}  {x1:7.1f} {y1:7.1f} {x2:7.1f} {y2:7.1f}")
    return 0
