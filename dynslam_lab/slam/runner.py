"""Run the whole pipeline over a sequence and write the run folder (``docs/architecture.md``).

``OUTDIR`` receives ``trajectory.txt`` (TUM format), ``timing.csv`` (one row per frame, one
column per stage in ms), ``summary.json``, ``keyframes.npz``, ``map_points.npz``,
``dynamic_points.npz``, ``thumbs/KFID.jpg``, ``map.ply`` (by ``mapping.dense`` when present)
and, with ``save_labels``, ``labels/NNNNNN.csv`` (the screener's keypoint table per frame).

A frame that cannot be read or processed is logged, counted as lost, and the run goes on.
Everything computed so far is written every ``flush_every`` frames, so a crash loses little.
"""

from __future__ import annotations

import json
import logging
import time
import traceback
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..config import config_to_dict
from ..evaluation.trajectory import write_tum_trajectory
from .system import System

__all__ = ["run_sequence", "STAGES", "blas_single_thread"]

log = logging.getLogger(__name__)

STAGES = ("orb", "detect", "screen", "track", "local_mapping", "loop", "total")


def _json_default(o: Any):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    return str(o)


def _write_outputs(outdir: Path, system: System, rows: list[dict], dyn_xyz: list[np.ndarray], dyn_frame: list[np.ndarray],
                   summary: dict) -> None:
    write_tum_trajectory(system.trajectory(), outdir / "trajectory.txt", header="dynslam_lab trajectory: timestamp tx ty tz qx qy qz qw")
    with (outdir / "timing.csv").open("w") as fh:
        fh.write("frame,timestamp," + ",".join(STAGES) + "\n")
        for r in rows:
            fh.write(f"{r['frame']},{r['timestamp']:.6f}," + ",".join(f"{r.get(s, float('nan')):.3f}" for s in STAGES) + "\n")
    np.savez(outdir / "keyframes.npz", **system.keyframe_arrays())
    np.savez(outdir / "map_points.npz", **system.map_point_arrays())
    xyz = np.concatenate(dyn_xyz) if dyn_xyz else np.zeros((0, 3))
    fr = np.concatenate(dyn_frame) if dyn_frame else np.zeros(0, np.int64)
    np.savez(outdir / "dynamic_points.npz", xyz=xyz, frame=fr)
    tmp = outdir / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=2, default=_json_default) + "\n")
    tmp.replace(outdir / "summary.json")


def _summary(sequence, system: System, rows: list[dict], n_frames: int, config, errors: list[str], complete: bool) -> dict:
    tracked = len(system.trajectory())
    stage_ms = {s: np.array([r.get(s, np.nan) for r in rows], float) for s in STAGES}
    return {
        "sequence": str(getattr(sequence, "root", "")),
        "complete": complete,
        "frames": n_frames,
        "processed": len(rows),
        "tracked": tracked,
        "lost": len(system.lost_frames),
        "lost_frames": list(system.lost_frames),
        "keyframes": len(system.map.keyframes),
        "map_points": int(len(system.map.point_ids())),
        "loops": len(system.loop_results),
        "loop_edges": [list(e) for e in system.keyframe_arrays()["loop_edges"].tolist()],
        "timing_median_ms": {s: (float(np.nanmedian(v)) if np.isfinite(v).any() else None) for s, v in stage_ms.items()},
        "timing_mean_ms": {s: (float(np.nanmean(v)) if np.isfinite(v).any() else None) for s, v in stage_ms.items()},
        "errors": errors[-50:],
        "config": config_to_dict(config),
    }


def blas_single_thread():
    """A context limiting BLAS to one thread when ``threadpoolctl`` is installed (else a no-op).

    The optimisation problems here are small; a multi-threaded BLAS on a shared machine spends
    more time waiting for its threads than computing (local BA measured 10x slower)."""
    import contextlib

    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


def run_sequence(
    sequence,
    outdir: str | Path,
    config=None,
    detector=None,
    screener=None,
    loop_closer=None,
    max_frames: int | None = None,
    progress: bool = True,
    save_labels: bool = False,
    flush_every: int = 50,
) -> dict:
    """Run SLAM over ``sequence`` (a :class:`~dynslam_lab.datasets.tum.TumSequence`) and write ``outdir``.

    Parameters
    ----------
    sequence : the frames (indexable, ``len``, ``camera``, ``groundtruth`` or None).
    outdir : run folder (created).
    config : root :class:`~dynslam_lab.config.Config` (default values when None).
    detector, screener, loop_closer : optional stages (see ``docs/architecture.md``).
    max_frames : process only the first frames.
    progress : show a tqdm progress bar.
    save_labels : write each frame's keypoint table to ``labels/``.
    flush_every : write all outputs every this many frames.

    Returns
    -------
    The summary dict (also in ``summary.json``), with ``ate``/``rpe`` when ground truth exists.
    """
    if config is None:
        from ..config import Config

        config = Config()
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    (outdir / "thumbs").mkdir(exist_ok=True)
    if save_labels:
        (outdir / "labels").mkdir(exist_ok=True)
    if screener is not None and hasattr(screener, "reset"):
        screener.reset()
    n = len(sequence) if max_frames is None else min(len(sequence), int(max_frames))
    if n <= 0:
        raise ValueError(f"{getattr(sequence, 'root', 'sequence')}: nothing to run (max_frames={max_frames})")
    system = System(sequence.camera, config, detector=detector, screener=screener, loop_closer=loop_closer)
    rows: list[dict] = []
    dyn_xyz: list[np.ndarray] = []
    dyn_frame: list[np.ndarray] = []
    region_masks: dict[int, np.ndarray] = {}
    errors: list[str] = []
    iterator = range(n)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(iterator, total=n, desc=f"dynslam {getattr(sequence, 'name', '')}", unit="frame")
        iterator = bar
    t_run = time.perf_counter()
    with blas_single_thread():
        _loop(sequence, system, iterator, bar, outdir, rows, dyn_xyz, dyn_frame, region_masks, errors, n, config,
              save_labels, flush_every)
    summary = _finish(sequence, system, outdir, rows, dyn_xyz, dyn_frame, region_masks, errors, n, config, t_run)
    return summary


def _loop(sequence, system, iterator, bar, outdir, rows, dyn_xyz, dyn_frame, region_masks, errors, n, config,
          save_labels, flush_every) -> None:
    stamps = np.asarray(sequence.timestamps, float) if hasattr(sequence, "timestamps") else np.arange(n, dtype=float)
    for i in iterator:
        ts = float(stamps[i])
        try:
            frame = sequence[i]
            res = system.process(frame)
        except Exception as exc:  # a bad frame must not end the run
            msg = f"frame {i}: {type(exc).__name__}: {exc}"
            log.warning("%s", msg)
            log.debug("%s", traceback.format_exc())
            errors.append(msg)
            system.mark_lost(i)
            rows.append({"frame": i, "timestamp": ts})
            continue
        rows.append({"frame": i, "timestamp": res.timestamp, **res.timings_ms})
        if res.dynamic_xyz is not None and len(res.dynamic_xyz):
            dyn_xyz.append(res.dynamic_xyz)
            dyn_frame.append(np.full(len(res.dynamic_xyz), i, np.int64))
        if res.is_keyframe:
            kf = system.map.keyframes.get(res.keyframe_id)
            if kf is not None and kf.thumbnail is not None:
                cv2.imwrite(str(outdir / "thumbs" / f"{kf.id}.jpg"), cv2.cvtColor(kf.thumbnail, cv2.COLOR_RGB2BGR))
            if res.region_mask is not None:
                region_masks[i] = np.asarray(res.region_mask, bool)
        if save_labels and res.table is not None and hasattr(res.table, "to_dataframe"):
            res.table.to_dataframe().to_csv(outdir / "labels" / f"{i:06d}.csv", index=False)
        if bar is not None:
            bar.set_postfix(state=res.state, kf=len(system.map.keyframes), lost=len(system.lost_frames), refresh=False)
        if flush_every and (i + 1) % flush_every == 0:
            _write_outputs(outdir, system, rows, dyn_xyz, dyn_frame, _summary(sequence, system, rows, n, config, errors, False))


def _finish(sequence, system, outdir, rows, dyn_xyz, dyn_frame, region_masks, errors, n, config, t_run) -> dict:
    summary = _summary(sequence, system, rows, n, config, errors, True)
    summary["wall_time_s"] = time.perf_counter() - t_run
    # Thumbnails of culled keyframes go.
    keep = {f"{k}.jpg" for k in system.map.keyframes}
    for p in (outdir / "thumbs").glob("*.jpg"):
        if p.name not in keep:
            p.unlink()
    # Evaluation against ground truth (evaluation.evaluate: ATE/RPE after SE(3) alignment).
    gt = getattr(sequence, "groundtruth", None)
    est = system.trajectory()
    if gt is not None and len(est) >= 2:
        try:
            from ..evaluation import evaluate

            ev = evaluate(gt, est, align="se3")
            summary["ate"] = ev["ate"]
            summary["rpe"] = ev["rpe"]
            summary["coverage"] = ev.get("coverage")
        except Exception as exc:  # evaluation must not lose the run
            summary["evaluation_error"] = f"{type(exc).__name__}: {exc}"
    _write_outputs(outdir, system, rows, dyn_xyz, dyn_frame, summary)
    # The dense map (another stage; its failure is reported, never fatal).
    try:
        from ..mapping.dense import write_dense_map
    except ImportError as exc:
        summary["dense_map_error"] = f"mapping.dense not available ({exc})"
    else:
        try:
            path = write_dense_map(sequence, outdir, region_masks or None, getattr(config, "dense_map", None))
            summary["dense_map"] = str(path)
        except Exception as exc:
            summary["dense_map_error"] = f"{type(exc).__name__}: {exc}"
            log.warning("dense map failed: %s", exc)
    tmp = outdir / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=2, default=_json_default) + "\n")
    tmp.replace(outdir / "summary.json")
    return summary
