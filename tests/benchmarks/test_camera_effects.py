"""benchmarks/camera_effects.py on a short stress scene: a run per (effect, filter) on copies the benchmark made,
the ratio to the unchanged sequence, resuming, and a copy it did not make refused."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pandas as pd
import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"
sys.path.insert(0, str(BENCH))

import camera_effects  # noqa: E402

from dynslam_lab.datasets.camera_effects import CameraEffects  # noqa: E402
from dynslam_lab.experiments.camera_effects import effect_copy  # noqa: E402


def test_runs_each_effect_on_its_copy_and_resumes(tmp_path, capsys):
    out = tmp_path / "runs"
    args = ["--sequences", "boxes_xyz", "--frames", "12", "--effects", "exposure,rate15", "--filters", "none", "--out", str(out)]
    assert camera_effects.main(args) == 0
    df = pd.read_csv(out / "camera_effects.csv")
    assert list(df["effect"]) == ["original", "exposure", "rate15"] and set(df["filter"]) == {"none"}
    assert list(df["frames"]) == [12, 12, 6]  # 15 frames a second: every other frame
    assert df.loc[0, "ate_vs_original"] == pytest.approx(1.0)
    assert (df["ate_rmse_m"] < 0.05).all()
    copy = out / "sequences" / "boxes_xyz__exposure"
    assert json.loads((copy / "camera_effects.json").read_text())["exposure"] == 0.03
    assert "| exposure | none | 1 |" in (out / "camera_effects.md").read_text()
    row = out / "boxes_xyz" / "rate15" / "none" / "row.json"
    stamp = row.stat().st_mtime_ns
    assert camera_effects.main(args) == 0  # resumed: nothing run again
    assert row.stat().st_mtime_ns == stamp
    assert "unknown effects" not in capsys.readouterr().err


def test_a_folder_that_is_not_the_copy_asked_for_is_refused(tmp_path):
    folder = tmp_path / "seq__exposure"
    folder.mkdir()
    (folder / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="not the copy"):
        effect_copy(tmp_path / "seq", CameraEffects(exposure=0.03), folder)
    assert (folder / "notes.txt").read_text() == "mine"
