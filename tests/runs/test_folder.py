"""``OutputFolder``: fresh folders, markers, journals, ``force`` that deletes only what was ours,
one writer at a time (a lock that a second process respects and a dead one releases)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import pytest

from dynslam_lab.runs import FolderLockedError, OutputFolder, OutputFolderError, atomic_write, read_marker
from dynslam_lab.runs.folder import JOURNAL, LOCK, MARKER, file_record


def test_fresh_folder_is_marked_and_journalled(tmp_path):
    out = tmp_path / "a" / "b"
    with OutputFolder(out, kind="run") as f:
        rec = f.write_text("x/y.txt", "hello")
        f.file("later.bin").write_bytes(b"12")  # a writer that writes itself
        (out / "other.csv").write_text("by code that knows nothing of the folder")
    assert rec == file_record(out / "x/y.txt") and rec["size"] == 5
    m = read_marker(out)
    assert m["kind"] == "run" and len(m["id"]) == 16 and f.id == m["id"]
    assert set((out / JOURNAL).read_text().split()) == {"x/y.txt", "later.bin", "other.csv"}
    assert not any(p.name.endswith(".tmp") for p in out.rglob("*"))


def test_empty_existing_folder_is_fine(tmp_path):
    (tmp_path / "empty").mkdir()
    with OutputFolder(tmp_path / "empty", kind="run") as f:
        f.write_text("a.txt", "a")
    assert (tmp_path / "empty" / "a.txt").read_text() == "a"


def test_a_folder_not_ours_is_never_touched(tmp_path):
    out = tmp_path / "mine"
    (out / "thumbs").mkdir(parents=True)
    (out / "trajectory.txt").write_text("the user's own")
    (out / "thumbs" / "holiday.jpg").write_bytes(b"jpg")
    for force in (False, True):
        with pytest.raises(OutputFolderError, match="not empty .* not written by dynslam_lab; nothing was changed"):
            OutputFolder(out, kind="run", force=force).open()
    assert (out / "trajectory.txt").read_text() == "the user's own" and (out / "thumbs" / "holiday.jpg").exists()
    assert not (out / MARKER).exists()


def test_a_file_is_not_a_folder(tmp_path):
    f = tmp_path / "out.txt"
    f.write_text("x")
    with pytest.raises(OutputFolderError, match="exists and is not a folder"):
        OutputFolder(f, kind="run").open()
    with pytest.raises(OutputFolderError, match="cannot write an output folder here"):
        OutputFolder(f / "sub", kind="run").open()
    assert f.read_text() == "x"


def test_force_replaces_only_a_previous_output_of_the_same_kind(tmp_path):
    out = tmp_path / "r"
    with OutputFolder(out, kind="run") as first:
        first.write_text("trajectory.txt", "old")
        first.write_text("thumbs/3.jpg", "old thumb")
    with pytest.raises(OutputFolderError, match="holds a previous 'run' output .* pass --force"):
        OutputFolder(out, kind="run").open()
    with pytest.raises(OutputFolderError, match="holds a previous 'run' output, not a 'ablation'"):
        OutputFolder(out, kind="ablation", force=True).open()
    # A user's file inside the previous output: --force refuses and deletes nothing.
    (out / "thumbs" / "mine.jpg").write_bytes(b"user")
    with pytest.raises(OutputFolderError, match=r"would delete 1 file\(s\) that dynslam_lab did not write there \(thumbs/mine.jpg\)"):
        OutputFolder(out, kind="run", force=True).open()
    assert (out / "trajectory.txt").read_text() == "old" and (out / "thumbs" / "3.jpg").exists()
    (out / "thumbs" / "mine.jpg").unlink()
    with OutputFolder(out, kind="run", force=True) as second:
        assert second.replaced and second.id != first.id
        assert sorted(p.name for p in out.iterdir()) == sorted([MARKER, JOURNAL, LOCK])
        second.write_text("trajectory.txt", "new")
    assert read_marker(out)["id"] == second.id and (out / "trajectory.txt").read_text() == "new"


def test_nested_outputs_are_judged_by_their_own_journal(tmp_path):
    out = tmp_path / "abl"
    with OutputFolder(out, kind="ablation"):
        with OutputFolder(out / "seq" / "none", kind="run") as run:
            run.write_text("trajectory.txt", "t")
        atomic_write(out / "ablation.csv", lambda tmp: tmp.write_text("a,b\n"))
    (out / JOURNAL).write_text("ablation.csv\n")  # as if the ablation had been killed before closing
    with OutputFolder(out, kind="ablation", force=True) as again:
        assert again.replaced
    assert not (out / "seq").exists()


_HOLD = """
import sys, time
from dynslam_lab.runs import OutputFolder
f = OutputFolder(sys.argv[1], kind="run").open()
f.write_text("trajectory.txt", "x")
print("locked", flush=True)
time.sleep(60)
"""


def test_a_second_writer_is_refused_and_a_dead_ones_lock_goes(tmp_path):
    out = tmp_path / "busy"
    p = subprocess.Popen([sys.executable, "-c", _HOLD, str(out)], stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "locked"
        with pytest.raises(FolderLockedError, match=rf"another dynslam process \(pid {p.pid} on .*\) is writing"):
            OutputFolder(out, kind="run", force=True).open()
        assert (out / "trajectory.txt").read_text() == "x"
    finally:
        p.send_signal(signal.SIGKILL)  # kill -9: no clean-up code runs
        p.wait(timeout=10)
    # The kernel released the lock; the dead writer's journal lets --force replace its folder.
    with OutputFolder(out, kind="run", force=True) as f:
        assert f.replaced
    assert json.loads((out / MARKER).read_text())["pid"] == os.getpid()


def test_atomic_write_keeps_the_old_file_when_interrupted(tmp_path):
    p = tmp_path / "t.txt"
    p.write_text("old")

    def write(tmp):
        tmp.write_text("half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(p, write)
    assert p.read_text() == "old" and [q.name for q in tmp_path.iterdir()] == ["t.txt"]
    assert atomic_write(p, lambda tmp: tmp.write_text("new")) == file_record(p)
    assert p.read_text() == "new"


def test_single_output_files(tmp_path):
    from dynslam_lab.runs import check_output_file

    with pytest.raises(OutputFolderError, match="is a folder; give a file name such as"):
        check_output_file(tmp_path, ".npz")  # `vocab build --out /tmp` once wrote /tmp.npz
    assert not (tmp_path.parent / (tmp_path.name + ".npz")).exists()
    with pytest.raises(OutputFolderError, match=r"must end with \.npz"):
        check_output_file(tmp_path / "voc", ".npz")
    p = check_output_file(tmp_path / "new" / "voc.npz", ".npz")
    assert p.parent.is_dir() and not p.exists()
    p.write_bytes(b"theirs")
    with pytest.raises(OutputFolderError, match="exists; pass --force"):
        check_output_file(p, ".npz")
    assert check_output_file(p, ".npz", force=True) == p and p.read_bytes() == b"theirs"
