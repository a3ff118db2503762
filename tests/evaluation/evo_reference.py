"""evo as the independent reference of the ATE/RPE tests: the same trajectories in evo's types,
associated and aligned the way evo's command line does it, and the real trajectory pairs."""

from __future__ import annotations

import pytest

from dynslam_lab.evaluation import Trajectory

#: The statistics evo reports (``get_all_statistics``) and our ``ErrorStats`` hold.
STATS = ("rmse", "mean", "median", "std", "min", "max")

#: (ground truth, estimate) pairs under ``../shared/data``: TUM fr3 walking, fr1, fr2 and Bonn.
REAL_PAIRS = [
    ("tum/trajectories/fr3_walking_xyz_groundtruth.txt", "tum/trajectories/fr3_walking_xyz_orbslam2_bf.txt"),
    ("tum/trajectories/fr3_walking_xyz_groundtruth.txt", "tum/trajectories/fr3_walking_xyz_orbslam2_cfs.txt"),
    ("tum/trajectories/fr3_walking_xyz_groundtruth.txt", "tum/trajectories/fr3_walking_xyz_orbslam2_rm.txt"),
    ("tum/trajectories/fr1_xyz_groundtruth.txt", "tum/trajectories/fr1_xyz_rgbdslam.txt"),
    ("tum/trajectories/fr2_desk_groundtruth.txt", "tum/trajectories/fr2_desk_orbslam2.txt"),
    ("bonn/groundtruth.txt", "bonn/estimated_dynamic_orbslam.txt"),
]
#: Test ids of :data:`REAL_PAIRS`: the estimate's file stem.
REAL_IDS = [est.split("/")[-1][:-4] for _, est in REAL_PAIRS]


def evo_trajectory(traj: Trajectory):
    """``traj`` as an evo ``PoseTrajectory3D`` (skips the test where evo is not installed)."""
    evo_trajectory_module = pytest.importorskip("evo.core.trajectory")
    return evo_trajectory_module.PoseTrajectory3D(poses_se3=list(traj.poses), timestamps=traj.timestamps.copy())


def evo_synced(gt: Trajectory, est: Trajectory, align: str):
    """evo's pair ``(gt, est)``: associated within 0.02 s, ``est`` aligned to ``gt`` unless ``align == "none"``
    (``"sim3"`` corrects the scale)."""
    sync = pytest.importorskip("evo.core.sync")
    g, e = sync.associate_trajectories(evo_trajectory(gt), evo_trajectory(est), max_diff=0.02)
    if align != "none":
        e.align(g, correct_scale=(align == "sim3"))
    return g, e


def assert_stats_match(stats, reference: dict, label=None, abs_tol: float = 1e-6) -> None:
    """Every statistic of our ``ErrorStats`` equals evo's ``get_all_statistics()`` to ``abs_tol``."""
    for k in STATS:
        assert getattr(stats, k) == pytest.approx(reference[k], abs=abs_tol), (label, k)
