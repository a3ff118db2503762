"""Trajectory evaluation: TUM-format I/O, association, ATE and RPE (checked against evo in tests)."""
from .trajectory import Trajectory, TrajectoryError, read_tum_trajectory, write_tum_trajectory
from .sync import DEFAULT_MAX_DIFF, associate_trajectories, match_timestamps
from .ate import ALIGN_METHODS, AteResult, ErrorStats, align_trajectory, compute_ate, error_statistics
from .rpe import DELTA_UNITS, RpeResult, compute_rpe, relative_errors, rpe_pairs
from .tables import comparison_table, evaluate, format_report, improvement, stats_table

__all__ = [
    "Trajectory",
    "TrajectoryError",
    "read_tum_trajectory",
    "write_tum_trajectory",
    "DEFAULT_MAX_DIFF",
    "associate_trajectories",
    "match_timestamps",
    "ALIGN_METHODS",
    "AteResult",
    "ErrorStats",
    "align_trajectory",
    "compute_ate",
    "error_statistics",
    "DELTA_UNITS",
    "RpeResult",
    "compute_rpe",
    "relative_errors",
    "rpe_pairs",
    "comparison_table",
    "evaluate",
    "format_report",
    "improvement",
    "stats_table",
]
