"""An oracle detector: the synthetic renderer's true instances, made imperfect on purpose.

Synthetic frames carry ``instance_mask`` (``(H, W)`` int ids, 0 = background) and
``instance_classes`` (id -> COCO name). The oracle reports each instance as one detection
with its tight box and exact mask, then degrades the result the way a real network does, so a
notebook can show how the dynamic filters cope:

* **misses**: each instance is dropped with probability ``miss_rate``;
* **box jitter**: each box corner moves by ``N(0, (jitter * size)^2)`` pixels, and the mask
  is shifted with the box centre (a localisation error, not a new shape);
* **false positives**: ``Poisson(false_positives)`` extra boxes of a chosen class at random
  places, with a filled-box mask, scores uniform in ``[score_threshold, 1)``.

True detections get score 1. Randomness comes from a generator seeded by
``(oracle.seed, frame.index)``: the same frame gives the same detections whatever the order
in which frames are processed.
"""

from __future__ import annotations

import numpy as np

from ..datasets.frame import Frame
from scipy import ndimage

from .coco import COCO_CLASSES, class_id
from .config import DetectionConfig
from .detections import Detections

__all__ = ["OracleDetector", "instances_to_detections"]

_COCO_INDEX = {name: i for i, name in enumerate(COCO_CLASSES)}


def instances_to_detections(
    instance_mask: np.ndarray, instance_classes: dict[int, str], min_area: int = 1, source: str = "oracle"
) -> Detections:
    """Perfect detections of every instance in an instance-id image.

    Parameters
    ----------
    instance_mask : ``(H, W)`` int instance ids, 0 = background.
    instance_classes : id -> COCO class name; ids missing here (or with a non-COCO name)
        are skipped.
    min_area : instances with fewer pixels are skipped.

    Returns
    -------
    Detections with tight boxes (``x2 = max column + 1``: pixel edges), score 1, masks.
    """
    m = np.asarray(instance_mask)
    if m.ndim != 2:
        raise ValueError(f"instance_mask: expected (H, W) ids, got shape {m.shape}")
    h, w = m.shape
    labels = np.where(m > 0, m, 0).astype(np.int64)
    slices = ndimage.find_objects(labels)  # bounding slices of ids 1..max, one pass
    area = np.bincount(labels.ravel(), minlength=len(slices) + 1)
    keep_ids, boxes, cls = [], [], []
    for i, name in sorted(instance_classes.items()):  # one entry per instance, not per pixel
        if i <= 0 or i > len(slices) or slices[i - 1] is None or area[i] < max(min_area, 1):
            continue
        if name not in _COCO_INDEX:
            continue  # not a COCO class: no detector would report it
        sy, sx = slices[i - 1]
        keep_ids.append(i)
        boxes.append((sx.start, sy.start, sx.stop, sy.stop))
        cls.append(_COCO_INDEX[name])
    if not keep_ids:
        return Detections.empty((h, w), with_masks=True, source=source)
    masks = np.zeros((len(keep_ids), h, w), dtype=bool)
    for k, (i, (x1, y1, x2, y2)) in enumerate(zip(keep_ids, boxes)):
        masks[k, y1:y2, x1:x2] = m[y1:y2, x1:x2] == i
    boxes = np.asarray(boxes, dtype=np.float32)
    return Detections(boxes, np.ones(len(boxes)), cls, (h, w), masks=masks, source=source)


def _shift_masks(masks: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """Shift each ``(H, W)`` mask by integer ``(dx, dy)`` pixels (zeros fill the border)."""
    out = np.zeros_like(masks)
    h, w = masks.shape[1:]
    for k, (ox, oy) in enumerate(zip(dx, dy)):  # one slice copy per detection
        xs, xd = (0, ox) if ox >= 0 else (-ox, 0)
        ys, yd = (0, oy) if oy >= 0 else (-oy, 0)
        cw, ch = w - abs(ox), h - abs(oy)
        if cw > 0 and ch > 0:
            out[k, yd : yd + ch, xd : xd + cw] = masks[k, ys : ys + ch, xs : xs + cw]
    return out


class OracleDetector:
    """Detections from the true instance masks of synthetic frames.

    Parameters
    ----------
    config : ``config.oracle`` sets the imperfections; ``config.classes`` filters classes.
    """

    def __init__(self, config: DetectionConfig | None = None) -> None:
        self.config = config or DetectionConfig()
        self.source = "oracle"

    def detect(self, frame: Frame) -> Detections:
        """Detections of ``frame`` (needs ``frame.instance_mask``; a clear error otherwise)."""
        if frame.instance_mask is None:
            where = frame.rgb_path or f"frame {frame.index}"
            raise ValueError(
                f"{where}: the oracle detector needs a synthetic frame with an instance mask "
                "(use an ONNX model or a cache for real data)"
            )
        o = self.config.oracle
        det = instances_to_detections(frame.instance_mask, frame.instance_classes, o.min_area, self.source)
        h, w = det.image_size
        rng = np.random.default_rng([o.seed, int(frame.index)])
        if len(det) and o.miss_rate > 0:
            det = det.select(rng.random(len(det)) >= o.miss_rate)
        if len(det) and o.jitter > 0:
            wh = det.boxes[:, 2:] - det.boxes[:, :2]
            size = np.concatenate([wh, wh], axis=1)  # (w, h, w, h) per x1, y1, x2, y2
            noise = rng.normal(0.0, o.jitter, size=(len(det), 4)) * size
            boxes = det.boxes + noise.astype(np.float32)
            boxes[:, [0, 2]] = np.sort(np.clip(boxes[:, [0, 2]], 0, w), axis=1)
            boxes[:, [1, 3]] = np.sort(np.clip(boxes[:, [1, 3]], 0, h), axis=1)
            shift = np.round((boxes[:, :2] + boxes[:, 2:] - det.boxes[:, :2] - det.boxes[:, 2:]) / 2).astype(int)
            masks = _shift_masks(det.masks, shift[:, 0], shift[:, 1])
            det = Detections(boxes, det.scores, det.class_ids, (h, w), masks=masks, source=self.source)
        n_fp = int(rng.poisson(o.false_positives)) if o.false_positives > 0 else 0
        if n_fp:
            bw = rng.uniform(0.05, 0.3, n_fp) * w
            bh = rng.uniform(0.1, 0.5, n_fp) * h
            x1 = rng.uniform(0, w - bw)
            y1 = rng.uniform(0, h - bh)
            fp_boxes = np.stack([x1, y1, x1 + bw, y1 + bh], axis=1).astype(np.float32)
            fp_scores = rng.uniform(self.config.score_threshold, 1.0, n_fp)
            fp = Detections(
                fp_boxes, fp_scores, np.full(n_fp, class_id(o.false_positive_class)), (h, w), source=self.source
            )
            fp.masks = fp.region_masks()
            det = Detections(
                np.concatenate([det.boxes, fp.boxes]), np.concatenate([det.scores, fp.scores]),
                np.concatenate([det.class_ids, fp.class_ids]), (h, w),
                masks=np.concatenate([det.masks, fp.masks]), source=self.source,
            )
        if self.config.classes:
            keep = np.isin(det.class_ids, [class_id(c) for c in self.config.classes])
            det = det.select(keep)
        return det
