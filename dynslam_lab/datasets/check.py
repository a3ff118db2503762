"""What a run would take from a sequence folder, said before the run (``dynslam check SEQDIR``).

A sequence fetched or rendered elsewhere can be wrong in ways a run only shows as a bad trajectory: a
camera guessed from the folder's name, a depth scale in other units, timestamps that pair few frames,
ground truth that covers part of the run. :func:`check_sequence` reads what ``dynslam run`` would read
(the lists, the first frame, five depth images, the ground truth) and reports each part with a level:
``ok``, ``warning`` (the run starts, but read the line) or ``error`` (``dynslam run`` would refuse it).
The errors are the run's own (:class:`~dynslam_lab.datasets.tum.DatasetError`, the image size against the
camera by the run's rule, :func:`~dynslam_lab.datasets.depth_scale.check_depth_range`), so the two agree on what
is refused.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..camera import CAMERA_PRESETS, PinholeCamera, image_size_error, preset_from_name
from .depth_scale import depth_range_error, sample_depth
from .tum import DatasetError, TumSequence, associate, read_file_list

__all__ = ["CheckItem", "SequenceCheck", "check_sequence"]

LEVELS = ("ok", "warning", "error")


@dataclass(frozen=True)
class CheckItem:
    """One line of the report: ``topic`` (frames, camera, images, depth, truth, masks), ``level`` and what was found."""

    topic: str
    level: str
    text: str


@dataclass
class SequenceCheck:
    """The report of :func:`check_sequence`: its items in order; ``ok`` when no item is an error."""

    root: Path
    items: list[CheckItem] = field(default_factory=list)

    def add(self, topic: str, level: str, text: str) -> None:
        if level not in LEVELS:
            raise ValueError(f"level must be one of {LEVELS}, got {level!r}")
        self.items.append(CheckItem(topic, level, text))

    def count(self, level: str) -> int:
        return sum(i.level == level for i in self.items)

    @property
    def ok(self) -> bool:
        return self.count("error") == 0

    def format(self) -> str:
        width = max((len(i.topic) for i in self.items), default=5)
        mark = {"ok": " ", "warning": "!", "error": "X"}
        lines = [f"{mark[i.level]} {i.topic:<{width}}  {i.text}" for i in self.items]
        verdict = ("a run would start" if self.ok else "dynslam run would refuse it")
        n_e, n_w = self.count("error"), self.count("warning")
        lines.append(f"  {'verdict':<{width}}  {verdict} ({n_e} error{'s' * (n_e != 1)}, {n_w} warning{'s' * (n_w != 1)})")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {"root": str(self.root), "ok": self.ok, "errors": self.count("error"), "warnings": self.count("warning"),
                "items": [{"topic": i.topic, "level": i.level, "text": i.text} for i in self.items]}


def _camera_source(root: Path, override) -> str | None:
    """Where :func:`~dynslam_lab.camera.camera_for_sequence` takes the camera from, in its order; None: a guess."""
    if override is not None:
        return "--camera" if isinstance(override, str) else "the camera given"
    if (root / "camera.json").is_file():
        return "camera.json"
    return "the folder's name" if preset_from_name(root.name) is not None else None


def _rate(ts: np.ndarray) -> tuple[float, float]:
    """Mean frame interval (s; not the median: stamps rounded to 10 ms step 30 and 40 ms at 30 Hz) and the
    largest interval in median intervals (a gap: frames missing)."""
    if len(ts) < 2:
        return float("nan"), float("nan")
    d = np.diff(np.sort(ts))
    med = float(np.median(d))
    return float(d.mean()), float(d.max() / med) if med > 0 else float("inf")


def check_sequence(root: str | Path, camera: PinholeCamera | str | None = None, min_depth: float = 0.1,
                   max_depth: float = 8.0, max_diff: float = 0.02) -> SequenceCheck:
    """Check the sequence folder ``root`` as ``dynslam run`` would read it (``camera`` as ``--camera``;
    ``min_depth``, ``max_depth`` as ``tracking``'s). Never raises for the data: every problem is an item."""
    root = Path(root)
    rep = SequenceCheck(root)
    if camera is not None and isinstance(camera, str) and camera not in CAMERA_PRESETS:
        rep.add("camera", "error", f"unknown camera preset {camera!r}; choose one of {sorted(CAMERA_PRESETS)}")
        return rep
    cam_log = logging.getLogger("dynslam_lab.camera")  # a guessed camera is this report's line, not a log warning too
    was_disabled, cam_log.disabled = cam_log.disabled, True
    try:
        seq = TumSequence(root, camera=camera, max_diff=max_diff)
    except (DatasetError, ValueError, OSError) as exc:
        rep.add("frames", "error", str(exc))
        return rep
    finally:
        cam_log.disabled = was_disabled

    # frames: the lists, the pairs and the rate
    ts = seq.timestamps
    step, gap = _rate(ts)
    if (root / "associations.txt").is_file():
        pairs = f"{len(seq)} frames from associations.txt"
    else:
        a, _ = read_file_list(root / "rgb.txt")
        b, _ = read_file_list(root / "depth.txt")
        pr = associate(a, b, max_diff)
        dt = np.abs(a[pr[:, 0]] - b[pr[:, 1]]) * 1e3 if len(pr) else np.zeros(0)
        pairs = (f"{len(a)} colour, {len(b)} depth -> {len(seq)} pairs within {max_diff:g} s (|dt| median "
                 f"{np.median(dt):.1f} ms, max {dt.max():.1f} ms)")
    level = "ok"
    rate = f"{1.0 / step:.1f} Hz" if step > 0 else "one frame"
    if len(seq) > 1 and gap > 3:
        level = "warning"
        rate += f"; the largest gap is {gap:.0f} frame intervals (frames missing: tracking may be lost there)"
    rep.add("frames", level, f"{pairs}; {rate}, {ts[-1] - ts[0]:.1f} s")

    # camera: where the intrinsics come from
    cam = seq.camera
    source = _camera_source(root, camera)
    dist = "distortion " + " ".join(f"{v:g}" for v in cam.dist) if cam.has_distortion else "no distortion"
    desc = (f"'{cam.name}': fx {cam.fx:g}, fy {cam.fy:g}, cx {cam.cx:g}, cy {cam.cy:g}, {cam.width}x{cam.height}, "
            f"depth_scale {cam.depth_scale:g}, {dist}")
    if source is None:
        rep.add("camera", "warning", f"{desc}: a guess (no camera.json, no preset in the folder's name); write "
                                     f"{root / 'camera.json'} or pass --camera")
    else:
        rep.add("camera", "ok", f"{desc}, from {source}")

    # images: the first frame against the camera
    try:
        f0 = seq[0]
    except (DatasetError, OSError) as exc:
        rep.add("images", "error", f"frame 0: {exc}")
        return rep
    error = image_size_error(f0.rgb.shape, cam, f0.rgb_path or "frame 0")  # the run's rule (runs.runner)
    if error:
        rep.add("images", "error", error)
    else:
        rep.add("images", "ok", f"{cam.width}x{cam.height} colour and depth, as the camera")

    # depth: the scale
    s = sample_depth(seq, k=5)  # what the run's check_depth_range samples and judges
    error = depth_range_error(s, seq, min_depth, max_depth)
    if s.median_m is None:
        rep.add("depth", "error", f"no valid depth in the {len(s.paths) or 5} frames read")
    elif error:
        rep.add("depth", "error", error)
    else:
        rep.add("depth", "ok", f"median {s.median_m:.2f} m over {len(s.paths)} frames ({s.median_units:.0f} units at "
                               f"{cam.depth_scale:g} per metre), inside tracking's {min_depth:g}-{max_depth:g} m; "
                               f"{100 * s.no_depth_share:.0f} % of pixels without depth")

    # ground truth: how much of the run it covers
    gt = seq.groundtruth
    if gt is None:
        rep.add("truth", "ok", "no groundtruth.txt: the run will not be evaluated (no ATE, RPE)")
    else:
        poses = [T for T in (seq.gt_pose(i) for i in range(len(seq))) if T is not None]
        covered = len(poses)
        g_step, _ = _rate(gt.timestamps)
        P = np.array([T[:3, 3] for T in poses])
        path = float(np.linalg.norm(np.diff(P, axis=0), axis=1).sum()) if len(P) > 1 else 0.0
        level = "ok" if covered >= 0.5 * len(seq) else "warning"
        text = (f"{len(gt)} poses" + (f" at {1.0 / g_step:.0f} Hz" if g_step > 0 else "") +
                f"; {covered} of {len(seq)} frames within {max_diff:g} s of one; the camera's path {path:.2f} m")
        if level == "warning":
            text += " (ATE and RPE would cover only those frames)"
        rep.add("truth", level, text)

    # what the synthetic renderer adds (masks for the oracle and the keypoint scores)
    if (root / "masks").is_dir():
        n_masks = sum(1 for _ in (root / "masks").glob("*.png"))
        classes = sorted(set(seq.instance_classes.values()))
        moving = "moving.txt" if (root / "moving.txt").is_file() else "no moving.txt (every instance of an a-priori dynamic class counts as moving)"
        rep.add("masks", "ok", f"{n_masks} instance masks, {len(seq.instance_classes)} instances "
                               f"({', '.join(classes) or 'no classes'}), {moving}: the oracle and the keypoint scores can run")
    return rep
