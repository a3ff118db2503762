"""Matching binary ORB descriptors: Hamming distance, ratio test, orientation consistency,
and matching by projection.

The distance between two 256-bit descriptors is the number of differing bits (Hamming
distance, 0..256). ORB-SLAM2 (Mur-Artal and Tardos, T-RO 2017; ``ORBmatcher.cc``) accepts a
match when

* the best distance is below ``TH_LOW = 50`` (``TH_HIGH = 100`` when matching by projection),
* the best is clearly better than the second best, ``d1 < ratio * d2`` (Lowe's ratio test,
  ``ratio`` 0.6-0.9 depending on the caller),
* the rotation between the two keypoints, ``angle_b - angle_a``, falls into one of the three
  most populated bins of a 30-bin histogram over 360 degrees (a rigid camera motion turns all
  keypoints by about the same angle), and
* for matching by projection, the keypoint lies within a radius of the projected point that
  grows with the predicted pyramid level (``r = th * scale_factor**level``) and was found on a
  level within one of the predicted one.

Everything is vectorised: ``cv2.batchDistance`` finds the two nearest descriptors of each row
in C++, ``numpy.bitwise_count`` on 64-bit words gives Hamming distances of candidate pairs,
and ``scipy.spatial.cKDTree.sparse_distance_matrix`` lists the (projected point, keypoint)
pairs within the search radius.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "TH_LOW",
    "TH_HIGH",
    "check_descriptors",
    "hamming_words",
    "hamming_distance",
    "hamming_pairs",
    "knn2",
    "match_descriptors",
    "orientation_consistent",
    "search_by_projection",
    "Matches",
]

TH_LOW = 50  # ORB-SLAM2 ORBmatcher::TH_LOW, bits
TH_HIGH = 100  # ORB-SLAM2 ORBmatcher::TH_HIGH, bits


def check_descriptors(d: np.ndarray, name: str) -> np.ndarray:
    """``d`` as a C-contiguous ``(N, 32)`` uint8 array of ORB descriptors; a ``ValueError``
    naming ``name`` for any other shape or type."""
    d = np.ascontiguousarray(d)
    if d.ndim != 2 or d.shape[1] != 32 or d.dtype != np.uint8:
        raise ValueError(f"{name}: expected ORB descriptors (N, 32) uint8, got shape {d.shape} dtype {d.dtype}")
    return d


def hamming_words(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamming distances of descriptors viewed as 64-bit words (``(..., 4)`` uint64, broadcast):
    the popcount of ``a ^ b`` summed over the last axis, int32. The one kernel behind
    :func:`hamming_distance` and :func:`hamming_pairs`."""
    return np.bitwise_count(a ^ b).sum(axis=-1, dtype=np.int32)


def hamming_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """All pairwise Hamming distances ``(N, M)`` int32 between descriptors ``a (N, 32)`` and
    ``b (M, 32)`` uint8. Memory ``N*M*32`` bytes: meant for small sets, checks and cluster
    centres; use :func:`knn2` for nearest neighbours of large sets."""
    a = check_descriptors(a, "hamming_distance a").view(np.uint64)
    b = check_descriptors(b, "hamming_distance b").view(np.uint64)
    return hamming_words(a[:, None, :], b[None, :, :])


def hamming_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise Hamming distances ``(K,)`` int32 between ``a[k]`` and ``b[k]`` (both ``(K, 32)``)."""
    a = check_descriptors(a, "hamming_pairs a")
    b = check_descriptors(b, "hamming_pairs b")
    if a.shape != b.shape:
        raise ValueError(f"hamming_pairs: shapes differ, {a.shape} vs {b.shape}")
    return hamming_words(a.view(np.uint64), b.view(np.uint64))


def knn2(query: np.ndarray, train: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two nearest ``train`` descriptors of each ``query`` descriptor (Hamming).

    Returns ``(dist (N, 2) int32, idx (N, 2) int64)``; with a single train descriptor the second
    column is ``(256, -1)``.
    """
    query = check_descriptors(query, "knn2 query")
    train = check_descriptors(train, "knn2 train")
    n = len(query)
    if n == 0 or len(train) == 0:
        return np.full((n, 2), 256, np.int32), np.full((n, 2), -1, np.int64)
    k = min(2, len(train))
    dist, idx = cv2.batchDistance(query, train, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=k)
    dist = dist.astype(np.int32).reshape(n, k)
    idx = idx.astype(np.int64).reshape(n, k)
    if k == 1:
        dist = np.hstack([dist, np.full((n, 1), 256, np.int32)])
        idx = np.hstack([idx, np.full((n, 1), -1, np.int64)])
    return dist, idx


def orientation_consistent(angle_a: np.ndarray, angle_b: np.ndarray, n_bins: int = 30, keep_bins: int = 3) -> np.ndarray:
    """Boolean ``(K,)``: the rotation ``angle_b - angle_a`` (degrees) of each match falls into one
    of the ``keep_bins`` most populated bins of an ``n_bins`` histogram over 360 degrees.

    As ORB-SLAM2's ``ComputeThreeMaxima``, the second and third bins count only when they hold
    at least 10 % of the first bin's matches.
    """
    rot = np.mod(np.asarray(angle_b, float) - np.asarray(angle_a, float), 360.0)
    if rot.size == 0:
        return np.zeros(0, bool)
    bins = np.minimum((rot * n_bins / 360.0).astype(np.int64), n_bins - 1)
    counts = np.bincount(bins, minlength=n_bins)
    top = np.argsort(-counts, kind="stable")[:keep_bins]
    good = top[counts[top] >= 0.1 * counts[top[0]]]
    good = good[counts[good] > 0]
    return np.isin(bins, good)


@dataclass
class Matches:
    """Index pairs ``(K,)`` into two sets, and their Hamming distances ``(K,)``."""

    idx_a: np.ndarray
    idx_b: np.ndarray
    distance: np.ndarray

    def __len__(self) -> int:
        return len(self.idx_a)

    def select(self, keep: np.ndarray) -> "Matches":
        return Matches(self.idx_a[keep], self.idx_b[keep], self.distance[keep])


def _unique_best(idx_a: np.ndarray, idx_b: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Indices of pairs kept so that each ``idx_b`` appears once (the one with the lowest distance)."""
    if len(idx_b) == 0:
        return np.zeros(0, np.int64)
    order = np.lexsort((idx_a, dist, idx_b))
    first = np.ones(len(order), bool)
    first[1:] = idx_b[order][1:] != idx_b[order][:-1]
    return np.sort(order[first])


def match_descriptors(
    desc_a: np.ndarray,
    desc_b: np.ndarray,
    ratio: float = 0.8,
    max_distance: int = TH_LOW,
    angle_a: np.ndarray | None = None,
    angle_b: np.ndarray | None = None,
    cross_check: bool = False,
) -> Matches:
    """Brute-force match descriptors ``a (N, 32)`` to ``b (M, 32)``.

    A pair ``(i, j)`` is kept when ``j`` is the nearest neighbour of ``i`` with distance
    ``<= max_distance`` and ``d1 < ratio * d2``; each ``j`` is used once (lowest distance wins);
    with angles given, only rotation-consistent matches stay (:func:`orientation_consistent`);
    with ``cross_check`` also ``i`` must be the nearest neighbour of ``j``.
    """
    if not 0 < ratio <= 1:
        raise ValueError(f"match_descriptors: ratio must be in (0, 1], got {ratio}")
    dist, idx = knn2(desc_a, desc_b)
    ia = np.arange(len(dist))
    ok = (idx[:, 0] >= 0) & (dist[:, 0] <= max_distance) & (dist[:, 0] < ratio * dist[:, 1])
    m = Matches(ia[ok], idx[ok, 0], dist[ok, 0])
    m = m.select(_unique_best(m.idx_a, m.idx_b, m.distance))
    if cross_check and len(m):
        _, back = knn2(desc_b[m.idx_b], desc_a)
        m = m.select(back[:, 0] == m.idx_a)
    if angle_a is not None and angle_b is not None and len(m):
        m = m.select(orientation_consistent(np.asarray(angle_a)[m.idx_a], np.asarray(angle_b)[m.idx_b]))
    return m


def search_by_projection(
    proj_uv: np.ndarray,
    proj_desc: np.ndarray,
    radius: np.ndarray,
    pred_level: np.ndarray | None,
    kp_uv: np.ndarray,
    kp_octave: np.ndarray,
    kp_desc: np.ndarray,
    kp_available: np.ndarray | None = None,
    max_distance: int = TH_HIGH,
    ratio: float = 0.8,
    level_window: int = 1,
    ratio_any_level: bool = False,
    pred_depth: np.ndarray | None = None,
    kp_depth: np.ndarray | None = None,
    depth_tolerance: float = 0.0,
) -> Matches:
    """Match projected map points to keypoints near their projections (vectorised).

    Parameters
    ----------
    proj_uv : ``(M, 2)`` predicted pixels of the map points.
    proj_desc : ``(M, 32)`` uint8 map point descriptors.
    radius : ``(M,)`` search radius per point (px).
    pred_level : ``(M,)`` predicted pyramid level, or None for no level constraint.
    kp_uv, kp_octave, kp_desc : keypoints of the frame ``(N, 2)``, ``(N,)``, ``(N, 32)``.
    kp_available : ``(N,)`` bool, keypoints that may be matched (e.g. static and unmatched).
    max_distance : largest accepted Hamming distance (``TH_HIGH`` = 100).
    ratio : best / second-best distance ratio, tested when both candidates are on the same
        level as in ORB-SLAM2's ``SearchByProjection``.
    level_window : accepted ``|octave - pred_level|``.
    ratio_any_level : test the ratio against the second-best candidate on any level (ours: on a
        repeated pattern the neighbouring copy of a feature is the second candidate, often found on
        another level, and the nearest descriptor is then a coin toss; such a point is left out).
    pred_depth, kp_depth, depth_tolerance : with ``depth_tolerance > 0``, a pair is a candidate only
        when the keypoint's measured depth (``kp_depth (N,)``, m, <= 0 or NaN = missing) is within
        ``depth_tolerance * pred_depth`` of the point's predicted depth (``pred_depth (M,)``, m) (ours,
        RGB-D: a copy of a pattern on another surface has another depth).

    Returns
    -------
    Matches with ``idx_a`` into the map points and ``idx_b`` into the keypoints; each keypoint
    matched at most once.
    """
    proj_uv = np.asarray(proj_uv, float).reshape(-1, 2)
    kp_uv = np.asarray(kp_uv, float).reshape(-1, 2)
    radius = np.broadcast_to(np.asarray(radius, float), (len(proj_uv),))
    empty = Matches(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int32))
    if len(proj_uv) == 0 or len(kp_uv) == 0:
        return empty
    avail = np.ones(len(kp_uv), bool) if kp_available is None else np.asarray(kp_available, bool)
    kp_idx = np.flatnonzero(avail)
    if len(kp_idx) == 0:
        return empty
    pairs = cKDTree(proj_uv).sparse_distance_matrix(cKDTree(kp_uv[kp_idx]), float(radius.max()), output_type="ndarray")
    if len(pairs) == 0:
        return empty
    ia = pairs["i"].astype(np.int64)
    ib = kp_idx[pairs["j"].astype(np.int64)]
    ok = pairs["v"] <= radius[ia]
    if pred_level is not None:
        pl = np.asarray(pred_level)
        ok &= np.abs(np.asarray(kp_octave)[ib] - pl[ia]) <= level_window
    if depth_tolerance > 0 and pred_depth is not None and kp_depth is not None:
        zk = np.asarray(kp_depth, float)[ib]
        zp = np.asarray(pred_depth, float)[ia]
        has = np.isfinite(zk) & (zk > 0)
        ok &= ~has | (np.abs(zk - zp) <= depth_tolerance * zp)
    ia, ib = ia[ok], ib[ok]
    if len(ia) == 0:
        return empty
    d = hamming_pairs(np.asarray(proj_desc)[ia], np.asarray(kp_desc)[ib])
    # Best and second best candidate per map point.
    order = np.lexsort((d, ia))
    ia, ib, d = ia[order], ib[order], d[order]
    first = np.ones(len(ia), bool)
    first[1:] = ia[1:] != ia[:-1]
    best = np.flatnonzero(first)
    has_second = np.zeros(len(best), bool)
    nxt = best + 1
    in_range = nxt < len(ia)
    has_second[in_range] = ia[np.minimum(nxt, len(ia) - 1)][in_range] == ia[best][in_range]
    second_d = np.full(len(best), 256, np.int32)
    second_d[has_second] = d[nxt[has_second]]
    oct_k = np.asarray(kp_octave)
    same_level = np.zeros(len(best), bool)
    if ratio_any_level:
        same_level[has_second] = True
    else:
        same_level[has_second] = oct_k[ib[best][has_second]] == oct_k[ib[nxt[has_second]]]
    ok = d[best] <= max_distance
    ok &= ~(same_level & (d[best] > ratio * second_d))
    best = best[ok]
    m = Matches(ia[best], ib[best], d[best])
    return m.select(_unique_best(m.idx_a, m.idx_b, m.distance))
