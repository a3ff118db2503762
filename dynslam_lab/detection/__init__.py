"""Semantic detection: COCO boxes and instance masks of a-priori dynamic objects.

``build_detector(spec, config)`` makes the detector the rest of the system calls as
``detector.detect(frame) -> Detections``:

===============  ==============================================================
spec             detector
===============  ==============================================================
``none``         None (no semantic stage)
``oracle``       :class:`OracleDetector`, true instances of synthetic frames
``onnx:PATH``    :class:`OnnxDetector`, any YOLOv8/YOLO11(-seg), YOLOv5, YOLOX,
                 NanoDet or NanoDet-Plus export
``cache:DIR``    :class:`CacheDetector`, detections saved per frame as npz
===============  ==============================================================

A bare path ending in ``.onnx`` is read as ``onnx:PATH``.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from ..datasets.frame import Frame
from .cache import CacheDetector, load_detections, save_detections
from .coco import (
    APRIORI_DYNAMIC,
    ASG_CATEGORIES,
    ASG_PROBABILITIES,
    COCO_CLASSES,
    DYNAMIC_LEVELS,
    class_id,
    dynamic_level,
    is_apriori_dynamic,
    motion_probability,
)
from .config import DetectionConfig, MotionPriorConfig, OracleConfig
from .detections import Detections
from .draw import class_colour, draw_detections
from .nms import box_iou, nms, soft_nms, suppress
from .onnx_detector import LayoutError, ModelLayout, OnnxDetector, recognise_layout
from .oracle import OracleDetector, instances_to_detections

__all__ = [
    "Detector",
    "build_detector",
    "Detections",
    "DetectionConfig",
    "OracleConfig",
    "MotionPriorConfig",
    "OnnxDetector",
    "OracleDetector",
    "CacheDetector",
    "LayoutError",
    "ModelLayout",
    "recognise_layout",
    "instances_to_detections",
    "save_detections",
    "load_detections",
    "draw_detections",
    "class_colour",
    "box_iou",
    "nms",
    "soft_nms",
    "suppress",
    "COCO_CLASSES",
    "APRIORI_DYNAMIC",
    "ASG_CATEGORIES",
    "ASG_PROBABILITIES",
    "DYNAMIC_LEVELS",
    "class_id",
    "is_apriori_dynamic",
    "motion_probability",
    "dynamic_level",
]


@runtime_checkable
class Detector(Protocol):
    """Anything with ``detect(frame) -> Detections`` (boxes in image pixels, RGB input)."""

    def detect(self, frame: Frame) -> Detections: ...


def build_detector(spec: str, config: DetectionConfig | None = None) -> Detector | None:
    """Make the detector named by ``spec``: ``none``, ``oracle``, ``onnx:PATH``, ``cache:DIR``.

    ``cache:DIR`` reads ``DIR``; ``cache:DIR=onnx:PATH`` (or ``=oracle``) fills a missing
    entry with that detector and saves it. Raises ``ValueError`` for an unknown spec and
    ``FileNotFoundError`` for a missing model or cache.
    """
    config = config or DetectionConfig()
    spec = str(spec).strip()
    kind, _, arg = spec.partition(":")
    kind = kind.lower()
    if kind in ("", "none"):
        return None
    if kind == "oracle":
        return OracleDetector(config)
    if kind == "onnx":
        if not arg:
            raise ValueError("detector spec 'onnx:' needs a model path, e.g. onnx:models/yolov8n.onnx")
        return OnnxDetector(arg, config)
    if kind == "cache":
        if not arg:
            raise ValueError("detector spec 'cache:' needs a directory, e.g. cache:runs/dets")
        directory, _, inner = arg.partition("=")
        fallback = build_detector(inner, config) if inner else None
        return CacheDetector(directory, fallback, config)
    if spec.lower().endswith(".onnx"):
        return OnnxDetector(spec, config)
    raise ValueError(f"unknown detector spec {spec!r}: expected none, oracle, onnx:PATH or cache:DIR")
