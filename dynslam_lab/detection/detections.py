"""The result of object detection on one frame."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from .coco import COCO_CLASSES

__all__ = ["Detections"]


@dataclass
class Detections:
    """Detections of one image.

    Attributes
    ----------
    boxes : ``(N, 4)`` float32, ``x1, y1, x2, y2`` in pixels of the original image.
    scores : ``(N,)`` float32 confidences in [0, 1].
    class_ids : ``(N,)`` int64 COCO class indices (0 = person, 80 classes).
    masks : ``(N, H, W)`` bool instance masks at image size, or None (box-only detector).
    image_size : ``(H, W)`` of the image the boxes refer to.
    source : which backend made them (``"onnx:yolov8n-seg"``, ``"oracle"``, ...).
    """

    boxes: np.ndarray
    scores: np.ndarray
    class_ids: np.ndarray
    image_size: tuple[int, int]
    masks: np.ndarray | None = None
    source: str = ""
    timings_ms: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.boxes = np.asarray(self.boxes, dtype=np.float32).reshape(-1, 4)
        self.scores = np.asarray(self.scores, dtype=np.float32).reshape(-1)
        self.class_ids = np.asarray(self.class_ids, dtype=np.int64).reshape(-1)
        n = len(self.boxes)
        if len(self.scores) != n or len(self.class_ids) != n:
            raise ValueError(
                f"Detections: {n} boxes, {len(self.scores)} scores, {len(self.class_ids)} class ids (must match)"
            )
        if self.masks is not None:
            self.masks = np.asarray(self.masks, dtype=bool)
            if self.masks.shape != (n, *self.image_size):
                raise ValueError(f"Detections: masks shape {self.masks.shape} != ({n}, {self.image_size[0]}, {self.image_size[1]})")

    def __len__(self) -> int:
        return len(self.boxes)

    @classmethod
    def empty(cls, image_size: tuple[int, int], with_masks: bool = False, source: str = "") -> "Detections":
        h, w = image_size
        return cls(
            np.zeros((0, 4)), np.zeros(0), np.zeros(0, np.int64), (h, w),
            masks=np.zeros((0, h, w), bool) if with_masks else None, source=source,
        )

    @property
    def names(self) -> list[str]:
        """COCO class names of the detections."""
        return [COCO_CLASSES[i] if 0 <= i < len(COCO_CLASSES) else f"class{i}" for i in self.class_ids]

    def select(self, keep: np.ndarray) -> "Detections":
        """The detections at indices / boolean mask ``keep``."""
        return Detections(
            self.boxes[keep], self.scores[keep], self.class_ids[keep], self.image_size,
            masks=None if self.masks is None else self.masks[keep], source=self.source,
            timings_ms=dict(self.timings_ms),
        )

    def grown(self, margin_px: float, source: str | None = None) -> "Detections":
        """The same detections with every box grown by ``margin_px`` on each side (clipped to the
        image) and every mask dilated by as many pixels (a square): where an object seen on an
        earlier frame can be on this one (``detection.stride``). ``source``: the new ``source``
        (default: this one's)."""
        if margin_px < 0:
            raise ValueError(f"Detections.grown: margin_px must be >= 0, got {margin_px}")
        h, w = self.image_size
        boxes = self.boxes.copy()
        boxes[:, :2] -= margin_px
        boxes[:, 2:] += margin_px
        boxes[:, [0, 2]] = np.clip(boxes[:, [0, 2]], 0.0, w - 1.0)
        boxes[:, [1, 3]] = np.clip(boxes[:, [1, 3]], 0.0, h - 1.0)
        masks = self.masks
        r = int(round(margin_px))
        if masks is not None and r > 0 and len(masks):
            k = np.ones((2 * r + 1, 2 * r + 1), np.uint8)  # separable: a few tenths of a ms per mask
            masks = np.stack([cv2.dilate(m.astype(np.uint8), k) > 0 for m in masks])
        return Detections(boxes, self.scores.copy(), self.class_ids.copy(), self.image_size, masks=masks,
                          source=self.source if source is None else source)

    def region_masks(self) -> np.ndarray:
        """``(N, H, W)`` bool: the instance masks, or the filled boxes for a box-only detector."""
        if self.masks is not None:
            return self.masks
        h, w = self.image_size
        out = np.zeros((len(self), h, w), bool)
        b = np.round(self.boxes).astype(int)
        for k, (x1, y1, x2, y2) in enumerate(b):
            out[k, max(y1, 0) : min(y2 + 1, h), max(x1, 0) : min(x2 + 1, w)] = True
        return out

    def instance_at(self, uv: np.ndarray, use_masks: bool = True) -> np.ndarray:
        """For pixels ``(M, 2)``, the index of the detection that contains each one
        (the highest-scoring if several), or -1. Uses masks when present and ``use_masks``,
        otherwise boxes. Vectorised over pixels and detections."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        out = np.full(len(uv), -1, dtype=np.int64)
        if len(self) == 0 or len(uv) == 0:
            return out
        order = np.argsort(-self.scores, kind="stable")
        if use_masks and self.masks is not None:
            h, w = self.image_size
            ui = np.clip(np.round(uv[:, 0]).astype(int), 0, w - 1)
            vi = np.clip(np.round(uv[:, 1]).astype(int), 0, h - 1)
            inside = self.masks[order][:, vi, ui]  # (N, M)
        else:
            b = self.boxes[order]
            inside = (
                (uv[None, :, 0] >= b[:, None, 0]) & (uv[None, :, 0] <= b[:, None, 2])
                & (uv[None, :, 1] >= b[:, None, 1]) & (uv[None, :, 1] <= b[:, None, 3])
            )
        hit = inside.any(axis=0)
        first = inside.argmax(axis=0)
        out[hit] = order[first[hit]]
        return out
