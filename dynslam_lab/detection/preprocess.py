"""Fit an image into a network's fixed input: letterbox or stretch, and the way back.

A detector sees a fixed ``H_in x W_in`` tensor; a TUM frame is 640 x 480. Two common ways:

* **letterbox** (YOLOv5 / YOLOv8, YOLOX): scale by ``r = min(H_in / h, W_in / w)`` keeping
  the aspect ratio, then pad with grey 114, either centred (Ultralytics) or only right and
  bottom (YOLOX);
* **stretch** (NanoDet's default): scale x and y independently to fill the input.

Both are an axis-aligned affine map ``x_in = s_x x + p_x``, ``y_in = s_y y + p_y``; decoders
give boxes in input pixels and :meth:`InputTransform.to_image` maps them back.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["InputTransform", "letterbox", "stretch", "fit_image"]


@dataclass(frozen=True)
class InputTransform:
    """``x_in = sx * x + px``, ``y_in = sy * y + py`` from image to network-input pixels."""

    sx: float
    sy: float
    px: float
    py: float
    image_size: tuple[int, int]  # (h, w) of the original image
    input_size: tuple[int, int]  # (H_in, W_in) of the network input

    def to_image(self, boxes: np.ndarray, clip: bool = True) -> np.ndarray:
        """Map ``(N, 4)`` xyxy boxes from input pixels to image pixels (clipped to the image)."""
        b = np.asarray(boxes, dtype=np.float32).reshape(-1, 4)
        out = np.empty_like(b)
        out[:, 0::2] = (b[:, 0::2] - self.px) / self.sx
        out[:, 1::2] = (b[:, 1::2] - self.py) / self.sy
        if clip:
            h, w = self.image_size
            out[:, 0::2] = np.clip(out[:, 0::2], 0, w)
            out[:, 1::2] = np.clip(out[:, 1::2], 0, h)
        return out

    def to_input(self, boxes: np.ndarray) -> np.ndarray:
        """Map ``(N, 4)`` xyxy boxes from image pixels to input pixels."""
        b = np.asarray(boxes, dtype=np.float32).reshape(-1, 4)
        out = np.empty_like(b)
        out[:, 0::2] = b[:, 0::2] * self.sx + self.px
        out[:, 1::2] = b[:, 1::2] * self.sy + self.py
        return out


def _check_image(image: np.ndarray) -> tuple[int, int]:
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"image: expected (H, W, 3) uint8, got shape {image.shape} dtype {image.dtype}")
    return image.shape[0], image.shape[1]


def letterbox(
    image: np.ndarray, input_size: tuple[int, int], pad_value: int = 114, centre: bool = True
) -> tuple[np.ndarray, InputTransform]:
    """Resize keeping the aspect ratio, then pad to ``input_size``.

    Parameters
    ----------
    image : ``(h, w, 3)`` uint8.
    input_size : ``(H_in, W_in)`` network input, pixels.
    pad_value : grey level of the padding (114 in YOLOv5/v8/X).
    centre : pad both sides equally (Ultralytics); False pads right/bottom only (YOLOX).

    Returns
    -------
    padded : ``(H_in, W_in, 3)`` uint8.
    transform : the image-to-input map.
    """
    h, w = _check_image(image)
    H, W = input_size
    r = min(H / h, W / w)
    nw, nh = max(1, int(round(w * r))), max(1, int(round(h * r)))  # a 2 x 4000 image keeps one row
    resized = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_LINEAR) if (nw, nh) != (w, h) else image
    left = (W - nw) // 2 if centre else 0
    top = (H - nh) // 2 if centre else 0
    out = np.full((H, W, 3), pad_value, dtype=np.uint8)
    out[top : top + nh, left : left + nw] = resized
    return out, InputTransform(nw / w, nh / h, float(left), float(top), (h, w), (H, W))


def stretch(image: np.ndarray, input_size: tuple[int, int]) -> tuple[np.ndarray, InputTransform]:
    """Resize to ``input_size`` ignoring the aspect ratio (NanoDet's ``keep_ratio=False``)."""
    h, w = _check_image(image)
    H, W = input_size
    out = cv2.resize(image, (W, H), interpolation=cv2.INTER_LINEAR) if (H, W) != (h, w) else image
    return out, InputTransform(W / w, H / h, 0.0, 0.0, (h, w), (H, W))


def fit_image(image: np.ndarray, input_size: tuple[int, int], kind: str) -> tuple[np.ndarray, InputTransform]:
    """Dispatch on ``kind``: ``"letterbox"``, ``"letterbox_topleft"`` or ``"stretch"``."""
    if kind == "letterbox":
        return letterbox(image, input_size, centre=True)
    if kind == "letterbox_topleft":
        return letterbox(image, input_size, centre=False)
    if kind == "stretch":
        return stretch(image, input_size)
    raise ValueError(f"preprocess kind {kind!r}: expected 'letterbox', 'letterbox_topleft' or 'stretch'")
