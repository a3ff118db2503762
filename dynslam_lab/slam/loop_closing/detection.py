"""Loop detection: candidates from the keyframe database, then temporal consistency (ORB-SLAM2 ``DetectLoop``).

ORB-SLAM2 (Mur-Artal and Tardos 2017, Sec. V; ORB-SLAM, T-RO 2015, Sec. VII-A), for each new
keyframe ``K_i``:

1. ``s_min``: the lowest bag-of-words score (DBoW2, Galvez-Lopez and Tardos 2012, eq. 2) between
   ``K_i`` and its *connected* keyframes (covisibility weight ``>= 15``). Only *static* keypoints
   enter the vectors (:func:`~dynslam_lab.slam.keyframe_database.static_bow`): a person walking
   through two views must not make them look alike.
2. The keyframe database returns the keyframes not covisible with ``K_i`` that score at least
   ``s_min`` and share enough words, grouped with their covisible neighbours
   (:meth:`~dynslam_lab.slam.keyframe_database.KeyframeDatabase.detect_loop_candidates`).
3. **Consistency**: a candidate counts only when its group (it and its connected keyframes) shares
   a keyframe with a candidate group of the previous keyframe, for ``consistency_threshold = 3``
   keyframes in a row (:func:`consistent_candidates`).
"""

from __future__ import annotations

import numpy as np

from ..keyframe_database import KeyframeDatabase, LoopCandidate
from ..vocabulary import BowVector, bow_score
from .config import LoopClosingConfig

__all__ = ["consistent_candidates", "LoopDetector"]


def consistent_candidates(
    candidate_groups: dict[int, set[int]],
    previous: list[tuple[set[int], int]],
    threshold: int,
) -> tuple[list[int], list[tuple[set[int], int]]]:
    """The consistency check of ORB-SLAM2's ``DetectLoop`` (Sec. VII-A).

    Parameters
    ----------
    candidate_groups : candidate keyframe id -> its group (itself and its covisible keyframes).
    previous : the consistent groups of the previous keyframe, ``(group, consistency)``.
    threshold : consistency needed (3).

    Returns
    -------
    (accepted candidate ids, consistent groups to keep for the next keyframe). A candidate
    whose group shares a keyframe with a previous group continues that group's count (+1); one
    that shares none starts a new group at 0.
    """
    accepted: list[int] = []
    current: list[tuple[set[int], int]] = []
    used_prev = [False] * len(previous)
    for cand, group in candidate_groups.items():  # few candidates, few groups
        enough = False
        consistent = False
        for g, (prev_group, prev_count) in enumerate(previous):
            if group & prev_group:
                consistent = True
                count = prev_count + 1
                if not used_prev[g]:
                    current.append((group, count))
                    used_prev[g] = True
                if count >= threshold and not enough:
                    accepted.append(cand)
                    enough = True
        if not consistent:
            current.append((group, 0))
    return accepted, current


class LoopDetector:
    """Steps 1-3 for one keyframe at a time; keeps the consistent groups between keyframes.

    Parameters
    ----------
    config : thresholds.
    database : the keyframe database queried (the caller adds each keyframe after the query).

    Attributes
    ----------
    last_candidates : the database's candidates for the last keyframe (for notebooks).
    last_covisibility : keyframe id -> covisibility (``Map.covisibility``) of the last query's keyframe
        (what verification is frozen with; the candidates' come from the map's cache).
    """

    def __init__(self, config: LoopClosingConfig, database: KeyframeDatabase) -> None:
        self.config = config
        self.database = database
        self.last_candidates: list[LoopCandidate] = []
        self.last_covisibility: dict[int, dict[int, int]] = {}
        self._groups: list[tuple[set[int], int]] = []

    def reset(self) -> None:
        """Forget the consistent groups (after a loop is closed, as ORB-SLAM2)."""
        self._groups = []

    def detect(self, kf, mp, bow: BowVector) -> list[int]:
        """Ids of the candidates of keyframe ``kf`` (in map ``mp``) that passed consistency, best first."""
        cfg = self.config
        self.last_candidates = []
        cov = mp.covisibility(kf.id)
        self.last_covisibility = {kf.id: cov}
        strong = [k for k, w in cov.items() if w >= cfg.min_neighbour_weight and k in self.database]
        if not strong:
            self._groups = []
            return []
        min_score = min(bow_score(bow, self.database.bow(k)) for k in strong)  # a few neighbours
        # the map caches each keyframe's covisible keyframes in weight order: no dictionary or sort here

        def connected(i: int) -> list[int]:  # ORB-SLAM2 GetConnectedKeyFrames: weight >= 15 (else the best one)
            if i not in mp.keyframes:
                return []
            return mp.best_covisibles(i, None, cfg.min_neighbour_weight) or mp.best_covisibles(i, 1)

        def best(i: int) -> list[int]:
            return mp.best_covisibles(i, cfg.query.group_size) if i in mp.keyframes else []

        # ORB-SLAM2 excludes the connected keyframes (weight >= 15); "covisible" excludes any that
        # shares a point (stricter: fewer candidates near the query, but a few old points matched
        # again near a revisit hide the loop keyframe)
        excluded = set(cov) if cfg.exclude == "covisible" else set(connected(kf.id))
        cands = self.database.detect_loop_candidates(
            bow, exclude=excluded | {kf.id}, min_score=min_score, neighbours=best, config=cfg.query
        )
        self.last_candidates = cands
        if not cands:
            self._groups = []
            return []
        groups = {c.kf_id: {c.kf_id} | set(connected(c.kf_id)) for c in cands}
        accepted, self._groups = consistent_candidates(groups, self._groups, cfg.consistency_threshold)
        return [int(a) for a in np.asarray(accepted, np.int64)]
