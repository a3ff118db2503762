"""One RGB-D frame as it travels through the system."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..camera import PinholeCamera

__all__ = ["Frame"]


@dataclass
class Frame:
    """An RGB-D frame.

    Attributes
    ----------
    index : position in the sequence (0-based, after association).
    timestamp : seconds (the colour image's timestamp).
    rgb : ``(H, W, 3)`` uint8, RGB channel order.
    depth : ``(H, W)`` float32, metres; 0 where the sensor gave no reading.
    camera : intrinsics.
    T_w_c_gt : ``(4, 4)`` ground-truth pose (camera to world) when known, else None.
    instance_mask : ``(H, W)`` int32 instance ids (0 = background), synthetic data only.
    instance_classes : instance id -> COCO class name, synthetic data only.
    moving_ids : ids of the instances that move in this frame (the renderer's ``moving.txt``),
        synthetic data only; None when unknown.
    rgb_path, depth_path : files the images came from (for messages).
    """

    index: int
    timestamp: float
    rgb: np.ndarray
    depth: np.ndarray
    camera: PinholeCamera
    T_w_c_gt: np.ndarray | None = None
    instance_mask: np.ndarray | None = None
    instance_classes: dict[int, str] = field(default_factory=dict)
    moving_ids: frozenset[int] | None = None
    rgb_path: Path | None = None
    depth_path: Path | None = None

    @property
    def gray(self) -> np.ndarray:
        """``(H, W)`` uint8 grey image (computed once, then cached)."""
        g = self.__dict__.get("_gray")
        if g is None:
            g = cv2.cvtColor(self.rgb, cv2.COLOR_RGB2GRAY)
            self.__dict__["_gray"] = g
        return g

    @property
    def shape(self) -> tuple[int, int]:
        return self.depth.shape[:2]

    def dynamic_mask(self, classes: set[str] | None = None) -> np.ndarray | None:
        """Boolean ``(H, W)`` truth mask of the instances whose class is in ``classes``
        (all instances when None); None when the frame carries no instance mask."""
        if self.instance_mask is None:
            return None
        if classes is None:
            return self.instance_mask > 0
        ids = [i for i, c in self.instance_classes.items() if c in classes]
        return np.isin(self.instance_mask, ids)
