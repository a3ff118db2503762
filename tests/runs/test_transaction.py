"""A run folder as a transaction (issue 13, items 1-3): never overwritten or mixed, a true
``summary.json`` whatever stops the run (Ctrl-C at random points, in the dense map, during a
flush; a real SIGINT), and a second concurrent ``dynslam run`` refused."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import dynslam_lab.mapping.dense as dense
import dynslam_lab.runs.layout as layout
from dynslam_lab.cli import main
from dynslam_lab.config import Config
from dynslam_lab.datasets.tum import TumSequence
from dynslam_lab.pipeline import build_pipeline
from dynslam_lab.runs import RunInterrupted, read_marker, run_sequence, verify_run
from dynslam_lab.runs.folder import file_record
from dynslam_lab.slam.system import System
from tests.runs.sequences import write_sequence

ROOT = Path(__file__).resolve().parents[2]


def _run(seqdir, out, **kw):
    seq = TumSequence(seqdir, camera="default")
    system = build_pipeline(Config(), seq.camera, loop_closing=False)
    return run_sequence(seq, out, system, progress=False, **kw)


def _hashes(folder: Path) -> dict[str, dict]:
    return {p.relative_to(folder).as_posix(): file_record(p) for p in sorted(folder.rglob("*")) if p.is_file()}


def test_complete_run_lists_every_file_and_verifies(seqdir, tmp_path):
    out = tmp_path / "run"
    summary = _run(seqdir, out)
    assert summary["complete"] and summary["state"] == "complete" and verify_run(out) == []
    s = json.loads((out / "summary.json").read_text())
    assert s["run_id"] == read_marker(out)["id"]
    listed = set(s["files"])
    assert {"trajectory.txt", "timing.csv", "keyframes.npz", "map_points.npz", "dynamic_points.npz", "map.ply"} <= listed
    assert {f"thumbs/{k}.jpg" for k in np.load(out / "keyframes.npz")["ids"]} == {f for f in listed if f.startswith("thumbs/")}
    # A file changed behind the summary's back is reported, by name.
    with (out / "timing.csv").open("a") as fh:
        fh.write("99,0,0,0,0,0,0,0,0\n")
    problems = verify_run(out)
    assert any("timing.csv: differs" in p for p in problems) and any("timing.csv: 13 rows" in p for p in problems)


def test_a_second_run_never_overwrites_and_force_replaces_only_ours(seqdir, tmp_path, capsys):
    """Item 1: the second `dynslam run` into OUT refuses (exit 2) and changes nothing, a user's
    thumbnail included; --force replaces the run but not a user's file."""
    out = tmp_path / "run"
    args = ["run", str(seqdir), "--out", str(out), "--max-frames", "6", "--no-loop", "--quiet", "--camera", "default"]
    assert main(args) == 0
    capsys.readouterr()
    (out / "thumbs" / "mine.jpg").write_bytes(b"the user's own picture")
    before = _hashes(out)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "holds a previous 'run' output" in err and "--force" in err and err.count("\n") == 1
    assert _hashes(out) == before
    assert main(args + ["--force"]) == 2  # the user's file: refused, nothing deleted
    assert "thumbs/mine.jpg" in capsys.readouterr().err and _hashes(out) == before
    (out / "thumbs" / "mine.jpg").unlink()
    old_id = read_marker(out)["id"]
    assert main(args + ["--force"]) == 0
    assert read_marker(out)["id"] != old_id and verify_run(out) == []
    assert main(["run", str(seqdir), "--out", str(seqdir), "--quiet"]) == 2  # never into the sequence itself
    assert "not written by dynslam_lab" in capsys.readouterr().err


class _Tripwire:
    """Counts call sites as a run passes them; raises KeyboardInterrupt at the ``target``-th."""

    def __init__(self, target: int | None = None) -> None:
        self.events: list[str] = []
        self.target = target

    def hit(self, kind: str) -> None:
        self.events.append(kind)
        if self.target is not None and len(self.events) - 1 == self.target:
            raise KeyboardInterrupt


@pytest.fixture
def tripwire(monkeypatch):
    """Call sites: each frame, each file write (after the temporary file is written, before the
    rename: mid-flush), each keyframe of the dense map."""
    trip = _Tripwire()
    process, atomic, build = System.process, layout.atomic_write, dense.build_dense_map

    def process_hooked(self, frame):
        trip.hit("frame")
        return process(self, frame)

    def atomic_hooked(path, write):
        def w(tmp):
            write(tmp)
            trip.hit(f"write:{Path(path).name}")

        return atomic(path, w)

    def build_hooked(frames, config=None):
        def each():
            for item in frames:
                trip.hit("dense")
                yield item

        return build(each(), config)

    monkeypatch.setattr(System, "process", process_hooked)
    monkeypatch.setattr(layout, "atomic_write", atomic_hooked)
    monkeypatch.setattr(dense, "build_dense_map", build_hooked)
    return trip


def test_ctrl_c_at_five_random_points_leaves_a_true_partial_run(seqdir, tmp_path, tripwire):
    """Item 2: interrupted anywhere (frames, a flush half-way, the dense map), the folder's
    summary.json is true to its contents and says how far the run got; --force redoes it."""
    _run(seqdir, tmp_path / "dry", flush_every=4, flush_cost_ratio=0.0)  # a write every 4 frames, whatever it costs
    events = list(tripwire.events)
    frames = [i for i, e in enumerate(events) if e == "frame"]
    assert events.index("write:trajectory.txt") < frames[1]  # the first flush follows the first frame
    dense_ev = [i for i, e in enumerate(events) if e == "dense"]
    flush_ev = [i for i, e in enumerate(events) if e.startswith("write:") and e != "write:summary.json"
                and frames[2] < i < frames[-1]]
    assert dense_ev and flush_ev
    rng = np.random.default_rng(13)
    targets = [int(rng.choice(dense_ev)), int(rng.choice(flush_ev)), int(rng.choice(frames[1:]))]
    targets += [int(t) for t in rng.choice(np.setdiff1d(np.arange(len(events)), targets), 2, replace=False)]
    for k, target in enumerate(targets):
        tripwire.events, tripwire.target = [], target
        out = tmp_path / f"int{k}"
        with pytest.raises(RunInterrupted, match=r"interrupted after \d+ of 12 frames") as exc:
            _run(seqdir, out, flush_every=4, flush_cost_ratio=0.0)
        s = json.loads((out / "summary.json").read_text())
        assert verify_run(out) == [], (events[target], verify_run(out))
        assert s["complete"] is False and s["state"] == "interrupted" and s["processed"] == exc.value.summary["processed"]
        assert s["processed"] == sum(e == "frame" for e in tripwire.events[: target + 1]) - (events[target] == "frame")
        assert "trajectory.txt" in s["files"] and "map.ply" not in s["files"]
        assert not [p for p in out.rglob("*.tmp")]  # no temporary file left behind
    tripwire.target = None
    assert _run(seqdir, out, flush_every=4, flush_cost_ratio=0.0, force=True)["complete"] and verify_run(out) == []


def _env():
    return {**os.environ, "PYTHONPATH": str(ROOT)}


def _wait_for(path: Path, proc: subprocess.Popen, seconds: float = 120) -> None:
    t_end = time.monotonic() + seconds
    while not path.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < t_end, f"{path} never appeared"
        time.sleep(0.05)


@pytest.mark.slow
def test_two_concurrent_runs_and_a_real_sigint(seqdir, tmp_path, capsys):
    """Item 3: while `dynslam run` writes OUT, a second one refuses with a clear message and the
    first finishes a clean folder. Item 2 with a real SIGINT after a random delay: exit code 130,
    a clear message, a true summary.json."""
    seq = write_sequence(tmp_path / "seq24", n=24)
    cmd = [sys.executable, "-m", "dynslam_lab", "run", str(seq), "--no-loop", "--quiet", "--camera", "default"]
    out = tmp_path / "shared"
    first = subprocess.Popen(cmd + ["--out", str(out)], env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for(out / ".dynslam-output.json", first)
    assert main(["run", str(seq), "--out", str(out), "--quiet", "--camera", "default"]) == 2
    err = capsys.readouterr().err
    assert f"another dynslam process (pid {first.pid}" in err and "is writing into this folder" in err
    _, first_err = first.communicate(timeout=300)
    assert first.returncode == 0, first_err
    assert verify_run(out) == [] and json.loads((out / "summary.json").read_text())["processed"] == 24

    # A sequence long enough (ca. 200 frames) that the signal lands mid-run on a fast machine too.
    long_seq = write_sequence(tmp_path / "seq_long", n=40, back_and_forth=5)
    n_long = len((long_seq / "rgb.txt").read_text().splitlines()) - 1
    cmd[cmd.index(str(seq))] = str(long_seq)
    out2 = tmp_path / "sigint"
    # Ctrl-C on a foreground run: SIGINT at its default disposition in the child, also when pytest itself was
    # started in the background by a shell without job control, which leaves SIGINT ignored for its children
    # (then a signal before the run installs its handler was ignored and the run ended with 0)
    proc = subprocess.Popen(cmd + ["--out", str(out2)], env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    _wait_for(out2 / "summary.json", proc)
    time.sleep(float(np.random.default_rng(5).uniform(0.0, 0.5)))
    assert proc.poll() is None, "the run finished before the signal: make the sequence longer"
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "interrupted after" in err and f"of {n_long} frames" in err and "Traceback" not in err
    s = json.loads((out2 / "summary.json").read_text())
    assert verify_run(out2) == [] and s["state"] == "interrupted" and 1 <= s["processed"] < n_long
    shutil.rmtree(out2)
