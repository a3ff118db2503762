"""Trajectories in the TUM format: ``timestamp tx ty tz qx qy qz qw`` per line.

A :class:`Trajectory` holds timestamps ``(N,)`` in seconds and poses ``T_w_c (N, 4, 4)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..geometry.se3 import pose_from_tum, pose_to_tum
from ..textfile import data_lines

__all__ = ["Trajectory", "TrajectoryError", "read_tum_trajectory", "write_tum_trajectory", "DUPLICATES"]


class TrajectoryError(ValueError):
    """A trajectory file is malformed, or two trajectories cannot be compared."""


@dataclass
class Trajectory:
    """Timestamped camera poses ``T_w_c``.

    Attributes
    ----------
    timestamps : ``(N,)`` seconds, increasing.
    poses : ``(N, 4, 4)`` camera-to-world transforms.
    """

    timestamps: np.ndarray
    poses: np.ndarray

    def __post_init__(self) -> None:
        self.timestamps = np.asarray(self.timestamps, dtype=np.float64).reshape(-1)
        self.poses = np.asarray(self.poses, dtype=np.float64)
        if self.poses.ndim != 3 or self.poses.shape[1:] != (4, 4):
            raise TrajectoryError(f"poses must be (N, 4, 4), got {self.poses.shape}")
        if len(self.poses) != len(self.timestamps):
            raise TrajectoryError(f"{len(self.timestamps)} timestamps but {len(self.poses)} poses")

    def __len__(self) -> int:
        return len(self.timestamps)

    @property
    def positions(self) -> np.ndarray:
        """``(N, 3)`` camera centres in the world frame (metres)."""
        return self.poses[:, :3, 3]

    def subset(self, index: np.ndarray) -> "Trajectory":
        return Trajectory(self.timestamps[index], self.poses[index])

    def transformed(self, T: np.ndarray, scale: float = 1.0) -> "Trajectory":
        """Left-multiply every pose by ``T`` after scaling positions by ``scale`` (alignment)."""
        P = self.poses.copy()
        P[:, :3, 3] *= scale
        return Trajectory(self.timestamps.copy(), np.asarray(T, dtype=np.float64) @ P)

    @property
    def path_length(self) -> float:
        """Length of the path through the camera centres (metres)."""
        if len(self) < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.positions, axis=0), axis=1).sum())


#: What :func:`read_tum_trajectory` does with rows sharing a timestamp.
DUPLICATES = ("error", "first")


def read_tum_trajectory(path: str | Path, duplicates: str = "error") -> Trajectory:
    """Read a TUM trajectory file; clear error naming file and line on a malformed row.

    Parameters
    ----------
    path : the file (``timestamp tx ty tz qx qy qz qw`` per line, ``#`` comments).
    duplicates : rows with the same timestamp are an error naming their lines (``"error"``,
        default: one duplicated row of an estimate moved its ATE from 0.15 to 0.9 m), or only
        the first of them (in file order) is kept (``"first"``).
    """
    if duplicates not in DUPLICATES:
        raise ValueError(f"duplicates must be one of {DUPLICATES}, got {duplicates!r}")
    path = Path(path)
    lines: list[tuple[int, str]] = []
    rows: list[list[float]] = []
    for lineno, s, parts in data_lines(path, TrajectoryError, "trajectory file"):
        if len(parts) != 8:
            raise TrajectoryError(
                f"{path}:{lineno}: expected 8 values 'timestamp tx ty tz qx qy qz qw', got {len(parts)}"
            )
        try:
            rows.append([float(x) for x in parts])
        except ValueError:
            raise TrajectoryError(f"{path}:{lineno}: non-numeric value in {s!r}") from None
        lines.append((lineno, s))
    if not rows:
        raise TrajectoryError(f"{path}: no poses in file")
    data = np.asarray(rows)  # checks on all rows at once; the first bad row is named
    bad = ~np.isfinite(data).all(axis=1)
    if bad.any():
        lineno, s = lines[int(np.argmax(bad))]
        raise TrajectoryError(f"{path}:{lineno}: non-finite value in {s!r}")
    zero = np.linalg.norm(data[:, 4:8], axis=1) < 1e-6
    if zero.any():
        raise TrajectoryError(f"{path}:{lines[int(np.argmax(zero))][0]}: quaternion has zero norm")
    ts = data[:, 0]
    order = np.argsort(ts, kind="stable")  # stable: equal stamps stay in file order
    dup = np.flatnonzero(np.diff(ts[order]) == 0) + 1  # positions (in order) repeating the previous stamp
    if len(dup):
        if duplicates == "error":
            first = [lines[order[k - 1]][0] for k in dup]
            again = [lines[order[k]][0] for k in dup]
            shown = ", ".join(f"{ts[order[k]]:.6f} on lines {a} and {b}" for k, a, b in list(zip(dup, first, again))[:3])
            more = f" (and {len(dup) - 3} more)" if len(dup) > 3 else ""
            raise TrajectoryError(
                f"{path}: {len(dup)} duplicated timestamp(s): {shown}{more}; remove them, or keep the first row "
                "of each (dynslam eval --dedupe first)"
            )
        order = np.delete(order, dup)
    ts = ts[order]
    arr = data[order, 1:]
    arr[:, 3:] /= np.linalg.norm(arr[:, 3:], axis=1, keepdims=True)
    return Trajectory(ts, pose_from_tum(arr))


def write_tum_trajectory(traj: Trajectory, path: str | Path, header: str | None = None) -> None:
    """Write a trajectory in TUM format (timestamps with 6 decimals, values with 9 digits)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rows = pose_to_tum(traj.poses) if len(traj) else np.zeros((0, 7))
    with path.open("w") as fh:
        if header:
            for line in header.splitlines():
                fh.write(f"# {line}\n")
        for t, r in zip(traj.timestamps, rows):
            fh.write(f"{t:.6f} " + " ".join(f"{v:.9f}" for v in r) + "\n")
