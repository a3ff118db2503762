"""The parts of the synthetic renderer against independent references: plane depths, box geometry,
texel values, the projector-shadow rule, and the names other modules import."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.camera import PinholeCamera
from dynslam_lab.datasets import kinect, office, people, raycaster, scene, shapes, synthetic
from dynslam_lab.datasets.raycaster import raycast
from dynslam_lab.datasets.shapes import Shape, look_at, pose, rot_x, rot_y, rot_z
from dynslam_lab.datasets.textures import build_atlas, sample_atlas
from dynslam_lab.geometry.se3 import se3_inv

CAM = PinholeCamera(160.0, 160.0, 79.5, 59.5, width=160, height=120)


def _rays(camera):
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    return (u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy


def test_scene_and_synthetic_keep_their_public_names():
    # names other modules, notebooks and tests import from scene / synthetic, now defined in the split modules
    for name in ("Shape", "shape_corners", "rot_x", "rot_y", "rot_z", "pose", "look_at", "KINDS"):
        assert getattr(scene, name) is getattr(shapes, name)
    for name in ("GBuffer", "raycast", "camera_rays", "NEAR"):
        assert getattr(scene, name) is getattr(raycaster, name)
    for name in ("Walker", "Sitter", "SlidingObject", "person_parts", "walking_joints", "sitting_joints", "path_pose",
                 "PersonLook", "heading_rotation"):
        assert getattr(scene, name) is getattr(people, name)
    for name in ("OfficeScene", "build_office", "TextureBank", "ROOM_MIN", "ROOM_MAX", "VIEW_EYE", "VIEW_TARGET", "LAMP",
                 "FILL_LIGHTS", "AMBIENT", "PERSON"):
        assert getattr(scene, name) is getattr(office, name)
    for name in ("DepthNoise", "nguyen_sigma", "disparity_step", "kinect_depth"):
        assert getattr(synthetic, name) is getattr(kinect, name)
    assert set(scene.__all__) <= set(dir(scene)) and set(synthetic.__all__) <= set(dir(synthetic))
    with pytest.raises(ValueError, match="list of parts is empty"):
        raycast([], CAM, np.eye(4))


def test_room_depth_is_the_nearest_wall_plane():
    # camera at the centre of a 4 x 6 x 3 m room looking along +y: the depth of each pixel is the
    # nearest of the planes x = +-2, y = 3, z = +-1.5 along its ray (x, y, 1) in the camera frame
    room = Shape("room", (2.0, 3.0, 1.5))
    T_w_c = look_at((0.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    g = raycast([(room, np.eye(4))], CAM, T_w_c)
    xr, yr = _rays(CAM)
    with np.errstate(divide="ignore"):
        cand = np.stack([np.full(xr.shape, 3.0), 2.0 / np.abs(xr), 1.5 / np.abs(yr)])
    expect = cand.min(axis=0)
    assert np.all(g.part == 0)
    np.testing.assert_allclose(g.depth, expect, rtol=2e-6)
    # faces: back wall +y (3), side walls -x / +x (0 / 1), floor -z (4, image bottom), ceiling +z (5)
    which = cand.argmin(axis=0)
    clear = np.sort(cand, axis=0)[1] > expect * 1.001  # away from the room's edges
    want = np.where(which == 0, 3, np.where(which == 1, np.where(xr < 0, 0, 1), np.where(yr > 0, 4, 5)))
    assert np.array_equal(g.face[clear], want[clear])
    # normals point into the room: the back wall's is -y (world) = -z (camera)
    assert np.allclose(g.normal[which == 0], (0.0, 0.0, -1.0))
    assert np.allclose(g.normal[(which == 2) & (yr > 0)], (0.0, -1.0, 0.0))  # floor: up = -y (camera)


def test_floor_crossing_the_near_plane_is_cast_everywhere_below_the_horizon():
    # a large slab whose top z = 0 runs under and behind a camera 1.2 m above it: its bounding box
    # crosses the camera plane, so its screen rectangle comes from clipping the box to the near plane
    floor = Shape("box", (30.0, 30.0, 0.05))
    T_w_c = look_at((0.3, -2.0, 1.2), (0.3, 10.0, 1.2))
    g = raycast([(floor, pose(None, (0.0, 0.0, -0.05)))], CAM, T_w_c)
    _, yr = _rays(CAM)
    below = yr > 0
    with np.errstate(divide="ignore"):
        expect = np.where(below, 1.2 / yr, np.inf)  # t y = 1.2: the floor plane in the camera frame
    near = expect < 25.0  # rays that meet the top face inside the slab's extent
    assert near[-1].all() and near.sum() > 0.3 * near.size
    np.testing.assert_allclose(g.depth[near], expect[near], rtol=2e-6)
    assert np.all(g.part[near] == 0) and np.all(g.face[near] == 5)
    assert np.allclose(g.normal[near], (0.0, -1.0, 0.0), atol=1e-6)
    assert np.all(g.part[~below] == -1) and np.all(np.isinf(g.depth[~below]))
    assert not g.normal[~below].any() and not g.s[~below].any() and not g.t[~below].any() and not g.face[~below].any()


def test_box_faces_normals_and_occlusion_agree_with_the_geometry():
    room = Shape("room", (4.0, 4.0, 2.0))
    half = np.array([0.3, 0.2, 0.25])
    box = Shape("box", tuple(half), instance=1)
    ball = Shape("ellipsoid", (0.12, 0.12, 0.12), instance=2)
    T_w_b = pose(rot_z(0.6) @ rot_x(0.4) @ rot_y(-0.3), (0.1, 2.0, 0.05))
    T_w_s = pose(None, (-0.25, 1.0, 0.0))  # in front of the box, hiding part of it
    T_w_c = look_at((0.0, -0.2, 0.3), (0.0, 2.0, 0.0))
    parts = [(room, np.eye(4)), (box, T_w_b), (ball, T_w_s)]
    g = raycast(parts, CAM, T_w_c)
    xr, yr = _rays(CAM)
    on_box = g.part == 1
    assert on_box.sum() > 1500 and (g.part == 2).sum() > 300
    # hit points in the box frame lie on the face the G-buffer names, on its + or - side
    X_c = np.stack([xr, yr, np.ones_like(xr)], axis=-1)[on_box] * g.depth[on_box, None]
    T_b_c = se3_inv(T_w_b) @ T_w_c
    P = X_c @ T_b_c[:3, :3].T + T_b_c[:3, 3]
    f = g.face[on_box].astype(int)
    axis, sign = f // 2, np.where(f % 2 == 1, 1.0, -1.0)
    assert np.allclose(P[np.arange(len(P)), axis], sign * half[axis], atol=2e-5)
    assert np.all(np.abs(P) <= half + 2e-5)
    # the camera-frame normal is the face's outward normal rotated into the camera
    n_box = np.zeros((len(P), 3))
    n_box[np.arange(len(P)), axis] = sign
    T_c_b = se3_inv(T_b_c)
    assert np.allclose(g.normal[on_box], n_box @ T_c_b[:3, :3].T, atol=1e-6)
    # the sphere hides the box where it is nearer: no box pixel lies behind a sphere point on its ray
    C = (se3_inv(T_w_c) @ np.append(T_w_s[:3, 3], 1.0))[:3]
    d = np.stack([xr, yr, np.ones_like(xr)], axis=-1)[on_box]
    b = d @ C
    disc = b * b - (d * d).sum(1) * (C @ C - 0.12**2)
    t_sphere = (b - np.sqrt(np.maximum(disc, 0))) / (d * d).sum(1)
    assert np.all((disc < 0) | (t_sphere > g.depth[on_box] - 1e-5))
    # the same scene with the parts listed in another order gives the same G-buffer
    g2 = raycast([parts[2], parts[0], parts[1]], CAM, T_w_c)
    assert np.all(g.part >= 0) and np.array_equal(np.array([2, 0, 1])[g2.part], g.part)  # new index -> old index
    assert np.array_equal(g2.depth, g.depth) and np.array_equal(g2.normal_planes, g.normal_planes)


def test_texture_lookup_at_level_0_returns_the_texels():
    rng = np.random.default_rng(2)
    textures = [rng.integers(0, 256, (64, 96, 3), dtype=np.uint8), rng.integers(0, 256, (32, 32, 3), dtype=np.uint8)]
    atlas = build_atlas(textures)
    assert np.array_equal(atlas.image, atlas.rgba[..., :3]) and not atlas.rgba[..., 3].any()
    for ti, tex in enumerate(textures):
        h, w = tex.shape[:2]
        j, i = np.mgrid[0:h, 0:w]
        # texel (i, j) is centred at s = i + 0.5, t = j + 0.5, and the texture wraps round
        for shift in (0, w):
            s = (i + 0.5 + shift).astype(np.float32)
            t = (j + 0.5 - (h if shift else 0)).astype(np.float32)
            got = sample_atlas(atlas, np.full(s.shape, ti), s, t, np.zeros(s.shape, np.float32))
            assert np.abs(got * 255.0 - tex).max() <= 1.0 + 1e-4


def test_projector_shadow_follows_the_running_minimum_rule():
    # background u is hidden from the projector when some u' > u has u' - d(u') < u - d(u) - 0.05, d = f b / z
    rng = np.random.default_rng(6)
    H, W = 12, 90
    z = np.full((H, W), 3.0, np.float32)
    for r in range(H):  # random boards in front of the wall
        for _ in range(3):
            a = int(rng.integers(0, W - 5))
            z[r, a : a + int(rng.integers(3, 20))] = rng.uniform(0.8, 2.5)
    params = kinect.DepthNoise(edge_jump=1e9, edge_width=0, dropout_rate=0.0, min_cos=0.0, sigma_0=1e-6, sigma_2=0.0,
                               sigma_angle=0.0)
    got = kinect.kinect_depth(z, np.ones_like(z), 525.0, params, np.random.default_rng(0)) == 0
    fb = 580.0 * 0.075
    expect = np.zeros_like(got)
    for r in range(H):
        q = np.arange(W) - fb / z[r].astype(np.float64)
        for u in range(W - 1):
            expect[r, u] = q[u + 1 :].min() < q[u] - 0.05
    assert expect.sum() > 30
    assert np.array_equal(got, expect)
