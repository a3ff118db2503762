"""Loader for the TUM RGB-D layout, used for TUM, Bonn and the synthetic sequences.

A sequence folder holds::

    rgb.txt  depth.txt  [groundtruth.txt]  [associations.txt]  rgb/  depth/
    [camera.json  masks/  instances.json]      (synthetic sequences only)

``rgb.txt``/``depth.txt`` list ``timestamp filename`` per line (``#`` comments).
Colour and depth frames are paired by nearest timestamp, greedily over all pairs sorted
by time difference, keeping pairs within ``max_diff`` seconds (0.02 s), as TUM's
``associate.py`` does. Depth PNGs are 16-bit, ``depth_scale`` units per metre (5000).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from ..camera import PinholeCamera, camera_for_sequence
from ..evaluation.trajectory import read_tum_trajectory
from ..textfile import data_lines
from .frame import Frame

__all__ = ["read_file_list", "associate", "load_rgb", "load_depth", "TumSequence", "DatasetError"]


class DatasetError(ValueError):
    """A dataset file is missing or malformed; the message names the file and line."""


def _unit_hint(ts: np.ndarray, name: str) -> str:
    """A note when the timestamps of ``name`` are too large for seconds: milli-, micro- or nanoseconds since the
    epoch (the TUM layout lists seconds; seconds since 1970 are ~1e9 today)."""
    if len(ts) == 0 or not np.abs(ts).max() >= 1e11:
        return ""
    big = float(np.abs(ts).max())
    for unit, factor in (("milliseconds", 1e3), ("microseconds", 1e6), ("nanoseconds", 1e9)):
        if big / factor < 1e11:
            return (f"; {name}'s timestamps look like {unit} ({big:.3g}, which is {big / factor:.3g} s; the TUM layout "
                    f"lists seconds): divide them by {factor:.0e}")
    return f"; {name}'s timestamps ({big:.3g}) are too large for seconds (the TUM layout lists seconds)"


def read_file_list(path: str | Path, min_fields: int = 2) -> tuple[np.ndarray, list[list[str]]]:
    """Read a TUM list file (``rgb.txt``, ``depth.txt``, ``groundtruth.txt``).

    Returns ``(timestamps (N,), rows)`` where ``rows[i]`` are the fields after the timestamp.
    Comment (``#``) and blank lines are skipped; a malformed line raises :class:`DatasetError`
    naming the file and line number.
    """
    path = Path(path)
    stamps: list[float] = []
    rows: list[list[str]] = []
    for lineno, s, parts in data_lines(path, DatasetError, "file"):
        if len(parts) < min_fields:
            raise DatasetError(f"{path}:{lineno}: expected at least {min_fields} fields, got {len(parts)}: {s!r}")
        try:
            ts = float(parts[0])
        except ValueError:
            raise DatasetError(f"{path}:{lineno}: timestamp {parts[0]!r} is not a number") from None
        if not np.isfinite(ts):
            raise DatasetError(f"{path}:{lineno}: timestamp {parts[0]!r} is not finite")
        stamps.append(ts)
        rows.append(parts[1:])
    return np.asarray(stamps, dtype=np.float64), rows


def associate(first: np.ndarray, second: np.ndarray, max_diff: float = 0.02, offset: float = 0.0) -> np.ndarray:
    """Pair two timestamp lists by nearest time, each stamp used once.

    All candidate pairs with ``|a - (b + offset)| < max_diff`` are taken greedily in order of
    increasing difference (TUM ``associate.py``). Returns index pairs ``(M, 2)`` sorted by the
    first list's time. Vectorised with ``searchsorted``: only the neighbours within
    ``max_diff`` are candidates.
    """
    a = np.asarray(first, dtype=np.float64)
    b = np.asarray(second, dtype=np.float64) + offset
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    order_b = np.argsort(b, kind="stable")
    bs = b[order_b]
    lo = np.searchsorted(bs, a - max_diff, side="left")
    hi = np.searchsorted(bs, a + max_diff, side="right")
    counts = hi - lo
    ia = np.repeat(np.arange(len(a)), counts)
    if len(ia) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    starts = np.repeat(lo - np.cumsum(np.r_[0, counts[:-1]]), counts)
    jb_sorted = np.arange(len(ia)) + starts
    jb = order_b[jb_sorted]
    diff = np.abs(a[ia] - b[jb])
    keep = diff < max_diff
    ia, jb, diff = ia[keep], jb[keep], diff[keep]
    order = np.lexsort((jb, ia, diff))
    used_a = np.zeros(len(a), bool)
    used_b = np.zeros(len(b), bool)
    pairs = []
    for k in order:  # greedy over candidates only (a few per stamp)
        i, j = ia[k], jb[k]
        if not used_a[i] and not used_b[j]:
            used_a[i] = used_b[j] = True
            pairs.append((i, j))
    if not pairs:
        return np.zeros((0, 2), dtype=np.int64)
    out = np.asarray(pairs, dtype=np.int64)
    return out[np.argsort(a[out[:, 0]], kind="stable")]


def _imread(path: str | Path, flags: int, what: str) -> np.ndarray:
    """``cv2.imread`` with a :class:`DatasetError` naming the file when it is missing or undecodable."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: {what} not found")
    img = cv2.imread(str(path), flags)
    if img is None:
        raise DatasetError(f"{path}: cannot decode {what} (corrupt or not an image)")
    return img


_IMREAD_RGB = getattr(cv2, "IMREAD_COLOR_RGB", None)  # OpenCV >= 4.10 decodes to RGB order directly


def load_rgb(path: str | Path) -> np.ndarray:
    """Read a colour image as ``(H, W, 3)`` uint8 RGB; clear error for a missing or corrupt file."""
    if _IMREAD_RGB is not None:  # no BGR -> RGB pass over the image
        return _imread(path, _IMREAD_RGB, "colour image")
    return cv2.cvtColor(_imread(path, cv2.IMREAD_COLOR, "colour image"), cv2.COLOR_BGR2RGB)


def load_depth(path: str | Path, depth_scale: float = 5000.0) -> np.ndarray:
    """Read a 16-bit depth PNG as ``(H, W)`` float32 metres (0 = no reading).

    Raises :class:`DatasetError` if the file is missing, corrupt, or not 16-bit single
    channel (an 8-bit depth image means a wrong file or a lossy conversion).
    """
    path = Path(path)
    raw = _imread(path, cv2.IMREAD_UNCHANGED, "depth image")
    if raw.ndim != 2:
        raise DatasetError(f"{path}: depth image must be single-channel, got shape {raw.shape}")
    if raw.dtype != np.uint16:
        raise DatasetError(
            f"{path}: depth image must be 16-bit (uint16, {depth_scale:g} units per metre), got {raw.dtype}"
        )
    return raw.astype(np.float32) / np.float32(depth_scale)


@dataclass
class _Entry:
    ts: float
    rgb: Path
    depth: Path
    mask: Path | None


class TumSequence:
    """A TUM-layout RGB-D sequence with lazy frame loading.

    Parameters
    ----------
    root : sequence folder.
    camera : a :class:`PinholeCamera` or preset name; default picked from the folder name.
    max_diff : association tolerance in seconds (0.02 like ``associate.py``).
    associations : an association file (``ts rgb/x.png ts depth/y.png`` per line) to use instead
        of associating ``rgb.txt`` and ``depth.txt``; ``associations.txt`` in ``root`` is used
        when present unless ``associations=False``.
    max_frames, stride : take every ``stride``-th associated frame, at most ``max_frames``.

    Indexing gives :class:`Frame` objects; ``groundtruth`` is the ground-truth trajectory
    (``evaluation.trajectory.Trajectory``) or None; ``gt_pose(i)`` the pose nearest frame ``i``.
    """

    def __init__(
        self,
        root: str | Path,
        camera: PinholeCamera | str | None = None,
        max_diff: float = 0.02,
        associations: str | Path | bool | None = None,
        max_frames: int | None = None,
        stride: int = 1,
    ) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise DatasetError(f"{self.root}: sequence folder not found")
        if stride < 1:
            raise ValueError(f"stride must be >= 1, got {stride}")
        self.camera = camera_for_sequence(self.root, camera)
        self.max_diff = float(max_diff)
        self.name = self.root.name
        self._entries = self._read_entries(associations)
        self._entries = self._entries[::stride]
        if max_frames is not None:
            self._entries = self._entries[: int(max_frames)]
        if not self._entries:
            raise DatasetError(self._why_no_frames())
        self.instance_classes = self._read_instances()
        self._moving = self._read_moving()
        self._moving_ts = np.fromiter(self._moving, dtype=np.float64) if self._moving else np.zeros(0)
        self.groundtruth = self._read_groundtruth()
        self._gt_index = self._associate_gt()

    # ------------------------------------------------------------------ reading
    def _why_no_frames(self) -> str:
        """Why no frame was found: an empty list file, or timestamps that do not pair."""
        lists = [self.root / "rgb.txt", self.root / "depth.txt"]
        if (self.root / "associations.txt").is_file():
            lists = [self.root / "associations.txt"]
        for p in lists:
            if p.is_file() and len(read_file_list(p)[0]) == 0:
                return f"{p}: lists no frames (the file is empty or holds only comments)"
        if len(lists) == 1:
            return f"{self.root}: no frames left after stride/max_frames"
        (a, _), (b, _) = read_file_list(lists[0]), read_file_list(lists[1])
        hint = "".join(_unit_hint(ts, name) for ts, name in ((a, "rgb.txt"), (b, "depth.txt")))
        return (f"{self.root}: no colour/depth pairs within {self.max_diff} s of each other: rgb.txt spans "
                f"[{a.min():.6f}, {a.max():.6f}] s, depth.txt [{b.min():.6f}, {b.max():.6f}] s; check the timestamps{hint}")

    def _read_entries(self, associations) -> list[_Entry]:
        masks_dir = self.root / "masks"
        assoc_path: Path | None = None
        if associations not in (None, False, True):
            assoc_path = Path(associations)
        elif associations is not False and (self.root / "associations.txt").is_file():
            assoc_path = self.root / "associations.txt"
        entries: list[_Entry] = []
        if assoc_path is not None:
            ts, rows = read_file_list(assoc_path, min_fields=4)
            for k, (t, r) in enumerate(zip(ts, rows)):
                if len(r) < 3:
                    raise DatasetError(f"{assoc_path}: entry {k + 1} needs 'ts rgb ts depth', got {r!r}")
                rgb = self.root / r[0]
                mask = masks_dir / Path(r[0]).name
                entries.append(_Entry(float(t), rgb, self.root / r[2], mask if masks_dir.is_dir() else None))
            return entries
        rgb_ts, rgb_rows = read_file_list(self.root / "rgb.txt")
        d_ts, d_rows = read_file_list(self.root / "depth.txt")
        pairs = associate(rgb_ts, d_ts, self.max_diff)
        for i, j in pairs:
            rgb = self.root / rgb_rows[i][0]
            mask = masks_dir / Path(rgb_rows[i][0]).name
            entries.append(_Entry(float(rgb_ts[i]), rgb, self.root / d_rows[j][0], mask if masks_dir.is_dir() else None))
        return entries

    def _read_instances(self) -> dict[int, str]:
        p = self.root / "instances.json"
        if not p.is_file():
            return {}
        try:
            data = json.loads(p.read_text())
        except json.JSONDecodeError as exc:
            raise DatasetError(f"{p}: invalid JSON ({exc})") from exc
        if not isinstance(data, dict):
            raise DatasetError(f"{p}: expected an object of instance id -> class, got {type(data).__name__}")
        out = {}
        for k, v in data.items():
            if isinstance(v, dict) and not isinstance(v.get("class"), str):
                raise DatasetError(f"{p}: instance {k!r} has no \"class\" name (got {v!r})")
            try:
                out[int(k)] = v["class"] if isinstance(v, dict) else str(v)
            except ValueError:
                raise DatasetError(f"{p}: instance id {k!r} is not an integer") from None
        return out

    def _read_moving(self) -> dict[float, frozenset[int]] | None:
        p = self.root / "moving.txt"
        return read_moving(self.root) if p.is_file() else None

    def _moving_ids(self, ts: float) -> frozenset[int] | None:
        """The ids moving at colour timestamp ``ts`` (nearest ``moving.txt`` row), or None."""
        if self._moving is None:
            return None
        if not self._moving:
            return frozenset()
        j = int(np.argmin(np.abs(self._moving_ts - ts)))
        return self._moving[float(self._moving_ts[j])]

    def _read_groundtruth(self):
        p = self.root / "groundtruth.txt"
        if not p.is_file():
            return None
        return read_tum_trajectory(p, duplicates="first")  # real ground truth has them (fr2/desk: 1)

    def _associate_gt(self) -> np.ndarray | None:
        if self.groundtruth is None:
            return None
        pairs = associate(self.timestamps, self.groundtruth.timestamps, self.max_diff)
        idx = np.full(len(self), -1, dtype=np.int64)
        idx[pairs[:, 0]] = pairs[:, 1]
        return idx

    # ----------------------------------------------------------------- access
    def __len__(self) -> int:
        return len(self._entries)

    @property
    def timestamps(self) -> np.ndarray:
        return np.array([e.ts for e in self._entries])

    def depth_path(self, index: int) -> Path:
        """The depth image of frame ``index`` (as listed; not read)."""
        return self._entries[index].depth

    def gt_pose(self, index: int) -> np.ndarray | None:
        """Ground-truth ``T_w_c`` associated with frame ``index`` (within ``max_diff``), or None."""
        if self._gt_index is None or self._gt_index[index] < 0:
            return None
        return self.groundtruth.poses[self._gt_index[index]]

    def __getitem__(self, index: int) -> Frame:
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range for {len(self)} frames")
        e = self._entries[index]
        rgb = load_rgb(e.rgb)
        depth = load_depth(e.depth, self.camera.depth_scale)
        if rgb.shape[:2] != depth.shape:
            raise DatasetError(f"{e.depth}: depth size {depth.shape} differs from colour size {rgb.shape[:2]} ({e.rgb})")
        mask = None
        if e.mask is not None and e.mask.is_file():
            mask = _imread(e.mask, cv2.IMREAD_UNCHANGED, "instance mask").astype(np.int32)
        return Frame(
            index=index,
            timestamp=e.ts,
            rgb=rgb,
            depth=depth,
            camera=self.camera,
            T_w_c_gt=self.gt_pose(index),
            instance_mask=mask,
            instance_classes=dict(self.instance_classes),
            moving_ids=self._moving_ids(e.ts) if mask is not None else None,
            rgb_path=e.rgb,
            depth_path=e.depth,
        )

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self[i]

    def __repr__(self) -> str:
        return f"TumSequence({str(self.root)!r}, frames={len(self)}, camera={self.camera.name})"


def read_moving(root: str | Path) -> dict[float, frozenset[int]]:
    """Read ``moving.txt`` of a synthetic sequence: colour timestamp -> ids of the instances that
    move in that frame (``docs/synthetic.md``)."""
    path = Path(root) / "moving.txt"
    out: dict[float, frozenset[int]] = {}
    for lineno, s, parts in data_lines(path, FileNotFoundError, "moving.txt (only synthetic sequences have one)"):
        try:
            out[float(parts[0])] = frozenset(int(x) for x in parts[1:])
        except ValueError:
            raise ValueError(f"{path}:{lineno}: expected 'timestamp id id ...', got {s!r}") from None
    return out
