"""Turn the raw output tensors of common one-stage detectors into candidate boxes.

Every function here is plain numpy on the arrays ``onnxruntime`` returns, so the tests can
feed them tensors whose answer is known. Boxes come out in *network-input* pixels
(``x1, y1, x2, y2``); :class:`~dynslam_lab.detection.preprocess.InputTransform` maps them
to the image. Candidates below the score threshold are dropped before any per-box work.

Layouts (``N`` anchor points, ``nc`` classes, strides 8/16/32 over an ``H x W`` input, so
``N = sum_s (H/s)(W/s)``; 8,400 at 640 x 640):

* **YOLOv8 / YOLO11** ``[1, 4 + nc, N]``: rows ``cx, cy, w, h`` (input pixels, decoded), then
  the class probabilities (sigmoid applied). The segmentation model adds 32 mask
  coefficients per anchor, ``[1, 4 + nc + 32, N]``, and prototypes ``[1, 32, H/4, W/4]``;
  an instance mask is ``sigmoid(c^T P)`` cropped to its box (YOLACT's linear combination of
  prototypes, Bolya et al. 2019, which YOLOv8-seg and ASG-SLAM, Ge et al. 2024, use).
* **YOLOv5** ``[1, 3N, 5 + nc]``: three anchors per cell, ``cx, cy, w, h`` decoded,
  objectness, class probabilities; score = objectness x class probability.
* **YOLOX** ``[1, N, 5 + nc]`` *raw*: for the grid cell ``(g_x, g_y)`` of stride ``s``:
  ``cx = (t_x + g_x) s``, ``cy = (t_y + g_y) s``, ``w = e^{t_w} s``, ``h = e^{t_h} s``
  (Ge et al. 2021, anchor-free head); objectness and classes already sigmoid.
* **NanoDet** (GFL head, Li et al. 2020): per stride, class probabilities ``[1, N_s, nc]``
  and distribution boxes ``[1, N_s, 4 (R + 1)]``: each side's distance to the anchor centre
  ``((x + 0.5) s, (y + 0.5) s)`` is the expectation ``s * sum_k k softmax(d)_k``, ``k = 0..R``.
* **NanoDet-Plus** ``[1, A_4, nc + 4 (R + 1)]``: the same quantities concatenated over strides
  8/16/32/64 in one tensor, anchor centres at ``(x s, y s)`` (no half-cell offset).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from .preprocess import InputTransform

__all__ = [
    "Candidates",
    "anchor_count",
    "anchor_grid",
    "decode_yolov8",
    "decode_yolov5",
    "decode_yolox",
    "decode_nanodet",
    "decode_masks",
]

STRIDES = (8, 16, 32)


@dataclass
class Candidates:
    """Boxes above the score threshold, before suppression.

    boxes : ``(K, 4)`` float32 xyxy in network-input pixels.
    scores : ``(K,)`` float32.
    class_ids : ``(K,)`` int64.
    coeffs : ``(K, nm)`` float32 mask coefficients (YOLOv8-seg) or None.
    """

    boxes: np.ndarray
    scores: np.ndarray
    class_ids: np.ndarray
    coeffs: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.scores)

    def select(self, keep: np.ndarray) -> "Candidates":
        return Candidates(
            self.boxes[keep], self.scores[keep], self.class_ids[keep],
            None if self.coeffs is None else self.coeffs[keep],
        )


def anchor_count(input_size: tuple[int, int], strides: tuple[int, ...] = STRIDES) -> int:
    """Number of anchor points ``sum_s ceil(H/s) ceil(W/s)`` of an FPN over ``input_size``."""
    H, W = input_size
    return int(sum(-(-H // s) * -(-W // s) for s in strides))


@lru_cache(maxsize=16)
def anchor_grid(input_size: tuple[int, int], strides: tuple[int, ...] = STRIDES) -> tuple[np.ndarray, np.ndarray]:
    """Grid cells of every anchor point, level by level, row-major inside a level.

    Returns
    -------
    cells : ``(N, 2)`` float32 ``(g_x, g_y)`` cell indices.
    stride : ``(N,)`` float32 stride of each anchor's level, pixels.
    """
    H, W = input_size
    cells, stride = [], []
    for s in strides:
        hs, ws = -(-H // s), -(-W // s)
        gy, gx = np.mgrid[0:hs, 0:ws]
        cells.append(np.stack([gx.ravel(), gy.ravel()], axis=1))
        stride.append(np.full(hs * ws, s))
    c = np.concatenate(cells).astype(np.float32)
    st = np.concatenate(stride).astype(np.float32)
    c.setflags(write=False)
    st.setflags(write=False)
    return c, st


def _cxcywh_to_xyxy(b: np.ndarray) -> np.ndarray:
    half = b[:, 2:4] * 0.5
    return np.concatenate([b[:, 0:2] - half, b[:, 0:2] + half], axis=1).astype(np.float32)


def _best_class(cls: np.ndarray, allowed: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Highest class score and its class id per row of ``cls (K, nc)``, over ``allowed`` ids."""
    if allowed is not None:
        sub = cls[:, allowed]
        j = sub.argmax(axis=1)
        return sub[np.arange(len(sub)), j], allowed[j].astype(np.int64)
    j = cls.argmax(axis=1)
    return cls[np.arange(len(cls)), j], j.astype(np.int64)


def _rows_reaching(scores: np.ndarray, threshold: float) -> np.ndarray:
    """Sorted indices of the rows of ``scores (N, C)`` with some entry >= ``threshold``.

    One comparison over the flat array: faster than a row-wise ``max`` over short rows.
    """
    rows = np.flatnonzero(scores.ravel() >= threshold) // scores.shape[1]
    if len(rows) == 0:
        return rows
    return rows[np.concatenate([[True], rows[1:] != rows[:-1]])]


def _check(out: np.ndarray, ndim: int, what: str) -> np.ndarray:
    a = np.asarray(out)
    if a.ndim != ndim or a.shape[0] != 1:
        raise ValueError(f"{what}: expected a batch-1 tensor of rank {ndim}, got shape {a.shape}")
    return a[0]


def decode_yolov8(
    output: np.ndarray,
    num_classes: int,
    score_threshold: float,
    num_masks: int = 0,
    allowed: np.ndarray | None = None,
) -> Candidates:
    """Decode a YOLOv8/YOLO11 head ``[1, 4 + nc (+ nm), N]``.

    Parameters
    ----------
    output : the head tensor.
    num_classes : ``nc``.
    score_threshold : keep anchors whose best class probability is >= this.
    num_masks : ``nm`` mask coefficients after the classes (32 for -seg, 0 for detection).
    allowed : class ids to consider (None = all).
    """
    o = _check(output, 3, "YOLOv8 output")
    if o.shape[0] != 4 + num_classes + num_masks:
        raise ValueError(f"YOLOv8 output: {o.shape[0]} rows, expected 4 + {num_classes} + {num_masks}")
    cls = o[4 : 4 + num_classes]  # (nc, N)
    best = cls.max(axis=0) if allowed is None else cls[allowed].max(axis=0)
    idx = np.flatnonzero(best >= score_threshold)
    sel = o[:, idx].T  # (K, C)
    scores, class_ids = _best_class(sel[:, 4 : 4 + num_classes], allowed)
    coeffs = sel[:, 4 + num_classes :].astype(np.float32) if num_masks else None
    return Candidates(_cxcywh_to_xyxy(sel[:, :4]), scores.astype(np.float32), class_ids, coeffs)


def decode_yolov5(
    output: np.ndarray, num_classes: int, score_threshold: float, allowed: np.ndarray | None = None
) -> Candidates:
    """Decode a YOLOv5 head ``[1, N, 5 + nc]`` (boxes decoded, objectness, class probabilities)."""
    o = _check(output, 3, "YOLOv5 output")
    if o.shape[1] != 5 + num_classes:
        raise ValueError(f"YOLOv5 output: {o.shape[1]} columns, expected 5 + {num_classes}")
    rows = o[o[:, 4] >= score_threshold]  # score = obj * cls <= obj
    cls, class_ids = _best_class(rows[:, 5:], allowed)
    scores = rows[:, 4] * cls
    ok = scores >= score_threshold
    return Candidates(_cxcywh_to_xyxy(rows[ok, :4]), scores[ok].astype(np.float32), class_ids[ok])


def decode_yolox(
    output: np.ndarray,
    input_size: tuple[int, int],
    num_classes: int,
    score_threshold: float,
    allowed: np.ndarray | None = None,
    strides: tuple[int, ...] = STRIDES,
) -> Candidates:
    """Decode a raw YOLOX head ``[1, N, 5 + nc]`` over grids of ``strides``."""
    o = _check(output, 3, "YOLOX output")
    cells, stride = anchor_grid(tuple(input_size), tuple(strides))
    if o.shape[0] != len(cells) or o.shape[1] != 5 + num_classes:
        raise ValueError(
            f"YOLOX output: shape {o.shape}, expected ({len(cells)}, {5 + num_classes}) for input {input_size}"
        )
    idx = np.flatnonzero(o[:, 4] >= score_threshold)
    rows = o[idx]
    cls, class_ids = _best_class(rows[:, 5:], allowed)
    scores = rows[:, 4] * cls
    ok = scores >= score_threshold
    idx, rows = idx[ok], rows[ok]
    s = stride[idx, None]
    cxcy = (rows[:, 0:2] + cells[idx]) * s
    wh = np.exp(rows[:, 2:4]) * s
    return Candidates(_cxcywh_to_xyxy(np.concatenate([cxcy, wh], axis=1)), scores[ok].astype(np.float32), class_ids[ok])


def decode_nanodet(
    class_scores: list[np.ndarray],
    box_distributions: list[np.ndarray],
    strides: tuple[int, ...],
    input_size: tuple[int, int],
    score_threshold: float,
    reg_max: int = 7,
    center_offset: float = 0.5,
    allowed: np.ndarray | None = None,
) -> Candidates:
    """Decode NanoDet's per-stride outputs.

    Parameters
    ----------
    class_scores : per level ``[1, N_s, nc]`` sigmoid class probabilities.
    box_distributions : per level ``[1, N_s, 4 (reg_max + 1)]`` logits of the distance bins
        of the left, top, right, bottom sides.
    strides : the stride of each level (same order).
    input_size : ``(H, W)`` network input.
    reg_max : ``R``; distances are in ``0..R`` strides.
    center_offset : anchor centre ``(x + offset) * s``.
    """
    H, W = input_size
    boxes_all, scores_all, ids_all = [], [], []
    bins = np.arange(reg_max + 1, dtype=np.float32)
    for cls_l, reg_l, s in zip(class_scores, box_distributions, strides):
        cls = _check(cls_l, 3, "NanoDet class scores")
        reg = _check(reg_l, 3, "NanoDet box distribution")
        ws = -(-W // s)
        if reg.shape != (len(cls), 4 * (reg_max + 1)):
            raise ValueError(f"NanoDet: box output {reg.shape} does not match {len(cls)} x 4 x {reg_max + 1}")
        idx = _rows_reaching(cls if allowed is None else cls[:, allowed], score_threshold)
        if len(idx) == 0:
            continue
        scores, ids = _best_class(cls[idx], allowed)
        logits = reg[idx].reshape(len(idx), 4, reg_max + 1)
        e = np.exp(logits - logits.max(axis=2, keepdims=True))
        dist = (e * bins).sum(axis=2) / e.sum(axis=2) * s  # (K, 4) expected distances, pixels
        cx = (idx % ws + center_offset) * s
        cy = (idx // ws + center_offset) * s
        boxes_all.append(np.stack([cx - dist[:, 0], cy - dist[:, 1], cx + dist[:, 2], cy + dist[:, 3]], axis=1))
        scores_all.append(scores)
        ids_all.append(ids)
    if not boxes_all:
        return Candidates(np.zeros((0, 4), np.float32), np.zeros(0, np.float32), np.zeros(0, np.int64))
    return Candidates(
        np.concatenate(boxes_all).astype(np.float32),
        np.concatenate(scores_all).astype(np.float32),
        np.concatenate(ids_all).astype(np.int64),
    )


def decode_masks(
    coeffs: np.ndarray,
    prototypes: np.ndarray,
    boxes: np.ndarray,
    transform: InputTransform,
    threshold: float = 0.5,
) -> np.ndarray:
    """Instance masks at image size from mask coefficients and prototypes.

    ``m_k = sigmoid(c_k^T P)`` on the prototype grid, sampled bilinearly at every image
    pixel centre (through the letterbox map), thresholded, and cropped to the box.

    Parameters
    ----------
    coeffs : ``(K, nm)`` coefficients of the kept detections.
    prototypes : ``[1, nm, h_p, w_p]`` prototypes over the network input.
    boxes : ``(K, 4)`` xyxy boxes in *image* pixels.
    transform : image-to-input map of the frame.
    threshold : mask probability threshold in (0, 1).

    Returns
    -------
    ``(K, H, W)`` bool masks, ``(H, W)`` = ``transform.image_size``.
    """
    P = _check(prototypes, 4, "mask prototypes")
    nm, hp, wp = P.shape
    c = np.asarray(coeffs, dtype=np.float32).reshape(-1, nm)
    h, w = transform.image_size
    K = len(c)
    if K == 0:
        return np.zeros((0, h, w), dtype=bool)
    # einsum, not BLAS: a (K x 32) by (32 x hp wp) product is too small for threaded BLAS,
    # whose thread start-up costs milliseconds on a busy machine
    logits = np.einsum("km,mp->kp", c, P.reshape(nm, -1).astype(np.float32, copy=False)).reshape(K, hp, wp)
    Hin, Win = transform.input_size
    rx, ry = Win / wp, Hin / hp  # input pixels per prototype pixel
    # image pixel centre x + 0.5 -> input (x + 0.5) sx + px -> prototype index that / rx - 0.5
    ax, bx = transform.sx / rx, (0.5 * transform.sx + transform.px) / rx - 0.5
    ay, by = transform.sy / ry, (0.5 * transform.sy + transform.py) / ry - 0.5
    cut = float(np.log(threshold / (1.0 - threshold)))  # sigmoid(x) > t  <=>  x > logit(t)
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    # pixels whose centres lie in the box: x + 0.5 in [x1, x2]
    xa = np.clip(np.ceil(b[:, 0] - 0.5), 0, w).astype(int)
    xb = np.clip(np.floor(b[:, 2] - 0.5) + 1, 0, w).astype(int)
    ya = np.clip(np.ceil(b[:, 1] - 0.5), 0, h).astype(int)
    yb = np.clip(np.floor(b[:, 3] - 0.5) + 1, 0, h).astype(int)
    masks = np.zeros((K, h, w), dtype=bool)
    for k in range(K):  # one small warp per detection, over its box only
        bw, bh = xb[k] - xa[k], yb[k] - ya[k]
        if bw <= 0 or bh <= 0:
            continue
        M = np.array([[ax, 0.0, ax * xa[k] + bx], [0.0, ay, ay * ya[k] + by]], dtype=np.float64)
        up = cv2.warpAffine(
            logits[k], M, (int(bw), int(bh)), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_REPLICATE,
        )
        masks[k, ya[k] : yb[k], xa[k] : xb[k]] = up > cut
    return masks
