"""The line-based text files of the TUM RGB-D format, read one way everywhere.

``rgb.txt``, ``depth.txt``, ``groundtruth.txt``, association files and TUM trajectories
(Sturm et al., IROS 2012) share one layout: a record per line, fields separated by white
space (commas are accepted too, as TUM's ``associate.py`` does), ``#`` starts a comment line,
blank lines are skipped. :func:`data_lines` yields the records with their line numbers, so
every reader can name the file and line of a malformed record in its own error type.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

__all__ = ["data_lines"]


def data_lines(
    path: str | Path, error: type[Exception] = ValueError, what: str = "file"
) -> Iterator[tuple[int, str, list[str]]]:
    """The data lines of a TUM-format text file, as ``(line number, stripped text, fields)``.

    Parameters
    ----------
    path : the text file.
    error : exception type raised when the file is missing (the caller's own error class).
    what : what the file is, for that message (``"{path}: {what} not found"``).

    Raises
    ------
    error
        At once (not on the first iteration) when ``path`` is not a file.
    """
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: {what} not found")
    return _records(path)


def _records(path: Path) -> Iterator[tuple[int, str, list[str]]]:
    with path.open("r", encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, start=1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            yield lineno, s, s.replace(",", " ").split()
