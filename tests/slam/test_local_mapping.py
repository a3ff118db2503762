"""Local mapping steps on hand-built maps: points from depth, merging, culling of points and
keyframes (the counts are computed by hand from the construction)."""

from __future__ import annotations

import numpy as np

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.geometry.se3 import make_pose, transform_points
from dynslam_lab.slam.frame import KeyFrame
from dynslam_lab.slam.local_mapping import (
    LocalMappingConfig,
    create_points_from_depth,
    cull_keyframes,
    cull_recent_points,
    fuse_with_neighbours,
    local_ba_window,
    replace_points,
    run_local_ba,
)
from dynslam_lab.slam.map import Map

CAM = CAMERA_PRESETS["default"]


def _kf(mp, points_c, T=np.eye(4), static=None, octave=0, desc=None):
    n = len(points_c)
    uv, _ = CAM.project(np.nan_to_num(points_c, nan=1.0))
    kf = KeyFrame(mp.new_keyframe_id(), 0, 0.0, T, uv, np.zeros((n, 32), np.uint8) if desc is None else desc,
                  np.full(n, octave), np.zeros(n), points_c, np.full(n, -1, np.int64),
                  np.ones(n, bool) if static is None else static)
    mp.add_keyframe(kf)
    return kf


def test_points_from_depth_close_first_and_static_only():
    mp = Map()
    z = np.array([1.0, 2.0, 5.0, 6.0, 7.0, np.nan])
    pts = np.c_[np.zeros(6), np.zeros(6), z]
    static = np.array([True, False, True, True, True, True])
    T = make_pose(t=[1.0, 2.0, 3.0])
    kf = _kf(mp, pts, T=T, static=static)
    ids = create_points_from_depth(mp, kf, close_depth=3.0, min_new=2)
    # close: keypoint 0 (1 is dynamic); far ones until 2 points: keypoint 2 (5 m)
    assert list(kf.map_point_ids) == [ids[0], -1, ids[1], -1, -1, -1]
    assert np.allclose(mp.xyz[ids], transform_points(T, pts[[0, 2]]))
    assert list(mp.n_obs(ids)) == [1, 1]


def test_replace_points_merges_observations_without_duplicates():
    mp = Map()
    a = _kf(mp, np.c_[np.zeros(3), np.zeros(3), np.ones(3)])
    ids = mp.add_points(np.eye(3), np.zeros((3, 32), np.uint8), a, np.arange(3))
    b = _kf(mp, np.c_[np.zeros(3), np.zeros(3), np.ones(3)])
    b.map_point_ids[:] = [ids[0], ids[1], -1]
    mp.invalidate()
    replace_points(mp, np.array([ids[1]]), np.array([ids[0]]))  # b would see ids[0] twice
    assert not mp.alive[ids[1]]
    assert list(a.map_point_ids) == [ids[0], -1, ids[2]]  # a saw both: the duplicate goes
    for kf in (a, b):
        valid = kf.map_point_ids[kf.map_point_ids >= 0]
        assert len(valid) == len(np.unique(valid)) and ids[1] not in valid
    assert mp.observations(int(ids[0])) == {a.id: 0, b.id: 0}


def test_fusion_links_a_neighbour_keypoint_to_the_same_point():
    rng = np.random.default_rng(0)
    mp = Map()
    X = np.c_[rng.uniform(-1, 1, 50), rng.uniform(-0.7, 0.7, 50), rng.uniform(2, 3, 50)]
    desc = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    a = _kf(mp, X, desc=desc)
    ids = mp.add_points(X, desc, a, np.arange(50))
    T_b = make_pose(t=[0.05, 0, 0])
    Xb = transform_points(np.linalg.inv(T_b), X)
    b = _kf(mp, Xb, T=T_b, desc=desc)
    b.map_point_ids[:20] = ids[:20]  # tracking matched 20; fusion must find the other 30
    new_b = mp.add_points(X[20:25], desc[20:25], b, np.arange(20, 25))  # 5 duplicates made by b
    mp.invalidate()
    fuse_with_neighbours(mp, b, CAM, LocalMappingConfig(), scale_factor=1.2)
    assert np.array_equal(b.map_point_ids, a.map_point_ids)  # every keypoint now on a's point ...
    assert not mp.alive[new_b].any()  # ... and b's duplicates merged away (fewer observations)
    assert all(mp.n_obs(ids) == 2)


def test_recent_point_and_redundant_keyframe_culling():
    mp = Map()
    cfg = LocalMappingConfig()
    pts = np.c_[np.zeros(10), np.zeros(10), np.full(10, 2.0)]
    k0 = _kf(mp, pts)
    ids = mp.add_points(pts, np.zeros((10, 32), np.uint8), k0, np.arange(10))
    # found in 1 of 10 predicted views -> bad; the others are fine
    mp.n_visible[ids] = 10
    mp.n_found[ids] = 10
    mp.n_found[ids[0]] = 1
    still = cull_recent_points(mp, ids, current_kf_id=0, cfg=cfg)
    assert not mp.alive[ids[0]] and np.array_equal(still, ids[1:])
    # two keyframes later a point seen by a single keyframe is culled (RGB-D: fewer than 2)
    k1 = _kf(mp, pts)
    k1.map_point_ids[2:] = ids[2:]
    k2 = _kf(mp, pts)
    k2.map_point_ids[2:] = ids[2:]
    k3 = _kf(mp, pts)
    k3.map_point_ids[2:] = ids[2:]
    mp.invalidate()
    still = cull_recent_points(mp, still, current_kf_id=2, cfg=cfg)
    assert not mp.alive[ids[1]] and mp.alive[ids[2:]].all()
    # k1, k2, k3 see the same 8 points, each seen by 3 others: redundant ones go, k0 (origin) stays
    removed = cull_keyframes(mp, k3, cfg, close_depth=3.0)
    assert 0 not in removed and k3.id not in removed and set(removed) <= {k1.id, k2.id} and removed
    assert 0 in mp.keyframes and k3.id in mp.keyframes


def test_local_ba_holds_a_window_keyframe_with_few_points():
    """Four keyframes seeing 40 points, a fifth seeing 5 of them, its pose 5 cm / 2 deg off: with
    ``ba_hold_min_obs`` above 5 it keeps its pose (held, like the origin) while the others are optimised;
    without, local BA moves it (the counts are the construction's)."""
    from dynslam_lab.geometry.se3 import so3_exp

    rng = np.random.default_rng(0)
    X_w = np.c_[rng.uniform(-1.5, 1.5, 40), rng.uniform(-1.0, 1.0, 40), rng.uniform(2.5, 4.0, 40)]

    def build():
        mp = Map()
        kfs = []
        for i in range(4):
            T = make_pose(t=[0.1 * i, 0.0, 0.0])
            kfs.append(_kf(mp, transform_points(np.linalg.inv(T), X_w), T=T))
        ids = mp.add_points(X_w, np.zeros((40, 32), np.uint8), kfs[0], np.arange(40))
        for kf in kfs[1:]:
            kf.map_point_ids[:] = ids
        T_off = make_pose(so3_exp([0.0, np.radians(2.0), 0.0]), [0.25, 0.0, 0.0])  # the true pose: x = 0.2
        few = _kf(mp, transform_points(np.linalg.inv(make_pose(t=[0.2, 0.0, 0.0])), X_w[:5]), T=T_off)
        few.map_point_ids[:] = ids[:5]
        mp.invalidate()
        return mp, kfs, few, T_off

    mp, kfs, few, T_off = build()
    win = local_ba_window(mp, kfs[3], window=5, max_fixed=10, hold_min_obs=6)
    assert few.id in win.local and few.id in win.fixed and kfs[3].id not in win.fixed
    assert local_ba_window(mp, kfs[3], window=5, max_fixed=10).fixed == {0}
    assert LocalMappingConfig().ba_hold_min_obs == 30
    run_local_ba(mp, kfs[3], CAM, LocalMappingConfig(ba_hold_min_obs=6), bf=40.0, scale_factor=1.2)
    assert np.array_equal(few.T_w_c, T_off)
    mp, kfs, few, T_off = build()
    run_local_ba(mp, kfs[3], CAM, LocalMappingConfig(ba_hold_min_obs=0), bf=40.0, scale_factor=1.2)
    assert np.linalg.norm(few.T_w_c[:3, 3] - [0.2, 0.0, 0.0]) < 0.01  # free, its 5 points move it to its true pose
