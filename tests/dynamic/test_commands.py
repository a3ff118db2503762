"""``dynslam demo`` and ``dynslam ablation``: the tables they write and their errors."""

from __future__ import annotations

import shutil

import numpy as np
import pandas as pd
import pytest

from dynslam_lab.cli import main
from dynslam_lab.datasets.synthetic import synthetic_sequence


@pytest.mark.slow
def test_demo_writes_the_ablation_table(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--frames", "30", "--out", str(out), "--quiet"]) == 0
    df = pd.read_csv(out / "ablation.csv")
    assert list(df["filter"]) == ["none", "semantic", "depth_ransac", "geometry", "full", "oracle"]
    assert np.isfinite(df["ate_rmse_m"]).all() and (df["ate_rmse_m"] > 0).all()
    none = df.set_index("filter").loc["none"]
    assert none["improvement_pct"] == 0.0 and none["recall"] == 0.0
    oracle = df.set_index("filter").loc["oracle"]
    # perfect masks: never a mover's keypoint missed, never a static keypoint flagged beyond the outline band (their
    # margin, screening.oracle_margin_px = 4 px = OUTLINE_BAND_PX, flags the corners on it: docs/robustness.md
    # "Perfect masks and the corners on their outlines"); with the budget outside the masks (orb.truth_region_share
    # = 0, docs/robustness.md "ORB budget") there may be no keypoint on a mover at all (nan)
    for score in (oracle["recall"], oracle["precision_away"], oracle["recall_away"]):
        assert np.isnan(score) or score == 1.0
    assert none["recall_away"] == 0.0 and oracle["fn_without_depth"] == 0  # none flags nothing; masks miss nothing
    full = df.set_index("filter").loc["full"]
    # precision counts the keypoints that exist: with the budget prior (orb.prior_region_share 0.25, docs/robustness.md
    # "ORB budget") the people keep a quarter of their keypoints while the flagged static ones near them stay:
    # measured 0.82 (0.95 with the plain extraction, prior_region_share = 1.0), ATE 0.0027 m either way
    assert full["recall"] >= 0.95 and full["precision"] >= 0.78
    # the targets of the issue on synthetic walking: full >= 90% below none, within 1.5x of perfect masks
    assert full["improvement_pct"] >= 90.0
    # (perfect masks now get the whole budget outside the people: 0.0016 m against 0.0020 m with the plain extraction;
    # full 0.0027 m either way: below 2 mm the ratio is noise, hence the floor)
    assert full["ate_rmse_m"] <= 1.5 * max(oracle["ate_rmse_m"], 0.002)
    # improvement is (ATE_none - ATE) / ATE_none in percent
    expect = 100 * (none["ate_rmse_m"] - full["ate_rmse_m"]) / none["ate_rmse_m"]
    assert full["improvement_pct"] == pytest.approx(expect)
    md = (out / "ablation.md").read_text()
    assert "| filter |" in md and "| full |" in md and "| P away | R away | FN no depth |" in md
    assert "ATE RMSE" in capsys.readouterr().out
    for f in df["filter"]:
        assert (out / df["sequence"][0] / f / "trajectory.txt").is_file()


def test_ablation_needs_a_detector_without_synthetic_masks(tmp_path, capsys):
    src = synthetic_sequence("walking_xyz", n_frames=30, seed=0)
    seq = tmp_path / "plain"
    shutil.copytree(src, seq, ignore=shutil.ignore_patterns("masks", "moving.txt", "instances.json"))
    assert main(["ablation", str(seq), "--out", str(tmp_path / "a"), "--filters", "none;semantic", "--quiet"]) == 1
    assert "need a detector" in capsys.readouterr().err
    assert main(["ablation", str(seq), "--out", str(tmp_path / "b"), "--filters", "none;yolo", "--quiet"]) == 1
    assert "unknown filter" in capsys.readouterr().err


def test_split_filters():
    from dynslam_lab.commands.ablation import split_filters

    assert split_filters("none;semantic,epipolar;full") == ["none", "semantic,epipolar", "full"]
    assert split_filters("none,semantic,full") == ["none", "semantic", "full"]
    assert split_filters("semantic,epipolar") == ["semantic,epipolar"]
