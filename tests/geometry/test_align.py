"""Umeyama and Horn alignment: known transforms, agreement with each other and with evo."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dynslam_lab.geometry.align import Alignment, AlignmentError, horn_alignment, umeyama_alignment


def _random_sim3(rng):
    R = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    t = rng.uniform(-5, 5, size=3)
    c = float(rng.uniform(0.2, 3.0))
    return R, t, c


@pytest.mark.parametrize("solver", [umeyama_alignment, horn_alignment])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_recovers_exact_sim3(solver, seed):
    rng = np.random.default_rng(seed)
    R, t, c = _random_sim3(rng)
    x = rng.normal(size=(50, 3))
    y = c * x @ R.T + t
    a = solver(x, y, with_scale=True)
    np.testing.assert_allclose(a.R, R, atol=1e-10)
    np.testing.assert_allclose(a.t, t, atol=1e-10)
    assert a.scale == pytest.approx(c, rel=1e-10)
    np.testing.assert_allclose(a.apply(x), y, atol=1e-9)
    np.testing.assert_allclose((a.matrix @ np.c_[x, np.ones(50)].T).T[:, :3], y, atol=1e-9)


@pytest.mark.parametrize("solver", [umeyama_alignment, horn_alignment])
def test_rigid_ignores_scale(solver):
    rng = np.random.default_rng(5)
    R, t, _ = _random_sim3(rng)
    x = rng.normal(size=(40, 3))
    y = x @ R.T + t
    a = solver(x, y, with_scale=False)
    assert a.scale == 1.0
    np.testing.assert_allclose(a.R, R, atol=1e-10)
    assert np.linalg.det(a.R) == pytest.approx(1.0)


def test_umeyama_equals_horn_on_noisy_points():
    rng = np.random.default_rng(7)
    R, t, c = _random_sim3(rng)
    x = rng.normal(size=(200, 3))
    y = c * x @ R.T + t + rng.normal(0, 0.2, size=(200, 3))
    for with_scale in (False, True):
        u = umeyama_alignment(x, y, with_scale)
        h = horn_alignment(x, y, with_scale)
        np.testing.assert_allclose(u.R, h.R, atol=1e-9)
        np.testing.assert_allclose(u.t, h.t, atol=1e-9)
        assert u.scale == pytest.approx(h.scale, rel=1e-9)


def test_optimality_against_perturbations():
    """The solution's cost is a minimum: small perturbations of R, t, c never lower it."""
    rng = np.random.default_rng(3)
    R, t, c = _random_sim3(rng)
    x = rng.normal(size=(100, 3))
    y = c * x @ R.T + t + rng.normal(0, 0.3, size=(100, 3))
    a = umeyama_alignment(x, y, with_scale=True)
    cost = np.mean(np.sum((y - a.apply(x)) ** 2, axis=1))
    for _ in range(50):
        dR = Rotation.from_rotvec(rng.normal(0, 1e-3, 3)).as_matrix()
        b = Alignment(dR @ a.R, a.t + rng.normal(0, 1e-3, 3), a.scale * (1 + rng.normal(0, 1e-3)))
        assert np.mean(np.sum((y - b.apply(x)) ** 2, axis=1)) >= cost


def test_reflection_is_not_returned():
    """Points mirrored by a reflection: the best *rotation* is returned (det +1), eq. 43."""
    rng = np.random.default_rng(11)
    x = rng.normal(size=(30, 3))
    y = x * np.array([1.0, 1.0, -1.0])
    a = umeyama_alignment(x, y)
    assert np.linalg.det(a.R) == pytest.approx(1.0)
    h = horn_alignment(x, y)
    np.testing.assert_allclose(a.R, h.R, atol=1e-9)


def test_matches_evo_umeyama():
    geometry = pytest.importorskip("evo.core.geometry")
    rng = np.random.default_rng(21)
    R, t, c = _random_sim3(rng)
    x = rng.normal(size=(80, 3))
    y = c * x @ R.T + t + rng.normal(0, 0.1, size=(80, 3))
    for with_scale in (False, True):
        r_e, t_e, c_e = geometry.umeyama_alignment(x.T, y.T, with_scale)
        a = umeyama_alignment(x, y, with_scale)
        np.testing.assert_allclose(a.R, r_e, atol=1e-12)
        np.testing.assert_allclose(a.t, t_e, atol=1e-12)
        assert a.scale == pytest.approx(c_e, rel=1e-12)


@pytest.mark.parametrize("solver", [umeyama_alignment, horn_alignment])
def test_bad_input(solver):
    with pytest.raises(AlignmentError, match=r"\(N, 3\)"):
        solver(np.zeros((5, 2)), np.zeros((5, 2)))
    with pytest.raises(AlignmentError, match="differ in shape"):
        solver(np.zeros((5, 3)), np.zeros((4, 3)))
    with pytest.raises(AlignmentError, match="at least 3"):
        solver(np.zeros((2, 3)), np.zeros((2, 3)))
    line = np.outer(np.arange(6.0), [1.0, 2.0, 3.0])
    with pytest.raises(AlignmentError, match="degenerate"):
        solver(line, line + 1.0)
    bad = np.ones((4, 3))
    bad[0, 0] = np.nan
    with pytest.raises(AlignmentError, match="NaN"):
        solver(bad, np.ones((4, 3)))


@pytest.mark.parametrize("solver", [umeyama_alignment, horn_alignment])
def test_planar_points(solver):
    """A ground robot's path lies in a plane (rank-2 covariance): still a unique rotation."""
    rng = np.random.default_rng(13)
    R, t, c = _random_sim3(rng)
    x = np.c_[rng.normal(size=(60, 2)), np.zeros(60)]
    y = c * x @ R.T + t
    a = solver(x, y, with_scale=True)
    np.testing.assert_allclose(a.R, R, atol=1e-9)
    np.testing.assert_allclose(a.apply(x), y, atol=1e-9)
