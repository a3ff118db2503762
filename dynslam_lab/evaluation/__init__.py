"""Trajectory evaluation: TUM-format I/O, association, ATE and RPE (checked against evo in tests)."""
from .trajectory import Trajectory, TrajectoryError, read_tum_trajectory, write_tum_trajectory
from .sync import DEFAULT_MAX_DIFF, associate_trajectories, match_timestamps
from .ate import ALIGN_METHODS, AteResult, ErrorStats, align_trajectory, compute_ate, error_statistics
from .rpe import DELTA_UNITS, RpeResult, compute_rpe, relative_errors, rpe_pairs

_TABLES = ("comparison_table", "evaluate", "format_report", "improvement", "stats_table")


def __getattr__(name: str):
    """The table helpers need pandas (~0.1 s to import): loaded on first use, so that reading a
    trajectory (``dynslam view``'s start-up) does not pay for them."""
    if name in _TABLES:
        from . import tables

        return getattr(tables, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

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
