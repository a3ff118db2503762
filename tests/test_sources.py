"""Every Python source of the project compiles without a warning: the package, the benchmarks and the
notebooks' jupytext percent sources (whose markdown lines must stay comments, or the file is no longer
Python and an editor or linter that opens it fails). An invalid escape in a docstring (``"\\,"``) is a
SyntaxWarning today and an error in a later Python."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = sorted(p for d in ("dynslam_lab", "benchmarks", "notebooks") for p in (ROOT / d).rglob("*.py"))


@pytest.mark.parametrize("path", SOURCES, ids=[str(p.relative_to(ROOT)) for p in SOURCES])
def test_source_compiles_without_warnings(path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        compile(path.read_text(encoding="utf-8"), str(path), "exec")
