"""Dense static point cloud of a run: keyframes back-projected with dynamic pixels left out.

Chang et al. 2021 (YOLACT-based SLAM, IEEE TIM), Section III-D: "Since RGB-D has depth
information, we aim to ... build a point cloud map and octree map with the static
information"; Fig. 9 (b): the map "reconstructed from updated keyframes, with statistical
filters and voxel filters, which have neater boundaries and less noise".

Our reading, step by step, for each keyframe ``i`` with pose ``T_w_c_i``:

1. leave out the pixels without depth, outside ``[min_depth, max_depth]``, at depth edges
   (flying pixels, :func:`~dynslam_lab.mapping.pointcloud.depth_edge_mask`) and in the
   dynamic mask ``M_i`` dilated by ``dilate_px`` pixels (masks are a few pixels short of
   object borders, and a person's outline is where depth jumps);
2. back-project the rest, every ``stride``-th pixel, ``X_w = T_w_c_i K^-1 z (u, v, 1)``;
3. fuse into a voxel grid (centroid per voxel of side ``voxel_size``, PCL ``VoxelGrid``);

then over the whole map:

4. drop voxels seen by fewer than ``min(min_observations, K)`` of the ``K`` keyframes (a
   person who stood still for a moment is seen only then; the static scene again and again);
5. statistical outlier removal (``d_i <= mu + alpha sigma`` over mean k-NN distances);
6. write ``OUTDIR/map.ply``.

:func:`write_dense_map` is what ``dynslam run`` calls at its end; :func:`map_quality`
scores a map against a synthetic sequence's truth (moving-object masks, true depth).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import cv2
import numpy as np

from ..datasets.frame import Frame
from .ply import write_ply
from .pointcloud import VoxelAccumulator, backproject_frame, depth_edge_mask, statistical_outlier_mask, voxel_keys

__all__ = ["DenseMapConfig", "DenseMap", "MapQuality", "static_exclusion_mask", "build_dense_map",
           "write_dense_map", "read_keyframes", "map_quality", "pose_alignment"]


@dataclass(frozen=True)
class DenseMapConfig:
    """Parameters of the dense static map (Chang et al. 2021, Sec. III-D, filters of PCL)."""

    stride: int = 2  # pixels; back-project every 2nd row/column (ours: 76,800 points per 640x480 keyframe)
    min_depth: float = 0.3  # metres; nearer readings dropped (Kinect v1 minimum range ~0.4 m, TUM)
    max_depth: float = 4.0  # metres; farther readings dropped (Kinect noise grows with z^2; ours)
    dilate_px: int = 5  # pixels; dynamic masks grown by this radius before leaving them out (ours)
    edge_rel_jump: float = 0.04  # relative depth jump marking a flying pixel, |dz| > 0.04 z (ours)
    voxel_size: float = 0.02  # metres; voxel filter leaf size (PCL VoxelGrid; Chang et al. give none)
    min_observations: int = 2  # keyframes that must see a voxel for it to stay, at most all of them (ours; 1 = off)
    sor_k: int = 20  # neighbours of the statistical filter (PCL setMeanK; PCL tutorial uses 50)
    sor_std_ratio: float = 2.0  # alpha of the statistical filter (PCL setStddevMulThresh; tutorial 1.0)
    batch_keyframes: int = 8  # keyframes back-projected before each merge into the voxel grid (memory/speed)

    def __post_init__(self) -> None:
        if self.stride < 1:
            raise ValueError(f"DenseMapConfig.stride must be >= 1 pixel, got {self.stride}")
        if not 0 <= self.min_depth < self.max_depth:
            raise ValueError(f"DenseMapConfig: need 0 <= min_depth < max_depth, got {self.min_depth}, {self.max_depth}")
        if self.dilate_px < 0:
            raise ValueError(f"DenseMapConfig.dilate_px must be >= 0, got {self.dilate_px}")
        if self.edge_rel_jump <= 0:
            raise ValueError(f"DenseMapConfig.edge_rel_jump must be > 0, got {self.edge_rel_jump}")
        if self.voxel_size <= 0:
            raise ValueError(f"DenseMapConfig.voxel_size must be > 0 metres, got {self.voxel_size}")
        if self.min_observations < 1:
            raise ValueError(f"DenseMapConfig.min_observations must be >= 1, got {self.min_observations}")
        if self.sor_k < 0 or self.sor_std_ratio <= 0:
            raise ValueError(
                f"DenseMapConfig: sor_k must be >= 0 (0 = off) and sor_std_ratio > 0, got {self.sor_k}, {self.sor_std_ratio}"
            )
        if self.batch_keyframes < 1:
            raise ValueError(f"DenseMapConfig.batch_keyframes must be >= 1, got {self.batch_keyframes}")


@dataclass
class DenseMap:
    """A fused dense point cloud.

    Attributes
    ----------
    xyz : ``(N, 3)`` world points (metres), one per kept voxel.
    rgb : ``(N, 3)`` uint8 mean colours.
    n_obs : ``(N,)`` number of keyframes that saw each voxel.
    stats : counts after each step (``input_points``, ``voxels``, ``after_min_observations``,
        ``after_outlier_filter``, ``keyframes``, ``excluded_pixels``: pixels with depth left out).
    """

    xyz: np.ndarray
    rgb: np.ndarray
    n_obs: np.ndarray
    stats: dict = field(default_factory=dict)


def static_exclusion_mask(depth: np.ndarray, dynamic_mask: np.ndarray | None, config: DenseMapConfig) -> np.ndarray:
    """Pixels of one keyframe to leave out of the map: dilated dynamic mask and depth edges.

    Parameters
    ----------
    depth : ``(H, W)`` metres.
    dynamic_mask : ``(H, W)`` bool (True = dynamic), or None.
    config : :class:`DenseMapConfig` (``dilate_px``, ``edge_rel_jump``).

    Returns
    -------
    ``(H, W)`` bool, True where the pixel is left out.
    """
    exclude = depth_edge_mask(depth, config.edge_rel_jump)
    if dynamic_mask is not None:
        m = np.asarray(dynamic_mask)
        if m.shape != depth.shape:
            raise ValueError(f"dynamic mask shape {m.shape} does not match depth {depth.shape}")
        m = m.astype(bool)
        if config.dilate_px > 0 and m.any():
            r = config.dilate_px
            kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
            m = cv2.dilate(m.astype(np.uint8), kernel) > 0
        exclude |= m
    return exclude


def build_dense_map(
    frames: Iterable[tuple[Frame, np.ndarray, np.ndarray | None]],
    config: DenseMapConfig | None = None,
) -> DenseMap:
    """Fuse keyframes into a filtered dense static point cloud.

    Parameters
    ----------
    frames : iterable of ``(frame, T_w_c (4, 4), dynamic_mask (H, W) bool or None)``, one per
        keyframe; frames are consumed one at a time (a generator keeps memory low).
    config : :class:`DenseMapConfig`.

    Returns
    -------
    DenseMap
    """
    config = config or DenseMapConfig()
    acc = VoxelAccumulator(config.voxel_size)
    obs_keys = np.zeros(0, dtype=np.int64)  # sorted voxel keys seen so far ...
    obs_count = np.zeros(0, dtype=np.int64)  # ... and how many keyframes saw each
    batch_xyz: list[np.ndarray] = []
    batch_rgb: list[np.ndarray] = []
    batch_keys: list[np.ndarray] = []
    n_in = n_kf = n_excl = 0

    def flush() -> None:
        nonlocal obs_keys, obs_count
        if not batch_xyz:
            return
        acc.add(np.concatenate(batch_xyz), np.concatenate(batch_rgb))
        keys = np.concatenate([obs_keys] + batch_keys)
        weights = np.concatenate([obs_count, np.ones(len(keys) - len(obs_keys), np.int64)])
        obs_keys, inv = np.unique(keys, return_inverse=True)
        obs_count = np.bincount(inv, weights=weights, minlength=len(obs_keys)).astype(np.int64)
        batch_xyz.clear()
        batch_rgb.clear()
        batch_keys.clear()

    for frame, T_w_c, mask in frames:
        exclude = static_exclusion_mask(frame.depth, mask, config)
        s = config.stride
        n_excl += int(np.count_nonzero(exclude[::s, ::s] & (frame.depth[::s, ::s] > 0)))
        xyz, rgb = backproject_frame(
            frame.depth, frame.camera, T_w_c, frame.rgb, exclude, s, config.min_depth, config.max_depth
        )
        n_in += len(xyz)
        n_kf += 1
        batch_xyz.append(xyz)
        batch_rgb.append(rgb)
        batch_keys.append(np.unique(voxel_keys(xyz, config.voxel_size)))  # one vote per keyframe and voxel
        if len(batch_xyz) >= config.batch_keyframes:
            flush()
    flush()
    xyz, rgb = acc.points()
    if rgb is None:
        rgb = np.zeros((len(xyz), 3), np.uint8)
    stats = {"keyframes": n_kf, "input_points": n_in, "excluded_pixels": n_excl, "voxels": len(xyz)}
    # The accumulator's keys and obs_keys are both the sorted set of occupied voxels.
    n_obs = obs_count if len(xyz) else np.zeros(0, np.int64)
    # A run with fewer keyframes than min_observations keeps what all of them saw.
    keep = n_obs >= min(config.min_observations, max(n_kf, 1))
    xyz, rgb, n_obs = xyz[keep], rgb[keep], n_obs[keep]
    stats["after_min_observations"] = len(xyz)
    if config.sor_k > 0 and len(xyz) > config.sor_k:
        keep = statistical_outlier_mask(xyz, config.sor_k, config.sor_std_ratio)
        xyz, rgb, n_obs = xyz[keep], rgb[keep], n_obs[keep]
    stats["after_outlier_filter"] = len(xyz)
    return DenseMap(xyz=xyz, rgb=rgb, n_obs=n_obs, stats=stats)


def read_keyframes(outdir: str | Path) -> dict[str, np.ndarray]:
    """Read ``OUTDIR/keyframes.npz`` (``ids``, ``frame_index``, ``timestamps``, ``poses``, ``loop_edges``).

    Raises ``FileNotFoundError``/``ValueError`` naming the file when it is missing or malformed.
    """
    path = Path(outdir) / "keyframes.npz"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: keyframes file not found (is {outdir} the output folder of 'dynslam run'?)")
    with np.load(path) as z:
        data = {k: z[k] for k in z.files}
    for key in ("ids", "frame_index", "poses"):
        if key not in data:
            raise ValueError(f"{path}: missing array {key!r} (has {sorted(data)})")
    K = len(data["ids"])
    if data["poses"].shape != (K, 4, 4):
        raise ValueError(f"{path}: poses must have shape ({K}, 4, 4), got {data['poses'].shape}")
    if data["frame_index"].shape != (K,):
        raise ValueError(f"{path}: frame_index must have shape ({K},), got {data['frame_index'].shape}")
    data.setdefault("timestamps", np.full(K, np.nan))
    data.setdefault("loop_edges", np.zeros((0, 2), np.int64))
    return data


def write_dense_map(sequence, outdir: str | Path, dynamic_masks: dict[int, np.ndarray] | None,
                    config: DenseMapConfig | None = None, path: str | Path | None = None) -> Path:
    """Build the dense static map of a run and write it to ``OUTDIR/map.ply``.

    Parameters
    ----------
    sequence : the :class:`~dynslam_lab.datasets.tum.TumSequence` the run processed.
    outdir : run output folder holding ``keyframes.npz``.
    dynamic_masks : frame index -> ``(H, W)`` bool dynamic pixels (the screener's
        ``region_mask``), or None; keyframes without an entry keep all their pixels.
    config : :class:`DenseMapConfig`.
    path : where to write the PLY instead of ``OUTDIR/map.ply`` (the run writer passes a
        temporary file that it then renames, so ``map.ply`` appears whole or not at all).

    Returns
    -------
    Path of ``map.ply`` (written also when no point survives: an empty, valid PLY).
    """
    outdir = Path(outdir)
    kf = read_keyframes(outdir)
    dynamic_masks = dynamic_masks or {}
    n = len(sequence)
    bad = [int(i) for i in kf["frame_index"] if not 0 <= int(i) < n]
    if bad:
        raise ValueError(f"{outdir / 'keyframes.npz'}: frame_index {bad[:5]} outside the sequence's {n} frames")

    def frames():
        for idx, T in zip(kf["frame_index"], kf["poses"]):
            yield sequence[int(idx)], T, dynamic_masks.get(int(idx))

    dmap = build_dense_map(frames(), config)
    return write_ply(outdir / "map.ply" if path is None else path, dmap.xyz, dmap.rgb,
                     comment=f"dynslam_lab dense static map, {dmap.stats['keyframes']} keyframes")


@dataclass(frozen=True)
class MapQuality:
    """Scores of a dense map against a synthetic sequence's truth.

    Attributes
    ----------
    dynamic_fraction : share of scored points lying on a moving object in some truth view.
    median_surface_error, p90_surface_error : metres; per point, the smallest
        ``|z_point - z_true(u, v)|`` over the truth views that see it (distance along the ray
        to the true surface).
    scored : points seen by at least one truth view (the others are not scored).
    total : points in the map.
    """

    dynamic_fraction: float
    median_surface_error: float
    p90_surface_error: float
    scored: int
    total: int


def map_quality(
    xyz: np.ndarray,
    views: Iterable[tuple[Frame, np.ndarray, np.ndarray]],
    on_surface_tol: float = 0.03,
) -> MapQuality:
    """Score a map against truth views: ground-truth pose, true depth and moving-object mask.

    A point is *on a moving object* when, in some view, it projects inside the moving mask and
    its depth is within ``on_surface_tol`` of the true depth there (it lies on the object's
    surface at that moment, not merely behind it).

    Parameters
    ----------
    xyz : ``(N, 3)`` map points (world, metres).
    views : iterable of ``(frame, T_w_c_true (4, 4), moving_mask (H, W) bool)``; ``frame.depth``
        is the true depth (synthetic renderer).
    on_surface_tol : metres.

    Returns
    -------
    MapQuality
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"map_quality: xyz must be (N, 3), got {xyz.shape}")
    best = np.full(len(xyz), np.inf)
    on_moving = np.zeros(len(xyz), dtype=bool)
    for frame, T_w_c, moving in views:
        cam = frame.camera
        R, t = T_w_c[:3, :3], T_w_c[:3, 3]
        X_c = (xyz - t) @ R  # R^T (X_w - t)
        z = X_c[:, 2]
        front = z > 1e-6
        u = np.full(len(xyz), -1, np.int64)
        v = np.full(len(xyz), -1, np.int64)
        u[front] = np.floor(cam.fx * X_c[front, 0] / z[front] + cam.cx + 0.5).astype(np.int64)
        v[front] = np.floor(cam.fy * X_c[front, 1] / z[front] + cam.cy + 0.5).astype(np.int64)
        H, W = frame.depth.shape
        ok = front & (u >= 0) & (u < W) & (v >= 0) & (v < H)
        d = np.zeros(len(xyz))
        d[ok] = frame.depth[v[ok], u[ok]]
        ok &= d > 0
        err = np.where(ok, np.abs(z - d), np.inf)
        best = np.minimum(best, err)
        if moving is not None:
            mv = np.zeros(len(xyz), dtype=bool)
            mv[ok] = np.asarray(moving, dtype=bool)[v[ok], u[ok]]
            on_moving |= mv & (err < on_surface_tol)
    scored = np.isfinite(best)
    n = int(scored.sum())
    if n == 0:
        return MapQuality(float("nan"), float("nan"), float("nan"), 0, len(xyz))
    return MapQuality(
        dynamic_fraction=float(on_moving[scored].mean()),
        median_surface_error=float(np.median(best[scored])),
        p90_surface_error=float(np.percentile(best[scored], 90)),
        scored=n,
        total=len(xyz),
    )


def pose_alignment(est_poses: np.ndarray, gt_poses: np.ndarray) -> np.ndarray:
    """Rigid transform ``S`` (4, 4) taking a run's world frame to the ground truth's, from full poses.

    Minimises ``sum_k ||R_gt_k - R R_est_k||_F^2`` (chordal mean of ``R_gt_k R_est_k^T``,
    projected on SO(3) with an SVD) and then takes ``t = mean_k(t_gt_k - R t_est_k)``. Unlike
    the Umeyama alignment of camera *centres* used for ATE, it uses the orientations too,
    which matters for maps: a short, nearly straight path leaves the rotation about its own
    axis undetermined, and 0.4 degrees of it moves points 3 m away by 2 cm.

    Parameters
    ----------
    est_poses, gt_poses : ``(K, 4, 4)`` ``T_w_c`` of the same frames in the two world frames.

    Returns
    -------
    ``S`` with ``S @ est_poses[k] ~ gt_poses[k]``; map points move with ``X_gt = S X_est``.
    """
    E = np.asarray(est_poses, dtype=np.float64)
    G = np.asarray(gt_poses, dtype=np.float64)
    if E.ndim != 3 or E.shape[1:] != (4, 4) or E.shape != G.shape or len(E) == 0:
        raise ValueError(f"pose_alignment: need two (K, 4, 4) pose stacks of equal K > 0, got {E.shape} and {G.shape}")
    M = np.einsum("kij,klj->il", G[:, :3, :3], E[:, :3, :3])  # sum_k R_gt_k R_est_k^T
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    S = np.eye(4)
    S[:3, :3] = R
    S[:3, 3] = (G[:, :3, 3] - E[:, :3, 3] @ R.T).mean(axis=0)
    return S
