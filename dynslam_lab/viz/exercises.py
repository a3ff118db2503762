"""Checks for the notebooks' exercises.

An exercise cell holds the reader's answer, ``None`` until they write one; the cell after it
calls :func:`check`, which says "not answered yet" for ``None`` and otherwise *asserts* the
answer (against a value the check cell computes with the library, or a test function). The
solutions are in ``notebooks/solutions/NN_name.py`` (``docs/notebooks.md``).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

__all__ = ["check"]


def check(exercise: str, answer: Any, expected: Any = None, *, test: Callable[[Any], bool] | None = None,
          rtol: float = 1e-6, atol: float = 1e-9, hint: str = "") -> None:
    """Assert the reader's ``answer`` to ``exercise``; only a note while it is ``None``.

    Parameters
    ----------
    exercise : the exercise's id, e.g. ``"04.1"``.
    answer : the reader's value (number, array, string ...), or None when not answered.
    expected : the right value; numbers and arrays compare with ``numpy.allclose(rtol, atol)``
        (same shape), anything else with ``==``.
    test : instead of ``expected``: a function of the answer that is True when it is right.
    hint : said when the answer is wrong.

    Raises
    ------
    AssertionError : the answer is wrong (the message names the exercise and gives the hint).
    """
    if answer is None:
        print(f"Exercise {exercise}: not answered yet (replace the None above; the solution is in "
              f"notebooks/solutions/)")
        return
    if test is not None:
        ok = bool(test(answer))
    elif isinstance(expected, (int, float, np.number, np.ndarray, list, tuple)) and not isinstance(expected, bool):
        a, e = np.asarray(answer, dtype=float), np.asarray(expected, dtype=float)
        ok = a.shape == e.shape and bool(np.allclose(a, e, rtol=rtol, atol=atol, equal_nan=True))
    else:
        ok = answer == expected
    assert ok, f"Exercise {exercise}: {answer!r} is not right" + (f" ({hint})" if hint else "")
    print(f"Exercise {exercise}: correct")
