"""benchmarks/room_witness.py: the witness on a short rendered sequence, and its arguments."""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"
sys.path.insert(0, str(BENCH))

import room_witness  # noqa: E402


@pytest.mark.slow
def test_on_a_static_scene_the_witness_agrees_with_the_truth(tmp_path, capsys):
    """A static office (nothing moves): the room's planes put every frame within a few millimetres of the truth,
    relative to the frame 6 back, as the run does."""
    out = tmp_path / "out"
    assert room_witness.main(["static_xyz", "--frames", "20", "--offset", "6", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| frame | earlier | run mm |" in text and "14 frames:" in text
    with open(out / "room_witness.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["frame"]) for r in rows] == list(range(6, 20))
    assert all(int(r["earlier"]) == int(r["frame"]) - 6 for r in rows)
    witness = np.array([float(r["witness_mm"]) for r in rows])
    run = np.array([float(r["run_mm"]) for r in rows])
    assert np.median(witness) < 3.0 and witness.max() < 8.0
    assert np.median(run) < 5.0
    # nothing pulled the run, so the room does not say it is off: the cost ratio stays near 1
    assert np.median([float(r["cost_ratio"]) for r in rows]) < 1.2


def test_bad_arguments_are_refused():
    with pytest.raises(SystemExit):
        room_witness.main(["static_xyz", "--frames", "8", "--offset", "8"])
