"""Zhang et al.'s rule: semantic levels decide, geometry checks the a-priori static.

Zhang et al. (IJGI 2023, Zhang et al. 2023, Sec. 4) sort detected objects into three dynamic levels.
"Dynamic objects ... were directly removed when they were in high and medium dynamic boxes.
For those dynamic objects with prior static, the algorithm ... uses geometric constraints to
eliminate them": a keypoint on a low-level (a-priori static) object, or on no object, is
dynamic only when the epipolar check (eqs. 16-17, :mod:`.epipolar`) flags it. So::

    dynamic = level in {high, medium}  or  geometric_violation

The level tables (which class is high, medium, low) are in :mod:`dynslam_lab.detection.coco`
(the paper names the levels but not their members; the split there is our reading).
"""

from __future__ import annotations

import numpy as np

from .semantic import LEVEL_CODES

__all__ = ["level_rule_verdict"]


def level_rule_verdict(level: np.ndarray, geometric: np.ndarray) -> np.ndarray:
    """The verdict of Zhang et al.'s rule.

    Parameters
    ----------
    level : ``(N,)`` int level codes (:data:`~dynslam_lab.dynamic.semantic.LEVEL_CODES`:
        0 none, 1 low, 2 medium, 3 high).
    geometric : ``(N,)`` bool, a geometric check (epipolar / multi-view) flags the keypoint.

    Returns
    -------
    ``(N,)`` bool: removed directly (high/medium) or by geometry (everything else).
    """
    level = np.asarray(level).reshape(-1)
    geometric = np.asarray(geometric, bool).reshape(-1)
    if level.shape != geometric.shape:
        raise ValueError(f"level_rule_verdict: level has {level.shape[0]} rows, geometric {geometric.shape[0]}")
    if level.size and (level.min() < 0 or level.max() > 3):
        raise ValueError("level_rule_verdict: level codes must be 0 (none), 1 (low), 2 (medium) or 3 (high)")
    return (level >= LEVEL_CODES["medium"]) | geometric
