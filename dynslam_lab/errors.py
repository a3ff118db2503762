"""The two kinds of error a command can end with, and their exit codes.

``dynslam`` (``cli.py``) turns every error into one line on stderr and an exit code:
:class:`UsageError` (the command line asks for something that cannot be done: an output folder
that is not empty, an option out of range) exits with 2, like argparse's own errors; any other
``ValueError`` or ``OSError`` (a missing, unreadable or malformed input file, data no frame of
which could be tracked) exits with 1. Both are ``ValueError`` subclasses, so library callers
(notebooks) catch them as before.
"""

from __future__ import annotations

__all__ = ["UsageError", "EXIT_USAGE", "EXIT_DATA", "EXIT_INTERRUPTED"]

#: Exit codes of the ``dynslam`` command line.
EXIT_DATA = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT, the shell's convention for Ctrl-C


class UsageError(ValueError):
    """The command line asks for something that cannot be done (exit code 2)."""
