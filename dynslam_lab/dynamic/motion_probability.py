"""Motion-probability restoration (ASG-SLAM, Ge et al. 2024, Ge et al. 2024, Sec. 2.4, eq. 3).

Removing every keypoint on a potentially moving object can leave too few for tracking (a
person filling the view, a desk full of cups and keyboards). ASG-SLAM grades COCO classes into
six categories of increasing prior motion probability (public facilities < household and office
items < vehicles < personal belongings < humans < animals) and watches the static ratio::

    delta = m / n                                                         (3)

with ``m`` the static keypoints of the frame and ``n`` all keypoints. While ``delta < delta_1``,
"feature points that were excluded from potentially moving objects are progressively restored
in order of increasing motion probability until the proportion of static feature points reaches
or exceeds delta_1".

Our reading:

* restoration works class group by class group: all excluded keypoints of the least probable
  motion probability come back at once, then the next, and so on (ties share a group);
* only keypoints excluded by the *semantic prior alone* can come back; a keypoint that a
  geometric test (epipolar, multi-view, flow) found moving stays out (``veto``), because the
  restoration is about prior belief, not about evidence of motion;
* the paper gives no value for ``delta_1``; the default 0.3 restores only when fewer than 30% of
  the keypoints are left.

The probabilities are in :mod:`dynslam_lab.detection.coco` (``ASG_PROBABILITIES``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["RestorationConfig", "RestorationResult", "static_ratio", "restore_by_motion_probability"]


@dataclass(frozen=True)
class RestorationConfig:
    """Parameters of motion-probability restoration (ASG-SLAM, Ge et al. 2024, Sec. 2.4)."""

    delta_1: float = 0.3  # static-ratio threshold delta_1 of eq. 3 (0..1); not given in the paper, ours 0.3
    geometric_veto: bool = True  # never restore a keypoint a geometric test flagged; ours, True

    def __post_init__(self) -> None:
        if not 0 <= self.delta_1 <= 1:
            raise ValueError(f"RestorationConfig.delta_1 must be in [0, 1], got {self.delta_1}")


@dataclass
class RestorationResult:
    """Output of :func:`restore_by_motion_probability`.

    Attributes
    ----------
    restored : ``(N,)`` bool keypoints given back.
    delta_before, delta_after : static ratio (eq. 3) before and after.
    groups : motion probabilities restored, in order.
    """

    restored: np.ndarray
    delta_before: float
    delta_after: float
    groups: list[float]


def static_ratio(dynamic: np.ndarray) -> float:
    """Eq. 3: ``delta = m / n`` (1.0 for a frame without keypoints)."""
    dynamic = np.asarray(dynamic, bool).reshape(-1)
    n = len(dynamic)
    return 1.0 if n == 0 else float((~dynamic).sum()) / n


def restore_by_motion_probability(
    dynamic: np.ndarray,
    semantic: np.ndarray,
    motion_prob: np.ndarray,
    veto: np.ndarray | None = None,
    config: RestorationConfig = RestorationConfig(),
) -> RestorationResult:
    """Give back excluded keypoints, least probable movers first, until ``delta >= delta_1``.

    Parameters
    ----------
    dynamic : ``(N,)`` bool verdict before restoration.
    semantic : ``(N,)`` bool, excluded by the semantic prior (restorable).
    motion_prob : ``(N,)`` prior motion probability of each keypoint's class (0..1).
    veto : ``(N,)`` bool geometric evidence of motion (never restored when ``config.geometric_veto``).
    config : ``delta_1`` and the veto switch.
    """
    dynamic = np.asarray(dynamic, bool).reshape(-1)
    n = len(dynamic)
    semantic = np.asarray(semantic, bool).reshape(-1)
    motion_prob = np.asarray(motion_prob, np.float64).reshape(-1)
    veto = np.zeros(n, bool) if veto is None else np.asarray(veto, bool).reshape(-1)
    for name, arr in (("semantic", semantic), ("motion_prob", motion_prob), ("veto", veto)):
        if len(arr) != n:
            raise ValueError(f"restore_by_motion_probability: {name} has {len(arr)} rows, dynamic has {n}")
    restored = np.zeros(n, bool)
    before = static_ratio(dynamic)
    candidates = dynamic & semantic
    if config.geometric_veto:
        candidates &= ~veto
    groups: list[float] = []
    current = dynamic.copy()
    for p in np.unique(motion_prob[candidates]):  # ascending motion probability (<= 6 categories)
        if static_ratio(current) >= config.delta_1:
            break
        group = candidates & (motion_prob == p)
        restored |= group
        current &= ~group
        groups.append(float(p))
    return RestorationResult(restored, before, static_ratio(current), groups)
