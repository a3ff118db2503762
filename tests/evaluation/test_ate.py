"""ATE: exact cases, recovery of a known alignment, and agreement with evo's APE to 1e-6."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dynslam_lab.evaluation import Trajectory, compute_ate, error_statistics, read_tum_trajectory
from tests.conftest import shared_file

STATS = ("rmse", "mean", "median", "std", "min", "max")


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
    sync = pytest.importorskip("evo.core.sync")
    metrics = pytest.importorskip("evo.core.metrics")
    from evo.core.trajectory import PoseTrajectory3D

    g = PoseTrajectory3D(poses_se3=list(gt.poses), timestamps=gt.timestamps.copy())
    e = PoseTrajectory3D(poses_se3=list(est.poses), timestamps=est.timestamps.copy())
    g, e = sync.associate_trajectories(g, e, max_diff=0.02)
    if align != "none":
        e.align(g, correct_scale=(align == "sim3"))
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((g, e))
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
    ref = ape.get_all_statistics()
    for k in STATS:
        assert getattr(r.stats, k) == pytest.approx(ref[k], abs=1e-6), k
    np.testing.assert_allclose(r.errors, ape.error, atol=1e-6)


REAL = [
    ("tum/trajectories/fr3_walking_xyz_groundtruth.txt", "tum/trajectories/fr3_walking_xyz_orbslam2_bf.txt"),
    ("tum/trajectories/fr3_walking_xyz_groundtruth.txt", "tum/trajectories/fr3_walking_xyz_orbslam2_cfs.txt"),
    ("tum/trajectories/fr3_walking_xyz_groundtruth.txt", "tum/trajectories/fr3_walking_xyz_orbslam2_rm.txt"),
    ("tum/trajectories/fr1_xyz_groundtruth.txt", "tum/trajectories/fr1_xyz_rgbdslam.txt"),
    ("tum/trajectories/fr2_desk_groundtruth.txt", "tum/trajectories/fr2_desk_orbslam2.txt"),
    ("bonn/groundtruth.txt", "bonn/estimated_dynamic_orbslam.txt"),
]


@pytest.mark.needs_shared
@pytest.mark.parametrize("align", ["se3", "sim3"])
@pytest.mark.parametrize("gt_rel, est_rel", REAL, ids=[p[1].split("/")[-1][:-4] for p in REAL])
def test_matches_evo_real(gt_rel, est_rel, align):
    pytest.importorskip("evo")
    gt = read_tum_trajectory(shared_file(gt_rel))
    est = read_tum_trajectory(shared_file(est_rel))
    ape = _evo_ape(gt, est, align)
    r = compute_ate(gt, est, align=align)
    ref = ape.get_all_statistics()
    for k in STATS:
        assert getattr(r.stats, k) == pytest.approx(ref[k], abs=1e-6), k
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
