"""Map bookkeeping: observations, covisibility weights, culling, spanning tree, scale range."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.geometry.se3 import make_pose
from dynslam_lab.slam.frame import KeyFrame
from dynslam_lab.slam.map import Map


def _kf(mp: Map, n: int, T=None, octave=0) -> KeyFrame:
    kid = mp.new_keyframe_id()
    kf = KeyFrame(
        id=kid, frame_index=kid, timestamp=float(kid), _T_w_c=np.eye(4) if T is None else T,
        uv=np.zeros((n, 2)), descriptors=np.zeros((n, 32), np.uint8), octave=np.full(n, octave),
        angle=np.zeros(n), points_c=np.zeros((n, 3)), map_point_ids=np.full(n, -1, np.int64), static=np.ones(n, bool),
    )
    mp.add_keyframe(kf)
    return kf


def test_covisibility_weights_and_spanning_tree():
    mp = Map()
    a = _kf(mp, 10)
    ids = mp.add_points(np.c_[np.arange(10.0), np.zeros(10), np.full(10, 2.0)], np.zeros((10, 32), np.uint8), a, np.arange(10))
    b = _kf(mp, 10)
    b.map_point_ids[:6] = ids[:6]  # b sees 6 of a's points
    c = _kf(mp, 10)
    c.map_point_ids[:3] = ids[4:7]  # c sees 3 of a's points, 2 of them also seen by b
    mp.invalidate()
    assert mp.covisibility(a.id) == {b.id: 6, c.id: 3}
    assert mp.covisibility(b.id) == {a.id: 6, c.id: 2}
    assert mp.best_covisibles(a.id) == [b.id, c.id]
    assert mp.observations(int(ids[5])) == {a.id: 5, b.id: 5, c.id: 1}
    assert list(mp.n_obs(ids[[0, 4, 5, 6, 9]])) == [2, 3, 3, 2, 1]
    # the parent of a new keyframe is the keyframe it shares most points with
    d = KeyFrame(id=mp.new_keyframe_id(), frame_index=9, timestamp=9.0, _T_w_c=np.eye(4), uv=np.zeros((4, 2)),
                 descriptors=np.zeros((4, 32), np.uint8), octave=np.zeros(4), angle=np.zeros(4),
                 points_c=np.zeros((4, 3)), map_point_ids=ids[[0, 7, 8, 9]].copy(), static=np.ones(4, bool))
    mp.add_keyframe(d)
    assert d.parent_id == a.id and d.id in a.children  # 4 shared with a, 1 with b
    # culling a point clears it from every keyframe
    mp.remove_points(ids[[5]])
    assert not mp.alive[ids[5]] and ids[5] not in a.map_point_ids and ids[5] not in b.map_point_ids
    assert mp.covisibility(a.id)[b.id] == 5


def test_remove_keyframe_keeps_pose_of_culled_anchor():
    mp = Map()
    a = _kf(mp, 3)
    ids = mp.add_points(np.eye(3) + [0, 0, 2], np.zeros((3, 32), np.uint8), a, np.arange(3))
    T_b = make_pose(t=[1.0, 0, 0])
    b = _kf(mp, 3, T=T_b)
    b.map_point_ids[:] = ids
    c = _kf(mp, 3, T=make_pose(t=[2.0, 0, 0]))
    c.map_point_ids[:] = ids
    c.parent_id = b.id
    b.children.add(c.id)
    mp.invalidate()
    mp.remove_keyframe(b.id)
    assert b.id not in mp.keyframes and c.parent_id == b.parent_id
    assert np.allclose(mp.keyframe_pose(b.id), T_b)
    a.set_pose(make_pose(t=[0, 1.0, 0]))  # a loop correction moves the parent ...
    assert np.allclose(mp.keyframe_pose(b.id)[:3, 3], [1.0, 1.0, 0])  # ... and the culled keyframe with it
    with pytest.raises(ValueError, match="first keyframe"):
        mp.remove_keyframe(a.id)


def test_scale_range_and_predicted_level():
    mp = Map(scale_factor=1.2, n_levels=8)
    kf = _kf(mp, 1, octave=2)
    pid = mp.add_points(np.array([[0.0, 0.0, 3.0]]), np.zeros((1, 32), np.uint8), kf, np.array([0]))
    # seen at 3 m on level 2: d_max = 3 * 1.2^2, d_min = d_max / 1.2^7
    assert np.isclose(mp.max_dist[pid[0]], 3 * 1.44)
    assert np.isclose(mp.min_dist[pid[0]], 3 * 1.44 / 1.2**7)
    assert np.allclose(mp.normal[pid[0]], [0, 0, 1])
    assert mp.predict_level(pid, np.array([3.0]))[0] == 2
    assert mp.predict_level(pid, np.array([3 * 1.44]))[0] == 0
    assert mp.predict_level(pid, np.array([0.1]))[0] == 7
    with pytest.raises(ValueError, match="not in the map"):
        mp.add_points(np.zeros((1, 3)), np.zeros((1, 32), np.uint8), KeyFrame(
            99, 0, 0.0, np.eye(4), np.zeros((1, 2)), np.zeros((1, 32), np.uint8), np.zeros(1), np.zeros(1),
            np.zeros((1, 3)), np.full(1, -1), np.ones(1, bool)), np.array([0]))
    with pytest.raises(ValueError, match="finite"):
        kf.set_pose(np.full((4, 4), np.nan))


def test_distinctive_descriptor_is_the_most_central_observation():
    rng = np.random.default_rng(0)
    mp = Map()
    base = rng.integers(0, 256, (1, 32), dtype=np.uint8)
    kfs = [_kf(mp, 2) for _ in range(5)]
    ids = mp.add_points(np.ones((2, 3)), rng.integers(0, 256, (2, 32), dtype=np.uint8), kfs[0], np.arange(2))
    bits = np.unpackbits(base, axis=1)
    variants = []
    for flips in ([], list(range(0, 20)), list(range(200, 220)), list(range(100, 140)), list(range(60, 80))):
        b = bits.copy()
        b[0, flips] ^= 1
        variants.append(np.packbits(b, axis=1)[0])
    # point 0 is seen by the 5 keyframes with the 5 variants; point 1 by keyframe 0 only
    for kf, v in zip(kfs, variants):
        kf.descriptors[0] = v
        kf.map_point_ids[0] = ids[0]
    mp.invalidate()
    before1 = mp.descriptors[ids[1]].copy()
    mp.update_descriptors(ids)
    # medians (self included): base 20; the others 40, 40, 60, 40 -> the base wins
    assert np.array_equal(mp.descriptors[ids[0]], variants[0])
    assert not np.array_equal(before1, kfs[0].descriptors[1])
    assert np.array_equal(mp.descriptors[ids[1]], kfs[0].descriptors[1])  # a single observation


def _brute_observations(mp: Map, ids) -> set[tuple[int, int, int]]:
    """Independent reference: scan every keyframe's map_point_ids with np.isin."""
    out = set()
    for kf in mp.keyframes.values():  # test reference only
        kp = np.flatnonzero(np.isin(kf.map_point_ids, np.asarray(ids, np.int64)) & (kf.map_point_ids >= 0))
        out |= {(kf.id, int(kf.map_point_ids[k]), int(k)) for k in kp}
    return out


def _brute_covisibility(mp: Map, kf_id: int) -> dict[int, int]:
    own = mp.keyframes[kf_id].map_point_ids
    own = np.unique(own[own >= 0])
    out = {}
    for kf in mp.keyframes.values():
        if kf.id != kf_id:
            w = int(np.isin(kf.map_point_ids[kf.map_point_ids >= 0], own).sum())
            if w:
                out[kf.id] = w
    return out


def _check_index(mp: Map, rng) -> None:
    queries = [mp.point_ids(), rng.integers(-3, mp.n_points_total + 3, 40), np.zeros(0, np.int64),
               np.repeat(mp.point_ids()[:5], 3)]
    for q in queries:
        kf, pt, kp, octave = mp.observations_of(q, with_octave=True)
        rows = {(int(a), int(b), int(c)) for a, b, c in zip(kf, pt, kp)}
        assert len(rows) == len(kf)  # no row twice, even for repeated ids
        assert rows == _brute_observations(mp, q)
        assert all(octave[i] == mp.keyframes[int(kf[i])].octave[kp[i]] for i in range(len(kf)))
    for kid in mp.keyframe_ids():
        brute = _brute_covisibility(mp, kid)
        assert mp.covisibility(kid) == brute
        order = sorted(brute, key=lambda k: (-brute[k], k))
        assert mp.best_covisibles(kid) == order
        assert mp.best_covisibles(kid, 3) == order[:3] and mp.best_covisibles(kid, 0) == []
        assert mp.best_covisibles(kid, None, 3) == [k for k in order if brute[k] >= 3]
        assert mp.best_covisibles(kid, 2, 2) == [k for k in order if brute[k] >= 2][:2]
    ids = np.arange(mp.n_points_total)
    brute_n = np.zeros(mp.n_points_total, np.int64)
    for kf in mp.keyframes.values():
        np.add.at(brute_n, kf.map_point_ids[kf.map_point_ids >= 0], 1)
    assert np.array_equal(mp.n_obs(ids), brute_n)


# compaction after every change, sometimes, never
COMPACTION = [(0, 0.0), (50, 0.25), (10**9, 0.0)]


@pytest.mark.parametrize("min_rows,fraction", COMPACTION)
def test_point_index_and_covisibility_cache_equal_brute_force(monkeypatch, min_rows, fraction):
    """The incremental observation table and the covisibility cache agree with a full np.isin scan
    after point additions, direct edits + invalidate(), point removals and keyframe deletion."""
    monkeypatch.setattr(Map, "COMPACT_MIN_ROWS", min_rows)
    monkeypatch.setattr(Map, "COMPACT_FRACTION", fraction)
    rng = np.random.default_rng(12)
    mp = Map()
    kfs = []
    for i in range(8):
        kf = _kf(mp, 60, octave=i % 3)
        if i:  # see a random subset of the existing points
            pool = mp.point_ids()
            take = rng.choice(len(pool), min(len(pool), 25), replace=False)
            kf.map_point_ids[rng.choice(30, len(take), replace=False)] = pool[take]
            mp.invalidate()
        free = np.flatnonzero(kf.map_point_ids < 0)[:20]
        mp.add_points(rng.normal(0, 1, (len(free), 3)) + [0, 0, 3], rng.integers(0, 256, (len(free), 32), dtype=np.uint8),
                      kf, free)
        kfs.append(kf)
        _check_index(mp, rng)
    before = mp.covisibility(kfs[0].id)
    before[kfs[1].id] = -7  # the cache hands out copies
    assert mp.covisibility(kfs[0].id) == _brute_covisibility(mp, kfs[0].id)
    mp.remove_points(rng.choice(mp.point_ids(), 30, replace=False))
    _check_index(mp, rng)
    mp.remove_keyframe(kfs[3].id)
    mp.remove_keyframe(kfs[6].id)
    _check_index(mp, rng)
    kf = _kf(mp, 60)  # after deletions: new keyframe, new points
    kf.map_point_ids[:10] = mp.point_ids()[:10]
    mp.invalidate()
    mp.add_points(np.tile([0.0, 0.0, 2.0], (5, 1)), np.zeros((5, 32), np.uint8), kf, np.arange(40, 45))
    _check_index(mp, rng)


@pytest.mark.parametrize("min_rows,fraction", COMPACTION)
@pytest.mark.parametrize("seed", [0, 1])
def test_random_map_edits_keep_the_index_equal_brute_force(monkeypatch, min_rows, fraction, seed):
    """A random sequence of map edits (new keyframes with new and re-observed points, observations
    added and removed by direct edits with ``invalidate(kf_ids)`` or ``invalidate()``, points fused
    as local mapping and loop fusion do, points removed, keyframes deleted): after each one the
    point-observer, covisibility and observation-count queries equal a brute-force scan."""
    monkeypatch.setattr(Map, "COMPACT_MIN_ROWS", min_rows)
    monkeypatch.setattr(Map, "COMPACT_FRACTION", fraction)
    rng = np.random.default_rng(seed)
    mp = Map()
    first = _kf(mp, 50)
    mp.add_points(rng.normal(0, 1, (20, 3)) + [0, 0, 3], rng.integers(0, 256, (20, 32), dtype=np.uint8), first,
                  np.arange(20))
    for step in range(60):
        op = rng.integers(6) if len(mp.keyframes) > 2 else 0
        kfs = mp.keyframe_ids()
        if op == 0:  # new keyframe: re-observes some points, creates some
            kf = _kf(mp, 50, octave=int(rng.integers(3)))
            pool = mp.point_ids()
            take = rng.choice(len(pool), min(len(pool), 15), replace=False)
            kf.map_point_ids[rng.choice(25, len(take), replace=False)] = pool[take]
            mp.invalidate([kf.id])
            free = np.flatnonzero(kf.map_point_ids < 0)[:10]
            mp.add_points(rng.normal(0, 1, (len(free), 3)) + [0, 0, 3],
                          rng.integers(0, 256, (len(free), 32), dtype=np.uint8), kf, free)
        elif op == 1:  # observations added and removed in place
            kf = mp.keyframes[int(rng.choice(kfs))]
            kf.map_point_ids[rng.choice(50, 3, replace=False)] = -1
            free = np.flatnonzero(kf.map_point_ids < 0)
            new = np.setdiff1d(mp.point_ids(), kf.map_point_ids)
            n = min(len(free), len(new), 3)
            kf.map_point_ids[free[:n]] = rng.choice(new, n, replace=False)
            mp.invalidate([kf.id] if rng.random() < 0.5 else None)
        elif op == 2:  # fuse: every observation of point a becomes one of point b (a keyframe seeing both keeps b)
            a, b = rng.choice(mp.point_ids(), 2, replace=False)
            for kf in mp.keyframes.values():
                has_a = kf.map_point_ids == a
                if has_a.any():
                    kf.map_point_ids[has_a] = -1 if (kf.map_point_ids == b).any() else b
            mp.alive[a] = False
            mp.invalidate()
        elif op == 3:
            mp.remove_points(rng.choice(mp.point_ids(), 3, replace=False))
        elif op == 4:
            mp.remove_keyframe(int(rng.choice(kfs[1:])))
        else:  # a query between edits fills the covisibility cache
            mp.covisibility(int(rng.choice(kfs)))
        _check_index(mp, rng)


def test_points_of_keyframes_are_the_sorted_unique_alive_ids():
    rng = np.random.default_rng(5)
    mp = Map()
    a = _kf(mp, 300)
    ids = mp.add_points(rng.normal(size=(300, 3)) + [0, 0, 3], np.zeros((300, 32), np.uint8), a, np.arange(300))
    kfs = [a]
    for _ in range(4):  # keyframes seeing random subsets of the points (shared ids, unmatched keypoints)
        k = _kf(mp, 200)
        k.map_point_ids[:] = np.where(rng.random(200) < 0.3, -1, rng.choice(ids, 200))
        kfs.append(k)
    mp.remove_points(ids[rng.choice(300, 40, replace=False)])  # culled points leave every keyframe
    b_ids = [kfs[1].id, kfs[3].id, a.id]
    ref = np.concatenate([mp.keyframes[k].map_point_ids for k in b_ids])
    ref = np.unique(ref[ref >= 0])
    ref = ref[mp.alive[ref]]
    got = mp.points_of(b_ids)
    assert np.array_equal(got, ref) and got.dtype.kind == "i"
    assert mp.points_of([]).shape == (0,)
