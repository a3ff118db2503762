"""The ``dynslam`` command line.

Each sub-command lives in its own module in :mod:`dynslam_lab.commands` and exposes
``register(subparsers)``, which adds its parser and sets ``func`` to the function that
runs it (``func(args) -> int`` exit code). Modules import their heavy dependencies
inside ``func`` so that ``dynslam --help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from . import __version__, commands


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dynslam",
        description="dynslam_lab: RGB-D SLAM in dynamic scenes (TUM, Bonn and synthetic sequences).",
    )
    parser.add_argument("--version", action="version", version=f"dynslam_lab {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (ValueError, FileNotFoundError, RuntimeError) as exc:
        # Bad input: one clear line, no traceback (set DYNSLAM_DEBUG=1 for the traceback).
        import os

        if os.environ.get("DYNSLAM_DEBUG"):
            raise
        print(f"dynslam {args.command}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
