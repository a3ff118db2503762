"""Shared fixtures: the real data beside the clone, and cached synthetic sequences."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("DYNSLAM_SHARED_DATA", ROOT.parent / "shared" / "data"))

# One cache of rendered synthetic sequences for the whole test session (and the notebooks
# it runs): inside the clone, ignored by git, so a clean clone renders them afresh.
os.environ.setdefault("DYNSLAM_CACHE", str(ROOT / ".cache" / "tests"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` (real TUM/Bonn fragments and ONNX models); skip where absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA} (a fresh clone without ../shared)")
    return SHARED_DATA


def shared_file(rel: str) -> Path:
    """Path of a file under ``../shared/data``; skips the test where it is absent."""
    p = SHARED_DATA / rel
    if not p.is_file():
        pytest.skip(f"real data file {p} not found")
    return p


def _free_gib(path: Path) -> float:
    while not path.exists():
        path = path.parent
    return shutil.disk_usage(path).free / 2**30


# The suite renders ~2.5 GB of synthetic sequences into DYNSLAM_CACHE and writes runs under the
# temporary folder; a disk that fills up mid-run fails tests with errors unrelated to the code.
NEEDED_GIB = 4.0


def pytest_report_header(config: pytest.Config) -> list[str]:
    lines = []
    for name, path in (("DYNSLAM_CACHE", Path(os.environ["DYNSLAM_CACHE"])),
                       ("temporary folder", Path(tempfile.gettempdir()))):
        free = _free_gib(path)
        line = f"disk: {name} {path}: {free:.1f} GiB free"
        if free < NEEDED_GIB:
            line += f" -- WARNING: the suite needs about {NEEDED_GIB:.0f} GiB; tests may fail with 'No space left on device'"
        lines.append(line)
    return lines
