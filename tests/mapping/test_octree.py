"""Octree occupancy map: Morton addressing, log-odds updates, free space, coarse levels."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.mapping.octree import OctreeConfig, OctreeMap, logit, morton_decode, morton_encode


def _interleave_slow(k):
    code = 0
    for bit in range(16):
        for axis in range(3):
            code |= ((int(k[axis]) >> bit) & 1) << (3 * bit + axis)
    return code


def test_morton_matches_bitwise_reference_and_inverts():
    rng = np.random.default_rng(0)
    keys = rng.integers(0, 1 << 16, (200, 3))
    codes = morton_encode(keys)
    assert codes.tolist() == [_interleave_slow(k) for k in keys]
    np.testing.assert_array_equal(morton_decode(codes), keys)
    # the parent of a node is its code without the last 3 bits = keys halved
    np.testing.assert_array_equal(morton_decode(codes >> 3), keys >> 1)


def _wall(z=2.02, half=0.5, step=0.01):
    xs, ys = np.meshgrid(np.arange(-half, half, step), np.arange(-half, half, step))
    return np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)], 1)


def test_wall_scan_hit_and_free_space():
    m = OctreeMap(OctreeConfig(resolution=0.05))
    m.insert_scan(_wall(), np.zeros(3))
    centres, side = m.occupied()
    assert side == 0.05
    np.testing.assert_allclose(centres[:, 2], 2.025)  # the wall's voxel layer, z in [2.0, 2.05)
    assert len(centres) == 20 * 20  # 1 m x 1 m of 5 cm voxels
    p = m.occupancy(np.array([[0.0, 0.0, 1.0], [0.01, 0.01, 2.02], [0.0, 0.0, 3.0]]))
    np.testing.assert_allclose(p[:2], [0.4, 0.7])  # one miss, one hit
    assert np.isnan(p[2])  # behind the wall: unknown


def test_repeated_scans_follow_log_odds_and_clamp():
    cfg = OctreeConfig(resolution=0.05)
    m = OctreeMap(cfg)
    for n in range(1, 7):
        m.insert_scan(_wall(), np.zeros(3))
        p = m.occupancy(np.array([[0.01, 0.01, 2.02], [0.0, 0.0, 1.0]]))
        L_hit = min(n * logit(0.7), logit(0.971))
        L_miss = max(n * logit(0.4), logit(0.1192))
        np.testing.assert_allclose(p, 1 / (1 + np.exp(-np.array([L_hit, L_miss]))), rtol=1e-5)


def test_moving_object_is_cleared_by_later_rays():
    """A person seen at 1 m, then gone: rays to the wall behind clear its voxels (OctoMap's point)."""
    m = OctreeMap(OctreeConfig(resolution=0.05))
    person = _wall(z=1.02, half=0.1)
    m.insert_scan(person, np.zeros(3))
    assert m.occupancy(np.array([[0.0, 0.0, 1.02]]))[0] > 0.5
    for _ in range(3):
        m.insert_scan(_wall(), np.zeros(3))
    assert m.occupancy(np.array([[0.0, 0.0, 1.02]]))[0] < 0.5


def test_coarse_levels_take_max_of_children():
    m = OctreeMap(OctreeConfig(resolution=0.05))
    m.insert_scan(_wall(), np.zeros(3))
    codes0, lo0 = m.nodes(0)
    for level in (1, 2, 3):
        codes, lo = m.nodes(level)
        parents = codes0 >> (3 * level)
        for c, v in zip(codes[:50], lo[:50]):
            assert v == lo0[parents == c].max()
        centres, side = m.occupied(level)
        assert side == pytest.approx(0.05 * 2**level)
        # every occupied leaf lies inside an occupied coarse node
        leaf_c, _ = m.occupied(0)
        d = np.abs(leaf_c[:, None, :] - centres[None]).max(axis=2)
        assert (d.min(axis=1) <= side / 2 + 1e-9).all()


def test_max_range_and_errors():
    m = OctreeMap(OctreeConfig(resolution=0.05, max_range=1.0))
    m.insert_scan(_wall(), np.zeros(3))
    assert len(m.occupied()[0]) == 0  # wall beyond range: free space only
    assert m.occupancy(np.array([[0.0, 0.0, 0.5]]))[0] < 0.5
    with pytest.raises(ValueError, match="prob_miss < 0.5 < prob_hit"):
        OctreeConfig(prob_hit=0.4)
    with pytest.raises(ValueError, match="origin"):
        m.insert_scan(_wall(), np.zeros(2))
    with pytest.raises(ValueError, match="outside"):
        m.keys_of(np.array([[1e4, 0.0, 0.0]]))
