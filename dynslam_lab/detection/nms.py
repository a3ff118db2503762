"""Box overlap and non-maximum suppression (hard and Gaussian soft-NMS).

A detector proposes many overlapping boxes per object; suppression keeps one.

**Hard NMS** (Zhang et al., IJGI 2023, Zhang et al. 2023, Sec. 2.2, eq. 5): take the box ``M`` with
the highest score, then for every other box ``b_i``

.. math::  s_i = \\begin{cases} s_i & \\mathrm{IoU}(M, b_i) < N_t \\\\ 0 & \\mathrm{IoU}(M, b_i) \\ge N_t \\end{cases}

and repeat with the next highest remaining box.

**Gaussian soft-NMS** (the "improved Gaussian-weighted NMS" of the same section, which
re-ranks boxes instead of deleting them; the Gaussian form is Bodla et al., ICCV 2017, eq. 3):

.. math::  s_i \\leftarrow s_i \\, e^{-\\mathrm{IoU}(M, b_i)^2 / \\sigma}

Boxes whose decayed score falls below the score threshold are dropped. A second person
standing half behind the first keeps a lowered score instead of vanishing.

Both are class-aware by default: boxes of different classes never suppress each other (we
shift each class's boxes by a class-dependent offset, so one pass handles all classes).
The loops run once per *kept* box, each step vectorised over the remaining boxes.
"""

from __future__ import annotations

import numpy as np

__all__ = ["box_iou", "nms", "soft_nms", "suppress"]


def _check_boxes(boxes: np.ndarray, name: str = "boxes") -> np.ndarray:
    b = np.asarray(boxes, dtype=np.float64)
    if b.ndim != 2 or b.shape[1] != 4:
        raise ValueError(f"{name}: expected shape (N, 4) x1, y1, x2, y2; got {b.shape}")
    return b


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union of every pair of boxes.

    Parameters
    ----------
    a : ``(N, 4)`` boxes ``x1, y1, x2, y2`` (pixels, continuous: area = (x2 - x1)(y2 - y1)).
    b : ``(M, 4)`` boxes.

    Returns
    -------
    ``(N, M)`` float64 IoU in [0, 1] (0 where both boxes are empty).
    """
    a = _check_boxes(a, "a")
    b = _check_boxes(b, "b")
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    wh = np.clip(rb - lt, 0.0, None)
    inter = wh[..., 0] * wh[..., 1]
    area_a = np.prod(np.clip(a[:, 2:] - a[:, :2], 0.0, None), axis=1)
    area_b = np.prod(np.clip(b[:, 2:] - b[:, :2], 0.0, None), axis=1)
    union = area_a[:, None] + area_b[None, :] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def _offset_by_class(boxes: np.ndarray, class_ids: np.ndarray | None) -> np.ndarray:
    """Shift each class's boxes apart so boxes of different classes never overlap."""
    if class_ids is None or len(boxes) == 0:
        return boxes
    ids = np.asarray(class_ids, dtype=np.float64).reshape(-1)
    if len(ids) != len(boxes):
        raise ValueError(f"class_ids: {len(ids)} ids for {len(boxes)} boxes")
    span = float(np.abs(boxes).max()) * 2.0 + 1.0
    return boxes + (ids * span)[:, None]


def _iou_with(m: int, idx: np.ndarray, cols: tuple[np.ndarray, ...]) -> np.ndarray:
    """IoU of box ``m`` with boxes ``idx``; ``cols`` = (x1, y1, x2, y2, area) 1-D arrays.

    The hot loop of NMS: plain 1-D ufuncs, no shape checks.
    """
    x1, y1, x2, y2, area = cols
    w = np.minimum(x2[m], x2[idx]) - np.maximum(x1[m], x1[idx])
    h = np.minimum(y2[m], y2[idx]) - np.maximum(y1[m], y1[idx])
    inter = np.maximum(w, 0.0) * np.maximum(h, 0.0)
    union = area[m] + area[idx] - inter
    return inter / np.maximum(union, np.finfo(np.float64).tiny)  # 0 / tiny = 0 for empty boxes


def _columns(b: np.ndarray) -> tuple[np.ndarray, ...]:
    x1, y1, x2, y2 = (np.ascontiguousarray(b[:, k]) for k in range(4))
    return x1, y1, x2, y2, np.maximum(x2 - x1, 0.0) * np.maximum(y2 - y1, 0.0)


def nms(
    boxes: np.ndarray,
    scores: np.ndarray,
    iou_threshold: float = 0.45,
    class_ids: np.ndarray | None = None,
    max_detections: int | None = None,
) -> np.ndarray:
    """Greedy hard NMS (Zhang et al. 2023 eq. 5).

    Parameters
    ----------
    boxes : ``(N, 4)`` x1, y1, x2, y2 pixels.
    scores : ``(N,)`` confidences.
    iou_threshold : ``N_t``; a box overlapping a kept one by IoU >= this is removed.
    class_ids : ``(N,)`` class of each box; when given, only boxes of the same class
        suppress each other. None: class-agnostic.
    max_detections : stop after this many kept boxes (None = no limit).

    Returns
    -------
    ``(K,)`` int64 indices of the kept boxes, by decreasing score.
    """
    b = _offset_by_class(_check_boxes(boxes), class_ids)
    s = np.asarray(scores, dtype=np.float64).reshape(-1)
    if len(s) != len(b):
        raise ValueError(f"scores: {len(s)} scores for {len(b)} boxes")
    cols = _columns(b)
    order = np.argsort(-s, kind="stable")
    keep: list[int] = []
    limit = len(order) if max_detections is None else max_detections
    while len(order) and len(keep) < limit:
        i = order[0]
        keep.append(int(i))
        rest = order[1:]
        order = rest[_iou_with(i, rest, cols) < iou_threshold]
    return np.asarray(keep, dtype=np.int64)


def soft_nms(
    boxes: np.ndarray,
    scores: np.ndarray,
    sigma: float = 0.5,
    score_threshold: float = 0.001,
    class_ids: np.ndarray | None = None,
    max_detections: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian soft-NMS: decay overlapping scores by ``exp(-IoU^2 / sigma)``.

    Parameters
    ----------
    boxes, scores, class_ids, max_detections : as in :func:`nms`.
    sigma : width of the Gaussian penalty (> 0); small sigma approaches hard NMS.
    score_threshold : boxes whose decayed score drops below this are discarded.

    Returns
    -------
    keep : ``(K,)`` int64 indices of the kept boxes, in the order they were selected
        (decreasing decayed score).
    new_scores : ``(K,)`` float64 their decayed scores.
    """
    if sigma <= 0:
        raise ValueError(f"soft_nms: sigma must be > 0, got {sigma}")
    b = _offset_by_class(_check_boxes(boxes), class_ids)
    s = np.asarray(scores, dtype=np.float64).reshape(-1).copy()
    if len(s) != len(b):
        raise ValueError(f"scores: {len(s)} scores for {len(b)} boxes")
    cols = _columns(b)
    idx = np.flatnonzero(s >= score_threshold)
    keep: list[int] = []
    kept_scores: list[float] = []
    limit = len(idx) if max_detections is None else max_detections
    while len(idx) and len(keep) < limit:
        j = int(np.argmax(s[idx]))
        m = idx[j]
        keep.append(int(m))
        kept_scores.append(float(s[m]))
        idx = np.delete(idx, j)
        iou = _iou_with(m, idx, cols)
        s[idx] *= np.exp(-(iou**2) / sigma)
        idx = idx[s[idx] >= score_threshold]
    return np.asarray(keep, dtype=np.int64), np.asarray(kept_scores, dtype=np.float64)


def suppress(
    boxes: np.ndarray,
    scores: np.ndarray,
    class_ids: np.ndarray,
    kind: str = "hard",
    iou_threshold: float = 0.45,
    sigma: float = 0.5,
    score_threshold: float = 0.0,
    class_agnostic: bool = False,
    max_detections: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Run the selected suppression: ``kind`` is ``"hard"``, ``"soft"`` or ``"none"``.

    Returns the kept indices and their (possibly decayed) scores, by decreasing score.
    """
    cls = None if class_agnostic else class_ids
    s = np.asarray(scores, dtype=np.float64).reshape(-1)
    if kind == "hard":
        keep = nms(boxes, s, iou_threshold, cls, max_detections)
        return keep, s[keep]
    if kind == "soft":
        return soft_nms(boxes, s, sigma, score_threshold, cls, max_detections)
    if kind == "none":
        keep = np.argsort(-s, kind="stable")[:max_detections]
        return keep, s[keep]
    raise ValueError(f"nms kind {kind!r}: expected 'hard', 'soft' or 'none'")
