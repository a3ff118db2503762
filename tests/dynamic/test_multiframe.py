"""The multi-frame free-space test (DynaSLAM's multi-view test, Bescos et al. 2018) and the 2-D test
against an older frame, on hand-built scenes with known geometry."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dynslam_lab.dynamic.epipolar import LkConfig, track_lk
from dynslam_lab.dynamic.multiframe import (
    MultiFrameConfig,
    eroded_depth,
    free_space_test,
    grid_points,
    vanished_test,
)
from dynslam_lab.geometry.se3 import make_pose, se3_inv, transform_points
from tests.dynamic.scenes import CAM, texture

CFG = MultiFrameConfig()


def _wall(z: float = 3.0) -> np.ndarray:
    return np.full((CAM.height, CAM.width), z, np.float32)


def test_points_on_a_static_wall_agree_with_every_earlier_frame():
    T_w_j = [make_pose(None, np.array([0.02 * k, -0.01 * k, 0.0])) for k in range(1, 4)]
    refs = [(T, _wall()) for T in T_w_j]
    # points of the same wall seen from the current camera at the origin
    uv = np.column_stack([np.linspace(100, 540, 50), np.linspace(80, 400, 50)])
    X_w = CAM.backproject(uv, np.full(50, 3.0))
    fs = free_space_test(X_w, refs, CAM, CFG)
    assert fs.violations.sum() == 0 and fs.occlusions.sum() == 0
    assert np.all(fs.agreements == 3) and np.all(fs.tested == 3)
    assert np.nanmax(fs.margin_m) < 0


def test_a_point_where_an_earlier_frame_saw_through_is_a_violation_and_one_behind_is_occluded():
    refs = [(np.eye(4), _wall(3.0))]
    uv = np.array([[320.0, 240.0], [100.0, 100.0], [500.0, 300.0]])
    z = np.array([2.0, 3.05, 3.6])  # 1 m in front of the wall / on it / 0.6 m behind it
    fs = free_space_test(CAM.backproject(uv, z), refs, CAM, CFG)
    assert fs.violations.tolist() == [1, 0, 0]
    assert fs.agreements.tolist() == [0, 1, 0]
    assert fs.occlusions.tolist() == [0, 0, 1]
    assert fs.margin_m[0] == pytest.approx(1.0 - 0.1, abs=1e-4)  # z_j - z_p - tau, tau = 0.1 m at 2 m


def test_the_margin_grows_with_depth_squared_and_holes_give_no_verdict():
    d = _wall(6.0)
    d[:, :320] = 0  # the left half: no reading
    refs = [(np.eye(4), d)]
    uv = np.array([[500.0, 240.0], [500.0, 200.0], [100.0, 240.0]])
    z = np.array([5.75, 5.5, 2.0])
    fs = free_space_test(CAM.backproject(uv, z), refs, CAM, CFG)
    # tau at 5.75 m is 0.01 * 5.75^2 = 0.33 m: 0.25 m in front agrees; 0.5 m in front does not
    assert fs.violations.tolist() == [0, 1, 0]
    assert fs.tested.tolist() == [1, 1, 0]


def test_erosion_keeps_a_point_beside_a_depth_edge_from_faking_a_violation():
    d = _wall(4.0)
    d[:, :300] = 1.5  # a near object left of x = 300
    # a point of the near object, predicted 1 px off the edge onto the far side (a small pose error)
    X_w = CAM.backproject(np.array([[300.6, 240.0]]), np.array([1.5]))
    assert free_space_test(X_w, [(np.eye(4), d)], CAM, CFG).violations[0] == 1
    assert free_space_test(X_w, [(np.eye(4), eroded_depth(d, 2))], CAM, CFG).violations[0] == 0


def test_vanished_marks_where_an_earlier_point_is_now_seen_through():
    small = CAM.scaled(0.25)
    before = np.full((small.height, small.width), 4.0, np.float32)
    before[40:80, 60:100] = 2.0  # an object 2 m away, gone now
    now = np.full_like(before, 4.0)
    P, _ = grid_points(before, small)
    van = vanished_test([(np.eye(4), P)], np.eye(4), eroded_depth(now, 1), small, CFG)
    assert van[45:75, 65:95].all()
    assert van.sum() == pytest.approx(40 * 40, rel=0.1)
    # an object still there: nothing vanished
    assert vanished_test([(np.eye(4), P)], np.eye(4), eroded_depth(before, 1), small, CFG).sum() == 0


def test_grid_points_back_project_the_cells_with_depth():
    small = CAM.scaled(0.25)
    d = np.zeros((small.height, small.width), np.float32)
    d[10, 20] = 2.0
    d[30, 5] = 3.0
    P, keep = grid_points(d, small)
    assert keep.tolist() == [10 * small.width + 20, 30 * small.width + 5]
    uv, z = small.project(P.astype(float))
    assert np.allclose(uv, [[20, 10], [5, 30]], atol=1e-4) and np.allclose(z, [2, 3])


def test_lk_started_at_the_prediction_finds_static_points_there_and_a_moved_patch_away_from_it():
    tex = texture(CAM.height, CAM.width, seed=5)
    moved = tex.copy()
    moved[200:280, 300:380] = np.roll(tex[200:280, 300:380], 6, axis=1)  # a patch that moved 6 px right
    M = np.array([[1.0, 0.0, 3.0], [0.0, 1.0, -2.0]])
    earlier = cv2.warpAffine(tex, M, (CAM.width, CAM.height), borderMode=cv2.BORDER_REFLECT)  # camera shift (3, -2) px
    # the current image is `moved`; the earlier frame saw everything at +(3, -2), except the patch's content
    uv = np.array([[150.0, 120.0], [450.0, 380.0], [340.0, 240.0]])
    guess = uv + [3.0, -2.0]  # the static prediction
    q, ok = track_lk(earlier, moved, uv, LkConfig(), guess=guess)
    assert ok[:2].all()
    assert np.linalg.norm(q[:2] - guess[:2], axis=1).max() < 0.2
    assert ok[2] and np.linalg.norm(q[2] - guess[2]) == pytest.approx(6.0, abs=0.5)


def test_config_is_checked():
    with pytest.raises(ValueError, match="offsets"):
        MultiFrameConfig(offsets=())
    with pytest.raises(ValueError, match="lk_offset"):
        MultiFrameConfig(lk_offset=-1)
    assert MultiFrameConfig(offsets=(1, 3, 9)).history_length == 9


def test_a_moving_camera_and_an_earlier_pose_give_the_same_verdicts_as_a_moved_point():
    """Free space judged in the earlier camera: the test depends on the poses, not on the frame."""
    T_w_j = make_pose(None, np.array([0.3, 0.0, 0.2]))
    d_j = _wall(3.0)  # the earlier camera saw a wall 3 m ahead of it
    X_j = CAM.backproject(np.array([[320.0, 240.0], [200.0, 200.0]]), np.array([2.0, 3.0]))
    X_w = transform_points(T_w_j, X_j)
    fs = free_space_test(X_w, [(T_w_j, d_j)], CAM, CFG)
    assert fs.violations.tolist() == [1, 0]
    assert np.allclose(transform_points(se3_inv(T_w_j), X_w), X_j)


def _slow_box_frames(n: int = 17, arrive: int = 8):
    """A wall at 3 m seen by a camera sliding 1 cm per frame; from frame ``arrive`` a box at 1.5 m
    stands in the middle of the view and creeps 0.5 px per frame (truth: the box's pixels)."""
    from dynslam_lab.datasets.frame import Frame

    h, w = CAM.height, CAM.width
    wall_tex, box_tex = texture(h, w + 200, 3), texture(h, w, 4)
    out = []
    for k in range(n):
        tx = 0.01 * k
        dx = int(round(CAM.fx * tx / 3.0))
        gray = wall_tex[:, dx : dx + w].copy()
        depth = np.full((h, w), 3.0, np.float32)
        box = np.zeros((h, w), bool)
        if k >= arrive:
            x0 = 250 + int((k - arrive) * 0.5) - int(round(CAM.fx * tx / 1.5)) + int(round(CAM.fx * 0.01 * arrive / 1.5))
            box[160:320, x0 : x0 + 140] = True
            gray[box] = box_tex[box]
            depth[box] = 1.5
        rgb = np.repeat(gray[:, :, None], 3, axis=2)
        T_w_c = make_pose(np.eye(3), np.array([tx, 0.0, 0.0]))
        out.append((Frame(index=k, timestamp=k / 30.0, rgb=rgb, depth=depth, camera=CAM, T_w_c_gt=T_w_c), box))
    return out


def test_far_frames_find_a_slow_mover_that_the_recent_frames_saw_standing_there():
    from dynslam_lab.dynamic.config import ScreeningConfig
    from dynslam_lab.dynamic.context import ScreeningContext
    from dynslam_lab.dynamic.screening import Screener

    frames = _slow_box_frames()
    ys, xs = np.mgrid[8 : CAM.height - 8 : 12, 8 : CAM.width - 8 : 12]
    uv = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(float)

    def last_verdict(far_count: int):
        cfg = ScreeningConfig(multiframe=MultiFrameConfig(offsets=(1, 2), lk_offset=0, far_every=3, far_count=far_count))
        s = Screener(("multiframe",), cfg)
        poses = {}
        for f, _ in frames:
            table = s.screen(f, uv, None, context=ScreeningContext(se3_inv(f.T_w_c_gt), dict(poses)))
            poses[float(f.timestamp)] = f.T_w_c_gt
        return s, table.dynamic

    box = frames[-1][1]
    on_box = box[uv[:, 1].astype(int), uv[:, 0].astype(int)]
    s, far = last_verdict(4)
    # history 14, 15 (+16 being screened); far frames 3, 6, 9, 12 (kept one every 3 as they leave the history)
    assert [f.index for f in s.memory.far] == [3, 6, 9, 12]
    _, near = last_verdict(0)
    assert far[on_box].mean() >= 0.95  # frames 3 and 6 saw the wall where the box stands now
    assert not far[~on_box].any()  # no static point lies where any earlier frame saw through
    assert near[on_box].mean() <= 0.1  # the recent frames saw the box there too: only its creeping edge
    with pytest.raises(ValueError, match="far_every"):
        MultiFrameConfig(far_every=0)
    with pytest.raises(ValueError, match="far_count"):
        MultiFrameConfig(far_count=-1)


def test_far_frames_are_dropped_when_a_loop_closure_moves_the_kept_poses():
    from dynslam_lab.dynamic.config import ScreeningConfig
    from dynslam_lab.dynamic.context import ScreeningContext
    from dynslam_lab.dynamic.history import FarFrames, FrameHistory, PastFrame
    from dynslam_lab.dynamic.screening import Screener

    h, far = FrameHistory(2), FarFrames(every=2, count=2)
    img, dep = np.zeros((4, 4), np.uint8), np.zeros((4, 4), np.float32)
    for k in range(6):
        evicted = h.push(PastFrame(k, float(k), img, dep, T_w_c=make_pose(None, np.array([0.1 * k, 0, 0]))))
        if evicted is not None:
            far.offer(evicted.index, evicted.T_w_c, lambda: dep[::2, ::2])
    assert [f.index for f in far] == [0, 2] and [f.index for f in h] == [4, 5]
    # the kept frames' poses move by 5 cm along y: update_poses reports the oldest one's correction
    shift = make_pose(None, np.array([0.0, 0.05, 0.0]))
    corr = h.update_poses({4.0: shift @ h.back(2).T_w_c, 5.0: shift @ h.back(1).T_w_c})
    assert np.allclose(corr, shift)
    assert h.update_poses({4.0: h.back(2).T_w_c}) is None  # nothing changed

    # through the screener: local BA's millimetres keep the far frames, a loop closure's decimetres drop them
    frames = _slow_box_frames()
    uv = np.array([[320.0, 240.0]])
    cfg = ScreeningConfig(multiframe=MultiFrameConfig(offsets=(1, 2), lk_offset=0, far_every=3, far_count=4))
    s = Screener(("multiframe",), cfg)
    poses = {}
    for f, _ in frames:
        s.screen(f, uv, None, context=ScreeningContext(se3_inv(f.T_w_c_gt), dict(poses)))
        poses[float(f.timestamp)] = f.T_w_c_gt
    stale = {f.index for f in s.memory.far}
    assert len(stale) == 4
    jitter = make_pose(None, np.array([0.002, 0.0, 0.0]))
    s.screen(frames[-1][0], uv, None, context=ScreeningContext(None, {t: jitter @ T for t, T in poses.items()}))
    assert len(s.memory.far) == 4
    loop = make_pose(None, np.array([0.0, 0.2, 0.0]))
    s.screen(frames[-1][0], uv, None, context=ScreeningContext(None, {t: loop @ T for t, T in poses.items()}))
    assert not stale & {f.index for f in s.memory.far}  # only a frame leaving the history since, with its new pose
    with pytest.raises(ValueError, match="far_min_filter_cells"):
        MultiFrameConfig(far_min_filter_cells=-1)


def _free_space_by_frame(X_w, refs, camera, config):
    """The forward test written point by point and frame by frame (float64): the reference for the
    vectorised :func:`free_space_test`. Returns the counts and, per point and frame, the distance of
    ``z_j - z_p`` to its nearest threshold and of the projection to its nearest rounding or border edge."""
    m = len(X_w)
    viol, agree, occl = np.zeros(m, int), np.zeros(m, int), np.zeros(m, int)
    slack = np.full(m, np.inf)
    for T_w_j, d in refs:
        h, w = d.shape
        X = transform_points(se3_inv(T_w_j), X_w)
        for i, (x, y, z) in enumerate(X):
            u, v = camera.fx * x / z + camera.cx, camera.fy * y / z + camera.cy
            b = config.border_px
            edge = min(abs(u - np.floor(u) - 0.5), abs(v - np.floor(v) - 0.5), abs(u - b), abs(v - b),
                       abs(u - (w - 1 - b)), abs(v - (h - 1 - b)))
            slack[i] = min(slack[i], edge)
            if not (z > 0.05 and b <= u <= w - 1 - b and b <= v <= h - 1 - b):
                continue
            zj = float(d[int(round(v)), int(round(u))])
            if zj <= 0:
                continue
            tau = max(config.depth_m, config.depth_quadratic * z * z)
            dz = zj - z
            slack[i] = min(slack[i], abs(abs(dz) - tau))
            viol[i] += dz > tau
            agree[i] += abs(dz) <= tau
            occl[i] += dz < -tau
    return viol, agree, occl, slack


def test_the_vectorised_free_space_test_counts_as_the_point_by_point_one():
    rng = np.random.default_rng(3)
    small = CAM.scaled(0.25)
    refs = []
    for k in range(4):
        d = rng.uniform(1.0, 5.0, (small.height, small.width)).astype(np.float32)
        d[rng.random(d.shape) < 0.1] = 0  # holes
        refs.append((make_pose(None, rng.normal(0, 0.05, 3)), d))
    uv = np.column_stack([rng.uniform(-20, small.width + 20, 400), rng.uniform(-20, small.height + 20, 400)])
    X_w = small.backproject(uv, rng.uniform(0.5, 5.0, 400))
    viol, agree, occl, slack = _free_space_by_frame(X_w, refs, small, CFG)
    clear = slack > 1e-3  # float32 rounding cannot flip these
    assert clear.mean() > 0.9
    for margin in (True, False):
        fs = free_space_test(X_w, refs, small, CFG, margin=margin)
        assert np.array_equal(fs.violations[clear], viol[clear])
        assert np.array_equal(fs.agreements[clear], agree[clear])
        assert np.array_equal(fs.occlusions[clear], occl[clear])
        assert np.isnan(fs.margin_m).all() != margin


def test_window_span_matches_a_window_by_window_loop():
    from dynslam_lab.dynamic.stages import _window_span

    rng = np.random.default_rng(4)
    d = rng.uniform(1.0, 4.0, (60, 80)).astype(np.float32)
    d[rng.random(d.shape) < 0.01] = 0
    uv = np.column_stack([rng.uniform(-2, 82, 300), rng.uniform(-2, 62, 300)])
    for r in (0, 2, 5):
        expected = []
        for u, v in uv:
            c, row = int(np.rint(u)), int(np.rint(v))
            win = d[max(row - r, 0) : row + r + 1, max(c - r, 0) : c + r + 1]
            full = row - r >= 0 and c - r >= 0 and row + r < d.shape[0] and c + r < d.shape[1]
            expected.append(win.max() - win.min() if full and (win > 0).all() else np.inf)
        assert np.array_equal(_window_span(d, uv, r), np.array(expected))
