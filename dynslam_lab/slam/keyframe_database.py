"""Keyframe database with an inverted index, and loop candidates by bag-of-words score.

ORB-SLAM2 (Mur-Artal and Tardos, T-RO 2017, Sec. V-A; ORB-SLAM, T-RO 2015, Sec. VII-A,
``KeyFrameDatabase::DetectLoopCandidates``) finds loop candidates for a new keyframe ``K_i``:

1. ``s_min``: the lowest BoW similarity between ``K_i`` and its covisible neighbours
   (computed by the caller, :class:`~dynslam_lab.slam.loop_closing.LoopCloser`).
2. Through the *inverted index* (word -> keyframes containing it) list the keyframes that share
   a word with ``K_i`` and are not connected to it in the covisibility graph; count the shared
   words of each. Keep those with more than ``0.8 *`` the largest count.
3. Score them (L1 score, DBoW2 eq. 2); drop those below ``s_min``.
4. Group each survivor with its best covisible neighbours and sum the scores of the group
   members that survived step 2 (``accumulated score``); keep the best-scored keyframe of every
   group whose accumulated score exceeds ``0.75 *`` the best group's. (Scores are compared
   with covisible groups, since a single keyframe's score is noisy.)

Our reading: the inverted index is three growing arrays ``(word, keyframe, weight)``, one
entry per word of each keyframe, sorted by word now and then into posting lists (CSR:
``ptr[w] .. ptr[w+1]`` are the entries of word ``w``). A query gathers the posting lists of its
words in one vectorised pass (plus a scan of the few entries added since the last sort), so
the score of every keyframe is one ``bincount`` (the L1 score is a sum of ``min`` over shared
words).

The same query serves **relocalisation** (ORB-SLAM2 ``DetectRelocalizationCandidates``): a lost
frame's BoW vector against every keyframe, steps 2-4 without exclusion and without ``s_min``
(:meth:`KeyframeDatabase.detect_relocalisation_candidates`).
"""

from __future__ import annotations

from collections.abc import Callable, Container, Iterable
from dataclasses import dataclass

import numpy as np

from .vocabulary import BowVector

__all__ = ["KeyframeDatabase", "LoopCandidate", "CandidateQueryConfig", "static_bow"]


def static_bow(vocabulary, frame) -> BowVector:
    """BoW vector of a frame or keyframe from its *static* keypoints only (``frame.descriptors``,
    ``frame.static``): a person walking through two views must not make them look alike. What
    the database stores for a keyframe and what relocalisation queries it with."""
    static = np.asarray(frame.static, bool)
    return vocabulary.bow(np.ascontiguousarray(frame.descriptors[static]))


@dataclass(frozen=True)
class CandidateQueryConfig:
    """Thresholds of ``DetectLoopCandidates`` (ORB-SLAM2 ``KeyFrameDatabase.cc``)."""

    common_words_ratio: float = 0.8  # keep keyframes sharing > ratio * max shared words; ORB-SLAM2: 0.8
    accumulated_ratio: float = 0.75  # keep groups scoring > ratio * best group score; ORB-SLAM2: 0.75
    group_size: int = 10  # covisible neighbours grouped with a candidate; ORB-SLAM2: 10

    def __post_init__(self) -> None:
        for name in ("common_words_ratio", "accumulated_ratio"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"CandidateQueryConfig.{name} must be in [0, 1], got {v}")
        if self.group_size < 0:
            raise ValueError(f"CandidateQueryConfig.group_size must be >= 0, got {self.group_size}")


@dataclass(frozen=True)
class LoopCandidate:
    """A loop candidate: keyframe id, its own BoW score, its group's accumulated score, shared words."""

    kf_id: int
    score: float
    accumulated_score: float
    common_words: int


class KeyframeDatabase:
    """Inverted index over the BoW vectors of keyframes.

    Parameters
    ----------
    n_words : size of the vocabulary (word ids are ``0 .. n_words-1``).
    """

    def __init__(self, n_words: int):
        if n_words < 1:
            raise ValueError(f"KeyframeDatabase: n_words must be >= 1, got {n_words}")
        self.n_words = int(n_words)
        self._word = np.zeros(1024, np.int64)
        self._kf = np.zeros(1024, np.int64)
        self._weight = np.zeros(1024)
        self._size = 0
        self._max_id = -1
        # posting lists (entries sorted by word) of the first `_indexed` entries
        self._indexed = 0
        self._ptr = np.zeros(self.n_words + 1, np.int64)
        self._post_kf = np.zeros(0, np.int64)
        self._post_weight = np.zeros(0)
        self.reindex_min = 20_000  # entries scanned linearly before the first index (ours)
        self.reindex_ratio = 0.25  # re-index when new entries exceed this share of the indexed (ours)
        self._bows: dict[int, BowVector] = {}
        self._removed: set[int] = set()
        self._dense = np.zeros(self.n_words)  # scratch of scores(): the query as a dense vector

    # ------------------------------------------------------------------ content
    def __len__(self) -> int:
        return len(self._bows) - len(self._removed)

    @property
    def n_entries(self) -> int:
        """Entries ``(word, keyframe, weight)`` in the inverted index."""
        return self._size

    def __contains__(self, kf_id: int) -> bool:
        return kf_id in self._bows and kf_id not in self._removed

    def bow(self, kf_id: int) -> BowVector:
        """The BoW vector stored for a keyframe."""
        if kf_id not in self._bows:
            raise KeyError(f"keyframe {kf_id} is not in the database")
        return self._bows[kf_id]

    def ids(self) -> list[int]:
        """Ids of the keyframes in the database (not removed), in insertion order."""
        return [i for i in self._bows if i not in self._removed]

    def add(self, kf_id: int, bow: BowVector) -> None:
        """Add keyframe ``kf_id`` with its BoW vector (each id once)."""
        kf_id = int(kf_id)
        if kf_id < 0:
            raise ValueError(f"KeyframeDatabase.add: keyframe id must be >= 0, got {kf_id}")
        if kf_id in self._bows:
            raise ValueError(f"KeyframeDatabase.add: keyframe {kf_id} already added")
        if len(bow.words) and (bow.words.min() < 0 or bow.words.max() >= self.n_words):
            raise ValueError(f"KeyframeDatabase.add: word ids of keyframe {kf_id} outside [0, {self.n_words})")
        n = len(bow.words)
        if self._size + n > len(self._word):
            cap = max(2 * len(self._word), self._size + n)
            for name in ("_word", "_kf", "_weight"):
                arr = getattr(self, name)
                new = np.zeros(cap, arr.dtype)
                new[: self._size] = arr[: self._size]
                setattr(self, name, new)
        sl = slice(self._size, self._size + n)
        self._word[sl] = bow.words
        self._kf[sl] = kf_id
        self._weight[sl] = bow.weights
        self._size += n
        self._max_id = max(self._max_id, kf_id)
        self._bows[kf_id] = bow

    def prune(self, live: Container[int]) -> None:
        """Forget every keyframe not in ``live`` (the map's keyframes: the culled ones go)."""
        if hasattr(live, "keys"):  # a dict of keyframes: one set difference, no Python loop over the ids
            gone = self._bows.keys() - live.keys() - self._removed
        else:
            gone = [kf_id for kf_id in self.ids() if kf_id not in live]
        for kf_id in gone:
            self.remove(kf_id)

    def remove(self, kf_id: int) -> None:
        """Forget a keyframe (culled); its entries are skipped by later queries."""
        if kf_id in self._bows:
            self._removed.add(int(kf_id))

    # ------------------------------------------------------------------ queries
    def scores(self, bow: BowVector) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """L1 scores of ``bow`` against every keyframe that shares a word with it.

        Returns ``(kf_ids (C,), common_words (C,), scores (C,))`` sorted by keyframe id.
        """
        n = self._size
        if n == 0 or len(bow.words) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
        self._maybe_reindex()
        # indexed part: the posting lists of the query's words, gathered in one pass
        ptr = self._ptr
        start, length = ptr[bow.words], ptr[bow.words + 1] - ptr[bow.words]
        total = int(length.sum())
        offset = np.repeat(start - (np.cumsum(length) - length), length)
        idx = offset + np.arange(total)
        kf = self._post_kf[idx]
        vals = np.minimum(np.repeat(bow.weights, length), self._post_weight[idx])
        # recent entries, not indexed yet: a scan with a lookup table over the vocabulary
        if self._indexed < n:
            q = self._dense  # all zeros between queries
            q[bow.words] = bow.weights
            qw = q[self._word[self._indexed : n]]
            q[bow.words] = 0.0
            hit = np.flatnonzero(qw > 0)
            kf = np.concatenate([kf, self._kf[self._indexed + hit]])
            vals = np.concatenate([vals, np.minimum(qw[hit], self._weight[self._indexed + hit])])
        # keyframe ids are small non-negative integers: count and sum by id, no sorting
        common = np.bincount(kf, minlength=self._max_id + 1)
        score = np.bincount(kf, weights=vals, minlength=self._max_id + 1)
        if self._removed:
            common[np.fromiter(self._removed, np.int64)] = 0
        ids = np.flatnonzero(common)
        return ids, common[ids], score[ids]

    def _maybe_reindex(self) -> None:
        """Sort the entries by word (posting lists, CSR) once enough new ones have come in.

        Between re-indexings the newest entries are scanned linearly; re-indexing when they
        outnumber ``reindex_ratio`` of the indexed ones keeps both the scan and the amortised
        sort cost small.
        """
        n = self._size
        if n - self._indexed <= max(self.reindex_min, self.reindex_ratio * self._indexed):
            return
        words = self._word[:n]
        order = np.argsort(words, kind="stable")
        self._post_kf = self._kf[:n][order]
        self._post_weight = self._weight[:n][order]
        self._ptr = np.concatenate([[0], np.cumsum(np.bincount(words, minlength=self.n_words))])
        self._indexed = n

    def detect_loop_candidates(
        self,
        bow: BowVector,
        exclude: Iterable[int],
        min_score: float,
        neighbours: Callable[[int], Iterable[int]],
        config: CandidateQueryConfig = CandidateQueryConfig(),
    ) -> list[LoopCandidate]:
        """Loop candidates for a query keyframe (ORB-SLAM2 ``DetectLoopCandidates``, steps 2-4).

        Parameters
        ----------
        bow : the query keyframe's BoW vector.
        exclude : keyframe ids never returned (the query itself and its covisible neighbours).
        min_score : ``s_min``, the lowest score of the query to its covisible neighbours.
        neighbours : ``kf_id -> ids`` of its best covisible keyframes (best first); the first
            ``config.group_size`` form the candidate's group.
        config : ratios of the query.

        Returns
        -------
        list of LoopCandidate, best accumulated score first.
        """
        return self._grouped_candidates(bow, exclude, min_score, neighbours, config)

    def detect_relocalisation_candidates(
        self,
        bow: BowVector,
        neighbours: Callable[[int], Iterable[int]],
        config: CandidateQueryConfig = CandidateQueryConfig(),
        exclude: Iterable[int] = (),
    ) -> list[LoopCandidate]:
        """Keyframes a lost frame may be relocalised against (ORB-SLAM2
        ``DetectRelocalizationCandidates``; ORB-SLAM, T-RO 2015, Sec. V-C).

        The query of :meth:`detect_loop_candidates` for a *frame* instead of a keyframe: every
        keyframe sharing words with it (a lost frame has no covisible keyframes to exclude and no
        ``s_min``), those with more than ``0.8 *`` the largest number of shared words scored,
        each grouped with its best covisible keyframes, and the best keyframe of every group
        scoring above ``0.75 *`` the best group returned.

        Parameters
        ----------
        bow : BoW vector of the frame (its static keypoints).
        neighbours : ``kf_id -> ids`` of a keyframe's best covisible keyframes (best first).
        config : ratios of the query (the same as for loops in ORB-SLAM2).
        exclude : keyframe ids never returned (e.g. culled ones).

        Returns
        -------
        list of LoopCandidate, best accumulated score first.
        """
        return self._grouped_candidates(bow, exclude, 0.0, neighbours, config)

    def _grouped_candidates(
        self,
        bow: BowVector,
        exclude: Iterable[int],
        min_score: float,
        neighbours: Callable[[int], Iterable[int]],
        config: CandidateQueryConfig,
    ) -> list[LoopCandidate]:
        """Steps 2-4 shared by the loop and the relocalisation queries."""
        ids, common, score = self.scores(bow)
        excl = np.fromiter((int(e) for e in exclude), np.int64)
        keep = ~np.isin(ids, excl)
        ids, common, score = ids[keep], common[keep], score[keep]
        if len(ids) == 0:
            return []
        min_common = config.common_words_ratio * common.max()
        keep = common > min_common
        # keyframes sharing enough words: the pool the group scores are summed over
        pool = dict(zip(ids[keep].tolist(), score[keep].tolist()))
        pool_common = dict(zip(ids[keep].tolist(), common[keep].tolist()))
        cand = [(i, s) for i, s in pool.items() if s >= min_score]
        if not cand:
            return []
        groups = []
        for kf_id, s in cand:  # loop over the few candidates (typically < 20)
            acc, best_id, best_s = s, kf_id, s
            for nb in list(neighbours(kf_id))[: config.group_size]:
                if nb in pool:
                    acc += pool[nb]
                    if pool[nb] > best_s:
                        best_id, best_s = nb, pool[nb]
            groups.append((acc, best_id, best_s))
        best_acc = max(g[0] for g in groups)
        out: dict[int, LoopCandidate] = {}
        for acc, best_id, best_s in sorted(groups, key=lambda g: -g[0]):
            if acc > config.accumulated_ratio * best_acc and best_id not in out:
                out[best_id] = LoopCandidate(best_id, best_s, acc, int(pool_common[best_id]))
        return list(out.values())
