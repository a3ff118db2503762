"""The multi-frame free-space test: does a point now stand where earlier frames saw through?

Chang et al. 2021 (Sec. III-B, eq. 2) compare each keypoint with the previous frame only: a
mover must move 4 px or 0.1 m in one frame (33 ms) to be seen, and a slow one (a box pushed at
0.3 m/s two metres away: 2.6 px per frame) never is. DynaSLAM (Bescos et al. 2018, Sec. III-C)
compares each frame with the **several earlier keyframes** that overlap it most and tests depth:
a keypoint ``x`` of a keyframe is projected into the current frame with the poses, giving a
predicted depth ``z_proj``; when the current frame measures ``z'`` there and
``z_proj - z' > tau_z``, something now stands in front of where the static point should be,
and the pixel is dynamic.

We run the same test the other way round, from the current frame into each earlier frame ``j``
(so every current keypoint and pixel gets a verdict), at several time offsets (``offsets``,
default 1, 2, 4, 8 and 16 frames back: a slow mover has moved far enough 16 frames ago, a fast
one already in the previous frame). With the current point ``X_w`` (back-projected with its
depth and the reference pose of :mod:`.reference_pose`), its projection into ``j`` at predicted
depth ``z_p``, and the depth ``z_j`` that frame ``j`` measured at that pixel:

* ``z_j - z_p > tau``: frame ``j`` saw *through* the place where the point is now: the point was
  not there then. It moved (or was carried in): **violation**, dynamic evidence. No static
  point can produce it, whatever the occlusions, which is why this test alone is precise.
* ``z_p - z_j > tau``: something stood in front of the point in frame ``j`` (an occlusion,
  possibly by a mover): no verdict.
* otherwise frame ``j`` **agrees**.

``tau = max(depth_m, depth_quadratic * z_p^2)`` (the Kinect's depth error grows with ``z^2``,
Khoshelham & Elberink 2012; :mod:`.multiview`). Frame ``j``'s depth is first eroded by a
``min_filter_px`` minimum filter, so that a point beside a depth edge meets the nearer surface
and a small pose error at an edge cannot fake a violation; holes (0) spread with the filter and
give no verdict.

The **backward** test is ours: each point of frame ``j`` is projected into the current frame; where
the current frame sees through it (``z_c - z_p > tau``), the point has **vanished**. That marks
a receding mover (the forward test cannot: from the current frame it looks occluded) but also
background that a mover has just uncovered, so it is used only by the region stage
(:mod:`.regions`), never as a keypoint's verdict.

Both run densely on a reduced grid (``factor``, default 4: 160x120 for 640x480) for the region
stage, and the forward test also at every keypoint at full resolution.

The **2-D test** is Chang et al.'s eq. 2 (:mod:`.multiview`) against an older frame (``lk_offset``,
default 8 frames back) instead of the previous one: a flat face sliding within its own plane keeps
its depth, and a mover that starts slowly has moved 2-3 cm (6 px at 2 m) after 8 frames but not 4 px
in any one. Each keypoint with depth is predicted into that frame as if static; pyramidal LK starts
at the prediction (``OPTFLOW_USE_INITIAL_FLOW``) and is checked forward-backward; where the older
frame's depth agrees with the prediction (the point was visible then), a keypoint found more than
``reprojection_px`` from its prediction has moved (ours), provided its displacement against the previous
frame points the same way by at least ``direction_min_px`` and a quarter of its per-frame share: a mover
keeps its direction, LK locked on the wrong repeat of a pattern does not.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry.se3 import se3_inv

__all__ = ["MultiFrameConfig", "FreeSpace", "free_space_test", "eroded_depth", "grid_points", "vanished_test"]


@dataclass(frozen=True)
class MultiFrameConfig:
    """Parameters of the multi-frame free-space test (DynaSLAM, Bescos et al. 2018; Chang et al. 2021 eq. 2)."""

    offsets: tuple[int, ...] = (1, 2, 4, 8, 16)  # earlier frames judged against, in frames back; ours (DynaSLAM: 5 keyframes)
    lk_offset: int = 8  # the earlier frame of the 2-D test (frames back; the nearest kept one with a pose); 0 = off; ours
    reprojection_px: float = 3.0  # 2-D test: keypoint this far from where a static point would be (px); Chang et al. 2021: 4 (one frame)
    direction_min_px: float = 0.25  # ... and moved at least this far the same way since the previous frame (px); ours
    depth_m: float = 0.1  # free-space margin tau (m); Chang et al. 2021: 0.1 (DynaSLAM's tau_z 0.4 on TUM)
    depth_quadratic: float = 0.01  # tau grows as depth_quadratic * z^2 (1/m); ours, as in MultiViewConfig
    min_filter_px: int = 2  # radius of the minimum filter on the earlier frame's depth (full-res px); ours
    factor: int = 4  # reduction of the dense grid (4 -> 160x120 at 640x480); ours
    border_px: float = 1.0  # projections closer than this to the image edge give no verdict (px); ours
    far_every: int = 16  # a frame leaving the history is kept as a far frame when this many frames passed since the last one; ours
    far_count: int = 8  # far frames kept (reduced depth and pose only; 8 x 16 frames = 4 s at 30 Hz); 0 = off; ours
    far_min_filter_cells: int = 3  # minimum filter on a far frame's reduced depth (cells of `factor` px): covers the pose drift of seconds (3 cells = 12 px, 1.3 deg); ours
    far_reset_m: float = 0.05  # a correction of the kept poses larger than this (a loop closure) drops the far frames (m); ours

    def __post_init__(self) -> None:
        if not self.offsets or any(int(o) < 1 for o in self.offsets):
            raise ValueError(f"MultiFrameConfig.offsets must be frame offsets >= 1, got {self.offsets}")
        if self.depth_m <= 0 or self.depth_quadratic < 0:
            raise ValueError("MultiFrameConfig: depth_m must be > 0 (m) and depth_quadratic >= 0 (1/m)")
        if self.min_filter_px < 0 or self.factor < 1 or self.border_px < 0:
            raise ValueError("MultiFrameConfig: min_filter_px >= 0, factor >= 1 and border_px >= 0 required")
        if self.lk_offset < 0 or self.reprojection_px <= 0 or self.direction_min_px < 0:
            raise ValueError("MultiFrameConfig: lk_offset must be >= 0 (frames), reprojection_px > 0 and direction_min_px >= 0 (px)")
        if self.far_every < 1:
            raise ValueError(f"MultiFrameConfig.far_every must be >= 1 (frames), got {self.far_every}")
        if self.far_min_filter_cells < 0 or self.far_reset_m <= 0:
            raise ValueError("MultiFrameConfig: far_min_filter_cells must be >= 0 (cells) and far_reset_m > 0 (m)")
        if self.far_count < 0:
            raise ValueError(f"MultiFrameConfig.far_count must be >= 0 (frames kept; 0 = off), got {self.far_count}")

    @property
    def history_length(self) -> int:
        """Frames the screener keeps for this test."""
        return int(max(self.offsets))


@dataclass
class FreeSpace:
    """Forward test of ``M`` points against ``J`` earlier frames.

    Attributes
    ----------
    violations : ``(M,)`` int, earlier frames that saw through the point.
    agreements : ``(M,)`` int, earlier frames whose depth agrees.
    occlusions : ``(M,)`` int, earlier frames that saw something in front of the point.
    tested : ``(M,)`` int, earlier frames that gave a verdict (violation or agreement).
    margin_m : ``(M,)`` largest ``z_j - z_p - tau`` over the frames (m; > 0 is a violation), nan untested.
    """

    violations: np.ndarray
    agreements: np.ndarray
    occlusions: np.ndarray
    tested: np.ndarray
    margin_m: np.ndarray


def eroded_depth(depth: np.ndarray, radius: int) -> np.ndarray:
    """Minimum filter of a depth image over a ``(2 r + 1)^2`` square (holes, 0, spread)."""
    if radius <= 0:
        return np.asarray(depth, np.float32)
    k = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * radius + 1, 2 * radius + 1))
    return cv2.erode(np.asarray(depth, np.float32), k)


def grid_points(depth: np.ndarray, camera) -> tuple[np.ndarray, np.ndarray]:
    """Camera points ``(K, 3)`` float32 of the pixels of a depth grid that have depth (``camera`` of
    that grid), and their flat indices ``(K,)`` in the grid."""
    h, w = depth.shape
    z = depth.reshape(-1)
    keep = np.flatnonzero(z > 0)
    v, u = np.divmod(keep, w)
    zk = z[keep].astype(np.float32)
    P = np.empty((len(keep), 3), np.float32)
    P[:, 0] = (u.astype(np.float32) - camera.cx) * (zk / camera.fx)
    P[:, 1] = (v.astype(np.float32) - camera.cy) * (zk / camera.fy)
    P[:, 2] = zk
    return P, keep


def _project(P_c: np.ndarray, camera, shape: tuple[int, int], border: float):
    """Nearest pixels of camera points ``(..., 3)``: ``(z, flat index, inside)`` (index 0 outside)."""
    P = np.asarray(P_c, np.float32)
    return _pixels(P[..., 0], P[..., 1], P[..., 2], camera, shape, border)


def _pixels(x: np.ndarray, y: np.ndarray, z: np.ndarray, camera, shape: tuple[int, int], border: float):
    """:func:`_project` on the coordinates given apart (float32 arrays of one shape; ``x`` and ``y`` may
    be overwritten): ``(z, flat index (intp), inside)``. One pass per operation, in place where it can."""
    h, w = shape
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.divide(1.0, z, dtype=np.float32)
        u = np.multiply(x, camera.fx, dtype=np.float32)
        u *= inv
        u += np.float32(camera.cx)
        v = np.multiply(y, camera.fy, dtype=np.float32)
        v *= inv
        v += np.float32(camera.cy)
        inside = z > 0.05
        inside &= u >= border
        inside &= v >= border
        inside &= u <= w - 1 - border
        inside &= v <= h - 1 - border
        np.rint(u, out=u)
        np.rint(v, out=v)
    v *= w  # row * w + column: exact in float32 below 2^24 pixels
    v += u
    idx = np.where(inside, v, np.float32(0)).astype(np.intp)
    return z, idx, inside


def _tau(z: np.ndarray, config: MultiFrameConfig) -> np.ndarray:
    return np.maximum(config.depth_m, config.depth_quadratic * z * z)


def _into_frames(X: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points ``X (M, 3)`` moved by each of the poses ``T (J, 4, 4)``: their coordinates ``x, y, z``,
    each ``(J, M)`` float32 and contiguous (one small matrix product per pose, no ``(J, M, 3)`` layout)."""
    Xt = np.ascontiguousarray(np.asarray(X, np.float32).T)  # (3, M)
    T = np.asarray(T, np.float32)
    P = np.matmul(T[:, :3, :3], Xt)  # (J, 3, M)
    P += T[:, :3, 3:]
    return P[:, 0], P[:, 1], P[:, 2]


def free_space_test(X_w: np.ndarray, refs, camera, config: MultiFrameConfig, margin: bool = True) -> FreeSpace:
    """The forward test of world points ``X_w (M, 3)`` against earlier frames (all frames at once).

    Parameters
    ----------
    X_w : ``(M, 3)`` world points (m) of the current frame.
    refs : sequence of ``(T_w_c (4, 4), eroded depth (h, w))`` of the earlier frames, with
        ``camera`` the intrinsics of that depth grid.
    camera : intrinsics of the earlier frames' depth images.
    margin : compute ``margin_m`` (else it is all nan: the counts alone are cheaper).
    """
    X_w = np.asarray(X_w, np.float32).reshape(-1, 3)
    m = len(X_w)
    if not refs or m == 0:
        z = np.zeros(m, np.int64)
        return FreeSpace(z, z.copy(), z.copy(), z.copy(), np.full(m, np.nan))
    T = np.stack([se3_inv(T_w_j) for T_w_j, _ in refs])  # (J, 4, 4) T_j_w
    h, w = refs[0][1].shape
    x, y, zp = _into_frames(X_w, T)
    zp, idx, inside = _pixels(x, y, zp, camera, (h, w), config.border_px)
    zj = np.empty_like(zp)
    for j, (_, d) in enumerate(refs):
        np.take(np.asarray(d, np.float32).reshape(-1), idx[j], out=zj[j])
    inside &= zj > 0  # seen by frame j, with a reading there
    tau = _tau(zp, config)
    d = zj
    d -= zp  # z_j - z_p (nan or garbage where not inside: masked below)
    with np.errstate(invalid="ignore"):
        viol = ((d > tau) & inside).sum(axis=0)
        agree = ((np.abs(d) <= tau) & inside).sum(axis=0)
        occl = ((d < -tau) & inside).sum(axis=0)
        if margin:
            d -= tau
            d[~inside] = -np.inf
            out = d.max(axis=0).astype(np.float64)
            out[~np.isfinite(out)] = np.nan
        else:
            out = np.full(m, np.nan)
    return FreeSpace(viol, agree, occl, viol + agree, out)


def vanished_test(refs, T_w_c: np.ndarray, current_min: np.ndarray, camera, config: MultiFrameConfig) -> np.ndarray:
    """The backward test on a grid: ``(h, w)`` int, per current pixel the earlier frames one of whose
    points projected there and was seen through (the current depth, eroded, lies beyond it by more
    than ``tau``).

    Parameters
    ----------
    refs : sequence of ``(T_w_j (4, 4), camera points (K_j, 3))`` of the earlier frames (their grid
        points with depth, :func:`grid_points`).
    T_w_c : the current reference pose (camera -> world).
    current_min : ``(h, w)`` eroded current depth on the grid of ``camera``.
    """
    h, w = current_min.shape
    seen = np.zeros((max(len(refs), 1), h * w), bool)
    T_c_w = se3_inv(T_w_c)
    flat_min = current_min.reshape(-1)
    for j, (T_w_j, P) in enumerate(refs):
        x, y, z = _into_frames(P, (T_c_w @ T_w_j)[None])
        zp, idx, inside = _pixels(x[0], y[0], z[0], camera, (h, w), config.border_px)
        zc = flat_min.take(idx)
        inside &= zc > 0
        zc -= zp
        with np.errstate(invalid="ignore"):
            inside &= zc > _tau(zp, config)
        seen[j, idx[inside]] = True
    return seen.sum(axis=0).reshape(h, w)

