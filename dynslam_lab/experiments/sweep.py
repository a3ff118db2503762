"""Parameter sweeps: many independent runs on a process pool here or a Dask cluster beyond.

The papers' sensitivity figures (ATE or precision against a threshold) are sweeps: one SLAM run
per sequence, seed, filter and parameter value. :func:`run_sweep` takes a
:class:`~dynslam_lab.experiments.sweep_spec.SweepSpec` (``dynslam sweep SPEC.toml``) and

1. lists its runs, each named by the hash of its inputs (:func:`~.sweep_spec.run_id`);
2. skips the runs already finished in ``OUT/runs/`` (``summary.json`` complete and the sweep's
   record written), and removes what unfinished runs left, so a killed sweep started again
   redoes only those;
3. hands the others to an existing engine, one task per run: a local
   :class:`concurrent.futures.ProcessPoolExecutor` (``workers`` processes, each with
   ``cores // workers`` BLAS and OpenCV threads), or a Dask ``distributed`` cluster
   (``scheduler="tcp://HOST:8786"``, or a ``distributed.Client``), gathering results as they
   finish;
4. writes ``OUT/results.csv``, one row per run (:func:`results_table`), and the plots of each
   metric against each swept parameter (:mod:`.sweep_plots`).

Each task (:func:`execute_run`) renders or reads its sequence itself (a synthetic sequence is
rendered once per cache: a lock in ``OUT/locks/`` keeps two workers from rendering the same one,
and the renderer's cache is atomic anyway), builds the system with
:func:`dynslam_lab.pipeline.build_pipeline` and runs it with
:func:`dynslam_lab.runs.run_sequence`, exactly like ``dynslam run``, scoring the keypoint
verdicts against the synthetic truth on the way (:class:`.scoring.KeypointScorer`). A run that
fails records its error (``OUT/runs/RUN_ID/error.txt`` and the table) and the sweep goes on.

``OUT`` holds::

    sweep.json        the spec and the list of runs (id, sequence, filter, detector, parameters)
    results.csv       the table (rewritten as runs finish)
    plots/METRIC__PARAM.png
    runs/RUN_ID/      a run folder (docs/architecture.md) + sweep_run.json (inputs, keypoint
                      scores, status) or error.txt
    locks/            render locks (one per synthetic sequence)

With a Dask cluster, ``OUT`` must be a path that every worker sees (a shared filesystem): the
workers write the run folders and the client reads them back.
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import fcntl
import json
import math
import multiprocessing
import os
import shutil
import signal
import socket
import sys
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

import cv2
import pandas as pd
from threadpoolctl import threadpool_limits
from tqdm.auto import tqdm

from ..datasets.synthetic import synthetic_sequence
from ..datasets.tum import TumSequence
from ..pipeline import build_pipeline
from ..runs import FILES, run_sequence
from ..runs.layout import atomic_write
from .scoring import KeypointScorer
from .sweep_plots import save_plots
from .sweep_spec import RunTask, SweepSpec, run_id, run_inputs

__all__ = [
    "RECORD",
    "TIMING_PREFIXES",
    "SweepReport",
    "run_sweep",
    "execute_run",
    "is_finished",
    "results_table",
    "deterministic_columns",
    "available_cores",
]

#: The sweep's record of a run, beside the run folder's own files.
RECORD = "sweep_run.json"
#: The file a failed run leaves (the traceback).
ERROR_FILE = "error.txt"
#: Columns of the table that measure time: they differ between two sweeps of the same spec.
TIMING_PREFIXES = ("timing_median_ms.", "timing_mean_ms.", "wall_time_s")
#: Keys of ``summary.json`` that are not metrics (identities, lists, paths, the config).
_NOT_METRICS = ("schema_version", "complete", "sequence", "lost_frames", "loop_edges", "errors", "pipeline",
                "config", "dense_map", "dense_map_error", "evaluation_error", "files", "run_id", "state", "stopped")
#: Seconds between rewrites of results.csv while the sweep runs.
_TABLE_EVERY_S = 5.0


def available_cores() -> int:
    """Processors this process may run on (its affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - macOS, Windows
        return os.cpu_count() or 1


# ------------------------------------------------------------------------- one run (in a worker)
@contextlib.contextmanager
def _thread_budget(threads: int):
    """BLAS and OpenCV limited to ``threads`` for the block (restored after)."""
    previous = cv2.getNumThreads()
    cv2.setNumThreads(int(threads))
    try:
        with threadpool_limits(limits=int(threads)):
            yield
    finally:
        cv2.setNumThreads(previous)


@contextlib.contextmanager
def _file_lock(path: Path):
    """An exclusive ``flock`` on ``path`` (created), released at the end of the block."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _open_sequence(task: RunTask, locks: Path) -> TumSequence:
    seq = task.sequence
    if seq.synthetic:
        with _file_lock(locks / f"{seq.identity['cache_key']}.lock"):
            root = synthetic_sequence(seq.preset, n_frames=seq.n_frames, seed=seq.seed)
        return TumSequence(root)
    return TumSequence(seq.path, camera=seq.camera)


def _write_json(path: Path, data: dict) -> None:
    atomic_write(path, lambda tmp: tmp.write_text(json.dumps(data, indent=1, default=str) + "\n"))


def _clear(run_dir: Path) -> None:
    """Remove what an unfinished run left in its folder (the sweep made the folder), so that the
    run starts in a fresh one."""
    if run_dir.exists():
        shutil.rmtree(run_dir)


def execute_run(task: RunTask, threads: int = 1) -> dict:
    """Do one run of a sweep (in a worker process or a Dask worker) and return its record.

    The record (also ``RUN_DIR/sweep_run.json``) holds ``run_id``, ``status`` (``done`` or
    ``failed``), ``error``, ``inputs``, ``keypoints`` (confusion counts, precision and recall
    against the synthetic truth, or None), ``seconds``, ``host`` and ``pid``. Any exception of
    the run is caught and recorded (``RUN_DIR/error.txt`` holds the traceback): one failed run
    never ends a sweep.

    Parameters
    ----------
    task : the run.
    threads : BLAS and OpenCV threads for this run (and the detector's, unless the config sets them).
    """
    t0 = time.perf_counter()
    run_dir = Path(task.run_dir)
    record: dict[str, Any] = {"run_id": task.run_id, "status": "failed", "error": None, "inputs": task.inputs,
                              "keypoints": None, "host": socket.gethostname(), "pid": os.getpid()}
    try:
        _clear(run_dir)
        config = task.config()
        # The worker must name the run as the client did: same package (version, defaults, renderer)
        # and the same sequence files.
        here = dataclasses.replace(task.sequence, identity=task.sequence.current_identity())
        mine = run_id(run_inputs(here, task.filters, task.inputs["detector"], config, task.loop_closing))
        if mine != task.run_id:
            raise RuntimeError(f"this worker names the run {mine}, the client {task.run_id}: the worker's dynslam_lab "
                               "(version, defaults, renderer) or the sequence's files differ from the client's")
        if config.detection.num_threads == 0:  # the detector's threads: this worker's share (not in the hash)
            config = dataclasses.replace(config, detection=dataclasses.replace(config.detection, num_threads=int(threads)))
        with _thread_budget(threads):
            seq = _open_sequence(task, run_dir.parent.parent / "locks")
            system = build_pipeline(config, seq.camera, detector=task.detector, filters=task.filters,
                                    loop_closing=task.loop_closing)
            scorer = KeypointScorer() if task.sequence.has_truth() else None
            run_sequence(seq, run_dir, system, max_frames=task.sequence.max_frames, progress=False, on_frame=scorer)
        if scorer is not None:
            record["keypoints"] = scorer.score.to_dict()
        record["status"] = "done"
    except Exception as exc:  # a failed run is recorded, never fatal to the sweep
        record["error"] = f"{type(exc).__name__}: {exc}"
        run_dir.mkdir(parents=True, exist_ok=True)
        tb = traceback.format_exc()
        atomic_write(run_dir / ERROR_FILE, lambda tmp: tmp.write_text(tb))
    record["seconds"] = time.perf_counter() - t0
    _write_json(run_dir / RECORD, record)
    return record


def is_finished(run_dir: str | Path) -> bool:
    """The run is done: ``summary.json`` says ``complete`` and the sweep's record says ``done``
    (the record is written right after the summary; a run killed between the two is redone)."""
    run_dir = Path(run_dir)
    try:
        summary = json.loads((run_dir / FILES["summary"]).read_text())
        record = json.loads((run_dir / RECORD).read_text())
    except (OSError, ValueError):
        return False
    return bool(summary.get("complete")) and record.get("status") == "done"


# ------------------------------------------------------------------------- the table
def _flatten(d: dict, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, f"{prefix}{k}."))
        elif isinstance(v, bool):
            out[f"{prefix}{k}"] = int(v)
        elif isinstance(v, (int, float)) or v is None:
            out[f"{prefix}{k}"] = math.nan if v is None else v
    return out


def _cell(v: Any) -> Any:
    """A parameter value as a table cell (lists as compact JSON)."""
    return json.dumps(v, separators=(",", ":")) if isinstance(v, (list, tuple)) else v


def _row(task: RunTask, out: Path) -> dict[str, Any]:
    """The table row of one run, read from its folder (no metrics unless it is done)."""
    seq = task.sequence
    run_dir = Path(task.run_dir)
    row: dict[str, Any] = {"run_id": task.run_id, "status": "pending", "error": "", "sequence": seq.label,
                           "seed": seq.seed if seq.synthetic else math.nan,
                           "n_frames": seq.n_frames if seq.synthetic else math.nan,
                           "filter": task.filters, "detector": task.detector}
    row.update({k: _cell(v) for k, v in task.params})
    record: dict = {}
    with contextlib.suppress(OSError, ValueError):
        record = json.loads((run_dir / RECORD).read_text())
    summary: dict = {}
    with contextlib.suppress(OSError, ValueError):
        summary = json.loads((run_dir / FILES["summary"]).read_text())
    if record:
        row["status"] = "done" if is_finished(run_dir) else "failed"
        row["error"] = record.get("error") or ("" if row["status"] == "done" else "run folder incomplete")
    if row["status"] == "done":  # the metrics of a finished run only (a failed one may have left a partial summary)
        row.update(_flatten({k: v for k, v in summary.items() if k not in _NOT_METRICS}))
        row["n_errors"] = len(summary.get("errors", []))
        for k, v in (record.get("keypoints") or {}).items():
            row[f"keypoints.{k}"] = math.nan if v is None else v
    row["run_dir"] = str(run_dir.relative_to(out)) if run_dir.is_relative_to(out) else str(run_dir)
    return row


def results_table(tasks: Iterable[RunTask], out: str | Path, rows: dict[str, dict] | None = None) -> pd.DataFrame:
    """The tidy table of a sweep: one row per run in plan order.

    Columns: ``run_id, status (done | failed | pending), error, sequence, seed, n_frames, filter,
    detector``, one column per swept parameter (its dotted key), then every number of
    ``summary.json`` flattened with dots (``frames``, ``tracked``, ``lost``, ``keyframes``,
    ``map_points``, ``loops``, ``timing_median_ms.STAGE``, ``timing_mean_ms.STAGE``,
    ``wall_time_s``, ``ate.rmse``..., ``rpe.trans.rmse``..., ``coverage``), ``n_errors`` (frames
    that failed), ``keypoints.{tp,fp,fn,tn,precision,recall}`` on sequences with truth, and
    ``run_dir`` (relative to ``out``). ``rows`` caches rows already read (run id -> row).
    """
    out = Path(out).resolve()
    tasks = list(tasks)
    rows = rows if rows is not None else {}
    data = [rows[t.run_id] if t.run_id in rows else _row(t, out) for t in tasks]
    columns: dict[str, None] = {}
    for r in data:
        columns.update(dict.fromkeys(k for k in r if k != "run_dir"))
    df = pd.DataFrame(data, columns=[*columns, "run_dir"])
    return df


def deterministic_columns(df: pd.DataFrame) -> list[str]:
    """The columns of a results table that do not measure time (equal between two sweeps of one spec)."""
    return [c for c in df.columns if not c.startswith(TIMING_PREFIXES)]


def _write_table(df: pd.DataFrame, path: Path) -> None:
    atomic_write(path, lambda tmp: df.to_csv(tmp, index=False))


# ------------------------------------------------------------------------- engines
def _init_worker(parent_pid: int) -> None:
    """A pool worker: it dies with the sweep, and leaves Ctrl-C to the sweep.

    On Linux the worker asks for SIGKILL when its parent dies (``prctl(PR_SET_PDEATHSIG)``), so
    that a killed sweep leaves no worker writing into a run folder that the next sweep redoes.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and ends the workers
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # 1 = PR_SET_PDEATHSIG
        if os.getppid() != parent_pid:  # the parent died before the request
            os._exit(1)


def _failed_record(task: RunTask, exc: BaseException) -> dict:
    """Record of a run whose worker died (the engine's error, not the run's)."""
    run_dir = Path(task.run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    record = {"run_id": task.run_id, "status": "failed", "error": f"{type(exc).__name__}: {exc}",
              "inputs": task.inputs, "keypoints": None}
    with contextlib.suppress(OSError):
        _write_json(run_dir / RECORD, record)
    return record


def _run_in_process(tasks: list[RunTask], threads: int, done: Callable[[RunTask, dict], None]) -> None:
    for task in tasks:
        done(task, execute_run(task, threads))


def _run_pool(tasks: list[RunTask], workers: int, threads: int, done: Callable[[RunTask, dict], None]) -> None:
    # spawn: each worker is a fresh interpreter and a child of this process (so it can die with it;
    # a forkserver's workers are the server's children and outlive a killed sweep), with no copy
    # of this process's threads.
    ctx = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_init_worker, initargs=(os.getpid(),))
    futures = {pool.submit(execute_run, t, threads): t for t in tasks}
    try:
        for fut in as_completed(futures):
            task = futures[fut]
            try:
                record = fut.result()
            except Exception as exc:  # the worker died (killed, out of memory): the run is recorded as failed
                record = _failed_record(task, exc)
            done(task, record)
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        # The running workers stop now: their runs are unfinished and will be redone.
        for proc in list(getattr(pool, "_processes", {}).values()):  # no public way before Python 3.14
            with contextlib.suppress(Exception):
                proc.kill()
        raise
    pool.shutdown(wait=True)


def _run_dask(tasks: list[RunTask], scheduler: Any, done: Callable[[RunTask, dict], None], log: Callable[[str], None]) -> None:
    try:  # optional heavy dependency: the `sweeps` extra
        from distributed import Client
        from distributed import as_completed as dask_as_completed
    except ImportError as exc:
        raise RuntimeError("a Dask scheduler was given but Dask is not installed: pip install 'dynslam_lab[sweeps]'") from exc
    own = not isinstance(scheduler, Client)
    client = Client(scheduler) if own else scheduler
    try:
        log(f"sweep: Dask scheduler {client.scheduler.address}, dashboard {client.dashboard_link}")
        futures = {}
        for t in tasks:  # one task per run; 1 BLAS/OpenCV thread each (a worker runs one task per thread)
            fut = client.submit(execute_run, t, 1, key=f"dynslam-run-{t.run_id}", pure=False)
            futures[fut.key] = (fut, t)
        for fut in dask_as_completed([f for f, _ in futures.values()]):
            task = futures[fut.key][1]
            try:
                record = fut.result()
            except Exception as exc:  # the worker died (KilledWorker) or the task could not be run
                record = _failed_record(task, exc)
            done(task, record)
            fut.release()
    finally:
        if own:
            client.close()


# ------------------------------------------------------------------------- the sweep
@dataclass
class SweepReport:
    """What :func:`run_sweep` did.

    Attributes
    ----------
    out : the sweep folder; table : the results (also ``out/results.csv``).
    total : runs in the spec; skipped : finished before (not redone); executed : run now;
    failed : runs that failed now; seconds : wall time; plots : PNG files written;
    engine : ``in-process``, ``process pool (N workers, T threads each)`` or ``dask (ADDRESS)``.
    """

    out: Path
    table: pd.DataFrame
    total: int
    skipped: int
    executed: int
    failed: int
    seconds: float
    engine: str
    plots: list[Path] = field(default_factory=list)


@contextlib.contextmanager
def _sweep_lock(out: Path):
    """One sweep at a time in ``out`` (the lock goes with the process, killed or not)."""
    fh = (out / ".sweep.lock").open("a")
    try:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError as exc:
            raise RuntimeError(f"{out}: another sweep is running in this folder") from exc
        yield
    finally:
        fh.close()


def _plan_json(spec: SweepSpec, tasks: list[RunTask]) -> dict:
    return {
        "spec": {"source": spec.source, "name": spec.name, "filters": list(spec.filters), "detectors": list(spec.detectors),
                 "grid": {k: list(v) for k, v in spec.grid}, "config": spec.overrides, "loop_closing": spec.loop_closing,
                 "sequences": [s.identity | {"label": s.label, "max_frames": s.max_frames} for s in spec.sequences]},
        "runs": [{"run_id": t.run_id, "sequence": t.sequence.label, "seed": t.sequence.seed, "filter": t.filters,
                  "detector": t.detector, "params": dict(t.params)} for t in tasks],
    }


def _interleave(tasks: list[RunTask]) -> list[RunTask]:
    """Submission order: round robin over sequences, so that the first tasks of a pool render
    different sequences instead of waiting for one."""
    groups: dict[str, list[RunTask]] = {}
    for t in tasks:
        groups.setdefault(json.dumps(t.sequence.identity, sort_keys=True), []).append(t)
    out = []
    queues = list(groups.values())
    while any(queues):
        for q in queues:
            if q:
                out.append(q.pop(0))
    return out


def run_sweep(
    spec: SweepSpec,
    out: str | Path,
    workers: int | None = None,
    scheduler: Any = None,
    progress: bool = True,
    plots: bool = True,
    log: Callable[[str], None] | None = None,
) -> SweepReport:
    """Run every unfinished run of ``spec`` into ``out`` and write the table and the plots.

    Parameters
    ----------
    spec : the sweep (:func:`~.sweep_spec.load_spec`).
    out : the sweep folder (created; a folder of an earlier sweep is resumed).
    workers : local worker processes (default: the cores available); ``0`` runs in this process
        (debugging, notebooks). Each worker gets ``max(1, cores // workers)`` BLAS and OpenCV threads.
    scheduler : a Dask scheduler address (``tcp://HOST:8786``) or a ``distributed.Client``; default
        ``spec.scheduler``; None runs on the local pool.
    progress : a tqdm bar over runs.
    plots : write ``out/plots/*.png``.
    log : where status lines go (default: stderr when ``progress``, else nowhere).

    Returns
    -------
    :class:`SweepReport`.
    """
    t_start = time.perf_counter()
    if log is None:
        log = (lambda msg: tqdm.write(msg, file=sys.stderr)) if progress else (lambda msg: None)
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    scheduler = scheduler if scheduler is not None else spec.scheduler
    cores = available_cores()
    workers = cores if workers is None else int(workers)
    if workers < 0:
        raise ValueError(f"workers must be >= 0, got {workers}")
    threads = max(1, cores // max(workers, 1))
    with _sweep_lock(out):
        tasks = spec.tasks(out)
        _write_json(out / "sweep.json", _plan_json(spec, tasks))
        todo = [t for t in tasks if not is_finished(t.run_dir)]
        skipped = len(tasks) - len(todo)
        if scheduler is not None:
            address = scheduler if isinstance(scheduler, str) else getattr(scheduler.scheduler, "address", "?")
            engine = f"Dask cluster at {address}"
        elif workers == 0:
            engine = f"in-process ({threads} threads)"
        else:
            engine = f"process pool ({workers} workers, {threads} BLAS/OpenCV threads each)"
        log(f"sweep {spec.name}: {len(tasks)} runs, {skipped} finished before, {len(todo)} to do, on a {engine}")

        todo_ids = {t.run_id for t in todo}
        rows: dict[str, dict] = {t.run_id: _row(t, out) for t in tasks if t.run_id not in todo_ids}
        failed = 0
        last_write = [0.0]
        bar = tqdm(total=len(todo), desc=f"sweep {spec.name}", unit="run", disable=not progress)

        def done(task: RunTask, record: dict) -> None:
            nonlocal failed
            row = rows[task.run_id] = _row(task, out)
            if record.get("status") == "done" and row["status"] != "done":  # the worker wrote it elsewhere
                row["status"] = "failed"
                row["error"] = record["error"] = (f"run folder {task.run_dir} not found complete from here: with a Dask "
                                                  "cluster, OUT must be on a filesystem every worker shares")
            if row["status"] != "done":
                failed += 1
                log(f"sweep: run {task.run_id} ({task.sequence.label}, {task.filters}) failed: {record.get('error')}")
            bar.set_postfix(failed=failed, refresh=False)
            bar.update()
            if time.perf_counter() - last_write[0] > _TABLE_EVERY_S:
                _write_table(results_table(tasks, out, rows), out / "results.csv")
                last_write[0] = time.perf_counter()

        order = _interleave(todo)
        with bar:
            if not todo:
                log(f"sweep {spec.name}: nothing to do")
            elif scheduler is not None:
                _run_dask(order, scheduler, done, log)
            elif workers == 0:
                _run_in_process(order, threads, done)
            else:
                _run_pool(order, min(workers, len(todo)), threads, done)
        table = results_table(tasks, out, rows)
        _write_table(table, out / "results.csv")
        written: list[Path] = []
        if plots:
            written = save_plots(table, spec, out / "plots")
    seconds = time.perf_counter() - t_start
    log(f"sweep {spec.name}: {len(todo) - failed} runs done, {failed} failed, {skipped} skipped, {seconds:.1f} s; "
        f"wrote {out / 'results.csv'}")
    return SweepReport(out, table, len(tasks), skipped, len(todo), failed, seconds, engine, written)
