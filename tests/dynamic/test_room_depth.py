"""Step 3c of the reference pose: the room's depth against an earlier frame's (dynamic/room_depth.py).

The room is ray-cast analytically (a floor, a back wall and two side walls), so the true poses and
every depth are known; the checks are against those poses and against the movers' labels."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.camera import PinholeCamera
from dynslam_lab.dynamic.reference_pose import ReferencePoseConfig, depth_moved_surfaces, refine_pose
from dynslam_lab.dynamic.regions import surface_segments
from dynslam_lab.dynamic.room_depth import RoomDepth, align_room, front_share, reference_grid, room_labels, room_points
from dynslam_lab.geometry.se3 import make_pose, se3_inv, so3_exp, transform_points

GRID = PinholeCamera(131.25, 131.25, 79.875, 59.875, 160, 120, name="grid")  # a 640x480 Kinect reduced 4x
K = GRID.K * 4.0  # the full image (pixels of the keypoints)
K[2, 2] = 1.0
# planes n . X = c in the world: floor (y = 1.2), back wall (z = 4.5), left and right walls (x = -/+2.5)
PLANES = [(np.array([0.0, 1.0, 0.0]), 1.2), (np.array([0.0, 0.0, 1.0]), 4.5),
          (np.array([-1.0, 0.0, 0.0]), 2.5), (np.array([1.0, 0.0, 0.0]), 2.5)]


def _room_depth(T_c_w: np.ndarray, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    """Depth (m) of the room on GRID's pixels seen from ``T_c_w`` (nearest plane along each ray)."""
    v, u = np.mgrid[0:GRID.height, 0:GRID.width].astype(np.float64)
    d_c = np.stack([(u - GRID.cx) / GRID.fx, (v - GRID.cy) / GRID.fy, np.ones_like(u)], axis=-1)  # z = 1
    R, t = T_c_w[:3, :3], T_c_w[:3, 3]
    d_w = d_c @ R  # R^T d for every ray
    C = -R.T @ t
    best = np.full(u.shape, np.inf)
    for n, c in PLANES:
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (c - n @ C) / (d_w @ n)
        best = np.where((s > 0) & (s < best), s, best)
    z = best  # the ray's z component is 1, so the parameter is the depth
    if noise:
        z = z + np.random.default_rng(seed).normal(0.0, noise, z.shape)
    return np.where(np.isfinite(z), z, 0.0).astype(np.float32)


def _room(T_now: np.ndarray, T_ref: np.ndarray, noise: float = 0.001) -> RoomDepth:
    depth = _room_depth(T_now, noise, seed=1)
    labels = np.ones(depth.shape, np.int64)
    ids = room_labels(depth, np.bincount(labels.ravel(), minlength=2), 0.1)
    X = room_points(depth, labels, ids, GRID)
    return RoomDepth(X, reference_grid(_room_depth(T_ref, noise, seed=2), GRID), T_ref, GRID)


def _pose_error(T_a, T_b):
    D = T_a @ se3_inv(T_b)
    ang = np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(D[:3, 3])), float(ang)


T_REF = make_pose(so3_exp(np.radians([2.0, -5.0, 0.0])), np.array([0.05, 0.0, 0.0]))
T_TRUE = make_pose(so3_exp(np.radians([0.0, 4.0, 1.0])), np.array([-0.12, 0.03, 0.1])) @ T_REF


def test_the_room_aligns_back_to_the_true_pose_from_a_pulled_one():
    # the features slid 4 cm sideways and turned 1.2 deg (the far wall trades one against the other)
    T_pulled = make_pose(so3_exp(np.radians([0.0, -1.2, 0.0])), np.array([0.04, 0.0, 0.01])) @ T_TRUE
    a = align_room(_room(T_TRUE, T_REF), T_pulled)
    dt, da = _pose_error(a.T_c_w, T_TRUE)
    assert dt < 0.003 and da < 0.1, (dt, da)
    assert a.d_start > 5 * a.d_end and a.d_end < 0.002  # the noise (1 mm) is what is left
    assert a.n > 1000


def test_from_the_true_pose_the_alignment_gains_nothing():
    a = align_room(_room(T_TRUE, T_REF), T_TRUE)
    assert _pose_error(a.T_c_w, T_TRUE)[0] < 0.002
    assert a.d_start < 1.2 * a.d_end  # nothing to gain: step 3c must not fire


def test_a_single_wall_leaves_the_free_directions_at_the_start_pose():
    # only the back wall: depth fixes the distance to it and two tilts, not the slide along it
    depth = _room_depth(T_TRUE)
    grid_ref = _room_depth(T_REF)
    wall = np.zeros(depth.shape, np.int64)
    X_all = GRID.backproject_depth(depth)
    on_wall = np.abs(transform_points(se3_inv(T_TRUE), X_all.reshape(-1, 3))[:, 2] - 4.5).reshape(depth.shape) < 1e-3
    wall[on_wall] = 1
    X = room_points(depth, wall, np.array([1]), GRID)
    T_slid = make_pose(np.eye(3), np.array([0.03, 0.0, 0.0])) @ T_TRUE  # along the wall
    a = align_room(RoomDepth(X, reference_grid(grid_ref, GRID), T_REF, GRID), T_slid)
    # the slide stays (the prior holds it), nothing else moves it by more than a few mm
    assert abs(_pose_error(a.T_c_w, T_slid)[0]) < 0.005


def _features(seed: int = 3):
    """Map points: 60 on the far walls (label 1: the room), two faces of a carried box 1.2 m in front
    (labels 2 and 3, 40 each) that moved 6 cm sideways since they were mapped."""
    rng = np.random.default_rng(seed)
    C = se3_inv(T_TRUE)
    wall = np.column_stack([rng.uniform(-2.0, 2.0, 40), rng.uniform(-0.8, 1.0, 40), np.full(40, 4.5)])
    side = np.column_stack([np.full(20, -2.5), rng.uniform(-0.8, 1.0, 20), rng.uniform(3.0, 4.4, 20)])
    box_c = np.column_stack([rng.uniform(-0.3, 0.3, 80), rng.uniform(-0.3, 0.3, 80), np.full(80, 1.2)])
    box_c[40:, 2] += rng.uniform(0.0, 0.3, 40)  # the second face, deeper
    box_c[40:, 0] = 0.3
    box_w = transform_points(C, box_c)
    X_w = np.vstack([wall, side, box_w])
    labels = np.r_[np.ones(60, int), np.full(40, 2), np.full(40, 3)]
    moved = X_w.copy()
    moved[60:] += T_TRUE[:3, :3].T @ np.array([0.06, 0.0, 0.0])  # the box moved 6 cm in the camera's x
    X_c = transform_points(T_TRUE, moved)
    uv = (X_c[:, :2] / X_c[:, 2:]) * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    uv += rng.normal(0.0, 0.3, uv.shape)
    return X_w, uv, labels


def test_step_3c_finds_the_carried_box_and_restores_the_pose():
    X_w, uv, labels = _features()
    sigma = np.ones(len(X_w))
    # the pose the features give when the box holds them: refined from a start the box has pulled
    T_pulled = make_pose(so3_exp(np.radians([0.0, -0.8, 0.0])), np.array([0.035, 0.0, 0.0])) @ T_TRUE
    T_feat = refine_pose(T_pulled, X_w, uv, K, (1.0, 0.7), sigma=sigma)
    cfg = ReferencePoseConfig()
    moving, T, fired = depth_moved_surfaces(T_feat, X_w, uv, K, sigma, labels, np.ones(len(X_w), bool), cfg,
                                            _room(T_TRUE, T_REF), np.array([1]))
    assert fired
    assert np.array_equal(moving, labels > 1)  # both faces of the box, nothing of the room
    dt, da = _pose_error(T, T_TRUE)
    assert dt < 0.004 and da < 0.15, (dt, da)


def test_step_3c_stays_quiet_when_the_features_fix_the_pose():
    # the static features fix the pose to 6 mm; depth with 5 mm of noise (a Kinect at 1.5 m) cannot do better
    X_w, uv, labels = _features()
    static = labels == 1
    sigma = np.ones(static.sum())
    T_feat = refine_pose(T_TRUE, X_w[static], uv[static], K, (1.0, 0.7), sigma=sigma)
    moving, T, fired = depth_moved_surfaces(T_feat, X_w[static], uv[static], K, sigma, labels[static],
                                            np.ones(static.sum(), bool), ReferencePoseConfig(),
                                            _room(T_TRUE, T_REF, noise=0.005), np.array([1]))
    assert not fired and not moving.any() and T is T_feat
    # off by configuration
    off = ReferencePoseConfig(room_depth_gain=0.0)
    assert not depth_moved_surfaces(T_feat, X_w, uv, K, np.ones(len(X_w)), labels, np.ones(len(X_w), bool), off,
                                    _room(T_TRUE, T_REF), np.array([1]))[2]


def test_step_3c_keeps_the_feature_pose_when_the_map_itself_disagrees_with_the_depth():
    # a map built under a pose 3.6 cm off (drift): the static features agree with the map, the depth with the
    # truth; the reference pose judges keypoints against map points, so the features' pose must stay (the
    # moved box is among the matches: it must not be taken for a surface that pulled the features)
    X_w, uv, labels = _features()
    static = labels == 1
    X_map = X_w.copy()
    X_map[static] += np.array([0.02, 0.0, 0.03])
    sigma = np.ones(len(X_w))
    T_feat = refine_pose(T_TRUE, X_map[static], uv[static], K, (2.0, 1.0, 0.7), sigma=sigma[static])
    assert _pose_error(T_feat, T_TRUE)[0] > 0.02  # the features follow the map
    a = align_room(_room(T_TRUE, T_REF), T_feat)
    assert a.d_start > 2 * a.d_end  # the depth alone would move the pose back to the truth ...
    moving, T, fired = depth_moved_surfaces(T_feat, X_map, uv, K, sigma, labels, np.ones(len(X_w), bool),
                                            ReferencePoseConfig(), _room(T_TRUE, T_REF), np.array([1]))
    assert not fired and T is T_feat and not moving.any()  # ... but the room's map points miss that pose


def test_room_labels_take_the_large_surfaces_only():
    depth = np.ones((10, 10), np.float32)
    depth[0, :5] = 0.0  # 95 cells with depth
    cells = np.array([5, 60, 25, 9, 1])  # label 0 first
    assert room_labels(depth, cells, 0.1).tolist() == [1, 2]
    assert room_labels(np.zeros((4, 4), np.float32), cells, 0.1).size == 0
    # the previous frame's dynamic region covers most of surface 2: a mover, not the room
    labels = np.zeros((10, 10), np.int64)
    labels.flat[:60] = 1
    labels.flat[60:85] = 2
    prior = np.zeros((10, 10), bool)
    prior.flat[55:80] = True  # 5 cells of surface 1, 20 of 25 of surface 2
    assert room_labels(depth, cells, 0.1, labels, prior, 0.5).tolist() == [1]
    assert room_labels(depth, cells, 0.1, labels, prior, 0.9).tolist() == [1, 2]


def test_an_object_standing_in_the_room_is_not_its_shell():
    """A large box 2 m from the camera (its face fills 20 % of the grid) in front of the ray-cast room: along its
    whole outline it is the nearer side of a depth step, the walls and floor the farther one; the room's
    surfaces keep it out, a box mapped at rest that starts to move would pull the room's depth with it."""
    depth = _room_depth(T_REF)
    box = np.zeros(depth.shape, bool)
    box[30:80, 50:110] = True
    depth[box] = 2.0
    n, labels = surface_segments(depth, GRID, 0.04, 35.0)
    cells = np.bincount(labels.ravel(), minlength=n + 1)
    share = front_share(depth, labels, len(cells), 0.04)
    box_label = np.bincount(labels[box]).argmax()
    assert (labels[box] == box_label).all() and share[box_label] == 1.0
    big = [lab for lab in np.flatnonzero(cells >= 0.1 * (depth > 0).sum()) if lab > 0]
    shell = [lab for lab in big if lab != box_label]
    assert len(shell) >= 2 and all(share[lab] < 0.25 for lab in shell)  # behind the box (creases count for neither)
    assert box_label in room_labels(depth, cells, 0.1, labels).tolist()  # max_front = 1: the old rule keeps it
    kept = room_labels(depth, cells, 0.1, labels, max_front=0.75, step_rel=0.04).tolist()
    assert kept == shell
    # with the keypoints' surfaces: a textured box (half the keypoints on a fifth of the cells) is left out,
    # a plain one (a tenth of the keypoints) fixes what the walls leave free and stays
    others = [lab for lab in range(1, n + 1) if lab != box_label]
    textured = np.array([box_label] * 50 + others * (50 // len(others) + 1))[:100]
    plain = np.array([box_label] * 10 + others * (90 // len(others) + 1))[:100]
    assert room_labels(depth, cells, 0.1, labels, max_front=0.75, keypoint_labels=textured).tolist() == shell
    assert box_label in room_labels(depth, cells, 0.1, labels, max_front=0.75, keypoint_labels=plain).tolist()
    # a surface with no depth step on its outline (an empty room's wall) has share 0
    assert front_share(np.ones((4, 4), np.float32), np.ones((4, 4), np.int64), 2, 0.04).tolist() == [0.0, 0.0]


@pytest.mark.parametrize("field,value", [("room_depth_max_front", 1.5), ("room_depth_gain", -1.0), ("room_depth_min_share", 0.0),
                                         ("room_depth_min_points", 3), ("room_depth_min_m", -0.1),
                                         ("room_depth_miss", 0.0), ("room_depth_pull", 0.5)])
def test_room_depth_config_is_checked(field, value):
    with pytest.raises(ValueError, match=field):
        ReferencePoseConfig(**{field: value})


def test_stale_map_points_are_those_the_room_found_moving():
    """The map points the SLAM system removes after a frame (``Screener.moved_map_ids``): those matched on the
    surfaces the reference pose found moving, only when the room decided (step 3b's room test or step 3c)."""
    from dynslam_lab.dynamic.reference_pose import ReferencePose
    from dynslam_lab.dynamic.screening import stale_map_points

    ref = ReferencePose.none(6)
    ref.map_index[:] = [0, 1, -1, 2, 3, 4]
    ref.surface_moved[:] = [True, True, True, False, True, False]  # keypoint 2 has no map match
    map_ids = np.array([10, 11, 12, 13, 14])
    assert len(stale_map_points(ref, map_ids)) == 0  # the leave-one-out test alone: not culled
    ref.room_depth = True
    assert stale_map_points(ref, map_ids).tolist() == [10, 11, 13]
    ref.room_depth, ref.room = False, True
    assert stale_map_points(ref, map_ids).tolist() == [10, 11, 13]
    ref.surface_moved[:] = False
    assert len(stale_map_points(ref, map_ids)) == 0
