"""Perfect screening from the synthetic truth, and the truth lookups the scores use.

The synthetic renderer (``dynslam_lab.datasets.synthetic``) writes an instance-id image per
frame and the instances that truly move in each frame (``moving.txt``; the loader puts them on
``Frame.moving_ids``). A keypoint is **truly dynamic** when its pixel (nearest integer position)
lies on an instance that moves in that frame. A sitting person counts as dynamic only in the
frames where the renderer moves them; instances that never move (chairs, monitors) are static.
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from ..detection.coco import APRIORI_DYNAMIC
from .config import ScreeningConfig
from .table import KeypointTable, check_uv, depth_at, values_at

__all__ = ["moving_mask", "truth_dynamic", "grown_mask", "OracleScreener"]


def moving_mask(frame) -> np.ndarray | None:
    """``(H, W)`` bool pixels of the instances moving in ``frame``; None without instance masks.

    Without ``Frame.moving_ids`` (a sequence written by an older renderer, or a frame built by
    hand) every instance of an a-priori dynamic class counts as moving.
    """
    if frame.instance_mask is None:
        return None
    ids = frame.moving_ids
    if ids is None:
        ids = {i for i, c in frame.instance_classes.items() if c in APRIORI_DYNAMIC}
    return np.isin(frame.instance_mask, np.array(sorted(ids), dtype=np.int64))


def truth_dynamic(frame, uv: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray | None:
    """``(N,)`` bool truth of the keypoints ``uv`` (see the module docstring), or None. ``mask``: the
    frame's :func:`moving_mask` when the caller has it already (else it is made here)."""
    mask = moving_mask(frame) if mask is None else mask
    if mask is None:
        return None
    return values_at(mask, check_uv(uv), outside=False).astype(bool)


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1000.0


def grown_mask(mask: np.ndarray, margin_px: float) -> np.ndarray:
    """``mask`` and every pixel within ``margin_px`` (Euclidean, pixel centres) of it; the same array when the
    margin is 0 or the mask empty. Exact distances, as the scorer's outline band uses
    (``dynslam_lab.experiments.scoring.signed_outline_distance``)."""
    if margin_px <= 0 or not mask.any():
        return mask
    return cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE) <= margin_px


class OracleScreener:
    """Perfect screening from the synthetic truth: a keypoint is dynamic when its pixel lies on an
    instance that moves in this frame, or within ``ScreeningConfig.oracle_margin_px`` of one: a corner
    whose FAST circle (radius 3 px) reaches across a moving outline is made partly by the mover and
    moves with it, whichever side its centre lies on (docs/robustness.md, "Perfect masks and the
    corners on their outlines"). The truth the scores use (:func:`truth_dynamic`) stays the pixel's."""

    stages = ("oracle",)
    name = "oracle"

    def __init__(self, config: ScreeningConfig | None = None):
        self.config = config or ScreeningConfig()
        # the last frame's instance image and moving ids (held, so identity means the same image) and its grown mask
        self._last: tuple[object, object, np.ndarray | None] | None = None

    def reset(self) -> None:
        """Forget the last frame's mask."""
        self._last = None

    def _mask(self, frame) -> np.ndarray | None:
        """The moving instances of ``frame`` grown by ``oracle_margin_px``; computed once per frame (the
        ORB budget asks for it before the keypoints exist, the screening after)."""
        last = self._last
        if last is not None and last[0] is frame.instance_mask and last[1] == frame.moving_ids:
            return last[2]
        mask = moving_mask(frame)
        if mask is not None:
            mask = grown_mask(mask, self.config.oracle_margin_px)
        self._last = (frame.instance_mask, frame.moving_ids, mask)
        return mask

    def known_region(self, frame) -> np.ndarray | None:
        """``(H, W)`` bool pixels known dynamic in ``frame`` before any keypoint exists (the moving
        instances and their margin), or None without instance masks: the SLAM system gives the keypoint
        budget to the rest of the image (``OrbConfig.truth_region_share``)."""
        return self._mask(frame)

    def screen(self, frame, uv: np.ndarray, detections=None) -> KeypointTable:
        uv = check_uv(uv)
        t0 = time.perf_counter()
        mask = self._mask(frame)
        if mask is None:
            raise ValueError(
                f"oracle screening needs a synthetic sequence with instance masks; frame {frame.index} "
                f"({frame.rgb_path}) has none"
            )
        dyn = values_at(mask, uv, outside=False).astype(bool)
        inst = values_at(frame.instance_mask, uv, outside=0).astype(np.int64)
        n = len(uv)
        reason = np.where(dyn, "oracle", "").astype(object)
        return KeypointTable(
            uv=uv, depth=depth_at(frame.depth, uv), class_id=np.full(n, -1), instance=np.where(inst > 0, inst, -1),
            motion_prob=np.zeros(n), dynamic=dyn, reason=reason, stages={"oracle": dyn.copy()},
            region_mask=mask, timings_ms={"total": _ms(t0)},
        )
