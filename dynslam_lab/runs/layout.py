"""The run folder: its files, one writer and one reader, with a schema version.

``dynslam run SEQDIR --out OUTDIR`` (and the ablation, the sweeps, the notebooks) write::

    OUTDIR/
      summary.json         frames, tracked, lost, keyframes, map points, loops, per-stage ms, the
                           config every stage ran with, ATE/RPE when ground truth exists,
                           ``schema_version`` and ``complete``
      trajectory.txt       TUM format (timestamp tx ty tz qx qy qz qw), every tracked frame
      timing.csv           one row per frame: frame, timestamp, then one column per stage (ms)
      keyframes.npz        ids (K,), frame_index (K,), timestamps (K,), poses (K, 4, 4) T_w_c,
                           loop_edges (L, 2) keyframe ids
      map_points.npz       xyz (M, 3) world metres, rgb (M, 3) uint8, n_obs (M,)
      dynamic_points.npz   xyz (D, 3) world positions of keypoints judged dynamic, frame (D,)
      thumbs/KFID.jpg      160x120 keyframe thumbnails (the viewer's image frustums)
      labels/NNNNNN.csv    per-frame keypoint tables (``--save-labels``)
      map.ply              the dense static point cloud (:mod:`dynslam_lab.mapping.dense`)

Every file is written atomically (a temporary file in the same folder, then a rename), so a
reader never sees half a file. :class:`RunWriter` writes, :func:`read_run` reads and checks
shapes, naming the file at fault.
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

from ..evaluation.trajectory import Trajectory, read_tum_trajectory, write_tum_trajectory
from ..mapping.ply import read_ply_header

__all__ = [
    "SCHEMA_VERSION",
    "FILES",
    "STAGES",
    "RunWriter",
    "RunContents",
    "read_run",
    "atomic_write",
]

#: Version of the layout above; bumped when a file changes meaning.
SCHEMA_VERSION = 1

#: File names of the run folder.
FILES = {
    "summary": "summary.json",
    "trajectory": "trajectory.txt",
    "timing": "timing.csv",
    "keyframes": "keyframes.npz",
    "map_points": "map_points.npz",
    "dynamic_points": "dynamic_points.npz",
    "thumbs": "thumbs",
    "labels": "labels",
    "dense_map": "map.ply",
}

#: Columns of ``timing.csv`` after ``frame, timestamp`` (ms). ``read``: waiting for the frame's
#: images (what the read-ahead did not hide); ``total``: ``System.process``; ``wall``: the frame's
#: wall time in the run loop (read + process). Detection runs beside ORB extraction, so the stages
#: may sum to more than ``total``.
STAGES = ("read", "orb", "detect", "screen", "track", "local_mapping", "loop", "total", "wall")


def atomic_write(path: Path, write: Callable[[Path], None]) -> None:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then rename it to ``path``."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        write(tmp_path)
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def _json_default(o: Any):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def _save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    def write(tmp: Path) -> None:
        with tmp.open("wb") as fh:
            np.savez(fh, **arrays)

    atomic_write(path, write)


class RunWriter:
    """Writes the files of one run folder (layout in the module docstring).

    Parameters
    ----------
    outdir : the run folder (created with ``thumbs/``, and ``labels/`` when ``labels``).
    labels : per-frame keypoint tables will be written.
    """

    def __init__(self, outdir: str | Path, labels: bool = False) -> None:
        self.outdir = Path(outdir)
        self.outdir.mkdir(parents=True, exist_ok=True)
        (self.outdir / FILES["thumbs"]).mkdir(exist_ok=True)
        if labels:
            (self.outdir / FILES["labels"]).mkdir(exist_ok=True)

    def path(self, key: str) -> Path:
        """Path of one of :data:`FILES`."""
        return self.outdir / FILES[key]

    def trajectory(self, trajectory: Trajectory) -> None:
        atomic_write(self.path("trajectory"), lambda tmp: write_tum_trajectory(
            trajectory, tmp, header="dynslam_lab trajectory: timestamp tx ty tz qx qy qz qw"))

    def timing(self, rows: list[dict]) -> None:
        """``rows``: one dict per frame with ``frame``, ``timestamp`` and stage ms (missing = nan)."""
        lines = ["frame,timestamp," + ",".join(STAGES)]
        for r in rows:
            lines.append(f"{r['frame']},{r['timestamp']:.6f}," + ",".join(f"{r.get(s, float('nan')):.3f}" for s in STAGES))
        atomic_write(self.path("timing"), lambda tmp: tmp.write_text("\n".join(lines) + "\n"))

    def keyframes(self, ids, frame_index, timestamps, poses, loop_edges) -> None:
        _save_npz(self.path("keyframes"), {
            "ids": np.asarray(ids, np.int64), "frame_index": np.asarray(frame_index, np.int64),
            "timestamps": np.asarray(timestamps, np.float64), "poses": np.asarray(poses, np.float64).reshape(-1, 4, 4),
            "loop_edges": np.asarray(loop_edges, np.int64).reshape(-1, 2)})

    def map_points(self, xyz, rgb, n_obs) -> None:
        _save_npz(self.path("map_points"), {"xyz": np.asarray(xyz, np.float64).reshape(-1, 3),
                                            "rgb": np.asarray(rgb, np.uint8).reshape(-1, 3),
                                            "n_obs": np.asarray(n_obs, np.int64).reshape(-1)})

    def dynamic_points(self, xyz, frame) -> None:
        _save_npz(self.path("dynamic_points"), {"xyz": np.asarray(xyz, np.float64).reshape(-1, 3),
                                                "frame": np.asarray(frame, np.int64).reshape(-1)})

    def thumbnail(self, kf_id: int, rgb: np.ndarray) -> None:
        """A keyframe's thumbnail (RGB uint8) as ``thumbs/KFID.jpg``."""
        path = self.path("thumbs") / f"{int(kf_id)}.jpg"

        def write(tmp: Path) -> None:
            ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
            if not ok:
                raise ValueError(f"{path}: could not encode the thumbnail")
            tmp.write_bytes(buf.tobytes())

        atomic_write(path, write)

    def labels(self, frame_index: int, table) -> None:
        """A frame's keypoint table (a pandas DataFrame) as ``labels/NNNNNN.csv``."""
        atomic_write(self.path("labels") / f"{int(frame_index):06d}.csv", lambda tmp: table.to_csv(tmp, index=False))

    def summary(self, summary: dict) -> None:
        """``summary.json`` with the schema version."""
        data = {"schema_version": SCHEMA_VERSION, **summary}
        atomic_write(self.path("summary"), lambda tmp: tmp.write_text(json.dumps(data, indent=2, default=_json_default) + "\n"))


@dataclass
class RunContents:
    """What a run folder holds (absent files are None / empty).

    Attributes
    ----------
    outdir : the folder.
    summary : ``summary.json`` as a dict.
    trajectory : ``trajectory.txt``.
    keyframes : arrays of ``keyframes.npz`` (ids, frame_index, timestamps, poses, loop_edges).
    map_points : arrays of ``map_points.npz`` (xyz, rgb or absent, n_obs or absent).
    dynamic_points : arrays of ``dynamic_points.npz`` (xyz, frame or absent).
    dense_path, dense_count : ``map.ply`` and its vertex count (header only: the points are
        read by :func:`dynslam_lab.mapping.ply.read_ply` when needed).
    thumbs : keyframe id -> thumbnail path.
    """

    outdir: Path
    summary: dict = field(default_factory=dict)
    trajectory: Trajectory | None = None
    keyframes: dict[str, np.ndarray] | None = None
    map_points: dict[str, np.ndarray] | None = None
    dynamic_points: dict[str, np.ndarray] | None = None
    dense_path: Path | None = None
    dense_count: int = 0
    thumbs: dict[int, Path] = field(default_factory=dict)

    @property
    def empty(self) -> bool:
        return all(x is None for x in (self.trajectory, self.keyframes, self.map_points, self.dense_path))


def _load_npz(path: Path, required: tuple[str, ...]) -> dict[str, np.ndarray] | None:
    if not path.is_file():
        return None
    try:
        with np.load(path) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable npz file ({exc})") from exc
    missing = [k for k in required if k not in data]
    if missing:
        raise ValueError(f"{path}: missing arrays {missing} (has {sorted(data)})")
    return data


def read_run(outdir: str | Path) -> RunContents:
    """Read a run folder (layout in the module docstring), checking each file's shapes.

    Raises ``FileNotFoundError`` for a missing folder and ``ValueError`` naming the file for a
    malformed one.
    """
    outdir = Path(outdir)
    if not outdir.is_dir():
        raise FileNotFoundError(f"{outdir}: run folder not found")
    run = RunContents(outdir=outdir)
    sp = outdir / FILES["summary"]
    if sp.is_file():
        try:
            summary = json.loads(sp.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"{sp}: invalid JSON ({exc})") from exc
        if not isinstance(summary, dict):
            raise ValueError(f"{sp}: expected a JSON object, got {type(summary).__name__}")
        run.summary = summary
    if (outdir / FILES["trajectory"]).is_file():
        run.trajectory = read_tum_trajectory(outdir / FILES["trajectory"])
    kf = _load_npz(outdir / FILES["keyframes"], ("ids", "frame_index", "poses"))
    if kf is not None:
        K = len(kf["ids"])
        if kf["poses"].shape != (K, 4, 4) or kf["frame_index"].shape != (K,):
            raise ValueError(f"{outdir / FILES['keyframes']}: {K} ids but poses {kf['poses'].shape} and "
                             f"frame_index {kf['frame_index'].shape}")
        kf["loop_edges"] = kf.get("loop_edges", np.zeros((0, 2), np.int64)).reshape(-1, 2)
        run.keyframes = kf
    mp = _load_npz(outdir / FILES["map_points"], ("xyz",))
    if mp is not None:
        mp["xyz"] = mp["xyz"].reshape(-1, 3)
        run.map_points = mp
    dp = _load_npz(outdir / FILES["dynamic_points"], ("xyz",))
    if dp is not None:
        dp["xyz"] = dp["xyz"].reshape(-1, 3)
        run.dynamic_points = dp
    ply = outdir / FILES["dense_map"]
    if ply.is_file():
        run.dense_path = ply
        run.dense_count = read_ply_header(ply).n_vertex
    thumbs = outdir / FILES["thumbs"]
    if thumbs.is_dir():
        run.thumbs = {int(p.stem): p for p in thumbs.glob("*.jpg") if p.stem.isdigit()}
    return run
