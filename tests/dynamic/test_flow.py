"""Adaptive-threshold dense flow (Chang et al. 2021 eq. 3, Fig. 5)."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.dynamic.flow import (
    FlowConfig,
    ego_motion_flow,
    farneback_flow,
    farneback_flow_async,
    flow_regions,
    human_driven_regions,
)
from dynslam_lab.geometry.se3 import make_pose
from tests.dynamic.scenes import CAM, two_layer_frames


def test_threshold_is_twice_the_mean_flow_in_the_mask_and_keeps_touching_regions():
    mag = np.zeros((60, 80), np.float32)
    person = np.zeros((60, 80), bool)
    person[20:50, 30:45] = True
    mag[person] = 1.0
    mag[25:30, 30:35] = 3.0  # a fast arm inside the mask
    mag[30:40, 45:55] = 5.0  # a carried box touching the mask
    mag[5:15, 2:12] = 5.0  # something fast far away: not human-driven
    p_bar = mag[person].mean()
    region, thr, pb = human_driven_regions(mag, person, FlowConfig(min_flow_px=0.0, touch_px=1, min_region_px=1))
    assert pb == pytest.approx(p_bar)
    assert thr == pytest.approx(2 * p_bar)
    assert region[30:40, 45:55].all() and region[25:30, 30:35].all()
    assert not region[5:15, 2:12].any()
    assert region.sum() == 10 * 10 + 5 * 5


def test_empty_mask_gives_no_threshold():
    region, thr, pb = human_driven_regions(np.ones((10, 10)), np.zeros((10, 10), bool))
    assert np.isnan(thr) and np.isnan(pb) and not region.any()


def test_ego_motion_flow_of_a_sideways_camera():
    depth = np.full((CAM.height, CAM.width), 2.0, np.float32)
    T_p_c = make_pose(np.eye(3), np.array([0.04, 0.0, 0.0]))  # current camera 4 cm right of the previous
    flow = ego_motion_flow(depth, CAM, T_p_c, (60, 80))
    assert np.allclose(flow[..., 0], CAM.fx * 0.04 / 2.0, atol=1e-4)
    assert np.allclose(flow[..., 1], 0.0, atol=1e-6)


def test_farneback_flow_recovers_the_wall_shift_in_full_resolution_pixels():
    (f0, _, _), (f1, mask, _) = two_layer_frames(2)
    flow = farneback_flow(f1.gray, f0.gray, FlowConfig())
    h, w = flow.shape[:2]
    assert (h, w) == (120, 160)
    left_wall = flow[10:110, 5:50]
    assert np.median(left_wall[..., 0]) == pytest.approx(CAM.fx * 0.02 / 3.0, abs=0.4)


def test_flow_regions_on_a_moving_person_with_ego_motion_removed():
    (f0, _, _), (f1, mask, _) = two_layer_frames(2)
    T_c_p = make_pose(np.eye(3), np.array([-0.02, 0.0, 0.0]))
    res = flow_regions(f1.gray, f0.gray, mask, f1.depth, CAM, T_c_p, FlowConfig())
    # the person moves ~12 px on its own: its residual flow is large, the wall's small
    small = res.magnitude
    assert res.mean_flow_px > 5.0
    assert np.nanmedian(small[5:110, 5:50]) < 1.0
    with pytest.raises(ValueError, match="person_mask"):
        flow_regions(f1.gray, f0.gray, mask[:10], config=FlowConfig())


def test_flow_computed_ahead_in_the_worker_thread_gives_the_same_regions():
    (f0, _, _), (f1, mask, _) = two_layer_frames(2)
    T_c_p = make_pose(np.eye(3), np.array([-0.02, 0.0, 0.0]))
    dense = farneback_flow_async(f1.gray, f0.gray, FlowConfig()).result()
    assert np.array_equal(dense, farneback_flow(f1.gray, f0.gray, FlowConfig()))
    ahead = flow_regions(f1.gray, f0.gray, mask, f1.depth, CAM, T_c_p, FlowConfig(), flow=dense)
    here = flow_regions(f1.gray, f0.gray, mask, f1.depth, CAM, T_c_p, FlowConfig())
    assert np.array_equal(ahead.region, here.region) and ahead.threshold_px == here.threshold_px
