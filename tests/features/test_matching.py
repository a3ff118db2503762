"""Descriptor matching: Hamming distances against a bit-unpacking reference, ratio test,
orientation consistency, matching by projection."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.features.matching import (
    hamming_distance,
    hamming_pairs,
    knn2,
    match_descriptors,
    orientation_consistent,
    search_by_projection,
)


def _ref_hamming(a, b):
    """Independent reference: unpack bits and count differences."""
    return (np.unpackbits(a[:, None, :], axis=-1) != np.unpackbits(b[None, :, :], axis=-1)).sum(-1)


def _flip(desc, n_bits, rng):
    out = desc.copy()
    bits = np.unpackbits(out, axis=1)
    for row in bits:  # test data only
        row[rng.choice(256, n_bits, replace=False)] ^= 1
    return np.packbits(bits, axis=1)


def test_hamming_matches_reference():
    rng = np.random.default_rng(1)
    a = rng.integers(0, 256, (40, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (25, 32), dtype=np.uint8)
    D = hamming_distance(a, b)
    assert D.shape == (40, 25) and np.array_equal(D, _ref_hamming(a, b))
    assert np.array_equal(hamming_pairs(a[:25], b), np.diag(_ref_hamming(a[:25], b)))
    d, i = knn2(a, b)
    R = _ref_hamming(a, b)
    assert np.array_equal(d[:, 0], R.min(1)) and np.array_equal(d[:, 1], np.sort(R, 1)[:, 1])
    assert np.array_equal(R[np.arange(40), i[:, 0]], R.min(1))


def test_match_descriptors_recovers_permutation_and_ratio_rejects_twins():
    rng = np.random.default_rng(2)
    a = rng.integers(0, 256, (200, 32), dtype=np.uint8)
    perm = rng.permutation(200)
    b = _flip(a[perm], 10, rng)  # b[j] is a[perm[j]] with 10 bits flipped
    m = match_descriptors(a, b, ratio=0.8, max_distance=50)
    assert len(m) == 200
    assert np.array_equal(perm[m.idx_b], m.idx_a)
    assert np.all(m.distance == 10)
    # a twin of a[0] in b: a[0] now has two equally good neighbours -> rejected by the ratio test
    b2 = np.vstack([b, b[np.flatnonzero(perm == 0)]])
    m2 = match_descriptors(a, b2, ratio=0.8)
    assert 0 not in m2.idx_a and len(m2) == 199
    with pytest.raises(ValueError, match="ratio"):
        match_descriptors(a, b, ratio=1.5)
    with pytest.raises(ValueError, match=r"\(N, 32\) uint8"):
        match_descriptors(a.astype(np.int32), b)


def test_orientation_consistency_flags_outliers():
    rng = np.random.default_rng(3)
    a = rng.uniform(0, 360, 300)
    b = np.mod(a + 42 + rng.normal(0, 1.5, 300), 360)  # inside one 12-degree bin
    bad = np.zeros(300, bool)
    bad[:30] = True
    b[bad] = np.mod(a[bad] + rng.uniform(90, 330, 30), 360)  # scattered rotations
    ok = orientation_consistent(a, b)
    assert ok[~bad].mean() > 0.98 and not ok[bad].any()
    # keypoints with the same descriptor but angles spread uniformly: the three top bins only
    ok2 = orientation_consistent(np.zeros(3000), rng.uniform(0, 360, 3000))
    assert 0.05 < ok2.mean() < 0.15


def test_search_by_projection_radius_level_and_uniqueness():
    rng = np.random.default_rng(4)
    n = 100
    kp_uv = rng.uniform(0, 600, (n, 2))
    kp_desc = rng.integers(0, 256, (n, 32), dtype=np.uint8)
    kp_oct = rng.integers(0, 3, n)
    # map points: projections 3 px from their keypoint, descriptors 8 bits away
    off = rng.normal(0, 1, (n, 2))
    off = 3 * off / np.linalg.norm(off, axis=1, keepdims=True)
    proj = kp_uv + off
    desc = _flip(kp_desc, 8, rng)
    m = search_by_projection(proj, desc, np.full(n, 5.0), kp_oct, kp_uv, kp_oct, kp_desc)
    assert len(m) == n and np.array_equal(m.idx_a, m.idx_b)
    # radius below the offset: no match
    assert len(search_by_projection(proj, desc, np.full(n, 2.0), kp_oct, kp_uv, kp_oct, kp_desc)) == 0
    # predicted level two away from the keypoint's octave: no match
    assert len(search_by_projection(proj, desc, 5.0, kp_oct + 2, kp_uv, kp_oct, kp_desc)) == 0
    # unavailable keypoints (e.g. dynamic) are never matched
    avail = np.arange(n) % 2 == 0
    m3 = search_by_projection(proj, desc, 5.0, None, kp_uv, kp_oct, kp_desc, kp_available=avail)
    assert np.all(avail[m3.idx_b])
    # two map points projecting onto one keypoint: it is matched once, to the closer descriptor
    proj2 = np.vstack([proj[:1], proj[:1]])
    desc2 = np.vstack([desc[:1], _flip(kp_desc[:1], 30, rng)])
    m4 = search_by_projection(proj2, desc2, 5.0, None, kp_uv, kp_oct, kp_desc)
    assert len(m4) == 1 and m4.idx_a[0] == 0 and m4.idx_b[0] == 0


def test_search_by_projection_depth_gate_and_any_level_ratio():
    """Hand-built repeated pattern: one map point, two keypoints within the radius with near-equal
    descriptors (a copy of the feature), one on another level and another surface."""
    rng = np.random.default_rng(7)
    d0 = rng.integers(0, 256, (1, 32), dtype=np.uint8)
    kp_desc = np.vstack([_flip(d0, 20, rng), _flip(d0, 21, rng)])  # distances 20 and 21 to the point
    assert list(hamming_distance(d0, kp_desc)[0]) == [20, 21]
    kp_uv = np.array([[100.0, 100.0], [106.0, 100.0]])
    kp_oct = np.array([0, 1])
    args = (np.array([[101.0, 100.0]]), d0, 10.0, np.array([0]), kp_uv, kp_oct, kp_desc)
    # ORB-SLAM2: second candidate on another level -> no ratio test, the nearer descriptor wins
    m = search_by_projection(*args, ratio=0.9)
    assert list(m.idx_b) == [0]
    # any level: 20 > 0.9 * 21, ambiguous -> left out; a looser ratio keeps it
    assert len(search_by_projection(*args, ratio=0.9, ratio_any_level=True)) == 0
    assert list(search_by_projection(*args, ratio=0.96, ratio_any_level=True).idx_b) == [0]
    # depth gate: the point is predicted at 2.0 m; keypoint 0 measures 2.5 m (25 % off), keypoint 1 2.1 m (5 %)
    gate = dict(pred_depth=np.array([2.0]), kp_depth=np.array([2.5, 2.1]))
    m = search_by_projection(*args, ratio=0.9, ratio_any_level=True, depth_tolerance=0.1, **gate)
    assert list(m.idx_b) == [1]  # the copy on the wrong surface is no candidate, so no ambiguity either
    assert list(search_by_projection(*args, ratio=0.9, ratio_any_level=True, depth_tolerance=0.3, **gate).idx_b) == []
    assert list(search_by_projection(*args, ratio=0.9, depth_tolerance=0.0, **gate).idx_b) == [0]  # 0 = off
    # a keypoint without depth (NaN or 0) is never excluded by the gate
    for missing in (np.nan, 0.0):
        m = search_by_projection(*args, ratio=0.9, depth_tolerance=0.1, pred_depth=np.array([2.0]),
                                 kp_depth=np.array([missing, 2.1]))
        assert list(m.idx_b) == [0]
