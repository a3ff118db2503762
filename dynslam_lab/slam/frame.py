"""Frames and keyframes of the SLAM system (ORB-SLAM2, Mur-Artal and Tardos, T-RO 2017, Sec. III).

A :class:`SlamFrame` is what tracking works on: the ORB keypoints of one RGB-D image, the
depth at each keypoint, the camera-frame 3D point it gives, the ``static`` verdict of the
screening stage, and the map point each keypoint is matched to (``-1`` for none).

RGB-D keypoints are treated as in ORB-SLAM2 (Sec. III-A): a keypoint with depth ``z`` gets a
virtual right-image coordinate ``u_R = u - bf / z`` (``bf`` = virtual baseline (m) times focal
length (px); ``Camera.bf = 40`` in ORB-SLAM2's TUM settings, 400 here: ``TrackingConfig.bf``), so that one residual form (u, v, u_R) serves
reprojection and depth errors alike. Keypoints closer than ``th_depth * bf / fx`` metres are
"close" (their depth is trusted); farther ones are treated as monocular in ORB-SLAM2.

A :class:`KeyFrame` is a frame kept in the map: its keypoints, descriptors, camera-frame
points, map point associations, pose ``T_w_c`` (which loop closing may change) and its parent
in the spanning tree.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..camera import PinholeCamera
from ..datasets.frame import Frame
from ..features.orb import Features
from ..geometry.se3 import se3_inv

__all__ = ["SlamFrame", "KeyFrame", "make_slam_frame", "keypoint_depths"]


def keypoint_depths(depth: np.ndarray, uv: np.ndarray, min_depth: float, max_depth: float) -> np.ndarray:
    """Depth ``(N,)`` in metres at keypoints ``uv (N, 2)`` (nearest pixel); ``nan`` where the
    depth image has no reading or the reading is outside ``[min_depth, max_depth]``."""
    depth = np.asarray(depth)
    uv = np.asarray(uv, float).reshape(-1, 2)
    h, w = depth.shape
    ui = np.clip(np.round(uv[:, 0]).astype(np.int64), 0, w - 1)
    vi = np.clip(np.round(uv[:, 1]).astype(np.int64), 0, h - 1)
    z = depth[vi, ui].astype(np.float64)
    return np.where((z >= min_depth) & (z <= max_depth) & np.isfinite(z), z, np.nan)


@dataclass
class SlamFrame:
    """One frame as tracking sees it.

    Attributes
    ----------
    index, timestamp : position in the sequence and time (s).
    features : the ORB features (``uv`` as detected).
    uv : ``(N, 2)`` float64 undistorted keypoint pixels.
    depth : ``(N,)`` metres at each keypoint, ``nan`` where none.
    points_c : ``(N, 3)`` camera-frame points from depth (metres), ``nan`` rows where none.
    static : ``(N,)`` bool, keypoints that may be used (not judged dynamic).
    map_point_ids : ``(N,)`` int64 matched map point per keypoint, ``-1`` for none.
    outlier : ``(N,)`` bool, matches rejected by the last pose optimisation.
    T_w_c : ``(4, 4)`` pose (camera to world) once tracked, else None.
    depth_image : ``(H, W)`` the frame's depth image (m, 0 = none; the frame's own array, not a copy)
        for the dense depth term of tracking, or None.
    dynamic_region : ``(H, W)`` bool pixels the screening judged dynamic (its region, or the oracle's
        masks), left out of the dense depth term when ``tracking.dense_mask_region``; None without one.
    gray_image : ``(H, W)`` uint8 the frame's grey image (the frame's own array) for the photometric term of
        tracking (``tracking.dense_photometric_sigma``), or None.
    """

    index: int
    timestamp: float
    features: Features
    uv: np.ndarray
    depth: np.ndarray
    points_c: np.ndarray
    static: np.ndarray
    map_point_ids: np.ndarray
    outlier: np.ndarray
    T_w_c: np.ndarray | None = None
    depth_image: np.ndarray | None = None
    dynamic_region: np.ndarray | None = None
    gray_image: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.uv)

    @property
    def descriptors(self) -> np.ndarray:
        return self.features.descriptors

    @property
    def octave(self) -> np.ndarray:
        return self.features.octave

    @property
    def angle(self) -> np.ndarray:
        return self.features.angle

    @property
    def T_c_w(self) -> np.ndarray:
        if self.T_w_c is None:
            raise ValueError(f"frame {self.index} has no pose")
        return se3_inv(self.T_w_c)

    def matched(self) -> np.ndarray:
        """Boolean ``(N,)``: keypoints with a map point that is not an outlier."""
        return (self.map_point_ids >= 0) & ~self.outlier


def make_slam_frame(
    frame: Frame,
    features: Features,
    static: np.ndarray | None = None,
    min_depth: float = 0.1,
    max_depth: float = 8.0,
    dynamic_region: np.ndarray | None = None,
) -> SlamFrame:
    """Build the tracking view of an RGB-D ``frame`` from its ``features``.

    ``static`` is the screening verdict (``True`` = may be used), default all True.
    Depths outside ``[min_depth, max_depth]`` metres count as missing. ``dynamic_region``: the screened
    region ``(H, W)`` bool of the frame (the depth image's shape; an empty one is kept as None), or None.
    """
    cam: PinholeCamera = frame.camera
    n = len(features)
    uv = cam.undistort_points(features.uv.astype(np.float64)) if n else np.zeros((0, 2))
    z = keypoint_depths(frame.depth, features.uv, min_depth, max_depth) if n else np.zeros(0)
    pts = cam.backproject(uv, z) if n else np.zeros((0, 3))
    if static is None:
        static = np.ones(n, bool)
    static = np.asarray(static, bool).reshape(-1)
    if len(static) != n:
        raise ValueError(f"static mask has {len(static)} entries for {n} keypoints (frame {frame.index})")
    return SlamFrame(
        index=frame.index,
        timestamp=float(frame.timestamp),
        features=features,
        uv=uv,
        depth=z,
        points_c=pts,
        static=static.copy(),
        map_point_ids=np.full(n, -1, np.int64),
        outlier=np.zeros(n, bool),
        depth_image=frame.depth,
        dynamic_region=_region_of(dynamic_region, frame.depth),
        gray_image=frame.gray,
    )


def _region_of(region: np.ndarray | None, depth: np.ndarray | None) -> np.ndarray | None:
    if region is None or depth is None:
        return None
    region = np.asarray(region, bool)
    if region.shape != np.shape(depth):
        raise ValueError(f"dynamic region of shape {region.shape} for a depth image of shape {np.shape(depth)}")
    return region if region.any() else None


@dataclass(eq=False)
class KeyFrame:
    """A keyframe of the map.

    Attributes
    ----------
    id : keyframe id (0, 1, 2, ... in creation order; never reused).
    frame_index, timestamp : the frame it was made from.
    uv : ``(N, 2)`` undistorted keypoint pixels.
    descriptors : ``(N, 32)`` uint8.
    octave : ``(N,)`` pyramid levels; angle : ``(N,)`` degrees.
    points_c : ``(N, 3)`` camera-frame points from depth (metres, ``nan`` where none).
    map_point_ids : ``(N,)`` int64, map point of each keypoint, ``-1`` for none.
    static : ``(N,)`` bool screening verdict.
    parent_id : parent in the spanning tree (``-1`` for the first keyframe).
    thumbnail : small RGB image (for the viewer) or None.
    depth_small : the frame's depth reduced ``LoopClosingConfig.dense_factor`` times per side (block means,
        float32 m, 0 = none) for the loop pose's depth alignment, or None.
    bad : set when culled.
    """

    id: int
    frame_index: int
    timestamp: float
    _T_w_c: np.ndarray
    uv: np.ndarray
    descriptors: np.ndarray
    octave: np.ndarray
    angle: np.ndarray
    points_c: np.ndarray
    map_point_ids: np.ndarray
    static: np.ndarray
    parent_id: int = -1
    thumbnail: np.ndarray | None = None
    depth_small: np.ndarray | None = None
    bad: bool = False
    children: set[int] = field(default_factory=set)
    loop_edges: set[int] = field(default_factory=set)

    @property
    def T_w_c(self) -> np.ndarray:
        """``(4, 4)`` camera-to-world pose (a copy; set it with ``kf.T_w_c = T`` or :meth:`set_pose`)."""
        return self._T_w_c.copy()

    @T_w_c.setter
    def T_w_c(self, T: np.ndarray) -> None:
        self.set_pose(T)

    def set_pose(self, T_w_c: np.ndarray) -> None:
        T = np.asarray(T_w_c, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"keyframe {self.id}: pose must be a finite (4, 4) matrix, got {T.shape}")
        self._T_w_c = T.copy()

    @property
    def T_c_w(self) -> np.ndarray:
        return se3_inv(self._T_w_c)

    @property
    def center(self) -> np.ndarray:
        """Camera centre in the world frame ``(3,)`` metres."""
        return self._T_w_c[:3, 3].copy()

    def __len__(self) -> int:
        return len(self.uv)

    @classmethod
    def from_frame(cls, kf_id: int, frame: SlamFrame, thumbnail: np.ndarray | None = None) -> "KeyFrame":
        """A keyframe copying a tracked frame's keypoints, pose and (inlier) map point matches."""
        if frame.T_w_c is None:
            raise ValueError(f"frame {frame.index} has no pose; cannot make a keyframe")
        ids = np.where(frame.outlier, -1, frame.map_point_ids).astype(np.int64)
        return cls(
            id=kf_id,
            frame_index=frame.index,
            timestamp=frame.timestamp,
            _T_w_c=np.asarray(frame.T_w_c, float).copy(),
            uv=frame.uv.copy(),
            descriptors=frame.descriptors.copy(),
            octave=frame.octave.copy(),
            angle=frame.angle.copy(),
            points_c=frame.points_c.copy(),
            map_point_ids=ids,
            static=frame.static.copy(),
            thumbnail=thumbnail,
        )
