"""The dense point-to-plane term against a hand-built room corner: normals of the vertex grid, the
Jacobian against finite differences, and the pose it recovers against the true one."""

from __future__ import annotations

import contextlib

import cv2
import numpy as np

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.geometry.se3 import make_pose, se3_inv, so3_exp
from dynslam_lab.slam import optimize as opt
from dynslam_lab.datasets.kinect import DepthNoise, kinect_depth, nguyen_sigma
from dynslam_lab.geometry.depth_alignment import (DenseTerm, DepthSource, HybridTerm, ReprojectionTerm, align_depth, fuse_depth_model,
                                                 image_level, photometric_term, smooth_depth, vertex_normal_grid,
                                                 brightness_transfer)
from dynslam_lab.slam.optimize import Observations, optimize_pose

CAM = CAMERA_PRESETS["default"]
# planes n . X = c in the world (unit n): a wall ahead, a wall to the right, the floor
PLANES = [(np.array([0.0, 0.0, 1.0]), 3.0), (np.array([1.0, 0.0, 0.0]), 1.2), (np.array([0.0, 1.0, 0.0]), 1.0)]


def _depth(T_w_c: np.ndarray) -> np.ndarray:
    """Exact depth image of the room corner seen from ``T_w_c`` (ray-plane intersections)."""
    v, u = np.mgrid[0 : CAM.height, 0 : CAM.width]
    rays = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones(u.shape)], axis=-1)  # z = 1
    R, C = T_w_c[:3, :3], T_w_c[:3, 3]
    d_w = rays @ R.T
    z = np.full(u.shape, np.inf)
    for n, c in PLANES:
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (c - n @ C) / (d_w @ n)
        z = np.where((s > 0) & (s < z), s, z)
    return np.where(np.isfinite(z), z, 0.0).astype(np.float32)


@contextlib.contextmanager
def _wall_and_floor_only():
    """The room without its side wall (the wall ahead and the floor) inside the ``with`` block: depth cannot
    see a slide along both."""
    planes = list(PLANES)
    PLANES[:] = [planes[0], planes[2]]
    try:
        yield
    finally:
        PLANES[:] = planes


def _term(T_w_ref: np.ndarray, T_w_cur: np.ndarray, stride: int = 8) -> DenseTerm:
    ref = vertex_normal_grid(_depth(T_w_ref), CAM, stride)
    X = CAM.backproject_depth(_depth(T_w_cur), stride).reshape(-1, 3)
    X = X[np.isfinite(X).all(axis=1)]
    return DenseTerm(X, np.full(len(X), 0.005), ref, se3_inv(T_w_ref), CAM)


def test_normals_of_the_room_corner_are_the_planes_normals():
    T = make_pose(so3_exp([0.05, 0.1, 0.0]), [0.1, -0.1, 0.2])
    g = vertex_normal_grid(_depth(T), CAM, 8)
    n_w = g.N.reshape(-1, 3) @ T[:3, :3].T
    ok = np.isfinite(n_w).all(axis=1)
    assert ok.mean() > 0.8
    # the known normals are the three planes' (facing the camera: minus the plane normal), but along
    # the creases where two planes meet (no depth jump there: the differences straddle both planes)
    best = np.max(np.stack([n_w[ok] @ -n for n, _ in PLANES], axis=1), axis=1)
    assert (best > 0.9999).mean() > 0.97 and best.min() > 0.5


def test_dense_jacobian_matches_finite_differences():
    T_w_ref = make_pose(so3_exp([0.0, 0.05, 0.0]), [0.0, 0.0, 0.0])
    T_w_cur = make_pose(so3_exp([0.01, 0.07, -0.01]), [0.03, -0.02, 0.05])
    term = _term(T_w_ref, T_w_cur)
    T_c_w = se3_inv(T_w_cur) @ make_pose(so3_exp([0.002, -0.003, 0.001]), [0.004, 0.0, -0.003])
    R, t = T_c_w[:3, :3], T_c_w[:3, 3]
    e0, J, _ = term.residuals(R, t)
    idx, _, _ = term.associate(R, t)
    assert len(idx) > 2000

    def e_fixed(dx):  # the same associations' residuals (planes: the association does not matter)
        Rn, tn = opt._rodrigues(dx[:3]) @ R, t + dx[3:]
        i2, _, d = term.associate(Rn, tn)
        full = np.full(len(term.X), np.nan)
        full[i2] = d / term.sigma[i2]
        return full[idx]

    eps = 1e-6
    J_num = np.stack([(e_fixed(e) - e_fixed(-e)) / (2 * eps) for e in np.eye(6) * eps], axis=1)
    ok = np.isfinite(J_num).all(axis=1)
    assert ok.mean() > 0.99
    np.testing.assert_allclose(J[ok], J_num[ok], atol=1e-3 * np.abs(J_num[ok]).max())


def test_dense_term_recovers_the_pose_with_two_feature_matches():
    """Two feature matches without depth (4 equations) cannot fix a pose; with the depth of the room
    corner the pose is found to a millimetre (the creases' mixed normals: 0.6 mm) from a start 3 cm
    and 1.5 deg off."""
    T_w_ref = make_pose(so3_exp([0.0, 0.05, 0.0]), [0.0, 0.0, 0.0])
    T_w_cur = make_pose(so3_exp([0.01, 0.08, -0.01]), [0.04, -0.02, 0.05])
    term = _term(T_w_ref, T_w_cur)
    X_w = np.array([[0.2, 0.1, 3.0], [-0.5, 0.3, 3.0]])
    T_c_w = se3_inv(T_w_cur)
    uv, _ = CAM.project(X_w @ T_c_w[:3, :3].T + T_c_w[:3, 3])
    obs = Observations.from_keypoints(uv, np.full(2, np.nan), np.zeros(2), 40.0, 1.2, z_sigma=np.full(2, np.nan))
    T0 = make_pose(so3_exp([0.0, 0.025, 0.01]), [0.03, 0.01, -0.01]) @ T_c_w
    T, out = optimize_pose(T0, X_w, obs, CAM, 40.0, dense=term)
    err = T @ T_w_cur
    assert np.linalg.norm(err[:3, 3]) < 1e-3 and not out.any()
    assert np.degrees(np.arccos(np.clip((np.trace(err[:3, :3]) - 1) / 2, -1, 1))) < 0.05
    T_f, _ = optimize_pose(T0, X_w, obs, CAM, 40.0)  # features alone: the pose stays where it started
    assert np.linalg.norm((T_f @ T_w_cur)[:3, 3]) > 0.02


def test_prior_residuals_match_finite_differences_and_vanish_at_the_prior():
    T_p = make_pose(so3_exp([0.1, -0.2, 0.05]), [0.3, -0.1, 1.2])
    term = DenseTerm(np.zeros((0, 3)), np.zeros(0), vertex_normal_grid(np.zeros((48, 64), np.float32), CAM, 8),
                     np.eye(4), CAM, T_prior=T_p, prior_sigma=(0.02, 1.0))
    e0, _ = term.prior_residuals(T_p[:3, :3], T_p[:3, 3])
    assert np.abs(e0).max() < 1e-6
    T = make_pose(so3_exp([0.004, 0.002, -0.003]), [0.01, -0.02, 0.005]) @ T_p
    R, t = T[:3, :3], T[:3, 3]
    e, J = term.prior_residuals(R, t)
    # by hand: the rotation part is the rotation vector of T T_p^-1 over 1 deg, the translation its
    # translation over 2 cm
    np.testing.assert_allclose(e[:3], np.array([0.004, 0.002, -0.003]) / np.radians(1.0), rtol=1e-6)
    np.testing.assert_allclose(e[3:], (T @ se3_inv(T_p))[:3, 3] / 0.02, rtol=1e-9)
    eps = 1e-7

    def f(dx):
        return term.prior_residuals(opt._rodrigues(dx[:3]) @ R, t + dx[3:])[0]

    J_num = np.stack([(f(d) - f(-d)) / (2 * eps) for d in np.eye(6) * eps], axis=1)
    np.testing.assert_allclose(J, J_num, atol=2e-2 * np.abs(J_num).max())  # first order at a 0.3 deg error


def test_reprojection_term_matches_opencv_and_finite_differences():
    rng = np.random.default_rng(5)
    T_c_w = make_pose(so3_exp([0.05, -0.1, 0.02]), [0.2, -0.1, 0.3])
    X_w = se3_inv(T_c_w)[:3, :3] @ np.column_stack([rng.uniform(-1, 1, 30), rng.uniform(-1, 1, 30), rng.uniform(1, 4, 30)]).T
    X_w = X_w.T + se3_inv(T_c_w)[:3, 3]
    sigma = rng.choice([1.0, 1.2, 1.44], 30)
    uv_true = cv2.projectPoints(X_w, cv2.Rodrigues(T_c_w[:3, :3])[0], T_c_w[:3, 3], CAM.K, None)[0].reshape(-1, 2)
    uv = uv_true + rng.normal(0, 0.5, uv_true.shape)
    term = ReprojectionTerm(X_w, uv, CAM.K, sigma)
    R, t = T_c_w[:3, :3], T_c_w[:3, 3]
    e, J = term.residuals(R, t)
    np.testing.assert_allclose(e.reshape(-1, 2), (uv_true - uv) / sigma[:, None], atol=1e-9)  # OpenCV's projection
    eps = 1e-6

    def f(dx):
        return term.residuals(opt._rodrigues(dx[:3]) @ R, t + dx[3:])[0]

    J_num = np.stack([(f(d) - f(-d)) / (2 * eps) for d in np.eye(6) * eps], axis=1)
    np.testing.assert_allclose(J, J_num, atol=1e-5 * np.abs(J_num).max())


def test_features_fix_the_slide_the_planes_leave_free():
    """The floor and the wall ahead only (no side wall): depth cannot see a slide along both; with a
    dozen feature matches joined to the alignment the slide is removed, without them it stays."""
    with _wall_and_floor_only():
        T_w_ref = make_pose(so3_exp([0.0, 0.05, 0.0]), [0.0, 0.0, 0.0])
        T_w_cur = make_pose(so3_exp([0.01, 0.08, -0.01]), [0.04, -0.02, 0.05])
        term = _term(T_w_ref, T_w_cur)
    T_true = se3_inv(T_w_cur)
    slid = make_pose(np.eye(3), T_true[:3, :3] @ np.array([0.03, 0.0, 0.0])) @ T_true  # 3 cm along the wall and the floor
    term.T_prior, term.prior_sigma = slid, (0.05, 2.0)
    rng = np.random.default_rng(2)
    X_w = np.column_stack([rng.uniform(-1.0, 1.0, 12), rng.uniform(-0.8, 0.8, 12), np.full(12, 3.0)])  # on the wall
    uv, _ = CAM.project(X_w @ T_true[:3, :3].T + T_true[:3, 3])
    feats = ReprojectionTerm(X_w, uv, CAM.K, np.ones(12))
    a = align_depth(term, slid)
    assert np.linalg.norm((a.T_c_w @ T_w_cur)[:3, 3]) > 0.02  # depth alone: the slide stays
    b = align_depth(term, slid, features=feats)
    assert np.linalg.norm((b.T_c_w @ T_w_cur)[:3, 3]) < 0.002


def _source(T_w_c: np.ndarray, priority: int = 0, depth: np.ndarray | None = None) -> DepthSource:
    g = vertex_normal_grid(_depth(T_w_c) if depth is None else depth, CAM, 4, step=2)
    return DepthSource.from_grid(g, T_w_c, priority)


def test_normals_two_cells_apart_are_the_planes_normals():
    T = make_pose(so3_exp([0.05, 0.1, 0.0]), [0.1, -0.1, 0.2])
    g = vertex_normal_grid(_depth(T), CAM, 4, step=2)
    n_w = g.N.reshape(-1, 3) @ T[:3, :3].T
    ok = np.isfinite(n_w).all(axis=1)
    assert ok.mean() > 0.8 and g.V.shape[:2] == (120, 160)
    best = np.max(np.stack([n_w[ok] @ -n for n, _ in PLANES], axis=1), axis=1)
    assert (best > 0.9999).mean() > 0.95


def test_fused_model_of_two_keyframes_is_the_room_seen_from_a_third_pose():
    """Two views of the room corner fused into the grid of a third pose: every fused vertex lies on one of
    the planes (exact float32 depth: to a micrometre but at the creases, where a cell's samples straddle two planes), its
    normal is that plane's, and the cells the two views see are nearly all filled."""
    T_a = make_pose(so3_exp([0.0, 0.05, 0.0]), [0.0, 0.0, 0.0])
    T_b = make_pose(so3_exp([0.02, 0.12, 0.0]), [0.15, -0.05, 0.1])
    T_r = make_pose(so3_exp([0.01, 0.09, -0.01]), [0.08, -0.02, 0.05])
    grid, count = fuse_depth_model([_source(T_a), _source(T_b)], se3_inv(T_r), CAM, 8)
    assert grid.V.shape == (60, 80, 3) and grid.stride == 8
    has = np.isfinite(grid.V).all(axis=-1)
    assert has.mean() > 0.9 and (count[has] > 0).all() and (count[~has] == 0).all()
    assert np.median(count[has]) >= 4  # two views of stride-4 samples per stride-8 cell
    V_w = grid.V[has] @ T_r[:3, :3].T + T_r[:3, 3]
    n_w = grid.N[has] @ T_r[:3, :3].T
    dist = np.min(np.stack([np.abs(V_w @ n - c) for n, c in PLANES], axis=1), axis=1)
    assert np.quantile(dist, 0.95) < 1e-6
    best = np.max(np.stack([n_w @ -n for n, _ in PLANES], axis=1), axis=1)
    assert (best > 0.9999).mean() > 0.9 and np.median(best) > 0.99999  # mixed along the creases


def test_fused_model_takes_the_lower_priority_only_where_the_first_leaves_cells_empty():
    """A keyframe that sees only the left half of the image (priority 0) and a last frame whose pose is 2 cm
    off (priority 1): the left cells come from the keyframe alone (on the planes), the right ones from the
    last frame (2 cm off the planes); nothing is averaged across the two."""
    T = make_pose(so3_exp([0.0, 0.05, 0.0]), [0.0, 0.0, 0.0])
    left = _depth(T)
    left[:, 320:] = 0.0
    off = make_pose(np.eye(3), [0.0, 0.0, 0.02]) @ T  # the last frame's (wrong) pose: its depth is T's
    grid, _ = fuse_depth_model([_source(T, 0, left), _source(off, 1, _depth(T))], se3_inv(T), CAM, 8)
    V_w = grid.V @ T[:3, :3].T + T[:3, 3]
    dist = np.min(np.stack([np.abs(V_w @ n - c) for n, c in PLANES], axis=-1), axis=-1)
    assert np.nanquantile(dist[:, 2:38], 0.95) < 1e-6  # cells 2..37: left of x = 300 px
    assert np.nanmedian(dist[:, 42:78]) > 0.01  # from the misplaced last frame


def test_dense_term_against_a_keyframe_model_recovers_the_pose():
    """The frame's depth against the model fused from two keyframes (not the last frame) and two feature
    matches: the pose to 1.5 mm (the creases' mixed normals; 0.6 mm against the exact last frame) from a start
    3 cm and 1.5 deg off."""
    T_a = make_pose(so3_exp([0.0, 0.05, 0.0]), [0.0, 0.0, 0.0])
    T_b = make_pose(so3_exp([0.02, 0.12, 0.0]), [0.15, -0.05, 0.1])
    T_w_cur = make_pose(so3_exp([0.01, 0.08, -0.01]), [0.04, -0.02, 0.05])
    T_c_w = se3_inv(T_w_cur)
    T0 = make_pose(so3_exp([0.0, 0.025, 0.01]), [0.03, 0.01, -0.01]) @ T_c_w
    grid, _ = fuse_depth_model([_source(T_a), _source(T_b)], T0, CAM, 8)  # seen from the start pose
    X = CAM.backproject_depth(_depth(T_w_cur), 8).reshape(-1, 3)
    X = X[np.isfinite(X).all(axis=1)]
    term = DenseTerm(X, np.full(len(X), 0.005), grid, T0, CAM)
    X_w = np.array([[0.2, 0.1, 3.0], [-0.5, 0.3, 3.0]])
    uv, _ = CAM.project(X_w @ T_c_w[:3, :3].T + T_c_w[:3, 3])
    obs = Observations.from_keypoints(uv, np.full(2, np.nan), np.zeros(2), 40.0, 1.2, z_sigma=np.full(2, np.nan))
    T, out = optimize_pose(T0, X_w, obs, CAM, 40.0, dense=term)
    err = T @ T_w_cur
    assert np.linalg.norm(err[:3, 3]) < 1.5e-3 and not out.any()
    assert np.degrees(np.arccos(np.clip((np.trace(err[:3, :3]) - 1) / 2, -1, 1))) < 0.05


def test_smoothing_removes_the_bias_of_quantised_depth():
    """The room corner seen by the Kinect model (noise and 1/8 px disparity steps: 1.6 cm at 2.3 m,
    :func:`~dynslam_lab.datasets.kinect.kinect_depth`) from eight pose pairs ~1 cm / 0.3 deg apart, aligned by
    depth alone starting at the true pose: on the raw depth the point-to-plane optimum lands off the truth (the
    two staircases pull it; median 3 mm here), averaged over 9 x 9 px first (``smooth_depth``) several times
    closer (0.2 mm)."""
    rng = np.random.default_rng(3)
    noise = DepthNoise(dropout_rate=0.0)
    ones = np.ones((CAM.height, CAM.width), np.float32)
    err = {1: [], 9: []}
    for k in range(8):
        T_ref = make_pose(so3_exp(rng.normal(0, 0.03, 3)), rng.normal(0, 0.1, 3))
        T_cur = make_pose(so3_exp(rng.normal(0, 0.004, 3)), rng.normal(0, 0.006, 3)) @ T_ref
        d_ref = kinect_depth(_depth(T_ref), ones, CAM.fx, noise, rng)
        d_cur = kinect_depth(_depth(T_cur), ones, CAM.fx, noise, rng)
        for size in err:
            ref = vertex_normal_grid(smooth_depth(d_ref, size), CAM, 8)
            X = CAM.backproject_depth(smooth_depth(d_cur, size), 8).reshape(-1, 3)
            X = X[np.isfinite(X).all(axis=1)]
            sigma = 1.5 * nguyen_sigma(X[:, 2], 0.0, noise)
            term = DenseTerm(X, sigma, ref, se3_inv(T_ref), CAM)
            obs = Observations.from_keypoints(np.zeros((0, 2)), np.zeros(0), np.zeros(0), 400.0, 1.2)
            T, _ = optimize_pose(se3_inv(T_cur), np.zeros((0, 3)), obs, CAM, 400.0, dense=term)
            err[size].append(np.linalg.norm((T @ T_cur)[:3, 3]))
    raw, smooth = np.median(err[1]), np.median(err[9])
    assert smooth < 0.4 * raw and smooth < 1e-3, (np.round(err[1], 4), np.round(err[9], 4))


def test_samples_the_reference_never_saw_do_not_pull_the_pose_back():
    """The wall ahead and the floor (a slide along both is free), the camera 6 cm to the side of the
    reference, the prior at the true pose. A sample that falls outside the reference's image cannot be
    associated; charged the gate, such samples pull the pose back towards the reference, where fewer of
    them fall outside: from a start 3 cm back, the pose stops 6.5 mm short of the prior, where the samples it would lose outweigh it
    (`loop_flat` seed 8: 32 mm a frame tracked as 9). Charged only where the prior puts them well inside
    the reference's image (``DenseTerm.in_view``), the pose returns to the truth."""
    with _wall_and_floor_only():
        T_w_ref = make_pose(np.eye(3), [0.0, 0.0, 0.0])
        T_w_cur = make_pose(np.eye(3), [0.06, 0.0, 0.0])
        term = _term(T_w_ref, T_w_cur)
    T_true = se3_inv(T_w_cur)
    term.T_prior, term.prior_sigma = T_true, (0.02, 1.0)
    none = Observations.from_keypoints(np.zeros((0, 2)), np.zeros(0), np.zeros(0), 40.0, 1.2, z_sigma=np.zeros(0))
    view = term.in_view(T_true, 16.0)
    # by hand: the reference sees a sample 6 cm to the right of where the frame does; the grid's cells
    # (8 px) span -4 ... 636 px, and 16 px in from both sides is 12 ... 620 px (all rows: the floor
    # and the wall fill the image from top to bottom)
    Y = term.X + np.array([0.06, 0.0, 0.0])
    u = CAM.fx * Y[:, 0] / Y[:, 2] + CAM.cx
    v = CAM.fy * Y[:, 1] / Y[:, 2] + CAM.cy
    assert np.array_equal(view, (u >= 12.0) & (u < 620.0) & (v >= 12.0) & (v < 460.0))
    assert 0.8 * len(view) < view.sum() < len(view)
    # the start: 3 cm back towards the reference (where a few wrong feature matches may leave it)
    T0 = se3_inv(make_pose(np.eye(3), [0.03, 0.0, 0.0]))
    slide = {}
    for name, charged in (("all", None), ("in view", view)):
        term.charged = charged
        T, _ = optimize_pose(T0, np.zeros((0, 3)), none, CAM, 40.0, dense=term)
        slide[name] = (T @ T_w_cur)[:3, 3]
    assert np.linalg.norm(slide["all"]) > 0.005  # held back towards the reference (6.5 mm)
    assert np.linalg.norm(slide["in view"]) < 0.001


# --- the photometric term (hybrid RGB-D odometry) -----------------------------------------------------------

def _image(T_w_c: np.ndarray) -> np.ndarray:
    """Grey image of the room corner seen from ``T_w_c``: plain walls (120) and floor (90) with one poster
    (200) on the wall ahead, x in [-0.4, 0.3] m, y in [-0.5, 0.2] m; blurred 1.5 px as a lens would."""
    z = _depth(T_w_c).astype(np.float64)
    X_c = CAM.backproject_depth(z)
    X_w = X_c @ T_w_c[:3, :3].T + T_w_c[:3, 3]
    img = np.full(z.shape, 120.0)
    img[np.abs(X_w[..., 1] - 1.0) < 1e-6] = 90.0  # the floor, y = 1
    poster = (np.abs(X_w[..., 2] - 3.0) < 1e-6) & (X_w[..., 0] > -0.4) & (X_w[..., 0] < 0.3) \
        & (X_w[..., 1] > -0.5) & (X_w[..., 1] < 0.2)
    img[poster] = 200.0
    return cv2.GaussianBlur(img.astype(np.float32), (0, 0), 1.5)


def _photo(T_w_ref: np.ndarray, T_w_cur: np.ndarray, scale: int):
    ref = image_level(_image(T_w_ref), _depth(T_w_ref), CAM, scale)
    cur = image_level(_image(T_w_cur), _depth(T_w_cur), CAM, scale)
    return photometric_term(cur, ref, se3_inv(T_w_ref), sigma=2.0)


def test_image_level_depth_is_the_block_mean_and_none_across_a_depth_edge():
    depth = np.full((8, 8), 2.0, np.float32)
    depth[:, 4:] = 3.0
    depth[0, 0] = 0.0  # a missing reading
    depth[4:, 2:4] = np.array([[2.0, 2.02]] * 4)
    lvl = image_level(np.zeros((8, 8), np.uint8), depth, CAM, 2)
    assert lvl.I.shape == (4, 4) and lvl.camera.fx == CAM.fx / 2
    assert np.isnan(lvl.z[0, 0])  # the block with the missing reading
    assert lvl.z[0, 1] == 2.0 and lvl.z[3, 3] == 3.0
    assert lvl.z[2, 1] == np.float32(2.01)  # 2 cm over 2 m: within 3 cm per m
    wide = depth.copy()
    wide[4:, 3] = 2.2  # 20 cm across the block: a depth edge
    assert np.isnan(image_level(np.zeros((8, 8), np.uint8), wide, CAM, 2).z[2, 1])
    odd = depth.copy()
    odd[1, 7], odd[7, 6], odd[6, 0] = np.nan, -1.0, np.inf  # unreadable values count as missing, like 0
    z = image_level(np.zeros((8, 8), np.uint8), odd, CAM, 2).z
    assert np.isnan(z[0, 3]) and np.isnan(z[3, 3]) and np.isnan(z[3, 0])
    assert int(np.isnan(z).sum()) == 4  # those three blocks and the one with the 0


def test_photometric_jacobian_matches_finite_differences():
    """The chain rule of :class:`PhotometricTerm` against central differences, on a reference image whose
    gradient is known exactly (a smooth wave, its gradient given in closed form, not by Sobel)."""
    T_w_ref = make_pose(so3_exp([0.0, 0.05, 0.0]), [0.0, 0.0, 0.0])
    T_w_cur = make_pose(so3_exp([0.01, 0.07, -0.01]), [0.03, -0.02, 0.05])
    ref = image_level(np.zeros((CAM.height, CAM.width), np.uint8), _depth(T_w_ref), CAM, 2)
    v, u = np.mgrid[0 : ref.I.shape[0], 0 : ref.I.shape[1]].astype(np.float64)
    ref.I = (100 + 50 * np.sin(u / 9.0) * np.cos(v / 7.0)).astype(np.float32)
    ref.gx = (50 / 9.0 * np.cos(u / 9.0) * np.cos(v / 7.0)).astype(np.float32)
    ref.gy = (-50 / 7.0 * np.sin(u / 9.0) * np.sin(v / 7.0)).astype(np.float32)
    cur = image_level(_image(T_w_cur), _depth(T_w_cur), CAM, 2)
    photo = photometric_term(cur, ref, se3_inv(T_w_ref), sigma=2.0, min_gradient=0.0, affine=False)  # the chain rule at fixed brightness
    assert len(photo.X) > 2000
    T_c_w = se3_inv(T_w_cur) @ make_pose(so3_exp([0.002, -0.003, 0.001]), [0.004, 0.0, -0.003])
    R, t = T_c_w[:3, :3], T_c_w[:3, 3]
    idx, e0, J = photo.evaluate(R, t)

    def e_fixed(dx):
        i2, e, _ = photo.evaluate(opt._rodrigues(dx[:3]) @ R, t + dx[3:])
        full = np.full(len(photo.X), np.nan)
        full[i2] = e
        return full[idx]

    eps = 1e-5
    J_num = np.stack([(e_fixed(e) - e_fixed(-e)) / (2 * eps) for e in np.eye(6) * eps], axis=1)
    ok = np.isfinite(J_num).all(axis=1)
    assert ok.mean() > 0.99
    # central differences of a bilinear image carry its interpolation error (a wave 40-60 px long: ~1 %)
    err = np.linalg.norm(J[ok] - J_num[ok], axis=1) / np.linalg.norm(J_num[ok], axis=1).max()
    assert np.median(err) < 0.02 and np.percentile(err, 99) < 0.1


def test_image_edges_fix_the_slide_a_plain_wall_leaves_free():
    """The floor and the wall ahead only, plain but for one poster: their depth cannot see a slide along both
    (the prior holds the pose where it started); the poster's edges and the crease, coarse to fine, remove it."""
    with _wall_and_floor_only():
        T_w_ref = make_pose(so3_exp([0.0, 0.05, 0.0]), [0.0, 0.0, 0.0])
        T_w_cur = make_pose(so3_exp([0.01, 0.08, -0.01]), [0.04, -0.02, 0.05])
        term = _term(T_w_ref, T_w_cur)
        photos = [_photo(T_w_ref, T_w_cur, s) for s in (4, 2)]
    T_true = se3_inv(T_w_cur)
    slid = make_pose(np.eye(3), T_true[:3, :3] @ np.array([0.03, 0.0, 0.0])) @ T_true  # 3 cm along the wall and the floor
    term.T_prior, term.prior_sigma = slid, (0.02, 1.0)
    a = align_depth(term, slid)
    assert np.linalg.norm((a.T_c_w @ T_w_cur)[:3, 3]) > 0.02  # depth alone: the slide stays
    T = slid
    for photo in photos:
        T = align_depth(term, T, iterations=10, photometric=photo).T_c_w
    D = T @ T_w_cur
    assert np.linalg.norm(D[:3, 3]) < 0.002
    assert np.degrees(np.linalg.norm(cv2.Rodrigues(D[:3, :3])[0])) < 0.05


def test_hybrid_term_appends_huber_bounded_photometric_rows():
    """:class:`HybridTerm` (the joint refinement's dense term): the depth term's rows and gate unchanged, then
    the photometric rows, each residual ``e`` with ``|e| > huber`` and its Jacobian row scaled by
    ``sqrt(huber / |e|)`` (its squared residual becomes ``huber |e|``: Huber's cost, up to the constant), the
    others as they are."""
    T_w_ref = make_pose(so3_exp([0.0, 0.05, 0.0]), [0.0, 0.0, 0.0])
    T_w_cur = make_pose(so3_exp([0.01, 0.07, -0.01]), [0.03, -0.02, 0.05])
    term = _term(T_w_ref, T_w_cur)
    photo = _photo(T_w_ref, T_w_cur, 2)
    T_c_w = se3_inv(T_w_cur) @ make_pose(so3_exp([0.004, -0.003, 0.002]), [0.01, 0.0, -0.006])  # off: large residuals
    R, t = T_c_w[:3, :3], T_c_w[:3, 3]
    e_d, J_d, gate_d = term.residuals(R, t)
    e_p, J_p = photo.residuals(R, t)
    e, J, gate = HybridTerm(term, photo, huber=2.0).residuals(R, t)
    n = len(e_d)
    assert np.array_equal(e[:n], e_d) and np.array_equal(J[:n], J_d) and np.array_equal(gate, gate_d)
    assert len(e) == n + len(e_p)
    big = np.abs(e_p) > 2.0
    assert 0.05 < big.mean() < 0.95  # both kinds present
    assert np.array_equal(e[n:][~big], e_p[~big]) and np.array_equal(J[n:][~big], J_p[~big])
    assert np.allclose(e[n:][big] ** 2, 2.0 * np.abs(e_p[big]))
    assert np.allclose(J[n:][big], J_p[big] * np.sqrt(2.0 / np.abs(e_p[big]))[:, None])


def test_every_thins_the_points_their_sigmas_and_the_charged_mask_together():
    """``DenseTerm.every(step)``: every ``step``-th point with its sigma and its ``charged`` flag (the joint
    refinement's ``joint_dense_step``); the residuals of the thinned term are those of the thinned points, and
    ``charged`` keeps the points' length (it once stayed at the full length, and the gate failed)."""
    T_w_ref = make_pose(so3_exp([0.0, 0.05, 0.0]), [0.0, 0.0, 0.0])
    T_w_cur = make_pose(so3_exp([0.01, 0.07, -0.01]), [0.03, -0.02, 0.05])
    term = _term(T_w_ref, T_w_cur)
    term.charged = np.arange(len(term.X)) % 3 != 0
    thin = term.every(2)
    assert thin is not term and len(thin.X) == (len(term.X) + 1) // 2
    assert np.array_equal(thin.X, term.X[::2]) and np.array_equal(thin.sigma, term.sigma[::2])
    assert np.array_equal(thin.charged, term.charged[::2])
    T_c_w = se3_inv(T_w_cur)
    e, J, gate = thin.residuals(T_c_w[:3, :3], T_c_w[:3, 3])
    idx, _, d = term.associate(T_c_w[:3, :3], T_c_w[:3, 3])
    even = idx % 2 == 0
    assert even.sum() > 100 and np.allclose(e, d[even] / term.sigma[idx[even]])
    missing = term.charged.copy()
    missing[idx] = False
    assert len(gate) == int(missing[::2].sum())
    assert term.every(1) is term


def test_brightness_transfer_recovers_gain_and_bias_past_outliers():
    """:func:`brightness_transfer` on intensities made with a known gain and bias, sensor noise and 10 %
    outliers (occlusions, highlights): the robust fit recovers both; on unchanged intensities, the identity."""
    rs = np.random.default_rng(3)
    c = rs.uniform(20, 230, 3000)
    I = 1.25 * c - 12.0 + rs.normal(0, 2.0, c.shape)
    I[:300] = rs.uniform(0, 255, 300)
    gain, bias = brightness_transfer(c, I, sigma=8.0)
    assert abs(gain - 1.25) < 0.01 and abs(bias + 12.0) < 1.5
    gain, bias = brightness_transfer(c, c + rs.normal(0, 2.0, c.shape), sigma=8.0)
    assert abs(gain - 1.0) < 0.005 and abs(bias) < 0.7
    assert brightness_transfer(c[:10], 2 * c[:10], sigma=8.0) == (1.0, 0.0)  # too few samples: the identity


def test_image_edges_fix_the_slide_under_an_exposure_change():
    """The plain wall and floor with one poster, the current frame exposed 30 % brighter (auto-exposure): with
    the brightness transfer the edges still remove the 3 cm slide; assuming equal brightness, the bright frame's
    residuals pull the pose off by several millimetres (the term the transfer exists for)."""
    with _wall_and_floor_only():
        T_w_ref = make_pose(so3_exp([0.0, 0.05, 0.0]), [0.0, 0.0, 0.0])
        T_w_cur = make_pose(so3_exp([0.01, 0.08, -0.01]), [0.04, -0.02, 0.05])
        term = _term(T_w_ref, T_w_cur)
        levels = []
        for s in (4, 2):
            ref = image_level(_image(T_w_ref), _depth(T_w_ref), CAM, s)
            cur = image_level(np.clip(1.3 * _image(T_w_cur) + 4.0, 0, 255), _depth(T_w_cur), CAM, s)
            levels.append((cur, ref))
    T_true = se3_inv(T_w_cur)
    slid = make_pose(np.eye(3), T_true[:3, :3] @ np.array([0.03, 0.0, 0.0])) @ T_true
    term.T_prior, term.prior_sigma = slid, (0.02, 1.0)
    errors = {}
    for affine in (True, False):
        T = slid
        for cur, ref in levels:
            photo = photometric_term(cur, ref, se3_inv(T_w_ref), sigma=2.0, affine=affine)
            T = align_depth(term, T, iterations=10, photometric=photo).T_c_w
        errors[affine] = np.linalg.norm((T @ T_w_cur)[:3, 3])
    assert errors[True] < 0.002
    assert errors[False] > 2 * errors[True] and errors[False] > 0.003


def test_a_mover_in_the_reference_image_is_left_out_when_marked_invalid():
    """``ImageLevel.invalid``: a dark square (a mover, grey 40: not in the frame) painted over the poster's
    corner in the *reference* image. The frame's edge pixels that land on it meet intensities no pose explains.
    Marked invalid (what tracking does with the pixels the reference's screening judged dynamic), exactly the
    samples whose bilinear footprint touches it are left out, and the alignment (depth and image, coarse to
    fine) ends as close to the true pose as without a mover; unmarked, the square's edges pull it away."""
    from dataclasses import replace

    from dynslam_lab.geometry.depth_alignment import _to_reference

    T_w_ref = make_pose(so3_exp([0.0, 0.05, 0.0]), [0.0, 0.0, 0.0])
    T_w_cur = make_pose(so3_exp([0.01, 0.07, -0.01]), [0.03, -0.02, 0.05])
    T_true = se3_inv(T_w_cur)
    start = T_true @ make_pose(so3_exp([0.004, -0.003, 0.002]), [0.01, 0.0, -0.006])
    img, depth = _image(T_w_ref), _depth(T_w_ref)
    mover = np.zeros(img.shape, bool)
    mover[150:300, 180:330] = True
    painted_img = img.copy()
    painted_img[mover] = 40.0
    refs = {"clean": {}, "painted": {}, "marked": {}}
    for scale in (4, 2):
        refs["clean"][scale] = image_level(img, depth, CAM, scale)
        refs["painted"][scale] = image_level(painted_img, depth, CAM, scale)
        h, w = refs["clean"][scale].I.shape
        block = cv2.resize(mover[: h * scale, : w * scale].astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) > 0
        refs["marked"][scale] = replace(refs["painted"][scale], invalid=cv2.dilate(block.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    errors = {}
    for name, levels in refs.items():
        T = start
        for scale in (4, 2):
            cur = image_level(_image(T_w_cur), _depth(T_w_cur), CAM, scale)
            photo = photometric_term(cur, levels[scale], se3_inv(T_w_ref), sigma=2.0)
            if name == "marked":
                idx, _, _ = photo.evaluate(T_true[:3, :3], T_true[:3, 3])
                all_idx, _, _ = photometric_term(cur, refs["clean"][scale], se3_inv(T_w_ref), sigma=2.0).evaluate(
                    T_true[:3, :3], T_true[:3, 3])
                _, _, u, v, _ = _to_reference(photo.X, se3_inv(T_w_ref), T_true[:3, :3], T_true[:3, 3], levels[scale].camera)
                iu, iv, inv = u[all_idx].astype(int), v[all_idx].astype(int), levels[scale].invalid
                lands = inv[iv, iu] | inv[iv, iu + 1] | inv[iv + 1, iu] | inv[iv + 1, iu + 1]  # the bilinear footprint
                assert 20 < lands.sum() < 0.5 * len(all_idx)
                assert np.array_equal(np.sort(idx), np.sort(all_idx[~lands]))
            T = align_depth(_term(T_w_ref, T_w_cur), T, iterations=10, photometric=photo).T_c_w
        errors[name] = np.linalg.norm((T @ T_w_cur)[:3, 3])
    assert errors["clean"] < 0.002 and errors["marked"] < 0.002, errors
    assert errors["painted"] > 2 * errors["marked"] and errors["painted"] > 0.002, errors
