"""Point clouds from RGB-D keyframes, and the two filters of Chang et al. 2021.

Chang, Dong, Li, Tang, Zhang, "A real-time dynamic object segmentation framework for SLAM
system in dynamic scenes" (YOLACT-based SLAM), IEEE TIM 2021, Section III-D and Fig. 9:
"the static feature points are introduced to construct the 3-D point cloud map, and the
statistical filters and voxel filters are applied to remove noise in the point cloud".
The paper uses PCL's filters; we implement the same definitions with numpy and scipy.

Back-projection (pinhole, depth ``z`` in metres) and transfer to the world frame::

    X_c = z ((u - c_x) / f_x, (v - c_y) / f_y, 1),      X_w = R_w_c X_c + t_w_c

**Voxel filter** (PCL ``VoxelGrid``): space is cut into cubes of side ``s``; the points of
one cube, with integer key ``k = floor(X / s)``, are replaced by their centroid (and mean
colour). :class:`VoxelAccumulator` keeps per-voxel sums and counts so that keyframes can be
fused one batch at a time in bounded memory with exactly the centroid of all of them.

**Statistical outlier filter** (PCL ``StatisticalOutlierRemoval``, Rusu et al. 2008): for
each point the mean distance ``d_i`` to its ``k`` nearest neighbours; with ``mu`` and
``sigma`` the mean and standard deviation of all ``d_i``, a point is kept when::

    d_i <= mu + alpha * sigma

**Flying pixels.** At a depth discontinuity the sensor (and interpolation) produces points
between the foreground and the background. :func:`depth_edge_mask` marks pixels whose
depth differs from a 4-neighbour by more than a fraction of their own depth; they are left
out, as is done before fusion in KinectFusion-style systems.
"""

from __future__ import annotations

import numpy as np

from ..camera import PinholeCamera

__all__ = [
    "backproject_frame",
    "depth_edge_mask",
    "voxel_keys",
    "voxel_downsample",
    "VoxelAccumulator",
    "statistical_outlier_mask",
]


def depth_edge_mask(depth: np.ndarray, rel_jump: float) -> np.ndarray:
    """Pixels at a depth discontinuity.

    Parameters
    ----------
    depth : ``(H, W)`` metres, 0 = no reading.
    rel_jump : a pixel is an edge when ``|z - z_n| > rel_jump * z`` for one of its four
        neighbours ``z_n`` with a reading, or when a neighbour has no reading.

    Returns
    -------
    ``(H, W)`` bool, True at edges.
    """
    d = np.asarray(depth, dtype=np.float32)
    if d.ndim != 2:
        raise ValueError(f"depth_edge_mask: depth must be (H, W), got {d.shape}")
    pad = np.pad(d, 1, mode="edge")
    centre = pad[1:-1, 1:-1]
    edge = np.zeros(d.shape, dtype=bool)
    for n in (pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]):
        edge |= (n <= 0) | (np.abs(centre - n) > rel_jump * centre)
    return edge & (d > 0)


def backproject_frame(
    depth: np.ndarray,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    rgb: np.ndarray | None = None,
    exclude: np.ndarray | None = None,
    stride: int = 1,
    min_depth: float = 0.0,
    max_depth: float = np.inf,
) -> tuple[np.ndarray, np.ndarray | None]:
    """World points of the valid pixels of one depth image.

    Parameters
    ----------
    depth : ``(H, W)`` float metres, 0 = no reading.
    camera : intrinsics of the depth image.
    T_w_c : ``(4, 4)`` camera-to-world pose.
    rgb : ``(H, W, 3)`` uint8 colours registered with ``depth``, or None.
    exclude : ``(H, W)`` bool, pixels to leave out (dynamic objects, depth edges), or None.
    stride : take every ``stride``-th row and column.
    min_depth, max_depth : keep pixels with ``min_depth < z <= max_depth`` (metres).

    Returns
    -------
    xyz : ``(N, 3)`` world points (metres).
    colors : ``(N, 3)`` uint8, or None without ``rgb``.
    """
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f"backproject_frame: depth must be (H, W), got {depth.shape}")
    H, W = depth.shape
    T = np.asarray(T_w_c, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise ValueError(f"backproject_frame: T_w_c must be a finite (4, 4) pose, got shape {T.shape}")
    if stride < 1:
        raise ValueError(f"backproject_frame: stride must be >= 1, got {stride}")
    if rgb is not None and np.shape(rgb)[:2] != (H, W):
        raise ValueError(f"backproject_frame: rgb {np.shape(rgb)} does not match depth {depth.shape}")
    if exclude is not None and np.shape(exclude) != (H, W):
        raise ValueError(f"backproject_frame: exclude mask {np.shape(exclude)} does not match depth {depth.shape}")
    v, u = np.mgrid[0:H:stride, 0:W:stride]
    z = depth[::stride, ::stride].astype(np.float64)
    keep = np.isfinite(z) & (z > min_depth) & (z <= max_depth)
    if exclude is not None:
        keep &= ~np.asarray(exclude, dtype=bool)[::stride, ::stride]
    u, v, z = u[keep], v[keep], z[keep]
    X_c = np.stack([(u - camera.cx) / camera.fx * z, (v - camera.cy) / camera.fy * z, z], axis=1)
    xyz = X_c @ T[:3, :3].T + T[:3, 3]
    colors = None if rgb is None else np.asarray(rgb)[::stride, ::stride][keep].astype(np.uint8)
    return xyz, colors


def voxel_keys(xyz: np.ndarray, voxel_size: float) -> np.ndarray:
    """Voxel of each point: integer indices ``floor(X / s)`` packed into one int64 (21 bits per axis).

    Parameters
    ----------
    xyz : ``(N, 3)`` points (metres), within ``+-2^20 s`` of the origin.
    voxel_size : voxel side ``s`` (metres).

    Returns
    -------
    ``(N,)`` int64 keys; equal keys mean the same voxel.
    """
    ijk = np.floor(xyz / voxel_size).astype(np.int64) + (1 << 20)
    if (ijk < 0).any() or (ijk >= (1 << 21)).any():
        raise ValueError(f"points beyond +-{(1 << 20) * voxel_size:g} m cannot be keyed with voxel size {voxel_size} m")
    return (ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2]


def voxel_downsample(
    xyz: np.ndarray, voxel_size: float, rgb: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """Voxel-grid filter: the centroid (and mean colour) of the points in each occupied voxel.

    Parameters
    ----------
    xyz : ``(N, 3)`` points (metres).
    voxel_size : voxel side ``s`` in metres (> 0).
    rgb : ``(N, 3)`` uint8 colours, or None.

    Returns
    -------
    ``(M, 3)`` centroids and ``(M, 3)`` uint8 mean colours (or None), one per occupied voxel,
    in increasing voxel-key order.
    """
    acc = VoxelAccumulator(voxel_size)
    acc.add(xyz, rgb)
    return acc.points()


class VoxelAccumulator:
    """Running voxel-grid fusion: per-voxel sums of positions and colours, and counts.

    ``add`` merges a batch of points (e.g. one keyframe) in ``O(N log N)``; ``points``
    returns the centroid of everything added so far, identical to one
    :func:`voxel_downsample` call over all points at once.

    Parameters
    ----------
    voxel_size : voxel side in metres (> 0).
    """

    def __init__(self, voxel_size: float) -> None:
        if not np.isfinite(voxel_size) or voxel_size <= 0:
            raise ValueError(f"voxel_size must be a positive number of metres, got {voxel_size!r}")
        self.voxel_size = float(voxel_size)
        self.keys = np.zeros(0, dtype=np.int64)
        self.sum_xyz = np.zeros((0, 3))
        self.sum_rgb = np.zeros((0, 3))
        self.count = np.zeros(0, dtype=np.int64)
        self.has_color: bool | None = None

    def __len__(self) -> int:
        return len(self.keys)

    def add(self, xyz: np.ndarray, rgb: np.ndarray | None = None) -> None:
        """Add ``(N, 3)`` points (metres) with optional ``(N, 3)`` uint8 colours."""
        xyz = np.asarray(xyz, dtype=np.float64)
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise ValueError(f"VoxelAccumulator.add: xyz must be (N, 3), got {xyz.shape}")
        if rgb is not None and np.shape(rgb) != xyz.shape:
            raise ValueError(f"VoxelAccumulator.add: rgb must be {xyz.shape} like xyz, got {np.shape(rgb)}")
        if self.has_color is None:
            self.has_color = rgb is not None
        elif self.has_color != (rgb is not None):
            raise ValueError("VoxelAccumulator.add: mix of coloured and uncoloured batches")
        if len(xyz) == 0:
            return
        col = np.zeros_like(xyz) if rgb is None else np.asarray(rgb, dtype=np.float64)
        keys = np.concatenate([self.keys, voxel_keys(xyz, self.voxel_size)])
        uniq, inv = np.unique(keys, return_inverse=True)
        weights = np.concatenate([self.count, np.ones(len(xyz), dtype=np.int64)])
        sx = np.concatenate([self.sum_xyz, xyz])
        sc = np.concatenate([self.sum_rgb, col])
        self.count = np.bincount(inv, weights=weights, minlength=len(uniq)).astype(np.int64)
        self.sum_xyz = np.stack([np.bincount(inv, weights=sx[:, a], minlength=len(uniq)) for a in range(3)], axis=1)
        self.sum_rgb = np.stack([np.bincount(inv, weights=sc[:, a], minlength=len(uniq)) for a in range(3)], axis=1)
        self.keys = uniq

    def points(self) -> tuple[np.ndarray, np.ndarray | None]:
        """Centroids ``(M, 3)`` metres and mean colours ``(M, 3)`` uint8 (None without colour)."""
        c = np.maximum(self.count, 1)[:, None]
        xyz = self.sum_xyz / c
        rgb = np.clip(np.rint(self.sum_rgb / c), 0, 255).astype(np.uint8) if self.has_color else None
        return xyz, rgb


def statistical_outlier_mask(xyz: np.ndarray, k: int = 50, std_ratio: float = 1.0) -> np.ndarray:
    """Statistical outlier removal: keep points whose mean k-NN distance is not unusually large.

    Parameters
    ----------
    xyz : ``(N, 3)`` points (metres).
    k : neighbours per point (PCL ``setMeanK``; 50 in the PCL tutorial).
    std_ratio : ``alpha`` in ``d_i <= mu + alpha * sigma`` (PCL ``setStddevMulThresh``; 1.0).

    Returns
    -------
    ``(N,)`` bool, True for the points kept (inliers).
    """
    from scipy.spatial import cKDTree  # here: the viewer reads map.ply through mapping/ without loading scipy

    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"statistical_outlier_mask: xyz must be (N, 3), got {xyz.shape}")
    if k < 1:
        raise ValueError(f"statistical_outlier_mask: k must be >= 1, got {k}")
    if len(xyz) <= k:
        return np.ones(len(xyz), dtype=bool)
    dist, _ = cKDTree(xyz).query(xyz, k=k + 1, workers=1)  # first neighbour is the point itself
    d = dist[:, 1:].mean(axis=1)
    return d <= d.mean() + std_ratio * d.std()
