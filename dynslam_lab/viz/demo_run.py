"""A made-up run folder in the ``dynslam run`` layout, to try the viewer and time it.

The camera circles a 6 x 4 x 3 m room looking outwards, every ``keyframe_every``-th frame
is a keyframe, sparse map points and the dense map lie on the walls, a few "dynamic" points
float in the middle, the estimate is the ground truth plus a slow drift, and the last
keyframe closes a loop with the first. Nothing here is a SLAM result: it exercises every
file of the layout (``docs/architecture.md``) with known geometry.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from ..evaluation.trajectory import Trajectory, write_tum_trajectory
from ..mapping.ply import write_ply

__all__ = ["write_demo_run", "ROOM_HALF_EXTENT"]

#: half sizes of the room (metres): x in [-3, 3], y in [-1.5, 1.5] (y down), z in [-2, 2].
ROOM_HALF_EXTENT = np.array([3.0, 1.5, 2.0])


def _circle_poses(n: int, radius: float, turns: float) -> np.ndarray:
    """Cameras on a horizontal circle (y = 0), optical axis pointing outwards, y axis down."""
    a = np.linspace(0, 2 * np.pi * turns, n, endpoint=False)
    z = np.stack([np.cos(a), np.zeros(n), np.sin(a)], axis=1)  # optical axis, outwards
    y = np.tile([0.0, 1.0, 0.0], (n, 1))  # image y axis, down
    x = np.cross(y, z)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = np.stack([x, y, z], axis=2)
    poses[:, :3, 3] = 0.3 * radius * z
    return poses


def _wall_points(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points on the walls, floor and ceiling of the room box."""
    e = ROOM_HALF_EXTENT
    P = rng.uniform(-e, e, size=(n, 3))
    axis = rng.integers(0, 3, n)
    sign = rng.choice([-1.0, 1.0], n)
    P[np.arange(n), axis] = sign * e[axis]
    return P


def write_demo_run(outdir: str | Path, n_frames: int = 300, keyframe_every: int = 10, n_map_points: int = 5000,
                   n_dense_points: int = 200_000, seed: int = 0, thumbs: bool = True) -> Path:
    """Write a demo run folder and return its path.

    Parameters
    ----------
    outdir : folder to create (may exist).
    n_frames : tracked frames; ``n_frames // keyframe_every`` keyframes.
    n_map_points, n_dense_points : sizes of the sparse and dense maps.
    seed : random seed.
    thumbs : write the 160x120 keyframe thumbnails.
    """
    if n_frames < 2 or keyframe_every < 1:
        raise ValueError(f"write_demo_run: need n_frames >= 2 and keyframe_every >= 1, got {n_frames}, {keyframe_every}")
    rng = np.random.default_rng(seed)
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    stamps = 1000.0 + np.arange(n_frames) / 30.0
    gt = _circle_poses(n_frames, 2.0, 1.0)
    est = gt.copy()
    est[:, :3, 3] += np.linspace(0, 1, n_frames)[:, None] * np.array([0.05, 0.0, -0.04])  # slow drift
    write_tum_trajectory(Trajectory(stamps, est), out / "trajectory.txt")
    write_tum_trajectory(Trajectory(stamps, gt), out / "groundtruth.txt")
    kf_frames = np.arange(0, n_frames, keyframe_every)
    K = len(kf_frames)
    ids = np.arange(K)
    loops = np.array([[K - 1, 0]]) if K > 2 else np.zeros((0, 2), np.int64)
    np.savez(out / "keyframes.npz", ids=ids, frame_index=kf_frames, timestamps=stamps[kf_frames],
             poses=est[kf_frames], loop_edges=loops)
    xyz = _wall_points(n_map_points, rng)
    rgb = rng.integers(60, 200, size=(n_map_points, 3)).astype(np.uint8)
    np.savez(out / "map_points.npz", xyz=xyz, rgb=rgb, n_obs=rng.integers(2, 20, n_map_points))
    dyn = rng.normal(0, 0.3, size=(max(n_map_points // 20, 1), 3))
    np.savez(out / "dynamic_points.npz", xyz=dyn, frame=rng.integers(0, n_frames, len(dyn)))
    dense = _wall_points(n_dense_points, rng)
    shade = (120 + 100 * (dense[:, 1] - dense[:, 1].min()) / np.ptp(dense[:, 1])).astype(np.uint8)
    write_ply(out / "map.ply", dense, np.stack([shade, shade, shade], axis=1), comment="dynslam_lab demo run")
    if thumbs:
        (out / "thumbs").mkdir(exist_ok=True)
        for k in ids:  # one small JPEG per keyframe
            hue = int(180 * k / max(K, 1))
            img = np.full((120, 160, 3), (hue, 120, 220), np.uint8)
            img = cv2.cvtColor(img, cv2.COLOR_HSV2BGR)
            cv2.putText(img, f"KF {k}", (30, 70), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (255, 255, 255), 2)
            cv2.imwrite(str(out / "thumbs" / f"{k}.jpg"), img)
    summary = {"frames": n_frames, "tracked": n_frames, "lost": [], "keyframes": K, "map_points": n_map_points,
               "loops": len(loops), "demo": True}
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return out
