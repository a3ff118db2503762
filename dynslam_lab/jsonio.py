"""Strict JSON out: numpy values made plain, non-finite numbers written as ``null``.

Python's ``json.dumps`` writes ``NaN`` and ``Infinity`` for non-finite floats, which are not
JSON (RFC 8259): other readers (``jq``, browsers, ``json.loads(..., parse_constant=...)``)
reject the file. Everything the toolkit writes as JSON (``summary.json``, ``dynslam detect
--json``, ``dynslam eval --json``) goes through :func:`dumps`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["json_safe", "dumps"]


def json_safe(obj: Any) -> Any:
    """A copy of ``obj`` that ``json.dumps(..., allow_nan=False)`` accepts.

    Dicts, lists and tuples are converted item by item; numpy scalars and arrays become Python
    numbers and lists; non-finite floats become None; paths become strings; anything else
    unknown becomes its ``str``.
    """
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, np.generic):
        return json_safe(obj.item())
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if obj is None or isinstance(obj, (bool, int, str)):
        return obj
    if isinstance(obj, Path):
        return str(obj)
    return str(obj)


def dumps(obj: Any, **kwargs) -> str:
    """``json.dumps`` of :func:`json_safe` ``(obj)``, never emitting ``NaN``/``Infinity``."""
    return json.dumps(json_safe(obj), allow_nan=False, **kwargs)
