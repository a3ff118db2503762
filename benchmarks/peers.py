"""dynslam side by side with ORB-SLAM3 and Open3D: the papers' "ORB-SLAM vs ours" table.

Every paper the toolkit teaches (Wu et al. 2022, YOLO-SLAM; Zhang et al. 2023; Chang et al.
2021; Ge et al. 2024, ASG-SLAM) compares its dynamic variant with ORB-SLAM2/3 on the same
sequences: ATE, RPE and time per frame. This script runs, back to back on each sequence and
each in its own process:

* dynslam through its command line, ``dynslam run SEQ --out RUN --filters F --detector D
  --quiet``, once per filter set (default ``none``, ``geometry``, ``full``);
* the installed peers, each through its script in ``benchmarks/`` (``peer_orbslam3.py``:
  ORB-SLAM3 RGB-D, GPL-3.0, via ``pyorbslam3``; ``peer_open3d.py``: Open3D's RGB-D odometry,
  MIT, ``legacy`` and ``tensor``); a peer that is not installed is reported as skipped, with
  the reason, and the others run. ``--peer-script NAME=PATH`` adds any script that follows the
  same protocol (``PATH SEQDIR --out DIR [--max-frames N]`` writing ``trajectory.txt`` and
  ``peer.json``, see ``peer_common.py``).

Every trajectory is scored by the toolkit's own evaluation
(:func:`dynslam_lab.evaluation.evaluate`, what ``dynslam eval`` prints): ATE RMSE after a
rigid (SE(3)) alignment, RPE translation/rotation RMSE over consecutive tracked frames. Time
per frame is each system's own, measured in its process, **from the PNG files to the pose, decoding
included for every system**: a peer's is decoding the frame's images plus its per-frame call
(``total`` of its ``peer.json``; ``track`` alone is there too); dynslam's is the frame's whole time in
the run loop (``wall`` of ``timing.csv``: ``System.process`` and the wait for the frame, whose decoding
and ORB extraction the read-ahead thread does beside the previous frame, so what it did not hide is
counted). ``wall_s`` is the whole process (start-up, vocabulary, decoding).
Ratios are to the reference peer on the same sequence (``--reference``, default the first
peer of ``--peers`` that ran): ``ate_ratio`` < 1 means a smaller error than the peer.

``--rounds N`` runs every system N times on each sequence, the systems in turn within a round and in
the reverse order in every second round (so that none always runs first, on a cold machine, or last,
after the others warmed it). Each round's ratios are to the same round's reference run, taken back to
back; the table gives the median over the rounds of each value and of each ratio, and the smallest and
largest ms ratio (``mean_ms_ratio_min``, ``mean_ms_ratio_max``): on a shared 2-core machine one run's
ratio moves by about 0.1, so a speed claim reads the median and the range. ``peers_rounds.csv`` keeps
every run.

Writes ``OUT/peers.csv`` (one row per sequence and system; with ``--rounds`` the medians),
``OUT/peers_rounds.csv`` (with ``--rounds`` > 1: one row per run), ``OUT/peers.md`` (the tables),
``OUT/bars.png`` (per-sequence bars of ATE, RPE and ms per frame), ``OUT/trajectories_SEQ.png``
(each system's aligned trajectory over the ground truth) and ``OUT/runs/SEQ/SYSTEM/`` (each
run's folder and ``.log``; ``OUT/runs/SEQ/roundK/SYSTEM/`` with ``--rounds``). ORB-SLAM3 needs an ORB vocabulary in DBoW2 text format: by default
the toolkit's vocabulary exported with ``dynslam vocab export VOC.npz --format dbow2``, or
``--orb-vocabulary ORBvoc.txt``.

Usage::

    python benchmarks/peers.py static_xyz walking_rpy --max-frames 300 --out /tmp/peers
    python benchmarks/peers.py SEQDIR... --detector onnx:yolox_nano.onnx --out DIR
    python benchmarks/peers.py SEQDIR --peers orbslam3 --orb-vocabulary ORBvoc.txt --out DIR
    python benchmarks/peers.py walking_xyz static_xyz --filters none,full --peers orbslam3 --rounds 3 --out DIR

A SEQDIR that is not a folder but a synthetic preset name (``dynslam synth --list``) is
rendered first, with ``--max-frames`` frames (default 300).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dynslam_lab.config import Config, load_config
from dynslam_lab.evaluation import Trajectory, TrajectoryError, read_tum_trajectory
from dynslam_lab.pipeline import detector_stages

HERE = Path(__file__).resolve().parent
DEFAULT_FILTERS = ("none", "geometry", "full")
#: Peers this script knows: name -> (script in benchmarks/, its extra arguments).
PEERS = {
    "orbslam3": ("peer_orbslam3.py", ()),
    "open3d_legacy": ("peer_open3d.py", ("--method", "legacy")),
    "open3d_tensor": ("peer_open3d.py", ("--method", "tensor")),
}
LABELS = {"orbslam3": "ORB-SLAM3", "open3d_legacy": "Open3D legacy", "open3d_tensor": "Open3D tensor"}
VOCABULARY_FILE = "orb_vocabulary_dbow2.txt"
WALL_MARK = "# peers.py: process wall time s: "  # last line of each run's log
#: Columns of ``peers.csv``, in order.
COLUMNS = (
    "sequence", "system", "kind", "status", "frames", "tracked", "lost", "coverage", "loops",
    "ate_rmse_m", "rpe_trans_rmse_m", "rpe_rot_rmse_deg", "mean_ms", "median_ms", "wall_s",
    "ate_ratio", "rpe_trans_ratio", "mean_ms_ratio", "reference", "run_dir",
    "rounds", "mean_ms_ratio_min", "mean_ms_ratio_max",
)
#: Columns of ``peers_rounds.csv`` (one row per run, ``--rounds`` > 1).
ROUND_COLUMNS = ("round",) + COLUMNS[: COLUMNS.index("rounds")]
#: Numeric columns a row of several rounds takes the median of.
_MEDIAN = ("frames", "tracked", "lost", "coverage", "loops", "ate_rmse_m", "rpe_trans_rmse_m", "rpe_rot_rmse_deg",
           "mean_ms", "median_ms", "wall_s", "ate_ratio", "rpe_trans_ratio", "mean_ms_ratio")
#: The per-frame time compared, by kind of system, both from the files to the pose: dynslam's ``wall`` (the
#: frame's whole time in the run loop: ``System.process`` plus the wait for the frame, i.e. its decoding and
#: ORB extraction where the read-ahead thread did not hide them), a peer's decoding plus its track call.
FRAME_TIME = {"dynslam": "wall", "peer": "total"}
_RATIOS = {"ate_ratio": "ate_rmse_m", "rpe_trans_ratio": "rpe_trans_rmse_m", "mean_ms_ratio": "mean_ms"}


@dataclass(frozen=True)
class SystemSpec:
    """One system of the table and how to run it.

    ``command`` is the argument list before ``SEQDIR --out RUN [--max-frames N]``; ``kind`` is
    ``"dynslam"`` (its run folder has ``summary.json``) or ``"peer"`` (``peer.json``); ``skip``
    says why the system cannot run here (it is then reported, not run).
    """

    name: str
    kind: str
    command: tuple[str, ...]
    skip: str | None = None

    @property
    def label(self) -> str:
        return LABELS.get(self.name, self.name)

    @property
    def slug(self) -> str:
        return self.name.replace(" ", "_").replace("/", "_")


# ------------------------------------------------------------------------------ the systems
def dynslam_specs(filters: list[str], detector: str, config: str | None = None) -> list[SystemSpec]:
    """``dynslam run`` once per filter set, through the command line (``python -m dynslam_lab``)."""
    base = load_config(config, Config()) if config else Config()
    specs = []
    for f in filters:
        cmd = [sys.executable, "-m", "dynslam_lab", "run", "--filters", f, "--quiet"]
        if f != "none":
            cmd += ["--detector", detector]
        if config:
            cmd += ["--config", str(config)]
        try:
            needs = detector_stages(f, base)
        except ValueError:  # an unknown filter: `dynslam run` says so when it is run
            needs = []
        skip = None
        if needs and detector == "none":
            skip = (f"--filters {f} runs {needs}, which judge keypoints from detections: pass --detector oracle "
                    "(synthetic sequences) or onnx:MODEL.onnx (any sequence)")
        specs.append(SystemSpec(f"dynslam {f}", "dynslam", tuple(cmd), skip))
    return specs


def check_peer(script: Path, extra: tuple[str, ...] = ()) -> str | None:
    """None when the peer script's ``--check`` passes, else the reason it cannot run."""
    if not script.is_file():
        return f"peer script {script} not found"
    try:
        p = subprocess.run([sys.executable, str(script), "--check", *extra], capture_output=True, text=True,
                           timeout=120)
    except subprocess.TimeoutExpired:
        return f"{script.name} --check did not answer within 120 s"
    if p.returncode == 0:
        return None
    lines = (p.stdout + p.stderr).strip().splitlines()
    return lines[-1] if lines else f"{script.name} --check exited with {p.returncode}"


def export_vocabulary(out: Path) -> tuple[Path | None, str | None]:
    """The toolkit's ORB vocabulary in DBoW2 text format, through ``dynslam vocab export``.

    Returns ``(path, None)``, or ``(None, reason)`` when the command is missing or fails.
    The export is kept in ``out`` and reused by later runs into the same folder.
    """
    target = out / VOCABULARY_FILE
    if target.is_file():
        return target, None
    cmd = [sys.executable, "-m", "dynslam_lab", "vocab", "export", "default", "--format", "dbow2", "--out", str(target)]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0 or not target.is_file():
        last = (p.stderr or p.stdout).strip().splitlines()
        why = last[-1] if last else f"exit code {p.returncode}"
        return None, (f"vocabulary export unavailable (`dynslam vocab export --format dbow2`: {why}); "
                      "pass --orb-vocabulary ORBvoc.txt")
    return target, None


def peer_specs(names: list[str], out: Path, vocabulary: str | None = None,
               scripts: dict[str, Path] | None = None) -> list[SystemSpec]:
    """The requested peers, each checked (``--check``); a peer that cannot run gets ``skip``.

    ``names`` are keys of :data:`PEERS` or of ``scripts`` (extra peer scripts by name).
    ``vocabulary``: a DBoW2 text vocabulary for ORB-SLAM3; None exports the toolkit's.
    """
    scripts = dict(scripts or {})
    checked: dict[tuple[str, ...], str | None] = {}
    specs = []
    for name in names:
        if name in scripts:
            script, extra = Path(scripts[name]), ()
        elif name in PEERS:
            script, extra = HERE / PEERS[name][0], PEERS[name][1]
        else:
            raise ValueError(f"unknown peer {name!r}; choose from {sorted(PEERS)} or add --peer-script {name}=PATH")
        key = (str(script),)
        if key not in checked:
            checked[key] = check_peer(script)
        skip = checked[key]
        cmd = [sys.executable, str(script), *extra]
        if name == "orbslam3" and skip is None:
            if vocabulary is not None:
                voc = Path(vocabulary)
                skip = None if voc.is_file() else f"ORB vocabulary {voc} not found"
            else:
                voc, skip = export_vocabulary(out)
            cmd += ["--vocabulary", str(voc)]
        specs.append(SystemSpec(name, "peer", tuple(cmd), None if skip is None else f"skipped: {skip}"))
    return specs


# ---------------------------------------------------------------------------------- running
def sequence_label(seqdir: Path) -> str:
    """The sequence's name in tables: the synthetic preset (``synthetic.json``) or the folder name."""
    meta = seqdir / "synthetic.json"
    if meta.is_file():
        try:
            d = json.loads(meta.read_text())
            return f"{d['preset']['name']}"
        except (ValueError, KeyError, TypeError):
            pass
    return seqdir.name


def warm_page_cache(seqdir: Path) -> int:
    """Read every file of ``seqdir`` once, so that the first system run on a sequence does not pay for
    the disk while the later ones read from the page cache (measured: single frames of the first run
    waited 0.1-1.9 s for a cold read, `docs/speed.md`). Returns the bytes read."""
    total = 0
    for path in sorted(Path(seqdir).rglob("*")):
        if path.is_file():
            with open(path, "rb") as fh:
                while chunk := fh.read(1 << 20):
                    total += len(chunk)
    return total


def run_system(spec: SystemSpec, seqdir: Path, rundir: Path, max_frames: int | None,
               timeout: float | None = None) -> tuple[str, float]:
    """Run one system on one sequence in its own process; ``(status, wall seconds)``.

    Output goes to ``rundir``, the process's stdout and stderr to ``rundir.log``. Status is
    ``ok`` or ``failed: ...`` (exit code and last stderr line).
    """
    cmd = [*spec.command, str(seqdir), "--out", str(rundir)]
    if max_frames is not None:
        cmd += ["--max-frames", str(max_frames)]
    rundir.parent.mkdir(parents=True, exist_ok=True)
    log = rundir.parent / f"{rundir.name}.log"
    t0 = time.perf_counter()
    with log.open("w") as fh:
        fh.write("$ " + " ".join(cmd) + "\n")
        fh.flush()
        try:
            p = subprocess.run(cmd, stdout=fh, stderr=subprocess.STDOUT, timeout=timeout)
            code = p.returncode
        except subprocess.TimeoutExpired:
            code = None
    wall = time.perf_counter() - t0
    with log.open("a") as fh:
        fh.write(f"{WALL_MARK}{wall:.3f}\n")
    if code is None:
        return f"failed: timed out after {timeout:g} s (see {log})", wall
    if code != 0:
        tail = [s for s in log.read_text(errors="replace").splitlines() if s.strip() and not s.startswith(WALL_MARK)]
        return f"failed: exit code {code}: {tail[-1] if tail else ''} (see {log})", wall
    return "ok", wall


def logged_wall(rundir: Path) -> float:
    """The process wall time a finished run's log recorded (NaN when it has none)."""
    log = rundir.parent / f"{rundir.name}.log"
    if log.is_file():
        for line in reversed(log.read_text(errors="replace").splitlines()):
            if line.startswith(WALL_MARK):
                try:
                    return float(line[len(WALL_MARK):])
                except ValueError:
                    break
    return float("nan")


def _stat(d: dict | None, *keys) -> float:
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return float("nan")
        d = d[k]
    return float(d) if d is not None else float("nan")


def collect(spec: SystemSpec, seqdir: Path, rundir: Path, status: str, wall: float) -> dict:
    """One table row: the run's own counts and timing, and its ATE/RPE by the toolkit's evaluation."""
    from dynslam_lab.evaluation import evaluate  # pandas behind it: imported once the runs are done

    row = {c: float("nan") for c in COLUMNS}
    row.update(sequence=sequence_label(seqdir), system=spec.name, kind=spec.kind, status=status,
               wall_s=wall, run_dir=str(rundir), reference="")
    if status != "ok":
        return row
    summary_file = rundir / ("summary.json" if spec.kind == "dynslam" else "peer.json")
    try:
        s = json.loads(summary_file.read_text())
    except (OSError, ValueError) as exc:
        row["status"] = f"failed: cannot read {summary_file} ({exc})"
        return row
    lost = s.get("lost")
    row.update(
        frames=s.get("frames"), tracked=s.get("tracked"),
        lost=len(lost) if isinstance(lost, list) else lost, loops=s.get("loops"),
        mean_ms=_stat(s, "timing_mean_ms", FRAME_TIME[spec.kind]), median_ms=_stat(s, "timing_median_ms", FRAME_TIME[spec.kind]),
    )
    gt_file = seqdir / "groundtruth.txt"
    if not gt_file.is_file():
        return row
    try:
        gt = read_tum_trajectory(gt_file)
        est = read_tum_trajectory(rundir / "trajectory.txt")
        res = evaluate(gt, est, gt_name=str(gt_file), est_name=str(rundir / "trajectory.txt"))
    except (TrajectoryError, OSError, ValueError) as exc:
        row["status"] = f"failed: evaluation: {exc}"
        return row
    row.update(ate_rmse_m=_stat(res, "ate", "rmse"), rpe_trans_rmse_m=_stat(res, "rpe", "trans", "rmse"),
               rpe_rot_rmse_deg=_stat(res, "rpe", "rot", "rmse"), coverage=res["coverage"])
    (rundir / "evaluation.json").write_text(json.dumps(res, indent=1) + "\n")
    return row


def add_ratios(rows: list[dict], reference: str | None, peer_order: list[str]) -> list[dict]:
    """Fill ``ate_ratio``, ``rpe_trans_ratio``, ``mean_ms_ratio``: each row's value over the
    reference peer's on the same sequence and in the same round (``reference``, or the first of
    ``peer_order`` that ran there). Rows of a sequence without a reference keep NaN."""
    for seq, rnd in dict.fromkeys((r["sequence"], r.get("round", 1)) for r in rows):
        here = {r["system"]: r for r in rows if r["sequence"] == seq and r.get("round", 1) == rnd}
        candidates = [reference] if reference else peer_order
        ref = next((here[n] for n in candidates if n in here and here[n]["status"] == "ok"), None)
        if ref is None:
            continue
        for r in here.values():
            r["reference"] = ref["system"]
            for ratio, col in _RATIOS.items():
                a, b = float(r[col]), float(ref[col])
                r[ratio] = a / b if r["status"] == "ok" and math.isfinite(a) and math.isfinite(b) and b > 0 else float("nan")
    return rows


def combine_rounds(rows: list[dict]) -> list[dict]:
    """One row per sequence and system from the rows of every round (``add_ratios`` done per round): the
    median over the rounds that ran of each value in ``_MEDIAN`` (ratios included: the median of the
    rounds' own ratios), ``rounds`` the number of them, ``mean_ms_ratio_min`` and ``_max`` their range; the
    run folder and reference of the first. A system that ran in no round keeps its first failure."""
    out = []
    for key in dict.fromkeys((r["sequence"], r["system"]) for r in rows):
        runs = [r for r in rows if (r["sequence"], r["system"]) == key]
        ok = [r for r in runs if r["status"] == "ok"]
        row = dict(ok[0] if ok else runs[0])
        row.pop("round", None)
        row["rounds"] = len(ok)
        for c in _MEDIAN:
            vals = [float(r[c]) for r in ok if r[c] is not None and math.isfinite(float(r[c]))]
            m = float(np.median(vals)) if vals else float("nan")
            row[c] = int(m) if c in ("frames", "tracked", "lost", "loops") and m.is_integer() else m
        ratios = [float(r["mean_ms_ratio"]) for r in ok if math.isfinite(float(r["mean_ms_ratio"]))]
        row["mean_ms_ratio_min"] = min(ratios) if ratios else float("nan")
        row["mean_ms_ratio_max"] = max(ratios) if ratios else float("nan")
        out.append(row)
    return out


# ----------------------------------------------------------------------------------- tables
def _fmt(v, digits: int) -> str:
    if v is None or v == "":
        return "-"
    if isinstance(v, (float, np.floating)):
        return "-" if not math.isfinite(v) else f"{v:.{digits}f}"
    return str(v)


def _label(rows: list[dict], system: str) -> str:
    kind = next((r["kind"] for r in rows if r["system"] == system), "peer")
    return system if kind == "dynslam" else LABELS.get(system, system)


def pivot_markdown(rows: list[dict], column: str, digits: int) -> list[str]:
    """A papers' table: one row per sequence, one column per system, ``column``'s values."""
    seqs = list(dict.fromkeys(r["sequence"] for r in rows))
    systems = list(dict.fromkeys(r["system"] for r in rows))
    out = ["| sequence | " + " | ".join(_label(rows, s) for s in systems) + " |", "|---" * (len(systems) + 1) + "|"]
    for seq in seqs:
        cells = []
        for s in systems:
            r = next((r for r in rows if r["sequence"] == seq and r["system"] == s), None)
            cells.append("-" if r is None or r["status"] != "ok" else _fmt(r[column], digits))
        out.append(f"| {seq} | " + " | ".join(cells) + " |")
    return out


def table_markdown(rows: list[dict], header: str = "", failed_rounds: list[str] = ()) -> str:
    """``peers.md``: ATE, RPE and ms per frame as the papers' tables, then every measurement (with several
    rounds, the medians and the range of the ms ratio; ``failed_rounds`` lists the runs of a round that
    failed while another round of the same system ran)."""
    lines = ["# dynslam and its peers", ""]
    if header:
        lines += [header, ""]
    several = any(int(r.get("rounds") or 0) > 1 for r in rows)
    if several:
        lines += [f"Medians over {max(int(r.get('rounds') or 0) for r in rows)} rounds; each round's ratios are to "
                  "its own reference run; the ms ratio's range over the rounds in `mean_ms_ratio_min` and `_max`.", ""]
    for title, col, digits in (("ATE RMSE (m)", "ate_rmse_m", 4), ("RPE translation RMSE (m, 1 frame)", "rpe_trans_rmse_m", 4),
                               ("RPE rotation RMSE (deg, 1 frame)", "rpe_rot_rmse_deg", 3),
                               ("Mean ms per frame", "mean_ms", 1)):
        lines += [f"## {title}", ""] + pivot_markdown(rows, col, digits) + [""]
    cols = ("sequence", "system", "frames", "lost", "loops", "ate_rmse_m", "rpe_trans_rmse_m", "rpe_rot_rmse_deg",
            "mean_ms", "median_ms", "wall_s", "ate_ratio", "rpe_trans_ratio", "mean_ms_ratio")
    if several:
        cols += ("mean_ms_ratio_min", "mean_ms_ratio_max", "rounds")
    digits = {"ate_rmse_m": 4, "rpe_trans_rmse_m": 4, "rpe_rot_rmse_deg": 3, "mean_ms": 1, "median_ms": 1,
              "wall_s": 1, "ate_ratio": 2, "rpe_trans_ratio": 2, "mean_ms_ratio": 2, "mean_ms_ratio_min": 2,
              "mean_ms_ratio_max": 2}
    lines += ["## All measurements", "",
              "Ratios are to the reference peer on the same sequence (`reference` in peers.csv).", "",
              "| " + " | ".join(cols) + " |", "|---" * len(cols) + "|"]
    notes = []
    for r in rows:
        if r["status"] != "ok":
            notes.append(f"- {r['sequence']} / {_label(rows, r['system'])}: {r['status']}")
            continue
        lines.append("| " + " | ".join(_label(rows, r[c]) if c == "system" else _fmt(r[c], digits.get(c, 0))
                                      for c in cols) + " |")
    notes += list(failed_rounds)
    if notes:
        lines += ["", "Not measured:", ""] + notes
    return "\n".join(lines) + "\n"


def write_csv(rows: list[dict], path: Path, columns: tuple[str, ...] = COLUMNS) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with tmp.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(columns), extrasaction="ignore", lineterminator="\n")
        w.writeheader()
        for r in rows:
            w.writerow({c: ("" if isinstance(r[c], float) and not math.isfinite(r[c]) else r[c]) for c in columns})
    os.replace(tmp, path)


# ------------------------------------------------------------------------------------ plots
def aligned_estimate(run_dir: Path) -> Trajectory:
    """A finished run's trajectory aligned to the ground truth as its evaluation aligned it
    (``evaluation.json``'s ``align``: rotation, translation, scale)."""
    res = json.loads((Path(run_dir) / "evaluation.json").read_text())
    T = np.eye(4)
    T[:3, :3] = np.asarray(res["align"]["R"])
    T[:3, 3] = np.asarray(res["align"]["t"])
    return read_tum_trajectory(Path(run_dir) / "trajectory.txt").transformed(T, res["align"]["scale"])


def path_plane(gt: Trajectory) -> str:
    """The two world axes along which the ground-truth path spreads most (``"xy"``, ``"xz"``, ...)."""
    extent = np.ptp(gt.positions, axis=0)
    return "".join("xyz"[i] for i in sorted(np.argsort(extent)[-2:]))


def gt_over(gt: Trajectory, est: Trajectory) -> Trajectory:
    """The ground truth over the estimate's time span only, so a partial run is not drawn against the whole path."""
    span = (gt.timestamps >= est.timestamps[0] - 0.05) & (gt.timestamps <= est.timestamps[-1] + 0.05)
    return gt.subset(np.flatnonzero(span))


def plot_sequence_trajectories(rows: list[dict], seqdir: Path, path: Path) -> bool:
    """Each system's trajectory, aligned as the evaluation aligned it, over the ground truth
    (one panel per system, like the trajectory figures of YOLO-SLAM and ASG-SLAM)."""
    import matplotlib.pyplot as plt

    from dynslam_lab.viz.plots import plot_trajectories

    gt_file = seqdir / "groundtruth.txt"
    ok = [r for r in rows if r["status"] == "ok" and (Path(r["run_dir"]) / "evaluation.json").is_file()]
    if not gt_file.is_file() or not ok:
        return False
    gt = read_tum_trajectory(gt_file)
    plane = path_plane(gt)
    n = len(ok)
    ncol = min(n, 3)
    nrow = math.ceil(n / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 4.0 * nrow), squeeze=False, constrained_layout=True)
    for ax, r in zip(axes.ravel(), ok):
        aligned = aligned_estimate(Path(r["run_dir"]))
        plot_trajectories({"ground truth": gt_over(gt, aligned), _label(rows, r["system"]): aligned},
                          plane=plane, ax=ax, title=f"{_label(rows, r['system'])}: ATE {100 * r['ate_rmse_m']:.2f} cm")
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    fig.suptitle(f"{rows[0]['sequence']}: trajectories over the ground truth (top view, {plane})")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def plot_bars(rows: list[dict], path: Path) -> bool:
    """Per-sequence grouped bars of ATE RMSE, RPE translation RMSE and mean ms per frame."""
    import matplotlib.pyplot as plt

    ok = [r for r in rows if r["status"] == "ok"]
    if not ok:
        return False
    seqs = list(dict.fromkeys(r["sequence"] for r in rows))
    systems = list(dict.fromkeys(r["system"] for r in ok))
    width = 0.8 / len(systems)
    x = np.arange(len(seqs))
    fig, axes = plt.subplots(3, 1, figsize=(max(8.0, 1.6 * len(seqs) + 3), 9.5), constrained_layout=True)
    for ax, (col, title, log) in zip(axes, (("ate_rmse_m", "ATE RMSE (m)", True),
                                            ("rpe_trans_rmse_m", "RPE translation RMSE (m, 1 frame)", True),
                                            ("mean_ms", "mean ms per frame", False))):
        for k, s in enumerate(systems):
            vals = []
            for seq in seqs:
                r = next((r for r in ok if r["sequence"] == seq and r["system"] == s), None)
                vals.append(float(r[col]) if r is not None else np.nan)
            ax.bar(x + (k - (len(systems) - 1) / 2) * width, vals, width, label=_label(rows, s))
        ax.set_xticks(x, seqs)
        ax.set_title(title)
        if log:
            ax.set_yscale("log")
        ax.grid(True, axis="y", alpha=0.3)
    handles, names = axes[0].get_legend_handles_labels()
    fig.legend(handles, names, loc="outside upper center", ncol=min(len(systems), 3), fontsize="small")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


# -------------------------------------------------------------------------------------- main
def resolve_sequences(items: list[str], max_frames: int | None) -> list[Path]:
    """Folders as given; a synthetic preset name (office or stress scene, ``dynslam synth --list``) is
    rendered (cached) with ``max_frames`` frames (300)."""
    out = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            out.append(p.resolve())
            continue
        from dynslam_lab.datasets.synthetic import preset_names, synthetic_sequence

        if item not in preset_names() and not (item.endswith("_nomovers") and item.removesuffix("_nomovers") in preset_names()):
            raise SystemExit(f"error: {item}: neither a sequence folder nor a synthetic preset ({', '.join(preset_names())})")
        out.append(Path(synthetic_sequence(item, n_frames=max_frames or 300, progress=True)))
    return out


def run_benchmark(seqdirs: list[Path], specs: list[SystemSpec], out: Path, max_frames: int | None = None,
                  reference: str | None = None, timeout: float | None = None, reuse: bool = False,
                  plots: bool = True, header: str = "", rounds: int = 1) -> list[dict]:
    """Run every system on every sequence (back to back per sequence), evaluate, write the tables.

    ``rounds`` > 1: each sequence that many times over, the systems in reverse order in every second
    round, each round's runs in ``runs/SEQ/roundK/``; ``peers.csv`` holds the medians
    (:func:`combine_rounds`), ``peers_rounds.csv`` every run.
    ``reuse``: a run folder that already holds a finished run is read, not run again; without it
    an existing run folder is an error (nothing is overwritten). Returns the rows of ``peers.csv``.
    """
    if rounds < 1:
        raise ValueError(f"run_benchmark: rounds must be >= 1, got {rounds}")
    out.mkdir(parents=True, exist_ok=True)
    labels = [sequence_label(s) for s in seqdirs]
    if len(set(labels)) != len(labels):
        raise SystemExit(f"error: two sequences share a name: {labels}")
    order = {spec.name: i for i, spec in enumerate(specs)}
    plan = []  # (table position, round, sequence, label, spec, run folder), in the order run
    for si, (seq, label) in enumerate(zip(seqdirs, labels)):
        for k in range(1, rounds + 1):
            where = out / "runs" / label if rounds == 1 else out / "runs" / label / f"round{k}"
            plan += [((si, k, order[spec.name]), k, seq, label, spec, where / spec.slug)
                     for spec in (specs if k % 2 else specs[::-1])]
    if not reuse:
        taken = [str(d) for *_, d in plan if d.exists()]
        if taken:
            raise SystemExit(f"error: run folders exist already: {taken[0]} (and {len(taken) - 1} more); "
                             "pass --reuse to keep finished runs, or choose another --out")
    raw: list[tuple[tuple[int, int, int], int, SystemSpec, Path, Path, str, float]] = []
    warmed: set[Path] = set()
    for k, (pos, rnd, seq, label, spec, rundir) in enumerate(plan, 1):
        done = rundir / ("summary.json" if spec.kind == "dynslam" else "peer.json")
        if spec.skip:
            status, wall = spec.skip, float("nan")
        elif reuse and done.is_file():
            status, wall = "ok", logged_wall(rundir)
        else:
            if seq not in warmed:
                warm_page_cache(seq)
                warmed.add(seq)
            status, wall = run_system(spec, seq, rundir, max_frames, timeout)
        print(f"[{k}/{len(plan)}] {label}" + (f" round {rnd}" if rounds > 1 else "") + f" / {spec.name}: {status}"
              + ("" if math.isnan(wall) else f" ({wall:.1f} s)"), flush=True)
        raw.append((pos, rnd, spec, seq, rundir, status, wall))
    raw.sort(key=lambda x: x[0])  # the table's order: sequence, round, system
    per_run = [dict(collect(spec, seq, rundir, status, wall), round=rnd) for _, rnd, spec, seq, rundir, status, wall in raw]
    add_ratios(per_run, reference, [s.name for s in specs if s.kind == "peer"])
    rows = combine_rounds(per_run)
    failed = []
    if rounds > 1:
        write_csv(per_run, out / "peers_rounds.csv", ROUND_COLUMNS)
        ran = {(r["sequence"], r["system"]) for r in per_run if r["status"] == "ok"}  # in some round
        failed = [f"- {r['sequence']} / {_label(per_run, r['system'])}, round {r['round']}: {r['status']}"
                  for r in per_run if r["status"] != "ok" and (r["sequence"], r["system"]) in ran]
    write_csv(rows, out / "peers.csv")
    md = table_markdown(rows, header, failed)
    (out / "peers.md").write_text(md)
    if plots:
        import matplotlib

        matplotlib.use("Agg")
        for seq, label in zip(seqdirs, labels):
            plot_sequence_trajectories([r for r in rows if r["sequence"] == label], seq, out / f"trajectories_{label}.png")
        plot_bars(rows, out / "bars.png")
    return rows


def _peer_scripts(items: list[str]) -> dict[str, Path]:
    scripts = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise SystemExit(f"error: --peer-script expects NAME=PATH, got {item!r}")
        scripts[name] = Path(path)
    return scripts


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="Outputs: OUT/peers.csv, OUT/peers.md, OUT/bars.png, OUT/trajectories_SEQ.png, OUT/runs/")
    ap.add_argument("seqdirs", nargs="+", metavar="SEQDIR", help="TUM-layout sequence folders, or synthetic preset names")
    ap.add_argument("--out", required=True, metavar="DIR", help="output folder")
    ap.add_argument("--peers", default=",".join(PEERS), metavar="LIST",
                    help=f"comma-separated peers (default {','.join(PEERS)}); '' for none")
    ap.add_argument("--peer-script", action="append", default=[], metavar="NAME=PATH",
                    help="an extra peer script following peer_common.py's protocol (name it in --peers too)")
    ap.add_argument("--filters", default=",".join(DEFAULT_FILTERS), metavar="LIST",
                    help="dynslam filter sets, comma-separated (default none,geometry,full); '' for none")
    ap.add_argument("--detector", default="none", metavar="SPEC",
                    help="detector of the dynslam runs with filters (none, oracle, onnx:PATH, cache:DIR; default none)")
    ap.add_argument("--dynslam-config", default=None, metavar="FILE.toml", help="passed to dynslam run --config")
    ap.add_argument("--max-frames", type=int, default=None, metavar="N", help="first N frames of each sequence")
    ap.add_argument("--orb-vocabulary", default=None, metavar="ORBvoc.txt",
                    help="DBoW2 text vocabulary for ORB-SLAM3 (default: the toolkit's, via dynslam vocab export)")
    ap.add_argument("--reference", default=None, metavar="PEER", help="peer the ratios refer to (default: first of --peers that ran)")
    ap.add_argument("--timeout", type=float, default=None, metavar="S", help="stop a run after S seconds")
    ap.add_argument("--reuse", action="store_true", help="read finished runs already in OUT instead of running them again")
    ap.add_argument("--no-plots", action="store_true", help="tables only")
    ap.add_argument("--rounds", type=int, default=1, metavar="N",
                    help="run every system N times per sequence, in alternating order; medians and the ms ratio's range (default 1)")
    args = ap.parse_args(argv)
    if args.max_frames is not None and args.max_frames < 2:
        ap.error(f"--max-frames must be >= 2, got {args.max_frames}")
    if args.rounds < 1:
        ap.error(f"--rounds must be >= 1, got {args.rounds}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    seqdirs = resolve_sequences(args.seqdirs, args.max_frames)
    filters = [f for f in args.filters.split(",") if f]
    peers = [p for p in args.peers.split(",") if p]
    specs = dynslam_specs(filters, args.detector, args.dynslam_config)
    specs += peer_specs(peers, out, args.orb_vocabulary, _peer_scripts(args.peer_script))
    for s in specs:
        if s.skip:
            print(f"{s.label}: {s.skip}")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    header = (f"{len(seqdirs)} sequence(s), {args.max_frames or 'all'} frames; detector `{args.detector}`; "
              f"{os.cpu_count()} CPU cores, load average {load:.2f} at the start; runs back to back per sequence"
              + (f", {args.rounds} rounds in alternating order" if args.rounds > 1 else "") + "; "
              "ms per frame from the PNG files to the pose (decoding included) for every system.")
    rows = run_benchmark(seqdirs, specs, out, args.max_frames, args.reference, args.timeout, args.reuse,
                         not args.no_plots, header, args.rounds)
    print()
    print((out / "peers.md").read_text())
    print(f"wrote {out / 'peers.csv'}" + (f", {out / 'peers_rounds.csv'}" if args.rounds > 1 else "")
          + f", {out / 'peers.md'}" + ("" if args.no_plots else f", {out / 'bars.png'}"))
    return 0 if any(r["status"] == "ok" for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
