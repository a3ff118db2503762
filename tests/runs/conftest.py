"""Fixtures of the run-folder tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.runs.sequences import write_sequence


@pytest.fixture(scope="session")
def seqdir(tmp_path_factory) -> Path:
    """12 good frames with ground truth (read-only: tests copy it before breaking it)."""
    return write_sequence(tmp_path_factory.mktemp("runs") / "seq", n=12)
