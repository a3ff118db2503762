"""TUM trajectory files: round trip, and every malformed row named by file and line."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.evaluation import Trajectory, TrajectoryError, read_tum_trajectory, write_tum_trajectory
from dynslam_lab.geometry.se3 import make_pose, so3_exp


def test_round_trip_sorts_and_normalises(tmp_path):
    rng = np.random.default_rng(0)
    poses = np.stack([make_pose(so3_exp(rng.normal(size=3)), rng.normal(size=3)) for _ in range(6)])
    stamps = np.array([5.0, 1.0, 3.0, 2.0, 4.0, 6.0])
    write_tum_trajectory(Trajectory(stamps, poses), tmp_path / "t.txt", header="made by a test")
    back = read_tum_trajectory(tmp_path / "t.txt")
    order = np.argsort(stamps)
    np.testing.assert_allclose(back.timestamps, stamps[order], atol=1e-6)
    np.testing.assert_allclose(back.poses, poses[order], atol=1e-8)
    # a quaternion written with scale 2 is read as the same rotation
    row = "1.0 0 0 0 0 0 0.8 0.6\n2.0 1 2 3 0 0 1.6 1.2\n"
    (tmp_path / "s.txt").write_text(row)
    t = read_tum_trajectory(tmp_path / "s.txt")
    np.testing.assert_allclose(t.poses[0, :3, :3], t.poses[1, :3, :3], atol=1e-12)


@pytest.mark.parametrize("bad, message", [
    ("2.0 0 0 0 0 0 0\n", r"t\.txt:3: expected 8 values"),
    ("2.0 0 0 x 0 0 0 1\n", r"t\.txt:3: non-numeric value"),
    ("2.0 0 0 nan 0 0 0 1\n", r"t\.txt:3: non-finite value"),
    ("2.0 0 0 0 0 0 0 0\n", r"t\.txt:3: quaternion has zero norm"),
])
def test_bad_rows_are_named_by_line(tmp_path, bad, message):
    (tmp_path / "t.txt").write_text("# timestamp tx ty tz qx qy qz qw\n1.0 0 0 0 0 0 0 1\n" + bad + "3.0 0 0 0 0 0 0 1\n")
    with pytest.raises(TrajectoryError, match=message):
        read_tum_trajectory(tmp_path / "t.txt")


def test_missing_and_empty_files(tmp_path):
    with pytest.raises(TrajectoryError, match="nope.txt: trajectory file not found"):
        read_tum_trajectory(tmp_path / "nope.txt")
    (tmp_path / "e.txt").write_text("# only a comment\n\n")
    with pytest.raises(TrajectoryError, match="e.txt: no poses in file"):
        read_tum_trajectory(tmp_path / "e.txt")
