"""evaluate(), paper-style tables and the improvement percentage."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from dynslam_lab.evaluation import (
    compute_ate,
    compute_rpe,
    comparison_table,
    evaluate,
    format_report,
    improvement,
    read_tum_trajectory,
    stats_table,
)
from tests.conftest import shared_file


def test_improvement_like_yolo_slam_table4():
    # YOLO-SLAM Table 3/4, fr3_w_xyz: ORB-SLAM2 0.7521 m -> YOLO-SLAM 0.0146 m is 98.06 %.
    assert improvement(0.7521, 0.0146) == pytest.approx(98.0588, abs=1e-3)
    assert improvement(1.0, 1.5) == pytest.approx(-50.0)
    out = improvement(np.array([0.0, 2.0]), np.array([1.0, 1.0]))
    assert np.isnan(out[0]) and out[1] == pytest.approx(50.0)


def test_evaluate_is_json_and_consistent(synth):
    make, noisy = synth
    gt = make(n=300, rate=100.0)
    est = noisy(make(n=90, rate=30.0), sigma_t=0.02)
    r = evaluate(gt, est, align="sim3", delta=3, gt_name="g.txt", est_name="e.txt")
    again = json.loads(json.dumps(r))
    assert again == r
    assert r["n_matched"] == 90 and r["n_gt"] == 300
    ate = compute_ate(gt, est, align="sim3")
    rpe = compute_rpe(gt, est, align="sim3", delta=3)
    assert r["ate"]["rmse"] == ate.stats.rmse
    assert r["rpe"]["trans"]["median"] == rpe.trans.median
    assert r["rpe"]["rot"]["max"] == rpe.rot.max
    assert r["align"]["scale"] == pytest.approx(ate.alignment.scale)
    assert 0.2 < r["coverage"] <= 1.0
    text = format_report(r)
    assert "ATE (m)" in text and "RPE rot. (deg)" in text and f"{r['ate']['rmse']:.4f}" in text


def test_evaluate_without_rpe_when_too_short(synth):
    make, _ = synth
    gt = make(n=4)
    r = evaluate(gt, gt, delta=10)
    assert r["rpe"] is None
    assert "not computed" in format_report(r)


def test_tables(synth):
    make, noisy = synth
    gt = make(n=200, rate=100.0)
    results = {
        "small noise": evaluate(gt, noisy(gt, sigma_t=0.005, seed=2)),
        "large noise": evaluate(gt, noisy(gt, sigma_t=0.05, seed=3)),
    }
    df = stats_table(results, "ate")
    assert list(df.columns) == ["RMSE", "Mean", "Median", "S.D."]
    assert df.loc["small noise", "RMSE"] == results["small noise"]["ate"]["rmse"]
    assert df.loc["large noise", "RMSE"] > df.loc["small noise", "RMSE"]
    rot = stats_table(results, "rpe_rot", stats=("rmse", "max"))
    assert list(rot.columns) == ["RMSE", "Max"]
    with pytest.raises(ValueError, match="metric"):
        stats_table(results, "ape")
    with pytest.raises(ValueError, match="unknown statistics"):
        stats_table(results, "ate", stats=("rmse", "p95"))

    comp = comparison_table({"seq": results["large noise"]}, {"seq": results["small noise"]}, "ate",
                            baseline_label="ORB-SLAM2", ours_label="ours")
    b, o = results["large noise"]["ate"]["rmse"], results["small noise"]["ate"]["rmse"]
    assert comp.loc["seq", ("ORB-SLAM2", "RMSE")] == b
    assert comp.loc["seq", ("Improvement (%)", "RMSE")] == pytest.approx((b - o) / b * 100)
    assert isinstance(comp, pd.DataFrame)
    with pytest.raises(ValueError, match="not in both"):
        comparison_table({"a": results["small noise"]}, {"b": results["small noise"]})


@pytest.mark.needs_shared
def test_evaluate_real_bf_matches_evo_rmse():
    pytest.importorskip("evo")
    from evo.core import metrics, sync
    from evo.tools import file_interface

    gp = shared_file("tum/trajectories/fr3_walking_xyz_groundtruth.txt")
    ep = shared_file("tum/trajectories/fr3_walking_xyz_orbslam2_bf.txt")
    r = evaluate(read_tum_trajectory(gp), read_tum_trajectory(ep), gt_name=str(gp), est_name=str(ep))
    g, e = sync.associate_trajectories(
        file_interface.read_tum_trajectory_file(str(gp)), file_interface.read_tum_trajectory_file(str(ep)), max_diff=0.02
    )
    e.align(g)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((g, e))
    assert r["ate"]["rmse"] == pytest.approx(ape.get_statistic(metrics.StatisticsType.rmse), abs=1e-6)
    assert r["n_matched"] == 202
