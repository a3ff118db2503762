"""Timestamp association: hand-made cases, evo's matching, real partial trajectories."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.evaluation import Trajectory, TrajectoryError, associate_trajectories, read_tum_trajectory
from dynslam_lab.evaluation.sync import match_timestamps
from tests.conftest import shared_file
from tests.evaluation.evo_reference import evo_trajectory


def test_match_hand_case():
    ref = np.array([0.00, 0.01, 0.02, 0.03, 0.10])
    q = np.array([-0.05, 0.004, 0.015, 0.026, 0.065, 0.12, 0.2])
    iq, ir = match_timestamps(q, ref, max_diff=0.02)
    # -0.05: too early; 0.004 -> 0.00; 0.015 tie 0.01/0.02 -> earlier 0.01; 0.026 -> 0.03;
    # 0.065: 0.035 from both neighbours -> none; 0.12 -> 0.10 (0.02, inclusive); 0.2 -> none.
    assert iq.tolist() == [1, 2, 3, 5]
    assert ir.tolist() == [0, 1, 3, 4]


def test_match_unsorted_reference():
    ref = np.array([0.3, 0.1, 0.2])
    iq, ir = match_timestamps(np.array([0.21, 0.09]), ref, max_diff=0.02)
    assert iq.tolist() == [0, 1]
    assert ir.tolist() == [2, 1]


def test_match_bad_max_diff():
    with pytest.raises(ValueError, match="max_diff"):
        match_timestamps(np.zeros(2), np.zeros(2), max_diff=-1)


def test_partial_estimate(synth):
    make, noisy = synth
    gt = make(n=1000, rate=100.0)
    est = noisy(make(n=300, rate=30.0)).subset(np.arange(40, 200))
    g, e = associate_trajectories(gt, est, 0.02)
    assert len(g) == len(e) == 160
    assert np.all(np.abs(g.timestamps - e.timestamps) <= 0.005 + 1e-9)


def test_no_match_names_both():
    a = Trajectory(np.array([0.0, 1.0]), np.tile(np.eye(4), (2, 1, 1)))
    b = Trajectory(np.array([5.0, 6.0]), np.tile(np.eye(4), (2, 1, 1)))
    with pytest.raises(TrajectoryError, match=r"no matching timestamps between gt\.txt.*est\.txt"):
        associate_trajectories(a, b, gt_name="gt.txt", est_name="est.txt")


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_matches_evo_on_jittered_stamps(seed):
    sync = pytest.importorskip("evo.core.sync")
    rng = np.random.default_rng(seed)
    n_gt, n_est = int(rng.integers(200, 400)), int(rng.integers(50, 250))
    t_gt = np.sort(rng.uniform(0, 10, n_gt))
    t_est = np.sort(rng.uniform(-1, 11, n_est))
    gt = Trajectory(t_gt, np.tile(np.eye(4), (n_gt, 1, 1)))
    est = Trajectory(t_est, np.tile(np.eye(4), (n_est, 1, 1)))
    g, e = associate_trajectories(gt, est, 0.02)
    ge, ee = sync.associate_trajectories(evo_trajectory(gt), evo_trajectory(est), max_diff=0.02)
    np.testing.assert_array_equal(g.timestamps, ge.timestamps)
    np.testing.assert_array_equal(e.timestamps, ee.timestamps)


@pytest.mark.needs_shared
@pytest.mark.parametrize("name", ["bf", "cfs", "rm"])
def test_real_partial_trajectories_match_evo(name):
    sync = pytest.importorskip("evo.core.sync")
    file_interface = pytest.importorskip("evo.tools.file_interface")
    gt_path = shared_file("tum/trajectories/fr3_walking_xyz_groundtruth.txt")
    est_path = shared_file(f"tum/trajectories/fr3_walking_xyz_orbslam2_{name}.txt")
    g, e = associate_trajectories(read_tum_trajectory(gt_path), read_tum_trajectory(est_path))
    ge, ee = sync.associate_trajectories(
        file_interface.read_tum_trajectory_file(str(gt_path)),
        file_interface.read_tum_trajectory_file(str(est_path)),
        max_diff=0.02,
    )
    np.testing.assert_array_equal(g.timestamps, ge.timestamps)
    np.testing.assert_array_equal(e.timestamps, ee.timestamps)
    assert len(e) == {"bf": 202, "cfs": 43, "rm": 48}[name]
