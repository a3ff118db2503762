"""Two-view epipolar geometry: the distance of a pixel to its epipolar line.

A static scene point seen at ``p1`` in one image and ``p2`` in another satisfies
``p2^T F p1 = 0`` for the fundamental matrix ``F`` of the image pair (Hartley and Zisserman
2004, Sec. 9.2). ``p2`` must lie on the epipolar line ``l2 = F p1``; its distance to that
line (Zhang et al. 2023, eqs. 16-17; Chang et al. 2021, eq. 1; Ge et al. 2024, Sec. 2.3)::

    l2 = (a, b, c)^T = F p1                                              (16)
    d  = |p2^T l2| / sqrt(a^2 + b^2)                                     (17)
"""

from __future__ import annotations

import numpy as np

__all__ = ["epipolar_distance"]


def _pixels(p: np.ndarray, name: str) -> np.ndarray:
    p = np.asarray(p, np.float64)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"epipolar_distance: {name} must have shape (N, 2) (pixel x, y), got {p.shape}")
    return p


def epipolar_distance(F: np.ndarray, p_prev: np.ndarray, p_cur: np.ndarray) -> np.ndarray:
    """Eqs. 16-17: distance (px) of ``p_cur (N, 2)`` to the epipolar line ``F p_prev``."""
    F = np.asarray(F, np.float64)
    if F.shape != (3, 3):
        raise ValueError(f"epipolar_distance: F must be (3, 3), got {F.shape}")
    p1 = _pixels(p_prev, "p_prev")
    p2 = _pixels(p_cur, "p_cur")
    if len(p1) != len(p2):
        raise ValueError(f"epipolar_distance: {len(p1)} previous and {len(p2)} current pixels")
    h1 = np.column_stack([p1, np.ones(len(p1))])
    h2 = np.column_stack([p2, np.ones(len(p2))])
    lines = h1 @ F.T  # (N, 3): l2 = F p1 for every row
    num = np.abs(np.sum(h2 * lines, axis=1))
    return num / np.sqrt(lines[:, 0] ** 2 + lines[:, 1] ** 2)
