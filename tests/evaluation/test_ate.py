"""ATE: exact cases, recovery of a known alignment, and agreement with evo's APE to 1e-6."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dynslam_lab.evaluation import Trajectory, compute_ate, error_statistics, read_tum_trajectory
from tests.conftest import shared_file
from tests.evaluation.evo_reference import REAL_IDS, REAL_PAIRS, assert_stats_match, evo_synced


def test_error_statistics_hand_case():
    s = error_statistics(np.array([3.0, 4.0, 0.0, 1.0]))
    assert s.rmse == pytest.approx(np.sqrt(26 / 4))
    assert s.mean == pytest.approx(2.0)
    assert s.median == pytest.approx(2.0)
    assert s.std == pytest.approx(np.sqrt((1 + 4 + 4 + 1) / 4))
    assert (s.min, s.max, s.n) == (0.0, 4.0, 4)
    with pytest.raises(ValueError, match="empty"):
        error_statistics(np.zeros(0))
    with pytest.raises(ValueError, match="NaN"):
        error_statistics(np.array([1.0, np.nan]))


def test_transformed_copy_has_zero_ate(synth):
    make, _ = synth
    gt = make(n=200)
    S = np.eye(4)
    S[:3, :3] = Rotation.from_euler("xyz", [20, -40, 75], degrees=True).as_matrix()
    S[:3, 3] = [1.0, -2.0, 0.5]
    moved = gt.transformed(S, scale=1.0)
    r = compute_ate(gt, moved, align="se3")
    assert r.stats.rmse < 1e-10
    np.testing.assert_allclose(r.alignment.R @ S[:3, :3], np.eye(3), atol=1e-10)
    # Scaled copy: only Sim(3) removes the error, and recovers 1/scale.
    scaled = gt.transformed(S, scale=2.5)
    assert compute_ate(gt, scaled, align="se3").stats.rmse > 0.05
    rs = compute_ate(gt, scaled, align="sim3")
    assert rs.stats.rmse < 1e-10
    assert rs.alignment.scale == pytest.approx(1 / 2.5)


def test_known_offset_without_alignment(synth):
    make, _ = synth
    gt = make(n=50)
    P = gt.poses.copy()
    P[:, :3, 3] += [0.03, 0.04, 0.0]
    r = compute_ate(gt, Trajectory(gt.timestamps, P), align="none")
    np.testing.assert_allclose(r.errors, 0.05, atol=1e-12)
    assert r.stats.std == pytest.approx(0.0, abs=1e-12)


def test_bad_align(synth):
    make, _ = synth
    gt = make(n=10)
    with pytest.raises(ValueError, match="align must be one of"):
        compute_ate(gt, gt, align="affine")


def _evo_ape(gt, est, align):
    metrics = pytest.importorskip("evo.core.metrics")
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data(evo_synced(gt, est, align))
    return ape


@pytest.mark.parametrize("align", ["se3", "sim3", "none"])
@pytest.mark.parametrize("seed", [0, 1])
def test_matches_evo_synthetic(synth, align, seed):
    make, noisy = synth
    gt = make(n=500, rate=100.0, seed=seed)
    est = noisy(make(n=150, rate=30.0, seed=seed), sigma_t=0.02, seed=seed + 10)
    S = np.eye(4)
    S[:3, :3] = Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix()
    S[:3, 3] = [0.5, 1.0, -0.3]
    est = est.transformed(S, scale=0.7).subset(np.arange(20, 140))
    ape = _evo_ape(gt, est, align)
    r = compute_ate(gt, est, align=align)
    assert_stats_match(r.stats, ape.get_all_statistics())
    np.testing.assert_allclose(r.errors, ape.error, atol=1e-6)


@pytest.mark.needs_shared
@pytest.mark.parametrize("align", ["se3", "sim3"])
@pytest.mark.parametrize("gt_rel, est_rel", REAL_PAIRS, ids=REAL_IDS)
def test_matches_evo_real(gt_rel, est_rel, align):
    pytest.importorskip("evo")
    gt = read_tum_trajectory(shared_file(gt_rel), duplicates="first")  # fr2/desk repeats one stamp
    est = read_tum_trajectory(shared_file(est_rel))
    ape = _evo_ape(gt, est, align)
    r = compute_ate(gt, est, align=align)
    assert_stats_match(r.stats, ape.get_all_statistics())
    assert r.stats.n == len(ape.error)


def test_too_few_poses_to_align_names_files(synth):
    from dynslam_lab.evaluation import TrajectoryError

    make, _ = synth
    gt = make(n=100, rate=100.0)
    est = gt.subset(np.array([10, 50]))
    with pytest.raises(TrajectoryError, match=r"cannot align e\.txt to g\.txt \(se3\).*at least 3"):
        compute_ate(gt, est, gt_name="g.txt", est_name="e.txt")
    # Without alignment two poses are enough.
    assert compute_ate(gt, est, align="none").stats.n == 2
