"""Per-keypoint precision and recall of the dynamic verdict against the synthetic truth.

None of the papers can measure this: TUM has no per-pixel motion labels. The synthetic
renderer (``dynslam_lab.datasets.synthetic``) writes an instance-id image per frame and the
list of instances that truly move in each frame (``moving.txt``, read by ``read_moving``).

Truth. A keypoint is **truly dynamic** when its pixel (nearest integer position) lies on an
instance that moves in that frame. A sitting person counts as dynamic only in the frames where
the renderer moves them (a shifting arm or head); in the frames where they sit still their
keypoints are static, so a filter that removes every person pays in precision on sitting
sequences. Instances that never move (chairs, monitors) are static.

With ``TP`` dynamic keypoints judged dynamic, ``FP`` static judged dynamic and ``FN`` dynamic
judged static::

    precision = TP / (TP + FP),     recall = TP / (TP + FN)

summed over all frames of a run (micro-average), so frames with many keypoints weigh more.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .table import check_uv, values_at

__all__ = ["KeypointScore", "moving_ids", "moving_mask", "truth_dynamic", "score_keypoints", "ScoringScreener"]

_MOVING_CACHE: dict[Path, object] = {}


@dataclass
class KeypointScore:
    """Confusion counts of the dynamic verdict (keypoints)."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    tn: int = 0

    @property
    def precision(self) -> float:
        """``TP / (TP + FP)``; nan when nothing was judged dynamic."""
        d = self.tp + self.fp
        return self.tp / d if d else float("nan")

    @property
    def recall(self) -> float:
        """``TP / (TP + FN)``; nan when nothing was truly dynamic."""
        d = self.tp + self.fn
        return self.tp / d if d else float("nan")

    def __add__(self, other: "KeypointScore") -> "KeypointScore":
        return KeypointScore(self.tp + other.tp, self.fp + other.fp, self.fn + other.fn, self.tn + other.tn)

    def to_dict(self) -> dict:
        return {"tp": self.tp, "fp": self.fp, "fn": self.fn, "tn": self.tn,
                "precision": self.precision, "recall": self.recall}


def score_keypoints(predicted: np.ndarray, truth: np.ndarray) -> KeypointScore:
    """Confusion counts of ``predicted (N,)`` bool against ``truth (N,)`` bool."""
    p = np.asarray(predicted, bool).reshape(-1)
    t = np.asarray(truth, bool).reshape(-1)
    if p.shape != t.shape:
        raise ValueError(f"score_keypoints: {p.shape[0]} predictions, {t.shape[0]} truths")
    return KeypointScore(int((p & t).sum()), int((p & ~t).sum()), int((~p & t).sum()), int((~p & ~t).sum()))


def _sequence_root(frame) -> Path | None:
    if getattr(frame, "rgb_path", None) is None:
        return None
    return Path(frame.rgb_path).resolve().parent.parent


def moving_ids(frame) -> set[int] | None:
    """Ids of the instances that move in ``frame`` (from the renderer's ``moving.txt``), or None
    when the frame does not come from a synthetic sequence with that file."""
    root = _sequence_root(frame)
    if root is None or frame.instance_mask is None or not (root / "moving.txt").is_file():
        return None
    if root not in _MOVING_CACHE:
        from ..datasets.synthetic import read_moving

        _MOVING_CACHE[root] = read_moving(root)
    table = _MOVING_CACHE[root]
    return _lookup_moving(table, frame)


def _lookup_moving(table: dict[float, set[int]], frame) -> set[int]:
    """The moving ids of one frame from ``read_moving``'s result (colour timestamp -> ids): the
    entry nearest the frame's timestamp."""
    if not table:
        return set()
    keys = np.fromiter(table.keys(), dtype=np.float64, count=len(table))
    j = int(np.argmin(np.abs(keys - float(frame.timestamp))))
    return set(table[float(keys[j])])


def moving_mask(frame) -> np.ndarray | None:
    """``(H, W)`` bool pixels of the instances moving in ``frame``; None without instance masks.

    Without ``moving.txt`` (a synthetic sequence written by an older renderer, or a frame built
    by hand) every instance of an a-priori dynamic class counts as moving.
    """
    if frame.instance_mask is None:
        return None
    ids = moving_ids(frame)
    if ids is None:
        from ..detection.coco import APRIORI_DYNAMIC

        ids = {i for i, c in frame.instance_classes.items() if c in APRIORI_DYNAMIC}
    return np.isin(frame.instance_mask, np.array(sorted(ids), dtype=np.int64))


def truth_dynamic(frame, uv: np.ndarray) -> np.ndarray | None:
    """``(N,)`` bool truth of the keypoints ``uv`` (see the module docstring), or None."""
    mask = moving_mask(frame)
    if mask is None:
        return None
    return values_at(mask, check_uv(uv), outside=False).astype(bool)


@dataclass
class ScoringScreener:
    """Wraps a screener and scores every table it returns against the synthetic truth.

    Use it in place of the screener (``run_sequence(..., screener=ScoringScreener(s))``); after the
    run ``score`` holds the summed counts and ``per_frame`` one :class:`KeypointScore` per frame
    that had truth. With ``inner=None`` (the ``none`` filter) every keypoint is judged static.
    """

    inner: object | None
    score: KeypointScore = field(default_factory=KeypointScore)
    per_frame: list[KeypointScore] = field(default_factory=list)
    timings_ms: list[dict[str, float]] = field(default_factory=list)

    @property
    def name(self) -> str:
        return getattr(self.inner, "name", "none")

    def reset(self) -> None:
        if self.inner is not None:
            self.inner.reset()

    def screen(self, frame, uv, detections=None):
        from .table import KeypointTable, depth_at

        if self.inner is None:
            table = KeypointTable.blank(uv, depth_at(frame.depth, uv))
        else:
            table = self.inner.screen(frame, uv, detections)
        truth = truth_dynamic(frame, table.uv)
        if truth is not None:
            s = score_keypoints(table.dynamic, truth)
            self.per_frame.append(s)
            self.score = self.score + s
        self.timings_ms.append(dict(table.timings_ms))
        return table
