"""Trajectory evaluation: TUM-format I/O, ATE and RPE (checked against evo in tests)."""
from .trajectory import Trajectory, TrajectoryError, read_tum_trajectory, write_tum_trajectory

__all__ = ["Trajectory", "TrajectoryError", "read_tum_trajectory", "write_tum_trajectory"]
