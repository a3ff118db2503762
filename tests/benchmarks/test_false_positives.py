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
    # the misses without depth and the scores away from the outlines close each row; `none` finds nothing anywhere
    assert "| FN no depth | P / R away from outlines |" in text
    assert re.search(r"^\| `boxes_xyz` \| none \|.* \| [\d,]+ \| nan / 0\.00 \|$", text, re.M)
    # the recall by image speed: one row per run, recall 0 in every bin that holds keypoints for `none`
    speed_text, found_text = text.split("recall by the movers' image speed")[1].split("the misses by how much")
    speed = re.findall(r"^\| `boxes_xyz` \| (\w+) \| ((?:[^|]+\|){6})$", speed_text, re.M)
    assert {label for label, _ in speed} == {"geometry", "none"}
    none_cells = [c.strip() for c in dict(speed)["none"].split("|") if c.strip()]
    assert any(c != "-" for c in none_cells) and all(c == "-" or c.startswith("0.00 (") for c in none_cells)
    # the misses by how much of their mover was found: `none` finds no mover in any frame, so every miss is on a mover
    # not found; on every row the three kinds, and the slow and fast ones, add up to the misses
    found = {label: [int(v.replace(",", "")) for v in cells.split("|") if v.strip()]
             for label, cells in re.findall(r"^\| `boxes_xyz` \| (\w+) \| ((?:[^|]+\|){8})$", found_text, re.M)}
    assert set(found) == {"geometry", "none"}
    misses, unfound, part, mostly, slow, fast, unfound_slow, part_fast = found["none"]
    assert misses > 0 and (unfound, part, mostly) == (misses, 0, 0) and (unfound_slow, part_fast) == (slow, 0)
    for row in found.values():
        assert row[1] + row[2] + row[3] == row[0] == row[4] + row[5]
        assert row[6] <= min(row[1], row[4]) and row[7] <= min(row[2], row[5])
    assert (tmp_path / "runs" / "boxes_xyz_geometry" / "trajectory.txt").is_file()


def test_roots_runs_rendered_folders_and_refuses_a_missing_one(tmp_path, capsys):
    """``--roots``: any rendered folder (a camera-effect copy, say) is run under its folder's name; a name that is not
    a folder stops the benchmark with the name (``experiments.robustness.root_specs``, shared with camera_effects.py)."""
    import pytest

    from dynslam_lab.datasets.synthetic import synthetic_sequence
    from dynslam_lab.experiments.robustness import root_specs

    root = synthetic_sequence("boxes_xyz", n_frames=12, seed=0)
    specs = root_specs(f" {root}, ,")
    assert [(s.name, s.root) for s in specs] == [(root.name, root)]  # empty entries skipped
    with pytest.raises(ValueError, match="--roots: .*nowhere is not a folder"):
        root_specs(f"{root},{tmp_path / 'nowhere'}")
    with pytest.raises(SystemExit):
        false_positives.main(["--roots", str(tmp_path / "nowhere")])
    assert "nowhere is not a folder" in capsys.readouterr().err
    assert false_positives.main(["--roots", str(root), "--filters", "none", "--out", str(tmp_path / "runs")]) == 0
    assert f"| `{root.name}` | none |" in capsys.readouterr().out
