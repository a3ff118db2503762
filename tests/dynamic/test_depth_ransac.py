"""Depth-RANSAC (YOLO-SLAM eqs. 5-8) on hand-made depths and on the real TUM frame."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dynslam_lab.dynamic.depth_ransac import (
    DepthRansacConfig,
    adaptive_iterations,
    depth_ransac,
    screen_boxes,
    three_point_variance,
)
from tests.conftest import shared_file


def test_adaptive_iterations_eq8_by_hand():
    # w = 0.5, N = 2, P = 0.99: k = log(0.01) / log(1 - 0.25)
    assert adaptive_iterations(0.5, 2, 0.99) == pytest.approx(math.log(0.01) / math.log(0.75))
    assert adaptive_iterations(0.5, 2, 0.99) == pytest.approx(16.0078, abs=1e-3)
    assert adaptive_iterations(0.0) == math.inf
    assert adaptive_iterations(1.0) == 0.0
    with pytest.raises(ValueError, match="inlier_ratio"):
        adaptive_iterations(1.5)


def test_three_point_variance_is_numpy_population_variance():
    rng = np.random.default_rng(1)
    a, b, c = rng.uniform(0.5, 5, size=(3, 50))
    assert np.allclose(three_point_variance(a, b, c), np.var(np.stack([a, b, c]), axis=0))


def test_threshold_reading_in_square_metres():
    cfg = DepthRansacConfig()
    assert cfg.var_threshold_m2 == pytest.approx(0.43 * 0.2**2)
    # a keypoint d metres from two equal samples has variance 2 d^2 / 9: tolerance ~0.28 m
    d = math.sqrt(cfg.var_threshold_m2 * 9 / 2)
    assert 0.27 < d < 0.29


def test_largest_set_is_the_person_and_adaptive_k_stops_early():
    rng = np.random.default_rng(0)
    person = 2.0 + rng.normal(0, 0.05, 60)
    wall = rng.uniform(3.0, 4.5, 40)
    z = np.concatenate([person, wall])
    res = depth_ransac(z, DepthRansacConfig(select="largest"), rng=0)
    assert res.inliers[:60].all()
    assert not res.inliers[60:].any()
    assert res.iterations < 200  # k from eq. 8 with w ~ 0.6 is ~10, far below the cap
    assert res.k == pytest.approx(adaptive_iterations(60 / 100, 2, 0.99))


def test_front_selection_keeps_a_smaller_nearer_person():
    rng = np.random.default_rng(2)
    person = 1.5 + rng.normal(0, 0.05, 30)
    wall = 3.0 + rng.normal(0, 0.03, 70)
    z = np.concatenate([person, wall])
    largest = depth_ransac(z, DepthRansacConfig(select="largest"), rng=0)
    front = depth_ransac(z, DepthRansacConfig(select="front"), rng=0)
    assert largest.inliers[30:].all() and not largest.inliers[:30].any()
    assert front.inliers[:30].all() and not front.inliers[30:].any()


def test_screen_boxes_leaves_points_outside_boxes_static_and_labels_missing_depth():
    uv = np.array([[10, 10], [12, 12], [14, 14], [16, 16], [30, 30], [100, 100], [13, 13]], float)
    z = np.array([2.0, 2.05, 2.02, 3.5, 3.6, 2.0, np.nan])
    dyn, res = screen_boxes(uv, z, np.array([[0, 0, 40, 40]]), DepthRansacConfig(select="largest"), rng=0)  # no image: keypoints
    assert dyn.tolist() == [True, True, True, False, False, False, True]  # nan takes its nearest neighbour's label
    assert res[0].depth_range == pytest.approx((2.0, 2.05))
    dyn_s, _ = screen_boxes(uv, z, np.array([[0, 0, 40, 40]]), DepthRansacConfig(select="largest", missing_depth="static"), rng=0)
    assert not dyn_s[6]


def test_model_from_pixels_follows_the_area_not_the_corners():
    """A smooth person (few corners) filling most of a box in front of a textured wall (many corners)."""
    depth = np.full((100, 100), 4.0, np.float32)
    depth[10:95, 20:80] = 2.0  # the person: 60% of the box's area
    rng = np.random.default_rng(0)
    uv_wall = np.column_stack([rng.uniform(0, 19, 40), rng.uniform(0, 99, 40)])
    uv_person = np.column_stack([rng.uniform(25, 75, 10), rng.uniform(15, 90, 10)])
    uv = np.vstack([uv_wall, uv_person])
    z = np.concatenate([np.full(40, 4.0), np.full(10, 2.0)])
    box = np.array([[0, 0, 99, 99]])
    by_kp, _ = screen_boxes(uv, z, box, DepthRansacConfig(model_from="keypoints"), rng=0)
    by_px, res = screen_boxes(uv, z, box, DepthRansacConfig(model_from="pixels"), rng=0, depth_image=depth)
    assert by_kp[:40].all() and not by_kp[40:].any()  # the wall wins by keypoint count
    assert by_px[40:].all() and not by_px[:40].any()  # the person wins by area
    assert res[0].model == pytest.approx((2.0, 2.0))


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="var_threshold"):
        DepthRansacConfig(var_threshold=0)
    with pytest.raises(ValueError, match="select"):
        DepthRansacConfig(select="biggest")
    with pytest.raises(ValueError, match="finite"):
        depth_ransac(np.array([1.0, np.nan, 2.0]))
    with pytest.raises(ValueError, match="depth must have shape"):
        screen_boxes(np.zeros((3, 2)), np.zeros(2), np.zeros((1, 4)))


@pytest.mark.needs_shared
def test_real_tum_frame_person_dynamic_background_static():
    """fr3/walking_xyz: person keypoints come out dynamic, the box's background static."""
    cv2 = pytest.importorskip("cv2")
    from dynslam_lab.datasets.tum import load_depth, load_rgb
    from dynslam_lab.dynamic.table import depth_at, values_at
    from dynslam_lab.features.orb import extract_features

    rgb = load_rgb(shared_file("tum/frames/fr3_walking_xyz_1341846313.553992_rgb.png"))
    depth = load_depth(shared_file("tum/frames/fr3_walking_xyz_1341846313.592088_depth.png"))
    mask = cv2.imread(str(shared_file("tum/frames/fr3_walking_xyz_1341846313.553992_person_mask_yolact.png")),
                      cv2.IMREAD_UNCHANGED) > 0
    uv = extract_features(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)).uv.astype(float)
    n, _, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8))
    boxes = np.array([[x, y, x + w - 1, y + h - 1] for x, y, w, h, a in stats[1:] if a > 500], float)
    assert len(boxes) == 2  # the two people of the frame
    z = depth_at(depth, uv)
    dyn, _ = screen_boxes(uv, z, boxes, DepthRansacConfig(), rng=0, depth_image=depth)
    in_mask = values_at(mask, uv).astype(bool)
    in_box = ((uv[:, None, 0] >= boxes[None, :, 0]) & (uv[:, None, 0] <= boxes[None, :, 2])
              & (uv[:, None, 1] >= boxes[None, :, 1]) & (uv[:, None, 1] <= boxes[None, :, 3])).any(axis=1)
    has_z = np.isfinite(z)
    assert dyn[in_mask].mean() >= 0.9  # most person keypoints dynamic (measured 0.95)
    bg = in_box & ~in_mask & has_z
    assert bg.sum() > 50
    assert (~dyn[bg]).mean() >= 0.9  # background with depth inside the boxes stays static (measured 0.93)
    assert not dyn[~in_box].any()
    # fitted on the keypoints alone, the largest set of the left box is the wall behind the person
    dyn_k, _ = screen_boxes(uv, z, boxes, DepthRansacConfig(model_from="keypoints"), rng=0)
    assert dyn_k[in_mask].mean() < 0.8 and (~dyn_k[bg]).mean() < 0.5
