"""Shared fixtures: the real data beside the clone, and cached synthetic sequences."""

from __future__ import annotations

import os
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
