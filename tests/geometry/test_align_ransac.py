"""RANSAC scoring of rigid hypotheses: the matrix-product inlier test equals the distance test it replaced."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dynslam_lab.geometry.align import (
    make_pose,
    ransac_rigid_3d,
    rigid_alignment_batch,
    rigid_inliers_batch,
    umeyama_alignment,
)
from dynslam_lab.geometry.se3 import transform_points


def _old_inliers(R, t, P, Q, tol):
    """The scoring of ransac_rigid_3d before the matrix product: transformed points, their distance,
    ``distance < tol`` (kept here as the reference)."""
    err = np.linalg.norm(np.einsum("ixy,ny->inx", R, P) + t[:, None, :] - Q[None], axis=2)
    return err < tol


def _old_ransac(P, Q, tolerance, n_iterations, rng, refine_rounds=2):
    """ransac_rigid_3d as it was (reference), same sampling."""
    n = len(P)
    tol = np.broadcast_to(np.asarray(tolerance, float), (n,))
    rng = np.random.default_rng(rng)
    samples = np.argpartition(rng.random((n_iterations, n)), 2, axis=1)[:, :3]
    R, t, ok = rigid_alignment_batch(P[samples], Q[samples])
    err = np.linalg.norm(np.einsum("ixy,ny->inx", R, P) + t[:, None, :] - Q[None], axis=2)
    counts = np.where(ok, (err < tol).sum(axis=1), -1)
    best = int(np.argmax(counts))
    T, inl = make_pose(R[best], t[best]), err[best] < tol
    for _ in range(refine_rounds):
        a = umeyama_alignment(P[inl], Q[inl])
        T_new = make_pose(a.R, a.t)
        inl_new = np.linalg.norm(transform_points(T_new, P) - Q, axis=1) < tol
        if inl_new.sum() < inl.sum():
            break
        T, inl = T_new, inl_new
    return T, inl


def test_inliers_of_exact_rotations_at_the_tolerance_boundary():
    """Hand-built case where every number is exact in binary: rotations by multiples of 90 deg, dyadic
    coordinates, residuals of (0.375, 0.5, 0) = exactly 0.625 long. A residual equal to the tolerance
    is an outlier, one a hair shorter an inlier, in the old distance test and the new squared test."""
    rng = np.random.default_rng(1)
    R = np.stack([Rotation.from_euler("xyz", np.deg2rad(90 * rng.integers(0, 4, 3))).as_matrix().round()
                  for _ in range(6)])
    t = rng.integers(-16, 16, (6, 3)) / 8.0
    P = rng.integers(-64, 64, (40, 3)) / 16.0
    h = 2  # the hypothesis the pairs are built from
    Q = P @ R[h].T + t[h]
    off = np.array([0.375, 0.5, 0.0])
    Q[:10] += off  # exactly at the tolerance 0.625: outliers
    Q[10:20] += off * (1 - 2.0 ** -40)  # just inside: inliers
    Q[20:30] += off * 3  # far: outliers
    tol = np.full(40, 0.625)
    new = rigid_inliers_batch(R, t, P, Q, tol)
    np.testing.assert_array_equal(new, _old_inliers(R, t, P, Q, tol))
    expect = np.r_[np.zeros(10, bool), np.ones(10, bool), np.zeros(10, bool), np.ones(10, bool)]
    np.testing.assert_array_equal(new[h], expect)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_inliers_equal_the_distance_test_on_random_hypotheses(seed):
    """RANSAC-like hypotheses (3-point fits, many wrong) on pairs with 40 % outliers and per-pair
    tolerances, plus pairs put within 1e-12 relative of the tolerance of one hypothesis: equal sets."""
    rng = np.random.default_rng(seed)
    n = 500
    R0 = Rotation.random(random_state=seed).as_matrix()
    t0 = rng.uniform(-2, 2, 3)
    P = rng.uniform([-3, -2, 0.5], [3, 2, 6], (n, 3))
    Q = P @ R0.T + t0 + rng.normal(0, 0.01, (n, 3))
    out = rng.random(n) < 0.4
    Q[out] = rng.uniform([-3, -2, 0.5], [3, 2, 6], (out.sum(), 3))
    tol = 0.02 + 0.02 * P[:, 2]
    samples = np.argpartition(rng.random((400, n)), 2, axis=1)[:, :3]
    R, t, _ = rigid_alignment_batch(P[samples], Q[samples])
    # boundary pairs for hypothesis 0: residual direction random, length tol (1 +- 1e-12 .. 1e-16)
    b = np.arange(100)
    u = rng.normal(size=(100, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    rel = rng.choice([-1e-12, -1e-15, -1e-16, 0.0, 1e-16, 1e-15, 1e-12], 100)
    Q[b] = P[b] @ R[0].T + t[0] + u * (tol[b] * (1 + rel))[:, None]
    new = rigid_inliers_batch(R, t, P, Q, tol)
    np.testing.assert_array_equal(new, _old_inliers(R, t, P, Q, tol))
    assert 0 < new[0, b].sum() < 100  # the boundary pairs fall on both sides


def test_ransac_equals_the_old_scoring_and_recovers_the_pose():
    rng = np.random.default_rng(3)
    T = make_pose(Rotation.from_rotvec([0.2, -0.4, 0.1]).as_matrix(), [0.5, -0.2, 1.0])
    P = rng.uniform(-2, 2, (600, 3)) + [0, 0, 3]
    Q = transform_points(T, P) + rng.normal(0, 0.003, (600, 3))
    out = rng.random(600) < 0.5
    Q[out] = rng.uniform(-2, 2, (out.sum(), 3)) + [0, 0, 3]
    tol = 0.01 + 0.002 * P[:, 2]
    T_new, inl_new = ransac_rigid_3d(P, Q, tol, 1000, rng=5)
    T_old, inl_old = _old_ransac(P, Q, tol, 1000, rng=5)
    np.testing.assert_array_equal(inl_new, inl_old)
    np.testing.assert_array_equal(T_new, T_old)
    np.testing.assert_allclose(T_new, T, atol=3e-3)
    assert (inl_new & out).sum() <= 2 and (inl_new[~out]).mean() > 0.9


def test_non_finite_pairs_are_never_inliers():
    R = np.eye(3)[None]
    t = np.zeros((1, 3))
    P = np.array([[0.0, 0, 1], [np.nan, 0, 1], [0, np.inf, 1], [1, 1, 1]])
    Q = P.copy()
    Q[3] = [np.nan, 0, 0]
    np.testing.assert_array_equal(rigid_inliers_batch(R, t, P, Q, 0.1)[0], [True, False, False, False])
