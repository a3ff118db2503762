"""Draw detections on an image: boxes, labels and translucent instance masks.

Used by notebook 03 and by anyone who wants to look at what a detector saw. Returns a new
RGB image; nothing is drawn in place.
"""

from __future__ import annotations

import cv2
import numpy as np

from .detections import Detections

__all__ = ["class_colour", "draw_detections"]


def class_colour(class_id: int) -> tuple[int, int, int]:
    """A fixed, well-separated RGB colour per class id (golden-ratio hue steps)."""
    hue = int((class_id * 0.618033988749895 % 1.0) * 179)
    hsv = np.uint8([[[hue, 200, 255]]])
    r, g, b = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0]
    return int(r), int(g), int(b)


def draw_detections(
    rgb: np.ndarray,
    det: Detections,
    mask_alpha: float = 0.45,
    thickness: int = 2,
    labels: bool = True,
) -> np.ndarray:
    """Boxes, ``name score`` labels and masks of ``det`` over ``rgb``.

    Parameters
    ----------
    rgb : ``(H, W, 3)`` uint8 RGB image the detections refer to.
    det : the detections (boxes in pixels of ``rgb``).
    mask_alpha : opacity of the instance masks (0 = boxes only).
    thickness : box line width, pixels.
    labels : write class name and score above each box.

    Returns
    -------
    ``(H, W, 3)`` uint8 RGB image.
    """
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"rgb: expected (H, W, 3) uint8, got {rgb.shape} {rgb.dtype}")
    if tuple(rgb.shape[:2]) != tuple(det.image_size):
        raise ValueError(f"rgb is {rgb.shape[:2]} but the detections refer to a {det.image_size} image")
    out = rgb.copy()
    colours = [class_colour(int(c)) for c in det.class_ids]
    if det.masks is not None and mask_alpha > 0 and len(det):
        tint = np.zeros_like(out, dtype=np.float32)
        weight = np.zeros(out.shape[:2], dtype=np.float32)
        for m, col in zip(det.masks, colours):  # one vectorised blend per detection
            tint[m] = col
            weight[m] = mask_alpha
        out = (out * (1 - weight[..., None]) + tint * weight[..., None]).astype(np.uint8)
    for box, col, name, score in zip(det.boxes, colours, det.names, det.scores):
        x1, y1, x2, y2 = (int(round(v)) for v in box)
        cv2.rectangle(out, (x1, y1), (x2 - 1, y2 - 1), col, thickness)
        if labels:
            text = f"{name} {score:.2f}"
            (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
            ty = max(y1, th + 4)
            cv2.rectangle(out, (x1, ty - th - 4), (x1 + tw + 2, ty), col, -1)
            cv2.putText(out, text, (x1 + 1, ty - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return out
