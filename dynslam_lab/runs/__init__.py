"""Runs: a built system over a sequence, and the run folder it writes.

:mod:`.folder` makes any output folder a transaction (fresh, marked, locked, atomic files,
replaced only when ours); :mod:`.layout` owns the run folder's format (one writer, one reader,
a schema version, :func:`verify_run`); :mod:`.runner` drives
:class:`~dynslam_lab.slam.system.System` frame by frame and records.
"""

from .folder import FolderLockedError, OutputFolder, OutputFolderError, atomic_write, check_output_file, read_marker
from .layout import FILES, SCHEMA_VERSION, STAGES, RunContents, RunWriter, read_run, verify_run

__all__ = ["FILES", "SCHEMA_VERSION", "STAGES", "RunContents", "RunWriter", "read_run", "verify_run",
           "OutputFolder", "OutputFolderError", "FolderLockedError", "atomic_write", "read_marker", "check_output_file",
           "RunRecorder", "run_sequence", "RunInterrupted", "RunStopped"]

_RUNNER = ("RunRecorder", "run_sequence", "RunInterrupted", "RunStopped", "FLUSH_EVERY", "FLUSH_COST_RATIO")


def __getattr__(name: str):
    """The runner needs the whole SLAM stack (scipy, pandas): it is imported on first use, so that
    reading a run folder (``dynslam view``'s start-up) does not pay for it."""
    if name in _RUNNER:
        from . import runner

        return getattr(runner, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
