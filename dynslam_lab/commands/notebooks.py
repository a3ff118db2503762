"""``dynslam notebooks``: open the notebooks in JupyterLab, as notebooks.

Example::

    pip install -e ".[notebooks]"
    dynslam notebooks                    # JupyterLab on notebooks/00_quickstart.py
    dynslam notebooks 04                 # ... on notebooks/04_depth_ransac.py
    dynslam notebooks --no-browser --port 8899

The notebooks are jupytext percent ``.py`` files. JupyterLab opens a ``.py`` as a text file
unless its default viewer for Python files is jupytext's notebook view; this command starts
JupyterLab with ``JUPYTER_CONFIG_PATH`` pointing at ``notebooks/jupyter_config/``, whose
``labconfig/default_setting_overrides.json`` sets that viewer. Nothing is written to the
user's Jupyter settings. See ``docs/notebooks.md``.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

NOTEBOOKS = Path(__file__).resolve().parents[2] / "notebooks"  # the clone's notebooks/ (editable install)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "notebooks",
        help="open the notebooks in JupyterLab (needs the [notebooks] extra)",
        description=(
            "Start JupyterLab in the clone's notebooks/ folder, with the jupytext percent .py files "
            "opening as notebooks, and open NOTEBOOK (default 00). Needs: pip install -e \".[notebooks]\"."
        ),
    )
    p.add_argument("notebook", nargs="?", default="00", metavar="NOTEBOOK",
                   help="number or file name of the notebook to open (default 00, the quickstart)")
    p.add_argument("--port", type=int, default=None, help="JupyterLab's port (default: JupyterLab's, 8888 or the next free)")
    p.add_argument("--no-browser", action="store_true", help="do not open a browser (print the address only)")
    p.add_argument("--allow-root", action="store_true", help="let JupyterLab run as root (containers; it refuses otherwise)")
    p.add_argument("--dry-run", action="store_true", help="print the command and environment, do not start")
    p.set_defaults(func=run)


def find_notebook(name: str, folder: Path = NOTEBOOKS) -> Path:
    """``notebooks/NN_*.py`` for a number (``"4"``, ``"04"``), a stem or a file name."""
    if not folder.is_dir():
        raise FileNotFoundError(
            f"{folder}: no notebooks folder beside the package; install from a clone with "
            f"pip install -e \".[notebooks]\"")
    stem = Path(name).stem
    if stem.isdigit():
        hits = sorted(folder.glob(f"{int(stem):02d}_*.py"))
    else:
        hits = [p for p in (folder / f"{stem}.py",) if p.is_file()]
    if not hits:
        known = ", ".join(p.stem for p in sorted(folder.glob("[0-9][0-9]_*.py")))
        raise FileNotFoundError(f"no notebook {name!r} in {folder} (known: {known})")
    return hits[0]


def lab_command(notebook: Path, port: int | None = None, no_browser: bool = False,
                allow_root: bool = False) -> tuple[list[str], dict]:
    """The JupyterLab command line and environment that open ``notebook`` as a notebook."""
    env = dict(os.environ)
    config = str(notebook.parent / "jupyter_config")
    env["JUPYTER_CONFIG_PATH"] = os.pathsep.join([config] + [p for p in env.get("JUPYTER_CONFIG_PATH", "").split(os.pathsep) if p])
    cmd = [sys.executable, "-m", "jupyterlab", notebook.name]
    if port is not None:
        cmd.append(f"--ServerApp.port={port}")
    if no_browser:
        cmd.append("--no-browser")
    if allow_root:
        cmd.append("--allow-root")
    return cmd, env


def run(args: argparse.Namespace) -> int:
    if args.port is not None and not 0 < args.port < 65536:
        raise ValueError(f"--port must be in 1..65535, got {args.port}")
    notebook = find_notebook(args.notebook)
    missing = [m for m in ("jupyterlab", "jupytext", "ipywidgets", "ipykernel") if importlib.util.find_spec(m) is None]
    if missing:
        raise RuntimeError(f"{', '.join(missing)} not installed: pip install -e \".[notebooks]\" (from the clone)")
    cmd, env = lab_command(notebook, args.port, args.no_browser, args.allow_root)
    print(f"dynslam notebooks: JUPYTER_CONFIG_PATH={env['JUPYTER_CONFIG_PATH']} {' '.join(cmd)}  (in {notebook.parent})",
          flush=True)
    if args.dry_run:
        return 0
    try:
        return subprocess.call(cmd, cwd=notebook.parent, env=env)
    except KeyboardInterrupt:
        return 0
