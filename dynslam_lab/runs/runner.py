"""Run a built system over a sequence and write its run folder (:mod:`.layout`).

A frame that cannot be read or processed is logged, counted as lost, and the run goes on.
Everything computed so far is written every ``flush_every`` frames, so a crash loses little;
``summary.json`` says ``complete: false`` until the last frame, the evaluation and the dense map
are done.
"""

from __future__ import annotations

import logging
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from tqdm import tqdm

from ..config import config_to_dict
from ..datasets.prefetch import FramePrefetcher, PrefetchConfig
from ..evaluation.tables import evaluate
from ..mapping.dense import write_dense_map
from ..slam.system import FrameResult, System
from ..threads import blas_single_thread
from .layout import STAGES, RunWriter

__all__ = ["run_sequence", "RunRecorder"]

log = logging.getLogger(__name__)


@dataclass
class RunRecorder:
    """What a run accumulates frame by frame, and writes with a :class:`~.layout.RunWriter`.

    Attributes
    ----------
    rows : per-frame timing rows (``frame``, ``timestamp``, stage ms).
    dynamic_xyz, dynamic_frame : world points of keypoints judged dynamic, and their frames.
    region_masks : keyframe frame index -> ``(H, W)`` bool pixels judged dynamic (the dense map
        leaves them out).
    errors : one message per frame that failed.
    """

    writer: RunWriter
    save_labels: bool = False
    rows: list[dict] = field(default_factory=list)
    dynamic_xyz: list[np.ndarray] = field(default_factory=list)
    dynamic_frame: list[np.ndarray] = field(default_factory=list)
    region_masks: dict[int, np.ndarray] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)

    def failed(self, index: int, timestamp: float, exc: Exception) -> None:
        """A frame that could not be processed at all."""
        msg = f"frame {index}: {type(exc).__name__}: {exc}"
        log.warning("%s", msg)
        log.debug("%s", traceback.format_exc())
        self.errors.append(msg)
        self.rows.append({"frame": index, "timestamp": timestamp})

    def frame(self, index: int, res: FrameResult, system: System) -> None:
        """A processed frame: its timings, dynamic points, thumbnail, region mask, labels."""
        self.rows.append({"frame": index, "timestamp": res.timestamp, **res.timings_ms})
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

    def write(self, system: System, summary: dict) -> None:
        """Every file of the run as it stands, ``summary.json`` last."""
        w = self.writer
        w.trajectory(system.trajectory())
        w.timing(self.rows)
        w.keyframes(**system.keyframe_arrays())
        w.map_points(**system.map_point_arrays())
        xyz = np.concatenate(self.dynamic_xyz) if self.dynamic_xyz else np.zeros((0, 3))
        fr = np.concatenate(self.dynamic_frame) if self.dynamic_frame else np.zeros(0, np.int64)
        w.dynamic_points(xyz, fr)
        w.summary(summary)

    def summary(self, sequence, system: System, n_frames: int, complete: bool) -> dict:
        """The ``summary.json`` dict of the run so far."""
        stage_ms = {s: np.array([r.get(s, np.nan) for r in self.rows], float) for s in STAGES}
        return {
            "sequence": str(sequence.root),
            "complete": complete,
            "frames": n_frames,
            "processed": len(self.rows),
            "tracked": len(system.trajectory()),
            "lost": len(system.lost_frames),
            "lost_frames": list(system.lost_frames),
            "keyframes": len(system.map.keyframes),
            "map_points": int(len(system.map.point_ids())),
            "loops": len(system.loop_results),
            "loop_edges": [list(e) for e in system.keyframe_arrays()["loop_edges"].tolist()],
            "timing_median_ms": {s: (float(np.nanmedian(v)) if np.isfinite(v).any() else None) for s, v in stage_ms.items()},
            "timing_mean_ms": {s: (float(np.nanmean(v)) if np.isfinite(v).any() else None) for s, v in stage_ms.items()},
            "errors": self.errors[-50:],
            "pipeline": dict(system.description),
            "config": config_to_dict(system.effective_config()),
        }


def run_sequence(
    sequence,
    outdir: str | Path,
    system: System,
    max_frames: int | None = None,
    progress: bool = True,
    save_labels: bool = False,
    flush_every: int = 50,
    on_frame: Callable[[object, FrameResult], None] | None = None,
    prefetch: PrefetchConfig = PrefetchConfig(),
) -> dict:
    """Run ``system`` over ``sequence`` and write the run folder ``outdir``.

    Parameters
    ----------
    sequence : a :class:`~dynslam_lab.datasets.tum.TumSequence` (indexable, ``len``, ``root``,
        ``name``, ``timestamps``, ``groundtruth`` or None).
    outdir : run folder (created).
    system : the SLAM system, from :func:`dynslam_lab.pipeline.build_pipeline`; its screener's
        history is reset first.
    max_frames : process only the first frames.
    progress : show a tqdm progress bar.
    save_labels : write each frame's keypoint table to ``labels/``.
    flush_every : write all outputs every this many frames.
    on_frame : called as ``on_frame(frame, result)`` after each processed frame (scores,
        notebooks).
    prefetch : read-ahead of the frames (:class:`~dynslam_lab.datasets.prefetch.PrefetchConfig`;
        ``queue_size=0`` reads in this thread).

    Returns
    -------
    The summary dict (also in ``summary.json``), with ``ate``/``rpe`` when ground truth exists.
    """
    n = len(sequence) if max_frames is None else min(len(sequence), int(max_frames))
    if n <= 0:
        raise ValueError(f"{sequence.root}: nothing to run (max_frames={max_frames})")
    if system.screener is not None:
        system.screener.reset()
    rec = RunRecorder(RunWriter(outdir, labels=save_labels), save_labels=save_labels)
    stamps = np.asarray(sequence.timestamps, float)
    bar = tqdm(total=n, desc=f"dynslam {sequence.name}", unit="frame", disable=not progress)
    t_run = time.perf_counter()
    with blas_single_thread(), bar, FramePrefetcher(sequence, n, prefetch) as frames:
        t_frame = time.perf_counter()
        for item in frames:  # frames read ahead on the other core; a bad one arrives as its error
            i, frame = item.index, item.frame
            try:
                if item.error is not None:
                    raise item.error
                res = system.process(frame)
            except Exception as exc:  # a bad frame must not end the run
                rec.failed(i, float(stamps[i]), exc)
                system.mark_lost(i)
                bar.update()
                t_frame = time.perf_counter()
                continue
            res.timings_ms["read"] = item.wait_ms
            res.timings_ms["wall"] = 1e3 * (time.perf_counter() - t_frame)
            rec.frame(i, res, system)
            if on_frame is not None:
                on_frame(frame, res)
            bar.set_postfix(state=res.state, kf=len(system.map.keyframes), lost=len(system.lost_frames), refresh=False)
            bar.update()
            if flush_every and (i + 1) % flush_every == 0:
                rec.write(system, rec.summary(sequence, system, n, complete=False))
            t_frame = time.perf_counter()
    return _finish(sequence, system, rec, n, t_run)


def _finish(sequence, system: System, rec: RunRecorder, n: int, t_run: float) -> dict:
    summary = rec.summary(sequence, system, n, complete=False)
    summary["wall_time_s"] = time.perf_counter() - t_run
    # Thumbnails of culled keyframes go.
    keep = {f"{k}.jpg" for k in system.map.keyframes}
    for p in rec.writer.path("thumbs").glob("*.jpg"):
        if p.name not in keep:
            p.unlink()
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
    rec.write(system, summary)
    # The dense map (another stage; its failure is reported, never fatal).
    try:
        path = write_dense_map(sequence, rec.writer.outdir, rec.region_masks or None, system.config.dense_map)
        summary["dense_map"] = str(path)
    except Exception as exc:
        summary["dense_map_error"] = f"{type(exc).__name__}: {exc}"
        log.warning("dense map failed: %s", exc)
    summary["complete"] = True
    rec.writer.summary(summary)
    return summary
