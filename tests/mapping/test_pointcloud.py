"""Back-projection (checked with OpenCV's projectPoints), voxel and statistical filters
(checked against brute-force references)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.geometry.se3 import make_pose, so3_exp
from dynslam_lab.mapping.pointcloud import (
    VoxelAccumulator,
    backproject_frame,
    depth_edge_mask,
    statistical_outlier_mask,
    voxel_downsample,
)

CAM = CAMERA_PRESETS["tum_fr3"]


def test_backprojection_reprojects_with_opencv():
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 3.0, (CAM.height, CAM.width)).astype(np.float32)
    depth[::7, ::5] = 0.0  # holes
    T_w_c = make_pose(so3_exp(np.array([0.1, -0.2, 0.3])), np.array([0.5, -0.1, 1.2]))
    rgb = rng.integers(0, 256, (CAM.height, CAM.width, 3)).astype(np.uint8)
    exclude = np.zeros(depth.shape, bool)
    exclude[100:200, 300:400] = True
    xyz, col = backproject_frame(depth, CAM, T_w_c, rgb, exclude, stride=3, max_depth=2.5)
    v, u = np.mgrid[0 : CAM.height : 3, 0 : CAM.width : 3]
    z = depth[::3, ::3]
    keep = (z > 0) & (z <= 2.5) & ~exclude[::3, ::3]
    assert len(xyz) == keep.sum()
    # World -> camera with OpenCV: rvec/tvec of T_c_w.
    T_c_w = np.linalg.inv(T_w_c)
    rvec, _ = cv2.Rodrigues(T_c_w[:3, :3])
    uv, _ = cv2.projectPoints(xyz, rvec, T_c_w[:3, 3], CAM.K, None)
    np.testing.assert_allclose(uv.reshape(-1, 2), np.stack([u[keep], v[keep]], 1), atol=1e-6)
    np.testing.assert_array_equal(col, rgb[::3, ::3][keep])


def test_backprojection_rejects_bad_input():
    with pytest.raises(ValueError, match="exclude mask"):
        backproject_frame(np.ones((4, 4)), CAM, np.eye(4), exclude=np.zeros((3, 4), bool))
    with pytest.raises(ValueError, match="T_w_c"):
        backproject_frame(np.ones((4, 4)), CAM, np.eye(3))


def test_depth_edges_by_hand():
    d = np.full((5, 6), 2.0, np.float32)
    d[:, 3:] = 1.0  # a step from 2 m to 1 m between columns 2 and 3
    d[0, 0] = 0.0
    e = depth_edge_mask(d, 0.05)
    assert e[:, 2].all() and e[:, 3].all()
    assert not e[1:, 1].any() and not e[:, 5].any()
    assert e[1, 0] and e[0, 1]  # next to the hole
    assert not e[0, 0]  # no reading: not an edge (left out anyway)


def _voxel_reference(xyz, rgb, s):
    keys = np.floor(xyz / s).astype(np.int64)
    groups = {}
    for k, p, c in zip(map(tuple, keys), xyz, rgb):
        groups.setdefault(k, []).append((p, c))
    out = {k: (np.mean([g[0] for g in v], axis=0), np.mean([g[1] for g in v], axis=0)) for k, v in groups.items()}
    return out


def test_voxel_filter_matches_brute_force():
    rng = np.random.default_rng(1)
    xyz = rng.uniform(-0.5, 0.5, (3000, 3))
    rgb = rng.integers(0, 256, (3000, 3)).astype(np.uint8)
    c, col = voxel_downsample(xyz, 0.1, rgb)
    ref = _voxel_reference(xyz, rgb.astype(float), 0.1)
    assert len(c) == len(ref)
    keys = np.floor(c / 0.1).astype(np.int64)
    for k, p, q in zip(map(tuple, keys), c, col):
        np.testing.assert_allclose(p, ref[k][0], atol=1e-12)
        np.testing.assert_allclose(q, np.rint(ref[k][1]), atol=0)


def test_accumulator_in_batches_equals_one_call():
    rng = np.random.default_rng(2)
    xyz = rng.normal(size=(5000, 3))
    rgb = rng.integers(0, 256, (5000, 3)).astype(np.uint8)
    acc = VoxelAccumulator(0.05)
    for chunk in np.array_split(np.arange(5000), 7):
        acc.add(xyz[chunk], rgb[chunk])
    a, ac = acc.points()
    b, bc = voxel_downsample(xyz, 0.05, rgb)
    np.testing.assert_allclose(a, b, atol=1e-12)
    np.testing.assert_array_equal(ac, bc)
    with pytest.raises(ValueError, match="voxel_size"):
        VoxelAccumulator(0.0)


def test_statistical_filter_matches_brute_force_and_drops_outliers():
    rng = np.random.default_rng(4)
    inliers = rng.normal(scale=0.05, size=(400, 3))
    outliers = rng.uniform(1.0, 2.0, size=(10, 3)) * rng.choice([-1, 1], (10, 3))
    xyz = np.vstack([inliers, outliers])
    keep = statistical_outlier_mask(xyz, k=8, std_ratio=1.0)
    D = np.linalg.norm(xyz[:, None] - xyz[None], axis=2)
    d = np.sort(D, axis=1)[:, 1:9].mean(axis=1)
    np.testing.assert_array_equal(keep, d <= d.mean() + d.std())
    assert not keep[400:].any()
    assert keep[:400].mean() > 0.8
