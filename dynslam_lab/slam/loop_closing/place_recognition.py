"""Place recognition measured as DBoW2's paper does: precision and recall of loop candidates.

Galvez-Lopez and Tardos 2012 (DBoW2, Sec. VI) score a vocabulary by what it proposes on sequences
with known revisits: every image ``t`` is queried against the images seen before it (those of the
last ``min_gap`` seconds excluded, the temporal neighbours), the best-scoring earlier image is the
*candidate*, and the candidate counts when its score passes a threshold ``alpha``. A candidate is a
true loop when the two camera poses are close (ground truth); precision is the share of counted
candidates that are true, recall the share of the images that *have* a true earlier match whose
candidate is counted and true. Sweeping ``alpha`` gives the precision-recall curve; DBoW2 reports
the recall at 100 % precision. As DBoW2 does, the score is normalised by the score of the image
with its predecessor, ``eta = s(v_t, v_j) / s(v_t, v_{t-1})`` (:func:`normalised_scores`), so one
threshold fits images with few and with many words.

Functions here work on one sequence: :func:`sequence_bows` (bag-of-words vectors of a frame
subset, static keypoints only), :func:`similarity_matrix`, :func:`revisit_truth` (pairs of frames
whose true poses are within ``max_distance`` m and ``max_angle`` degrees), :func:`best_candidates`
and :func:`precision_recall`. Notebook 08 plots the similarity matrix and the curves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...features.orb import OrbConfig, extract_features
from ...geometry.se3 import se3_inv
from ..vocabulary import BowVector, Vocabulary, bow_score_many

__all__ = [
    "sequence_bows",
    "similarity_matrix",
    "revisit_truth",
    "normalised_scores",
    "best_candidates",
    "PrecisionRecall",
    "precision_recall",
]


def sequence_bows(sequence, vocabulary: Vocabulary, stride: int = 5, n_features: int = 1000,
                  max_frames: int | None = None) -> tuple[np.ndarray, list[BowVector]]:
    """BoW vectors of every ``stride``-th frame of ``sequence`` (static keypoints: instance masks of
    synthetic scenes are left out where present). Returns ``(frame indices (F,), vectors)``."""
    idx = np.arange(0, len(sequence), stride)
    if max_frames is not None:
        idx = idx[:max_frames]
    bows = []
    for i in idx.tolist():  # one ORB extraction per frame
        frame = sequence[i]
        dyn = frame.dynamic_mask()
        mask = None if dyn is None else (~dyn).astype(np.uint8)
        d = extract_features(frame.gray, OrbConfig(n_features=n_features), mask=mask).descriptors
        bows.append(vocabulary.bow(d))
    return idx, bows


def similarity_matrix(bows: list[BowVector], vocabulary: Vocabulary) -> np.ndarray:
    """``(F, F)`` L1 scores (DBoW2 eq. 2) between all frames."""
    return bow_score_many(bows, vocabulary.n_words)


def revisit_truth(poses: np.ndarray, max_distance: float = 0.5, max_angle: float = 30.0) -> np.ndarray:
    """``(F, F)`` bool: true poses ``T_w_c (F, 4, 4)`` within ``max_distance`` m and ``max_angle`` degrees
    of viewing direction (the angle between the optical axes), so the views overlap."""
    P = np.asarray(poses, float)
    c = P[:, :3, 3]
    z = P[:, :3, 2]
    dist = np.linalg.norm(c[:, None, :] - c[None, :, :], axis=2)
    cos = np.clip(z @ z.T, -1.0, 1.0)
    return (dist <= max_distance) & (np.degrees(np.arccos(cos)) <= max_angle)


def normalised_scores(S: np.ndarray) -> np.ndarray:
    """``eta[t, j] = S[t, j] / S[t, t-1]`` (DBoW2's normalisation by the predecessor); row 0 and rows
    whose predecessor score is 0 are 0."""
    S = np.asarray(S, float)
    prev = np.zeros(len(S))
    prev[1:] = S[np.arange(1, len(S)), np.arange(len(S) - 1)]
    out = np.zeros_like(S)
    ok = prev > 0
    out[ok] = S[ok] / prev[ok, None]
    return out


def best_candidates(S: np.ndarray, timestamps: np.ndarray, min_gap: float) -> tuple[np.ndarray, np.ndarray]:
    """For each frame ``t``, the earlier frame ``j`` (at least ``min_gap`` seconds before) with the
    highest score, and that score; ``-1`` / 0 where there is none."""
    ts = np.asarray(timestamps, float)
    allowed = ts[None, :] <= ts[:, None] - min_gap
    masked = np.where(allowed, S, -np.inf)
    j = np.argmax(masked, axis=1)
    has = np.isfinite(masked[np.arange(len(S)), j])
    return np.where(has, j, -1), np.where(has, masked[np.arange(len(S)), j], 0.0)


@dataclass(frozen=True)
class PrecisionRecall:
    """The curve over thresholds ``alpha``; ``recall_at_full_precision`` is DBoW2's headline number;
    ``n_queries_with_revisit`` the frames that have a true earlier match (the recall's denominator)."""

    alpha: np.ndarray
    precision: np.ndarray
    recall: np.ndarray
    recall_at_full_precision: float
    average_precision: float
    n_queries_with_revisit: int


def precision_recall(S: np.ndarray, truth: np.ndarray, timestamps: np.ndarray, min_gap: float = 3.0,
                     normalise: bool = True) -> PrecisionRecall:
    """Precision/recall of the best earlier candidate of every frame as the threshold sweeps.

    Parameters
    ----------
    S : ``(F, F)`` similarity matrix; truth : ``(F, F)`` bool revisits (:func:`revisit_truth`);
    timestamps : ``(F,)`` seconds; min_gap : temporal neighbours excluded (s);
    normalise : threshold the normalised score ``eta`` (DBoW2) rather than the raw score.
    """
    ts = np.asarray(timestamps, float)
    allowed = ts[None, :] <= ts[:, None] - min_gap
    score = normalised_scores(S) if normalise else np.asarray(S, float)
    j, s = best_candidates(score, ts, min_gap)
    has_revisit = np.any(truth & allowed, axis=1)
    q = np.flatnonzero(j >= 0)
    correct = np.zeros(len(S), bool)
    correct[q] = truth[q, j[q]]
    alphas = np.unique(np.concatenate([[np.inf], s[q]]))[::-1]
    prec, rec = [], []
    for a in alphas.tolist():  # one threshold per distinct candidate score (a few hundred)
        counted = (j >= 0) & (s >= a)
        n = int(counted.sum())
        tp = int((counted & correct).sum())
        prec.append(1.0 if n == 0 else tp / n)
        rec.append(0.0 if not has_revisit.any() else tp / int(has_revisit.sum()))
    prec, rec = np.asarray(prec), np.asarray(rec)
    full = rec[prec >= 1.0 - 1e-12]
    # average precision: precision integrated over recall steps
    ap = float(np.sum(np.diff(np.concatenate([[0.0], rec])) * prec))
    return PrecisionRecall(alphas, prec, rec, float(full.max()) if len(full) else 0.0, ap, int(has_revisit.sum()))
