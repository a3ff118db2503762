"""Small TUM-layout sequences for the run-folder and command tests: rendered frames of the test
room (``tests/slam/scene.py``, exact poses), optionally broken the way a user's data can be."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from dynslam_lab.evaluation.trajectory import Trajectory, write_tum_trajectory
from tests.slam import scene

__all__ = ["write_sequence"]


def write_sequence(root: Path, n: int = 12, depth_bits: int = 16, gt_offset: float = 0.0, gt: bool = True,
                   depth_size: tuple[int, int] | None = None, flat: bool = False, back_and_forth: int = 1) -> Path:
    """Write ``n`` rendered frames (640x480) in the TUM layout under ``root``.

    depth_bits : 16 (TUM) or 8 (a lossy conversion: every frame fails).
    gt_offset : seconds added to the ground-truth timestamps (large: no overlap with the frames).
    depth_size : (h, w) to resize the depth images to (a colour/depth size mismatch).
    flat : grey images without texture (nothing can be tracked).
    back_and_forth : play the ``n`` frames forwards, then backwards, ... this many times (a longer
        sequence from the same cached renders; timestamps keep increasing at 30 Hz).
    """
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    once = scene.frames(40, "xyz")[:n]
    frames = [f for k in range(back_and_forth) for f in (once if k % 2 == 0 else once[::-1][1:-1])]
    stamps = 1000 + np.arange(len(frames)) / 30.0
    rgb_lines, depth_lines = [], []
    for f, t in zip(frames, stamps):
        ts = f"{t:.6f}"
        rgb = np.full_like(f.rgb, 128) if flat else f.rgb
        cv2.imwrite(str(root / "rgb" / f"{ts}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        depth = f.depth if depth_size is None else cv2.resize(f.depth, depth_size[::-1], interpolation=cv2.INTER_NEAREST)
        if depth_bits == 16:
            cv2.imwrite(str(root / "depth" / f"{ts}.png"), np.round(depth * 5000).astype(np.uint16))
        else:
            cv2.imwrite(str(root / "depth" / f"{ts}.png"), np.clip(depth * 50, 0, 255).astype(np.uint8))
        rgb_lines.append(f"{ts} rgb/{ts}.png")
        depth_lines.append(f"{ts} depth/{ts}.png")
    (root / "rgb.txt").write_text("# colour\n" + "\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("# depth\n" + "\n".join(depth_lines) + "\n")
    if gt:
        write_tum_trajectory(Trajectory(stamps + gt_offset, np.stack([f.T_w_c_gt for f in frames])), root / "groundtruth.txt")
    return root
