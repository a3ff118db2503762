"""The run folder: its files, one writer and one reader, with a schema version.

``dynslam run SEQDIR --out OUTDIR`` (and the ablation, the sweeps, the notebooks) write::

    OUTDIR/
      summary.json         frames, tracked, lost, keyframes, map points, loops, per-stage ms, the
                           config every stage ran with, ATE/RPE when ground truth exists,
                           ``schema_version`` and ``complete``
      trajectory.txt       TUM format (timestamp tx ty tz qx qy qz qw), every tracked frame
      timing.csv           one row per frame: frame, timestamp, then one column per stage (ms)
      screen_timing.csv    with a screener: one row per frame, the screen stage's parts (ms): each
                           screening stage, ``total``, then the shared products a stage computed
                           first (``lk``, ``reference_pose``, ...: parts of that stage's time)
      keyframes.npz        ids (K,), frame_index (K,), timestamps (K,), poses (K, 4, 4) T_w_c,
                           loop_edges (L, 2) keyframe ids
      map_points.npz       xyz (M, 3) world metres, rgb (M, 3) uint8, n_obs (M,)
      dynamic_points.npz   xyz (D, 3) world positions of keypoints judged dynamic, frame (D,)
      thumbs/KFID.jpg      160x120 keyframe thumbnails (the viewer's image frustums)
      labels/NNNNNN.csv    per-frame keypoint tables (``--save-labels``)
      map.ply              the dense static point cloud (:mod:`dynslam_lab.mapping.dense`)
      .dynslam-output.json, .dynslam-output.files, .dynslam-output.lock
                           the output folder's marker, journal and lock (:mod:`.folder`)

``summary.json`` also holds ``run_id``, ``state`` (``running``, ``complete``, ``interrupted``,
``failed``), ``failed_frames`` and ``files`` (relative path -> size and SHA-256).

The folder is opened as an :class:`~.folder.OutputFolder` (fresh, locked, marked; see
:mod:`.folder`). Every file is written atomically (a temporary file in the same folder, then a
rename), so a reader never sees half a file. ``summary.json`` is always written last and lists
every file of the run it vouches for with its size and SHA-256 (``files``), beside the run's id
(``run_id``, the marker's); while the other files are being rewritten it lists none of them.
So at every instant, whatever stopped the run (Ctrl-C, a crash, ``kill -9``), each file the
summary lists is exactly the one this run wrote, and ``complete: true`` appears only when all of
them, ``map.ply`` included, are there. :func:`verify_run` checks exactly that.

:class:`RunWriter` writes, :func:`read_run` reads and checks shapes, naming the file at fault.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

from ..evaluation.trajectory import Trajectory, read_tum_trajectory, write_tum_trajectory
from ..jsonio import dumps
from ..mapping.ply import read_ply_header
from .folder import OutputFolder, atomic_write, file_record, read_marker

__all__ = [
    "SCHEMA_VERSION",
    "FILES",
    "STAGES",
    "RunWriter",
    "RunContents",
    "read_run",
    "verify_run",
    "atomic_write",
    "REQUIRED_FILES",
]

#: Version of the layout above; bumped when a file changes meaning.
SCHEMA_VERSION = 1

#: File names of the run folder.
FILES = {
    "summary": "summary.json",
    "trajectory": "trajectory.txt",
    "timing": "timing.csv",
    "screen_timing": "screen_timing.csv",
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

#: Files a complete run has (``map.ply`` too, unless the summary records a ``dense_map_error``).
REQUIRED_FILES = ("trajectory", "timing", "keyframes", "map_points", "dynamic_points")


def _npz(arrays: dict[str, np.ndarray]) -> Callable[[Path], None]:
    def write(tmp: Path) -> None:
        with tmp.open("wb") as fh:
            np.savez(fh, **arrays)

    return write


class RunWriter:
    """Writes the files of one run folder (layout in the module docstring).

    Parameters
    ----------
    outdir : the run folder, or the open :class:`~.folder.OutputFolder` of the run (then every
        file is also recorded in its journal, and ``summary.json`` carries its id).
    labels : per-frame keypoint tables will be written.

    Attributes
    ----------
    files : relative path -> ``{"size", "sha256"}`` of every file written so far (what
        :meth:`summary` lists). A file is dropped from it while being rewritten.
    run_id : the output folder's id, or None for a plain folder.
    """

    def __init__(self, outdir: str | Path | OutputFolder, labels: bool = False) -> None:
        self.folder = outdir if isinstance(outdir, OutputFolder) else None
        self.outdir = self.folder.path if self.folder is not None else Path(outdir)
        self.run_id = self.folder.id if self.folder is not None else None
        self.files: dict[str, dict] = {}
        self.outdir.mkdir(parents=True, exist_ok=True)
        (self.outdir / FILES["thumbs"]).mkdir(exist_ok=True)
        if labels:
            (self.outdir / FILES["labels"]).mkdir(exist_ok=True)

    def path(self, key: str) -> Path:
        """Path of one of :data:`FILES`."""
        return self.outdir / FILES[key]

    def write(self, rel: str, write: Callable[[Path], None]) -> None:
        """Write the file ``rel`` (relative to the run folder) atomically with ``write(tmp)``."""
        target = self.folder.file(rel) if self.folder is not None else self.outdir / rel
        self.files.pop(rel, None)  # unlisted while it changes: a summary never vouches for a file in flux
        self.files[rel] = atomic_write(target, write)

    def remove(self, rel: str) -> None:
        """Delete a file this writer wrote (e.g. the thumbnail of a culled keyframe)."""
        if rel not in self.files:
            raise ValueError(f"{self.outdir / rel}: not written by this run; not deleted")
        del self.files[rel]
        (self.outdir / rel).unlink(missing_ok=True)

    def trajectory(self, trajectory: Trajectory) -> None:
        self.write(FILES["trajectory"], lambda tmp: write_tum_trajectory(
            trajectory, tmp, header="dynslam_lab trajectory: timestamp tx ty tz qx qy qz qw"))

    def timing(self, rows: list[dict]) -> None:
        """``rows``: one dict per frame with ``frame``, ``timestamp`` and stage ms (missing = nan)."""
        lines = ["frame,timestamp," + ",".join(STAGES)]
        for r in rows:
            lines.append(f"{r['frame']},{r['timestamp']:.6f}," + ",".join(f"{r.get(s, float('nan')):.3f}" for s in STAGES))
        self.write(FILES["timing"], lambda tmp: tmp.write_text("\n".join(lines) + "\n"))

    def screen_timing(self, rows: list[dict], first: tuple[str, ...] = ()) -> None:
        """``rows``: one dict per screened frame with ``frame`` and the screener's ms by name; the
        columns are ``first`` (the screening stages in order, then ``total``) and then every other
        name in the order it first appears (missing = nan)."""
        seen = dict.fromkeys(k for r in rows for k in r if k != "frame")
        cols = [c for c in first if c in seen] + [c for c in seen if c not in first]
        lines = ["frame," + ",".join(cols)]
        for r in rows:
            lines.append(f"{r['frame']}," + ",".join(f"{r.get(c, float('nan')):.3f}" for c in cols))
        self.write(FILES["screen_timing"], lambda tmp: tmp.write_text("\n".join(lines) + "\n"))

    def keyframes(self, ids, frame_index, timestamps, poses, loop_edges) -> None:
        self.write(FILES["keyframes"], _npz({
            "ids": np.asarray(ids, np.int64), "frame_index": np.asarray(frame_index, np.int64),
            "timestamps": np.asarray(timestamps, np.float64), "poses": np.asarray(poses, np.float64).reshape(-1, 4, 4),
            "loop_edges": np.asarray(loop_edges, np.int64).reshape(-1, 2)}))

    def map_points(self, xyz, rgb, n_obs) -> None:
        self.write(FILES["map_points"], _npz({"xyz": np.asarray(xyz, np.float64).reshape(-1, 3),
                                              "rgb": np.asarray(rgb, np.uint8).reshape(-1, 3),
                                              "n_obs": np.asarray(n_obs, np.int64).reshape(-1)}))

    def dynamic_points(self, xyz, frame) -> None:
        self.write(FILES["dynamic_points"], _npz({"xyz": np.asarray(xyz, np.float64).reshape(-1, 3),
                                                  "frame": np.asarray(frame, np.int64).reshape(-1)}))

    def dense_map(self, write: Callable[[Path], object]) -> None:
        """``map.ply`` written by ``write(tmp)`` (e.g. :func:`dynslam_lab.mapping.dense.write_dense_map`
        with ``path=tmp``), atomically."""
        self.write(FILES["dense_map"], write)

    def thumbnail(self, kf_id: int, rgb: np.ndarray) -> None:
        """A keyframe's thumbnail (RGB uint8) as ``thumbs/KFID.jpg``."""
        rel = f"{FILES['thumbs']}/{int(kf_id)}.jpg"

        def write(tmp: Path) -> None:
            ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
            if not ok:
                raise ValueError(f"{self.outdir / rel}: could not encode the thumbnail")
            tmp.write_bytes(buf.tobytes())

        self.write(rel, write)

    def labels(self, frame_index: int, table) -> None:
        """A frame's keypoint table (a pandas DataFrame) as ``labels/NNNNNN.csv``."""
        self.write(f"{FILES['labels']}/{int(frame_index):06d}.csv", lambda tmp: table.to_csv(tmp, index=False))

    def summary(self, summary: dict, list_files: bool = True) -> None:
        """``summary.json`` with the schema version, the run id and (``list_files``) every file
        written so far with its size and SHA-256; ``list_files=False`` before rewriting files."""
        data = {"schema_version": SCHEMA_VERSION, "run_id": self.run_id, **summary,
                "files": dict(sorted(self.files.items())) if list_files else {}}
        text = dumps(data, indent=2) + "\n"
        atomic_write(self.path("summary"), lambda tmp: tmp.write_text(text))


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
    with path.open("rb") as fh:
        if fh.read(4) != b"PK\x03\x04":  # an npz file is a zip archive
            raise ValueError(f"{path}: not an npz file (it does not start like a zip archive; damaged or replaced?)")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as exc:  # zipfile, zlib, pickle and format errors of a damaged file: all one message
        raise ValueError(f"{path}: not a readable npz file ({type(exc).__name__}: {exc})") from None
    if not isinstance(data, dict):  # np.load gives an array for a plain .npy file
        raise ValueError(f"{path}: not an npz archive (a single array)")
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


def _count_lines(path: Path, skip_header: bool) -> int:
    with path.open("rb") as fh:
        rows = [ln for ln in fh.read().splitlines() if ln.strip() and not ln.startswith(b"#")]
    return len(rows) - (1 if skip_header and rows else 0)


def verify_run(outdir: str | Path, hashes: bool = True) -> list[str]:
    """What is untrue in a run folder's ``summary.json`` (an empty list when it is all true).

    Checks that the summary is a JSON object whose ``run_id`` is the folder marker's, that every
    file it lists exists with the listed size (and SHA-256 when ``hashes``), that
    ``trajectory.txt`` has ``tracked`` poses and ``timing.csv`` ``processed`` rows when listed,
    and that a ``complete`` run lists every file of :data:`REQUIRED_FILES` and ``map.ply``
    (unless its summary records a ``dense_map_error``).
    """
    outdir = Path(outdir)
    sp = outdir / FILES["summary"]
    try:
        summary = json.loads(sp.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        return [f"{sp}: unreadable ({exc})"]
    if not isinstance(summary, dict):
        return [f"{sp}: not a JSON object"]
    problems: list[str] = []
    marker = read_marker(outdir)
    if summary.get("run_id") is not None and (marker is None or marker.get("id") != summary["run_id"]):
        problems.append(f"{sp}: run_id {summary['run_id']} is not the folder's ({marker and marker.get('id')})")
    files = summary.get("files")
    if not isinstance(files, dict):
        return problems + [f"{sp}: 'files' is missing or not an object"]
    for rel, rec in files.items():
        p = outdir / rel
        if not p.is_file():
            problems.append(f"{p}: listed in summary.json but missing")
            continue
        actual = file_record(p) if hashes else {"size": p.stat().st_size}
        if not isinstance(rec, dict) or any(rec.get(k) != v for k, v in actual.items()):
            problems.append(f"{p}: differs from what summary.json lists ({rec} vs {actual})")
    if FILES["trajectory"] in files and (outdir / FILES["trajectory"]).is_file():
        n = _count_lines(outdir / FILES["trajectory"], skip_header=False)
        if n != summary.get("tracked"):
            problems.append(f"{outdir / FILES['trajectory']}: {n} poses, summary.json says tracked = {summary.get('tracked')}")
    if FILES["timing"] in files and (outdir / FILES["timing"]).is_file():
        n = _count_lines(outdir / FILES["timing"], skip_header=True)
        if n != summary.get("processed"):
            problems.append(f"{outdir / FILES['timing']}: {n} rows, summary.json says processed = {summary.get('processed')}")
    if summary.get("complete"):
        need = [FILES[k] for k in REQUIRED_FILES]
        if "dense_map_error" not in summary:
            need.append(FILES["dense_map"])
        missing = [f for f in need if f not in files]
        if missing:
            problems.append(f"{sp}: complete is true but {missing} are not listed")
    return problems
