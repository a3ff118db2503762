"""What the SLAM system knows before it tracks a frame, handed to the screener as plain arrays.

Screening runs before tracking, so the two-frame checks of the papers (Chang et al. 2021, Ge et
al. 2024, Zhang et al. 2023) estimate their own rough camera motion from keypoint pairs with the
previous frame. When movers fill much of the image that estimate follows them: RANSAC finds the
largest consistent set, and nothing guarantees it is the static world. A SLAM system already
knows more: DynaSLAM (Bescos et al. 2018, Sec. III-C) first runs a "low-cost tracking" of the
frame against the map, whose points come from earlier frames that were screened, and judges
keypoints against several earlier keyframes, not one previous frame.

:class:`ScreeningContext` carries that knowledge across the layer boundary (``dynamic/`` must
not import ``slam/``): the tracker's constant-velocity prediction of the pose, the poses of the
last tracked frames (which the screener pairs with the images it kept), and the points of the
local map with their descriptors. :func:`dynslam_lab.slam.system.System` builds one per frame
when its screener asks for it (``Screener.uses_context``); without one (a notebook screening
frames by hand) the stages fall back to the previous frame alone.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["ScreeningContext"]


def _pose_or_none(T, name: str) -> np.ndarray | None:
    if T is None:
        return None
    T = np.asarray(T, np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"ScreeningContext.{name} must be a finite (4, 4) pose, got shape {T.shape}")
    return T


@dataclass(frozen=True)
class ScreeningContext:
    """The system's state before tracking one frame (all arrays, no SLAM objects).

    Attributes
    ----------
    T_c_w_pred : ``(4, 4)`` predicted world -> camera pose of this frame (ORB-SLAM2's constant
        velocity model, Mur-Artal & Tardos 2017; the last pose while the velocity is unknown), or None
        (before the first tracked frame, after a lost frame).
    poses : timestamp (s) -> ``(4, 4)`` ``T_w_c`` of earlier tracked frames (as corrected by local
        BA and loop closing so far); the screener pairs them with the images it kept.
    map_ids : ``(M,)`` int64 ids of the local map points (stable for a run, never reused).
    map_xyz : ``(M, 3)`` world positions (m).
    map_descriptors : ``(M, 32)`` uint8 ORB descriptors of the map points.
    descriptors : ``(N, 32)`` uint8 descriptors of this frame's keypoints (same order as ``uv``).
    octave : ``(N,)`` pyramid level of each keypoint.
    scale_factor : ORB pyramid scale between levels (``OrbConfig.scale_factor``): a keypoint of level
        ``o`` is located to about ``scale_factor ** o`` pixels.
    """

    T_c_w_pred: np.ndarray | None = None
    poses: dict[float, np.ndarray] = field(default_factory=dict)
    map_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    map_xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    map_descriptors: np.ndarray = field(default_factory=lambda: np.zeros((0, 32), np.uint8))
    descriptors: np.ndarray | None = None
    octave: np.ndarray | None = None
    scale_factor: float = 1.2

    def __post_init__(self) -> None:
        object.__setattr__(self, "T_c_w_pred", _pose_or_none(self.T_c_w_pred, "T_c_w_pred"))
        if not self.scale_factor > 1:
            raise ValueError(f"ScreeningContext.scale_factor must be > 1, got {self.scale_factor}")
        ids = np.asarray(self.map_ids, np.int64).reshape(-1)
        xyz = np.asarray(self.map_xyz, np.float64).reshape(-1, 3)
        desc = np.asarray(self.map_descriptors, np.uint8).reshape(-1, 32)
        if not len(ids) == len(xyz) == len(desc):
            raise ValueError(f"ScreeningContext: map_ids ({len(ids)}), map_xyz ({len(xyz)}) and map_descriptors "
                             f"({len(desc)}) must have one row per map point")
        object.__setattr__(self, "map_ids", ids)
        object.__setattr__(self, "map_xyz", xyz)
        object.__setattr__(self, "map_descriptors", desc)
        if (self.descriptors is None) != (self.octave is None):
            raise ValueError("ScreeningContext: give both descriptors and octave of the keypoints, or neither")
        if self.descriptors is not None:
            d = np.asarray(self.descriptors, np.uint8).reshape(-1, 32)
            o = np.asarray(self.octave, np.int64).reshape(-1)
            if len(d) != len(o):
                raise ValueError(f"ScreeningContext: {len(d)} keypoint descriptors but {len(o)} octaves")
            object.__setattr__(self, "descriptors", d)
            object.__setattr__(self, "octave", o)
        poses = {}
        for ts, T in dict(self.poses).items():
            poses[float(ts)] = _pose_or_none(T, f"poses[{ts}]")
        object.__setattr__(self, "poses", poses)

    @property
    def n_map_points(self) -> int:
        return len(self.map_ids)
