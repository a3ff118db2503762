"""What every peer script shares: the TUM layout read the way ``dynslam run`` reads it, the
command line, and the run folder a peer writes (``benchmarks/peers.py`` reads it back).

A peer script is run as ``python benchmarks/peer_NAME.py SEQDIR --out DIR [--max-frames N]
[--camera PRESET]`` and writes, each file atomically:

* ``DIR/trajectory.txt``: TUM format (``t tx ty tz qx qy qz qw``, ``T_w_c``), every tracked frame;
* ``DIR/timing.csv``: ``frame,timestamp,decode_ms,track_ms,total_ms,tracked``, one row per frame;
* ``DIR/peer.json``: ``peer``, ``frames``, ``tracked``, ``lost``, ``lost_frames``, ``loops``,
  ``timing_mean_ms``/``timing_median_ms`` (``{"decode": ms, "track": ms, "total": ms}``, as
  ``dynslam run``'s ``summary.json``), ``init_s``, ``wall_time_s``, ``settings``, ``errors``.

Each frame's time is measured inside the peer process: ``decode_ms`` reading its PNG files
(:func:`load_frame_images`), ``track_ms`` its track call, ``total_ms`` both. ``total`` is the one
``benchmarks/peers.py`` compares with dynslam's ``wall``, which includes decoding as well (the part its
read-ahead thread did not hide): both systems are timed from the files to the pose.
``python benchmarks/peer_NAME.py --check`` exits 0 when the peer's library imports, and 3 with
the reason otherwise. This module imports only the toolkit (MIT), never a peer library.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from dynslam_lab.camera import PinholeCamera, camera_for_sequence
from dynslam_lab.datasets.tum import DatasetError, associate, read_file_list
from dynslam_lab.evaluation import Trajectory, write_tum_trajectory

__all__ = [
    "CHECK_FAILED",
    "TumFrame",
    "read_tum_frames",
    "load_frame_images",
    "peer_parser",
    "parse_peer_args",
    "sequence_camera",
    "check_import",
    "package_version",
    "PeerRecorder",
    "write_atomic",
]

#: Exit code of ``--check`` when the peer's library cannot be imported.
CHECK_FAILED = 3


@dataclass(frozen=True)
class TumFrame:
    """One colour/depth pair of a TUM-layout sequence."""

    index: int
    timestamp: float  # colour timestamp, seconds
    rgb: Path
    depth: Path


def read_tum_frames(seqdir: str | Path, max_frames: int | None = None, max_diff: float = 0.02) -> list[TumFrame]:
    """The colour/depth pairs of a sequence, in time order, the frames ``dynslam run`` processes.

    ``associations.txt`` (``ts rgb/x.png ts depth/y.png`` per line) is used when the folder has
    one; otherwise ``rgb.txt`` and ``depth.txt`` are paired by nearest timestamp within
    ``max_diff`` seconds, each stamp used once (TUM's ``associate.py``, through the toolkit's
    :func:`~dynslam_lab.datasets.tum.associate`). ``max_frames`` keeps the first N pairs.
    Raises :class:`~dynslam_lab.datasets.tum.DatasetError` naming the file when a list is
    missing or malformed, or when no pair is found.
    """
    root = Path(seqdir)
    if not root.is_dir():
        raise DatasetError(f"{root}: sequence folder not found")
    if max_frames is not None and max_frames < 1:
        raise ValueError(f"max_frames must be >= 1, got {max_frames}")
    pairs: list[tuple[float, str, str]] = []
    assoc = root / "associations.txt"
    if assoc.is_file():
        stamps, rows = read_file_list(assoc, min_fields=4)
        pairs = [(float(t), r[0], r[2]) for t, r in zip(stamps, rows)]
    else:
        rgb_t, rgb_rows = read_file_list(root / "rgb.txt")
        d_t, d_rows = read_file_list(root / "depth.txt")
        pairs = [(float(rgb_t[i]), rgb_rows[i][0], d_rows[j][0]) for i, j in associate(rgb_t, d_t, max_diff)]
    if not pairs:
        raise DatasetError(f"{root}: no colour/depth pairs within {max_diff} s of each other")
    pairs = pairs[:max_frames]
    return [TumFrame(k, t, root / rgb, root / depth) for k, (t, rgb, depth) in enumerate(pairs)]


def load_frame_images(frame: TumFrame) -> tuple[np.ndarray, np.ndarray]:
    """``(bgr (H, W, 3) uint8, depth (H, W) uint16 raw units)`` of a frame, as ``cv2.imread`` gives them.

    Raises :class:`DatasetError` naming the file when it is missing, undecodable, or the depth
    image is not 16-bit single channel or differs in size from the colour image.
    """
    bgr = cv2.imread(str(frame.rgb), cv2.IMREAD_COLOR)
    if bgr is None:
        raise DatasetError(f"{frame.rgb}: colour image missing or undecodable")
    depth = cv2.imread(str(frame.depth), cv2.IMREAD_UNCHANGED)
    if depth is None:
        raise DatasetError(f"{frame.depth}: depth image missing or undecodable")
    if depth.ndim != 2 or depth.dtype != np.uint16:
        raise DatasetError(f"{frame.depth}: depth must be 16-bit single channel, got {depth.dtype} {depth.shape}")
    if depth.shape != bgr.shape[:2]:
        raise DatasetError(f"{frame.depth}: depth size {depth.shape} differs from colour size {bgr.shape[:2]}")
    return bgr, depth


def peer_parser(description: str) -> argparse.ArgumentParser:
    """The command line every peer script accepts (its own options are added by the script)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("seqdir", nargs="?", metavar="SEQDIR", help="TUM-layout sequence folder")
    ap.add_argument("--out", metavar="DIR", help="run folder to write (created; must not hold a run already)")
    ap.add_argument("--max-frames", type=int, default=None, metavar="N", help="only the first N frames")
    ap.add_argument("--camera", default=None, metavar="PRESET",
                    help="camera preset (default: camera.json of the sequence, else from the folder name)")
    ap.add_argument("--check", action="store_true", help="only check that the peer's library imports (exit 0 or 3)")
    return ap


def parse_peer_args(ap: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    """Parse, and require SEQDIR and --out unless ``--check``."""
    args = ap.parse_args(argv)
    if not args.check and (args.seqdir is None or args.out is None):
        ap.error("SEQDIR and --out are required (or --check)")
    return args


def check_import(module: str) -> int:
    """``--check``: print the module's version and return 0, or print why it fails and return 3."""
    import importlib

    try:
        mod = importlib.import_module(module)
    except Exception as exc:  # ImportError, or OSError from a missing system library
        print(f"{module} unavailable: {type(exc).__name__}: {exc}")
        return CHECK_FAILED
    print(f"{module} {getattr(mod, '__version__', '(no version)')}")
    return 0


def package_version(dist: str) -> str | None:
    """Installed version of a distribution (``pyorbslam3``, ``open3d-cpu``), or None."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(dist)
    except PackageNotFoundError:
        return None


def write_atomic(path: Path, write) -> None:
    """Create ``path`` atomically: ``write(tmp_path)`` fills a temporary file in the same folder,
    which is then renamed; ``write`` may also be a string, the file's text."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    os.close(fd)
    try:
        if isinstance(write, str):
            Path(tmp).write_text(write)
        else:
            write(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


@dataclass
class PeerRecorder:
    """Per-frame results of a peer run, written as the run folder described in the module docstring.

    Usage: ``rec = PeerRecorder("open3d_tensor", seqdir, out, camera)``, then per frame
    ``rec.add(frame, track_ms, T_w_c or None, decode_ms)`` (or ``rec.error(frame, exc)`` for a frame
    that could not be read), then ``rec.write(settings)``.
    """

    peer: str
    seqdir: Path
    out: Path
    camera: PinholeCamera
    started: float = field(default_factory=time.perf_counter)
    init_s: float = 0.0
    loops: int = 0
    rows: list[tuple[int, float, float, float, bool]] = field(default_factory=list)  # frame, t, decode ms, track ms, tracked
    stamps: list[float] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.out = Path(self.out)
        if (self.out / "peer.json").exists() or (self.out / "trajectory.txt").exists():
            raise FileExistsError(f"{self.out}: already holds a run (peer.json / trajectory.txt); choose another --out")
        self.out.mkdir(parents=True, exist_ok=True)

    def add(self, frame: TumFrame, track_ms: float, T_w_c: np.ndarray | None, decode_ms: float = 0.0) -> None:
        """Record one frame: its track time and the time decoding its images (ms), and its pose, or
        None when the peer lost it."""
        ok = T_w_c is not None and bool(np.isfinite(T_w_c).all())
        self.rows.append((frame.index, frame.timestamp, float(decode_ms), float(track_ms), ok))
        if ok:
            self.stamps.append(frame.timestamp)
            self.poses.append(np.asarray(T_w_c, dtype=np.float64))

    def error(self, frame: TumFrame, exc: Exception) -> None:
        """A frame the peer could not process: logged on stderr, counted lost, the run goes on."""
        msg = f"frame {frame.index} ({frame.rgb.name}): {exc}"
        print(f"warning: {msg}", file=sys.stderr)
        self.errors.append(msg)
        self.rows.append((frame.index, frame.timestamp, float("nan"), float("nan"), False))

    def trajectory(self) -> Trajectory:
        if not self.poses:
            return Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
        return Trajectory(np.asarray(self.stamps), np.stack(self.poses))

    def summary(self, settings: dict) -> dict:
        ms = np.array([(r[2], r[3]) for r in self.rows], dtype=np.float64).reshape(-1, 2)
        ms = ms[np.isfinite(ms).all(axis=1)]
        ms = {"decode": ms[:, 0], "track": ms[:, 1], "total": ms.sum(axis=1)}
        lost = [r[0] for r in self.rows if not r[4]]
        mean = {k: float(v.mean()) if len(v) else float("nan") for k, v in ms.items()}
        median = {k: float(np.median(v)) if len(v) else float("nan") for k, v in ms.items()}
        return {
            "peer": self.peer,
            "sequence": str(self.seqdir),
            "camera": self.camera.name,
            "frames": len(self.rows),
            "tracked": len(self.rows) - len(lost),
            "lost": len(lost),
            "lost_frames": lost,
            "loops": int(self.loops),
            "timing_mean_ms": mean,
            "timing_median_ms": median,
            "init_s": float(self.init_s),
            "wall_time_s": time.perf_counter() - self.started,
            "settings": settings,
            "errors": self.errors,
        }

    def write(self, settings: dict, trajectory: Trajectory | None = None) -> dict:
        """Write ``trajectory.txt`` (``trajectory`` or the recorded poses), ``timing.csv`` and
        ``peer.json``; returns the summary."""
        traj = self.trajectory() if trajectory is None else trajectory
        header = f"{self.peer} on {self.seqdir}: T_w_c\ntimestamp tx ty tz qx qy qz qw"
        write_atomic(self.out / "trajectory.txt", lambda tmp: write_tum_trajectory(traj, tmp, header=header))
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["frame", "timestamp", "decode_ms", "track_ms", "total_ms", "tracked"])
        for i, t, dec, ms, ok in self.rows:
            w.writerow([i, f"{t:.6f}", f"{dec:.3f}", f"{ms:.3f}", f"{dec + ms:.3f}", int(ok)])
        write_atomic(self.out / "timing.csv", buf.getvalue())
        summary = self.summary(settings)
        write_atomic(self.out / "peer.json", json.dumps(summary, indent=1) + "\n")
        return summary


def sequence_camera(seqdir: str | Path, preset: str | None) -> PinholeCamera:
    """The camera of a sequence (``camera.json``, else the folder name), or the named preset."""
    return camera_for_sequence(seqdir, preset)
