"""Runs: a built system over a sequence, and the run folder it writes.

:mod:`.layout` owns the folder's format (one writer, one reader, a schema version);
:mod:`.runner` drives :class:`~dynslam_lab.slam.system.System` frame by frame and records.
"""

from .layout import FILES, SCHEMA_VERSION, STAGES, RunContents, RunWriter, read_run

__all__ = ["FILES", "SCHEMA_VERSION", "STAGES", "RunContents", "RunWriter", "read_run", "RunRecorder", "run_sequence"]


def __getattr__(name: str):
    """The runner needs the whole SLAM stack (scipy, pandas): it is imported on first use, so that
    reading a run folder (``dynslam view``'s start-up) does not pay for it."""
    if name in ("RunRecorder", "run_sequence"):
        from . import runner

        return getattr(runner, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
