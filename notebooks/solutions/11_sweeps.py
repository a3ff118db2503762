"""Solutions of the exercises of notebooks/11_sweeps.py."""

from __future__ import annotations

import numpy as np

THR = "screening.epipolar.threshold_px"


def log_range(start, stop, num):
    """Exercise 1: ``num`` values evenly spaced in log from ``start`` to ``stop`` (both included):
    ``start * (stop / start) ** (i / (num - 1))``, which is ``numpy.geomspace``."""
    return np.geomspace(start, stop, num).tolist()


def pooled_precision(table):
    """Exercise 2: TP and FP summed over the seeds, then TP / (TP + FP), per sequence and threshold
    (NaN where nothing was flagged)."""
    counts = table.groupby(["sequence", THR])[["keypoints.tp", "keypoints.fp"]].sum()
    flagged = counts["keypoints.tp"] + counts["keypoints.fp"]
    return counts["keypoints.tp"] / flagged.where(flagged > 0)


def predict_extension():
    """Exercise 3: walking_xyz gets 3 seeds, walking_static keeps 2, and 4 values of the threshold:
    (3 + 2) x 4 = 20 runs. The runs of the first spec (2 + 2 seeds x 3 values = 12) keep their names,
    since nothing that decides them changed, so they are finished."""
    return (3 + 2) * 4, (2 + 2) * 3
