"""The ``dynslam`` command line.

Each sub-command lives in its own module in :mod:`dynslam_lab.commands` and exposes
``register(subparsers)``, which adds its parser and sets ``func`` to the function that
runs it (``func(args) -> int`` exit code). Modules import their heavy dependencies
inside ``func`` so that ``dynslam --help`` stays fast.

:func:`main` is the one error boundary of every command: an error becomes one line on stderr,
``dynslam COMMAND: error: FILE: what is wrong``, and an exit code (``docs/reliability.md``):

* 2: usage (argparse's own errors, :class:`~dynslam_lab.errors.UsageError`: an output folder
  that is not empty or is locked, an option out of range or a combination that cannot work);
* 1: data (``ValueError``/``OSError``: a missing, unreadable or malformed file, a run in which
  no frame could be tracked) and anything unexpected (then said to be a bug);
* 130: Ctrl-C (a run leaves a consistent partial run folder).

``--debug`` (or ``DYNSLAM_DEBUG=1``) shows the traceback instead.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys

from . import __version__, commands
from .errors import EXIT_DATA, EXIT_INTERRUPTED, EXIT_USAGE, UsageError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dynslam",
        description="dynslam_lab: RGB-D SLAM in dynamic scenes (TUM, Bonn and synthetic sequences).",
    )
    parser.add_argument("--version", action="version", version=f"dynslam_lab {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error (for developers)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        module.register(sub)
    for p in sub.choices.values():  # `dynslam run ... --debug` works too
        p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    return parser


def describe_error(exc: BaseException) -> str:
    """One line for an error: the file it concerns (when known) and what is wrong."""
    if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
        where = exc.filename if exc.filename2 is None else f"{exc.filename} -> {exc.filename2}"
        return f"{where}: {exc.strerror}"
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_USAGE
    debug = bool(getattr(args, "debug", False) or os.environ.get("DYNSLAM_DEBUG"))
    name = f"dynslam {args.command}"
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt as exc:
        if debug:
            raise
        print(f"{name}: {exc}" if str(exc) else f"{name}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # `dynslam detect ... | head`: the reader left, nothing to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        return EXIT_DATA
    except UsageError as exc:
        if debug:
            raise
        print(f"{name}: error: {describe_error(exc)}", file=sys.stderr)
        return EXIT_USAGE
    except (ValueError, OSError) as exc:
        if debug:
            raise
        print(f"{name}: error: {describe_error(exc)}", file=sys.stderr)
        return EXIT_DATA
    except Exception as exc:  # a bug: still one line, and how to see more
        if debug:
            raise
        print(f"{name}: internal error: {type(exc).__name__}: {describe_error(exc)} "
              "(run with --debug for the traceback, and please report it)", file=sys.stderr)
        return EXIT_DATA


if __name__ == "__main__":
    sys.exit(main())
