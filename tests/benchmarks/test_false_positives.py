"""benchmarks/false_positives.py on a short stress scene: one row per run, the false positives split by kind."""

from __future__ import annotations

import re
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"
sys.path.insert(0, str(BENCH))

import false_positives  # noqa: E402


def test_the_table_has_a_row_per_run_with_every_kind(tmp_path, capsys):
    assert false_positives.main(["--sequences", "boxes_xyz", "--frames", "12", "--filters", "geometry,none",
                                 "--out", str(tmp_path / "runs")]) == 0
    text = capsys.readouterr().out
    rows = {m.group(1): m for m in re.finditer(r"^\| `boxes_xyz` \| (\w+) \| ([\d.]+) \| (\S+) / (\S+) \|((?: [\d,]+ \|){5})", text, re.M)}
    assert set(rows) == {"geometry", "none"}
    none_fp = [int(v.replace(",", "")) for v in rows["none"].group(5).split("|") if v.strip()]
    assert none_fp == [0, 0, 0, 0, 0]  # `none` judges nothing dynamic: no false positive of any kind
    assert (tmp_path / "runs" / "boxes_xyz_geometry" / "trajectory.txt").is_file()
