"""Temporal consistency: what was seen moving stays suspect.

Each frame's tests see only a moment: a mover that pauses for a step, turns to walk straight away
from the camera (its depth only grows, which looks like an occlusion to the free-space test), or
whose only moving part is hidden, escapes one frame's evidence. Two memories carry the verdicts
forward (our construction; DynaSLAM, Bescos et al. 2018, keeps no memory between frames):

* **Map points seen moving.** A map point matched (by :mod:`.reference_pose`) to a keypoint the
  screener judged dynamic is remembered; later keypoints matched to it are dynamic and it no
  longer enters the reference pose. Map point ids are stable for a run.
* **The previous frame's region as a prior.** The dynamic cells of frame ``t - 1`` are carried
  into frame ``t`` along the camera motion (each current cell is projected with its depth into
  frame ``t - 1``, where the region is looked up, grown by ``dilate_cells`` to cover the mover's
  own motion). The prior seeds region growing (:mod:`.regions`) but never decides alone: a region
  needs fresh evidence too, so a mover that stops is released once every earlier frame agrees
  with it.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .multiframe import grid_points

__all__ = ["TemporalConfig", "warp_region", "MovingMapPoints"]


@dataclass(frozen=True)
class TemporalConfig:
    """Parameters of temporal consistency (ours)."""

    dilate_cells: int = 0  # the previous region grows by this many cells before the lookup; ours, 0 (a grown prior spills onto uncovered background)
    max_moving_points: int = 200_000  # map point ids remembered at most (oldest forgotten first); ours
    cull_moved_points: bool = True  # map points on a surface found moving against the room (reference pose step 3b's room test, or step 3c) are removed from the SLAM map (their stored positions are stale; screening.stale_map_points); ours (for every surface step 3b finds: carried_xyz 0.09 -> 0.45 m)
    hold_overlap: float = 0.5  # a surface lying this share inside the cells of surfaces seen moving in the previous frame is the same object (fraction of its cells); ours
    hold_frames: int = 3  # ... and stays dynamic this many frames after the last fresh verdict on it (frames; 0 = off): a mover mapped at rest and found moving is mapped again where it now stands by the next keyframes, and its motion against those fresh points stays below every threshold for a few frames (random_438: 0.25 m -> 8 mm); 5 and 10 held false verdicts too long (random_401 0.07 -> 0.48 m); docs/robustness.md "Held surfaces, three frames"; ours
    release_frames: int = 0  # a map point seen moving whose keypoint is then seen at one world position (within release_tolerance_m + release_depth_share x depth) on this many frames, and nowhere else meanwhile, is released: forgotten as moving and culled from the map (its stored position is what was off); 0 = off; ours (docs/robustness.md "Points seen moving that stand still")
    release_tolerance_m: float = 0.02  # ... the world position's allowed spread (m), plus
    release_depth_share: float = 0.01  # ... this share of the keypoint's depth

    def __post_init__(self) -> None:
        if self.dilate_cells < 0 or self.max_moving_points < 1:
            raise ValueError("TemporalConfig: dilate_cells >= 0 and max_moving_points >= 1 required")
        if not 0 < self.hold_overlap <= 1:
            raise ValueError(f"TemporalConfig.hold_overlap must be in (0, 1], got {self.hold_overlap}")
        if self.hold_frames < 0:
            raise ValueError(f"TemporalConfig.hold_frames must be >= 0 frames, got {self.hold_frames}")
        if self.release_frames < 0 or self.release_tolerance_m < 0 or self.release_depth_share < 0:
            raise ValueError("TemporalConfig: release_frames, release_tolerance_m and release_depth_share must be >= 0")


def warp_region(prev_region: np.ndarray, T_p_c: np.ndarray, depth: np.ndarray, camera, dilate_cells: int = 0,
                prev_depth: np.ndarray | None = None, depth_m: float = 0.1) -> np.ndarray:
    """The previous frame's region seen from the current frame.

    Parameters
    ----------
    prev_region : ``(h, w)`` bool dynamic cells of the previous frame (grid of ``camera``).
    T_p_c : ``(4, 4)`` current camera -> previous camera.
    depth : ``(h, w)`` current depth on the same grid (m, 0 = none).
    camera : intrinsics of the grid.
    dilate_cells : grow the previous region first (cells).
    prev_depth : ``(h, w)`` the previous frame's depth on the grid; a current point that the previous
        frame saw more than ``depth_m`` behind something (it was hidden then, e.g. background a mover
        has just uncovered) takes no prior.

    Returns ``(h, w)`` bool: current cells with depth whose point falls in the (grown) region.
    """
    region = np.asarray(prev_region, bool)
    h, w = region.shape
    if depth.shape != region.shape:
        raise ValueError(f"warp_region: depth {depth.shape} and region {region.shape} differ")
    out = np.zeros(h * w, bool)
    if not region.any():
        return out.reshape(h, w)
    if dilate_cells > 0:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * dilate_cells + 1, 2 * dilate_cells + 1))
        region = cv2.dilate(region.astype(np.uint8), k).astype(bool)
    P, keep = grid_points(depth, camera)
    Q = P @ T_p_c[:3, :3].T + T_p_c[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.round(camera.fx * Q[:, 0] / Q[:, 2] + camera.cx)
        v = np.round(camera.fy * Q[:, 1] / Q[:, 2] + camera.cy)
    ok = (Q[:, 2] > 0) & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    hit = np.zeros(len(keep), bool)
    r, c = v[ok].astype(np.int64), u[ok].astype(np.int64)
    hit[ok] = region[r, c]
    if prev_depth is not None:
        zp = prev_depth[r, c]
        hidden = (zp > 0) & (Q[ok, 2] - zp > depth_m)
        hit[np.flatnonzero(ok)[hidden]] = False
    out[keep] = hit
    return out.reshape(h, w)


class MovingMapPoints:
    """The ids of map points seen moving (insertion-ordered, bounded)."""

    def __init__(self, capacity: int) -> None:
        self.capacity = int(capacity)
        self._ids: dict[int, None] = {}
        self._still: dict[int, tuple[np.ndarray, int, int]] = {}  # id -> (where it stands, frames seen there, last frame seen)

    def __len__(self) -> int:
        return len(self._ids)

    def clear(self) -> None:
        self._ids.clear()
        self._still.clear()

    def release_still(self, ids, P_w: np.ndarray, tolerance: np.ndarray, frames: int, frame: int) -> np.ndarray:
        """Forget the points ``ids (K,)`` (remembered as moving) whose keypoints, seen on frame ``frame`` at the
        world positions ``P_w (K, 3)``, have been seen within ``tolerance (K,)`` metres of where they first stood
        still on ``frames`` frames, with no frame seeing them elsewhere; returns their ids. A point seen away
        from where it stood starts again from there; one not seen for ``frames`` frames is forgotten."""
        ids = np.asarray(ids, np.int64).reshape(-1)
        P_w = np.asarray(P_w, np.float64).reshape(-1, 3)
        tolerance = np.broadcast_to(np.asarray(tolerance, np.float64), ids.shape)
        released = []
        for i, p, tol in zip(ids.tolist(), P_w, tolerance):
            if i not in self._ids or not np.isfinite(p).all():
                continue
            anchor, n, _ = self._still.get(i, (p, 0, frame))
            anchor, n = (anchor, n + 1) if np.linalg.norm(p - anchor) <= tol else (p, 1)
            if n >= frames:
                released.append(i)
                self._ids.pop(i, None)
                self._still.pop(i, None)
            else:
                self._still[i] = (anchor, n, frame)
        self._still = {i: v for i, v in self._still.items() if frame - v[2] < frames and i in self._ids}
        return np.asarray(released, np.int64)

    def add(self, ids) -> None:
        for i in np.asarray(ids, np.int64).reshape(-1).tolist():
            self._ids.pop(i, None)
            self._ids[i] = None
        while len(self._ids) > self.capacity:
            self._ids.pop(next(iter(self._ids)))

    def array(self) -> np.ndarray:
        return np.fromiter(self._ids, np.int64, len(self._ids))

    def contains(self, ids) -> np.ndarray:
        """``(K,)`` bool for the ids ``(K,)``."""
        ids = np.asarray(ids, np.int64).reshape(-1)
        if not self._ids or len(ids) == 0:
            return np.zeros(len(ids), bool)
        return np.isin(ids, self.array())
