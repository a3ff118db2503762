"""Run a built system over a sequence and write its run folder (:mod:`.layout`) as a transaction.

The run folder is opened as an :class:`~.folder.OutputFolder` (fresh or, with ``force``, a
previous run folder replaced; locked against a second writer). A frame that cannot be read or
processed is logged, counted as lost, and the run goes on; but when the *first* frames all fail
with the same error (8-bit depth, colour and depth of different sizes, an oracle detector on real
data, an empty detection cache), that error would repeat on every frame: the run stops at once
with :class:`RunStopped` naming it.

Everything computed so far is written after the first frame and then every ``flush_every``
frames (10; later while writing would cost more than ``1 / flush_cost_ratio`` of the time since the last
write: the files grow with the run, and on a 1,500-frame run a write every 10 frames took 8.5 % of the
time), ``summary.json`` last, listing each file with its size and SHA-256; it says
``complete: true`` only after the last frame, the evaluation and the dense map. Ctrl-C (or any
error) stops the run cleanly: the files are written once more as they stand, ``summary.json``
says ``complete: false`` and ``state: "interrupted"`` with the frames done, and
:class:`RunInterrupted` (a ``KeyboardInterrupt``) is raised; ``dynslam run`` exits with 130.
"""

from __future__ import annotations

import logging
import re
import signal
import sys
import threading
import time
import traceback
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from tqdm import tqdm

from ..camera import image_size_error
from ..config import config_to_dict
from ..datasets.depth_scale import check_depth_range, depth_scale_from_trajectory
from ..datasets.prefetch import FramePrefetcher, PrefetchConfig
from ..evaluation.tables import evaluate
from ..mapping.dense import write_dense_map
from ..slam.system import FrameResult, System
from ..threads import blas_single_thread
from .folder import OutputFolder
from .layout import FILES, STAGES, RunWriter

__all__ = ["run_sequence", "RunRecorder", "RunInterrupted", "RunStopped", "FLUSH_EVERY", "FLUSH_COST_RATIO",
           "REPEATED_ERROR_FRAMES"]

log = logging.getLogger(__name__)

#: Frames between two writes of the run folder (after the first frame's).
FLUSH_EVERY = 10
#: A write waits (by whole ``FLUSH_EVERY`` steps) until the frames since the last one took at least this
#: many times as long as that write: writes cost at most ~1/20 of a run however long it grows.
FLUSH_COST_RATIO = 20.0
#: When this many first frames all fail with the same error, the run stops.
REPEATED_ERROR_FRAMES = 5


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped a run; its folder holds a consistent partial run (``complete: false``).

    Attributes: ``summary`` (what ``summary.json`` says), ``message`` (one line for the user).
    """

    def __init__(self, message: str, summary: dict) -> None:
        super().__init__(message)
        self.message = message
        self.summary = summary

    def __str__(self) -> str:
        return self.message


class RunStopped(ValueError):
    """A run stopped early because its configuration or data cannot work (the first frames all
    failed with the same error); its folder holds ``summary.json`` with ``state: "failed"``."""

    def __init__(self, message: str, summary: dict | None = None) -> None:
        super().__init__(message)
        self.summary = summary


def _error_shape(message: str) -> str:
    """A frame's error message without its paths and numbers (the same error on every frame)."""
    return re.sub(r"\d+(\.\d+)?", "#", re.sub(r"\S*[/\\]\S*", "<path>", message))


def _check_size(frame, camera) -> None:
    """A frame of another size than the camera would be tracked with the wrong intrinsics."""
    error = image_size_error(frame.rgb.shape, camera, frame.rgb_path or f"frame {frame.index}")
    if error:
        raise ValueError(error)


@contextmanager
def _sigint_deferred():
    """While the partial run is written after a Ctrl-C, a second Ctrl-C only says to wait."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        print("dynslam: still writing the partial run folder, one moment ...", file=sys.stderr, flush=True)

    try:
        old = signal.signal(signal.SIGINT, handler)
    except ValueError:  # not the main interpreter
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


@dataclass
class RunRecorder:
    """What a run accumulates frame by frame, and writes with a :class:`~.layout.RunWriter`.

    Attributes
    ----------
    rows : per-frame timing rows (``frame``, ``timestamp``, stage ms).
    screen_rows : per screened frame, the screener's own timings (``frame``, then ms by stage and
        shared product; ``screen_timing.csv``).
    dynamic_xyz, dynamic_frame : world points of keypoints judged dynamic, and their frames.
    region_masks : keyframe frame index -> ``(H, W)`` bool pixels judged dynamic (the dense map
        leaves them out).
    errors : one message per frame that failed (``summary.json`` keeps the first and last 25).
    n_ok : frames processed without an exception.
    error_shapes : the first frames' errors without paths and numbers (a repeating error).
    shape_counts : how often each kind of error occurred (only the first few are logged).
    config_dict : ``summary.json``'s ``config`` (computed on the first summary).
    """

    writer: RunWriter
    save_labels: bool = False
    rows: list[dict] = field(default_factory=list)
    screen_rows: list[dict] = field(default_factory=list)
    dynamic_xyz: list[np.ndarray] = field(default_factory=list)
    dynamic_frame: list[np.ndarray] = field(default_factory=list)
    region_masks: dict[int, np.ndarray] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)
    n_ok: int = 0
    error_shapes: list[str] = field(default_factory=list)
    shape_counts: dict[str, int] = field(default_factory=dict)
    config_dict: dict | None = None
    _config_key: int = -1

    def failed(self, index: int, timestamp: float, exc: Exception) -> None:
        """A frame that could not be processed at all (logged: the first few of each kind of error)."""
        msg = f"frame {index}: {type(exc).__name__}: {exc}"
        shape = _error_shape(f"{type(exc).__name__}: {exc}")
        seen = self.shape_counts.get(shape, 0)
        self.shape_counts[shape] = seen + 1
        starting = self.n_ok == 0 and seen > 0  # the first frames failing alike: the stop will say it once
        if not starting and seen < 3:
            note = " (further frames failing the same way are listed in summary.json only)" if seen == 2 else ""
            log.warning("%s%s", msg, note)
        log.debug("%s", traceback.format_exc())
        self.errors.append(msg)
        self.rows.append({"frame": index, "timestamp": timestamp})
        if self.n_ok == 0 and len(self.error_shapes) < REPEATED_ERROR_FRAMES:
            self.error_shapes.append(shape)

    def repeating_error(self, n_frames: int) -> str | None:
        """The error of the first frames when they all failed the same way (it will repeat)."""
        k = min(REPEATED_ERROR_FRAMES, n_frames)
        if self.n_ok == 0 and len(self.error_shapes) >= k and len(set(self.error_shapes[:k])) == 1:
            return f"the first {k} frames all failed with the same error, which would repeat on every frame: {self.errors[0]}"
        return None

    def frame(self, index: int, res: FrameResult, system: System) -> None:
        """A processed frame: its timings, dynamic points, thumbnail, region mask, labels."""
        self.n_ok += 1
        self.rows.append({"frame": index, "timestamp": res.timestamp, **res.timings_ms})
        screen_ms = getattr(res.table, "timings_ms", None)
        if screen_ms:
            self.screen_rows.append({"frame": index, **screen_ms})
        if res.dynamic_xyz is not None and len(res.dynamic_xyz):
            self.dynamic_xyz.append(res.dynamic_xyz)
            self.dynamic_frame.append(np.full(len(res.dynamic_xyz), index, np.int64))
        if res.is_keyframe:
            kf = system.map.keyframes.get(res.keyframe_id)
            if kf is not None and kf.thumbnail is not None:
                self.writer.thumbnail(kf.id, kf.thumbnail)
            if res.region_mask is not None:
                self.region_masks[index] = np.asarray(res.region_mask, bool)
        if self.save_labels and res.table is not None:
            self.writer.labels(index, res.table.to_dataframe())

    def write(self, system: System, summary: dict, final: bool = False, wait: bool = True) -> None:
        """Every file of the run as it stands, ``summary.json`` last; ``wait``: apply the loop
        closer's pending corrections first (False, for the flushes during a run: the frame loop does
        not wait for the worker, and the files show the map as it stands).

        While the files change, ``summary.json`` lists none of them, so that at every instant
        each file it lists is the one it describes. ``final`` also deletes the thumbnails of
        keyframes culled since they were written.
        """
        w = self.writer
        w.summary(summary, list_files=False)
        if final:
            keep = {f"{FILES['thumbs']}/{k}.jpg" for k in system.map.keyframes}
            for rel in [r for r in w.files if r.startswith(FILES["thumbs"] + "/") and r not in keep]:
                w.remove(rel)
        w.trajectory(system.trajectory(wait))
        w.timing(self.rows)
        if self.screen_rows:
            w.screen_timing(self.screen_rows, first=tuple(getattr(system.screener, "stages", ())) + ("total",))
        w.keyframes(**system.keyframe_arrays(wait))
        w.map_points(**system.map_point_arrays(wait))
        xyz = np.concatenate(self.dynamic_xyz) if self.dynamic_xyz else np.zeros((0, 3))
        fr = np.concatenate(self.dynamic_frame) if self.dynamic_frame else np.zeros(0, np.int64)
        w.dynamic_points(xyz, fr)
        w.summary(summary)

    def _config(self, system: System) -> dict:
        """The config every stage runs with (fixed for the run once the screener has measured the depth noise of
        its first frames: computed again only while that measurement grows)."""
        meter = _depth_noise_meter(system)
        key = len(meter.ratios) if meter is not None else 0
        if self.config_dict is None or key != self._config_key:
            self.config_dict, self._config_key = config_to_dict(system.effective_config()), key
        return self.config_dict

    def summary(self, sequence, system: System, n_frames: int, complete: bool, state: str = "running",
                wait: bool = True) -> dict:
        """The ``summary.json`` dict of the run so far (``state``: running, complete, interrupted, failed;
        ``wait``: as :meth:`write`)."""
        stage_ms = {s: np.array([r.get(s, np.nan) for r in self.rows], float) for s in STAGES}
        return {
            "sequence": str(sequence.root),
            "complete": complete,
            "state": state,
            "frames": n_frames,
            "processed": len(self.rows),
            "tracked": len(system.trajectory(wait)),
            "lost": len(system.lost_frames),
            "lost_frames": list(system.lost_frames),
            "keyframes": len(system.map.keyframes),
            "map_points": int(len(system.map.point_ids())),
            "loops": len(system.loop_results),
            "loop_edges": [list(e) for e in system.keyframe_arrays(wait)["loop_edges"].tolist()],
            "timing_median_ms": {s: (float(np.nanmedian(v)) if np.isfinite(v).any() else None) for s, v in stage_ms.items()},
            "timing_mean_ms": {s: (float(np.nanmean(v)) if np.isfinite(v).any() else None) for s, v in stage_ms.items()},
            "failed_frames": len(self.errors),
            "errors": self.errors if len(self.errors) <= 50 else
            self.errors[:25] + [f"... {len(self.errors) - 50} more ..."] + self.errors[-25:],
            "pipeline": dict(system.description),
            "config": self._config(system),
            "depth_noise_ratio": (meter.ratio if (meter := _depth_noise_meter(system)) is not None and meter.ratios
                                  else None),
        }


def _depth_noise_meter(system: System):
    """The screener's :class:`~dynslam_lab.dynamic.depth_noise.DepthNoiseMeter` (the depth noise of the first
    frames), or None without a screener that measures it (none, the oracle)."""
    return getattr(system.screener, "depth_noise", None)


class _PreparingSequence:
    """``sequence`` seen through ``system.prepare``: reading frame ``i`` also starts its ORB extraction
    and its detection in the system's worker threads, so that work is done for frames ``t+1 ..``
    while frame ``t`` is tracked (:meth:`~dynslam_lab.slam.system.System.prepare`)."""

    def __init__(self, sequence, system: System) -> None:
        self.sequence, self.system = sequence, system

    def __len__(self) -> int:
        return len(self.sequence)

    def __getitem__(self, index: int):
        frame = self.sequence[index]
        self.system.prepare(frame)
        return frame


def run_sequence(
    sequence,
    outdir: str | Path,
    system: System,
    max_frames: int | None = None,
    progress: bool = True,
    save_labels: bool = False,
    flush_every: int = FLUSH_EVERY,
    on_frame: Callable[[object, FrameResult], None] | None = None,
    force: bool = False,
    prefetch: PrefetchConfig = PrefetchConfig(),
    extract_ahead: bool = True,
    flush_cost_ratio: float = FLUSH_COST_RATIO,
) -> dict:
    """Run ``system`` over ``sequence`` and write the run folder ``outdir``.

    Parameters
    ----------
    sequence : a :class:`~dynslam_lab.datasets.tum.TumSequence` (indexable, ``len``, ``root``,
        ``name``, ``timestamps``, ``groundtruth`` or None).
    outdir : run folder: new or empty (or a previous run folder, with ``force``).
    system : the SLAM system, from :func:`dynslam_lab.pipeline.build_pipeline`; its screener's
        history is reset first.
    max_frames : process only the first frames.
    progress : show a tqdm progress bar.
    save_labels : write each frame's keypoint table to ``labels/``.
    flush_every : write all outputs after the first frame and then every this many frames, ...
    flush_cost_ratio : ... once the frames since the last write took at least this many times as long as
        that write did (else at the next multiple of ``flush_every``); 0 = every ``flush_every`` frames.
    on_frame : called as ``on_frame(frame, result)`` after each processed frame (scores,
        notebooks).
    force : replace a previous run folder at ``outdir`` (recognised by its marker; a folder
        holding files dynslam_lab did not write is never touched).
    prefetch : read-ahead of the frames (:class:`~dynslam_lab.datasets.prefetch.PrefetchConfig`;
        ``queue_size=0`` reads in this thread).
    extract_ahead : each frame's ORB extraction and detection start as soon as it is read, in worker
        threads (:meth:`~dynslam_lab.slam.system.System.prepare`; identical results). ``timing.csv``'s
        ``orb`` and ``detect`` are then measured in those threads; ``total`` holds only the wait for
        them, and ``wall`` is the frame's whole time in the run loop.

    Returns
    -------
    The summary dict (also in ``summary.json``), with ``ate``/``rpe`` when ground truth exists.

    Raises
    ------
    OutputFolderError
        ``outdir`` is a file, not empty, not writable, or another process writes into it.
    RunStopped
        The first frames all failed with the same error (the folder records it, ``state: failed``).
    RunInterrupted
        Ctrl-C; the folder holds the partial run (``complete: false``, ``state: interrupted``).
    """
    n = len(sequence) if max_frames is None else min(len(sequence), int(max_frames))
    if n <= 0:
        raise ValueError(f"{sequence.root}: nothing to run (max_frames={max_frames})")
    if flush_every < 1:
        raise ValueError(f"flush_every must be >= 1 frame, got {flush_every}")
    if not flush_cost_ratio >= 0:
        raise ValueError(f"flush_cost_ratio must be >= 0, got {flush_cost_ratio}")
    if callable(getattr(sequence, "depth_path", None)):  # a wrong depth scale is refused before anything is written
        tc = system.config.tracking
        check_depth_range(sequence, n, tc.min_depth, tc.max_depth)
    if system.screener is not None:
        system.screener.reset()
    with OutputFolder(outdir, kind="run", force=force) as folder:
        rec = RunRecorder(RunWriter(folder, labels=save_labels), save_labels=save_labels)
        stamps = np.asarray(sequence.timestamps, float)
        bar = tqdm(total=n, desc=f"dynslam {sequence.name}", unit="frame", disable=not progress)
        t_run = time.perf_counter()
        try:
            with blas_single_thread(), bar, FramePrefetcher(_PreparingSequence(sequence, system) if extract_ahead else sequence, n, prefetch) as frames:
                t_frame = time.perf_counter()
                t_flushed, flush_s = t_frame, 0.0  # the last write's end and duration
                for item in frames:  # frames read ahead on the other core; a bad one arrives as its error
                    i, frame = item.index, item.frame
                    try:
                        if item.error is not None:
                            raise item.error
                        _check_size(frame, system.camera)
                        res = system.process(frame)
                    except Exception as exc:  # a bad frame must not end the run ...
                        rec.failed(i, float(stamps[i]), exc)
                        system.mark_lost(i)
                        bar.update()
                        repeating = rec.repeating_error(n)
                        if repeating:  # ... but an error that will hit every frame does
                            raise RunStopped(repeating) from None
                        t_frame = time.perf_counter()
                        continue
                    res.timings_ms["read"] = item.wait_ms
                    res.timings_ms["wall"] = 1e3 * (time.perf_counter() - t_frame)
                    rec.frame(i, res, system)
                    if on_frame is not None:
                        on_frame(frame, res)
                    bar.set_postfix(state=res.state, kf=len(system.map.keyframes), lost=len(system.lost_frames), refresh=False)
                    bar.update()
                    if i == 0 or ((i + 1) % flush_every == 0
                                  and time.perf_counter() - t_flushed >= flush_cost_ratio * flush_s):
                        # no waiting for the loop closer's worker here: the frame loop goes on
                        t0 = time.perf_counter()
                        rec.write(system, rec.summary(sequence, system, n, complete=False, wait=False), wait=False)
                        t_flushed = time.perf_counter()
                        flush_s = t_flushed - t0
                    t_frame = time.perf_counter()
            return _finish(sequence, system, rec, n, t_run)
        except KeyboardInterrupt:
            summary = _stop(sequence, system, rec, n, t_run, "interrupted",
                            f"interrupted (Ctrl-C) after {len(rec.rows)} of {n} frames")
            raise RunInterrupted(
                f"interrupted after {len(rec.rows)} of {n} frames: the partial run in {folder.path} is consistent "
                f"(summary.json: complete false); run again with --force to redo it", summary) from None
        except RunStopped as exc:
            exc.summary = _stop(sequence, system, rec, n, t_run, "failed", str(exc))
            raise
        except Exception as exc:
            _stop(sequence, system, rec, n, t_run, "failed", f"{type(exc).__name__}: {exc}")
            raise


def _stop(sequence, system: System, rec: RunRecorder, n: int, t_run: float, state: str, why: str) -> dict:
    """Write the run as it stands after an interruption or a failure: a true ``summary.json``."""
    with _sigint_deferred():
        summary = rec.summary(sequence, system, n, complete=False, state=state)
        summary["stopped"] = why
        summary["wall_time_s"] = time.perf_counter() - t_run
        try:
            rec.write(system, summary)
        except Exception as exc:  # the system may be half-way through a frame: keep what was written whole
            log.warning("could not write every file of the partial run: %s", exc)
            summary["write_error"] = f"{type(exc).__name__}: {exc}"
            rec.writer.summary(summary)
    return summary


def _finish(sequence, system: System, rec: RunRecorder, n: int, t_run: float) -> dict:
    summary = rec.summary(sequence, system, n, complete=False)
    summary["wall_time_s"] = time.perf_counter() - t_run
    # Evaluation against ground truth (ATE/RPE after SE(3) alignment).
    est = system.trajectory()
    if sequence.groundtruth is not None and len(est) >= 2:
        try:
            ev = evaluate(sequence.groundtruth, est, align="se3")
            summary["ate"] = ev["ate"]
            summary["rpe"] = ev["rpe"]
            summary["coverage"] = ev.get("coverage")
        except Exception as exc:  # evaluation must not lose the run
            summary["evaluation_error"] = f"{type(exc).__name__}: {exc}"
            log.warning("evaluation against %s failed: %s", Path(sequence.root) / "groundtruth.txt", exc)
        try:  # a path of the wrong size: the depth scale (no verdict where the path cannot be aligned)
            read_with = getattr(sequence, "camera", system.camera)  # the camera whose depth_scale read the frames
            scale = depth_scale_from_trajectory(sequence.groundtruth, est, read_with.depth_scale)
            summary["trajectory_scale"] = scale.scale
            if scale.warning:
                summary["warnings"] = [scale.warning]
                log.warning("%s", scale.warning)
        except Exception as exc:  # a path that cannot be aligned with a scale (a camera at rest) has no verdict
            log.debug("no depth-scale verdict from the trajectory: %s", exc)
    rec.write(system, summary, final=True)
    # The dense map (another stage; its failure is reported, never fatal).
    outdir = rec.writer.outdir
    try:
        rec.writer.dense_map(lambda tmp: write_dense_map(sequence, outdir, rec.region_masks or None,
                                                         system.config.dense_map, path=tmp))
        summary["dense_map"] = str(outdir / FILES["dense_map"])
    except Exception as exc:
        summary["dense_map_error"] = f"{type(exc).__name__}: {exc}"
        log.warning("dense map failed: %s", exc)
    summary["complete"] = True
    summary["state"] = "complete"
    rec.writer.summary(summary)
    return summary
