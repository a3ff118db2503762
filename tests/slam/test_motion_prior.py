"""The motion prior of motion-only BA (``TrackingConfig.motion_prior_m``; ``depth_alignment.MotionPrior``).

Points on one far plane leave a sideways step and a small rotation nearly alike; the prior on the motion model's
prediction decides that direction, and does not move a pose the features fix."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.geometry.depth_alignment import MotionPrior
from dynslam_lab.geometry.se3 import make_pose, se3_inv, so3_exp, transform_points
from dynslam_lab.slam.optimize import Observations, optimize_pose
from dynslam_lab.slam.tracking import TrackingConfig

CAM = CAMERA_PRESETS["default"]
BF = 40.0


def test_the_prior_is_zero_at_the_prediction_and_its_jacobian_matches_finite_differences():
    T_p = make_pose(so3_exp(np.array([0.02, -0.01, 0.03])), np.array([0.1, -0.2, 0.3]))
    prior = MotionPrior(T_p, (0.02, 1.0))
    e, J, gate = prior.residuals(T_p[:3, :3], T_p[:3, 3])
    assert np.abs(e).max() < 1e-12 and len(gate) == 0
    # near the prediction, where the Jacobian (first order, DenseTerm.prior_residuals) holds
    R = so3_exp(np.array([0.001, 0.002, -0.001])) @ T_p[:3, :3]
    t = T_p[:3, 3] + np.array([0.001, 0.0, -0.002])
    e0, J, _ = prior.residuals(R, t)
    h = 1e-6
    for k in range(6):  # the step of the pose optimiser: R <- Exp(omega) R, t <- t + tau
        d = np.zeros(6)
        d[k] = h
        e1, _, _ = prior.residuals(so3_exp(d[:3]) @ R, t + d[3:])
        assert np.allclose((e1 - e0) / h, J[:, k], atol=1e-2 * max(1.0, np.abs(J[:, k]).max()))


def _plane_scene(n: int, depth: float, seed: int):
    """``n`` points on a plane ``depth`` m in front of a camera at the identity, seen in the middle third of the
    image with 1 px of noise (no depth readings: the far wall of a plain room)."""
    rng = np.random.default_rng(seed)
    uv = np.c_[rng.uniform(220, 420, n), rng.uniform(160, 320, n)]
    X = np.c_[(uv[:, 0] - CAM.cx) * depth / CAM.fx, (uv[:, 1] - CAM.cy) * depth / CAM.fy, np.full(n, depth)]
    noisy = uv + rng.normal(0.0, 1.0, uv.shape)
    return X, Observations(noisy, np.full(n, np.nan), np.ones(n))


def test_on_one_far_plane_the_prior_holds_the_position_that_the_features_leave_free():
    """A start 10 cm sideways with the matching rotation (the plane's points barely tell them apart): the features
    alone leave the camera far from the truth; with the prior on the true pose it returns within a centimetre."""
    errs = {"alone": [], "prior": []}
    for seed in range(5):
        X, obs = _plane_scene(60, 5.0, seed)
        start = make_pose(so3_exp(np.array([0.0, -0.1 / 5.0, 0.0])), np.array([0.1, 0.0, 0.0]))
        for name, term in (("alone", None), ("prior", MotionPrior(np.eye(4), (0.02, 1.0)))):
            T, _ = optimize_pose(start, X, obs, CAM, BF, dense=term)
            errs[name].append(np.linalg.norm(se3_inv(T)[:3, 3]))
    assert min(errs["alone"]) > 0.03  # the features do not find the way back
    assert max(errs["prior"]) < 0.01


def test_where_the_features_fix_the_pose_a_wrong_prediction_moves_it_by_less_than_a_millimetre():
    """Points at 1-4 m over the whole image (no degeneracy): a prediction 5 cm and 2 degrees off changes the pose
    by less than a millimetre against the features alone."""
    rng = np.random.default_rng(3)
    n = 300
    uv = np.c_[rng.uniform(20, 620, n), rng.uniform(20, 460, n)]
    z = rng.uniform(1.0, 4.0, n)
    X = np.c_[(uv[:, 0] - CAM.cx) * z / CAM.fx, (uv[:, 1] - CAM.cy) * z / CAM.fy, z]
    T_true = make_pose(so3_exp(np.array([0.01, 0.02, 0.0])), np.array([0.03, -0.02, 0.05]))
    X_w = transform_points(se3_inv(T_true), X)
    noisy = uv + rng.normal(0.0, 1.0, uv.shape)
    obs = Observations(noisy, noisy[:, 0] - BF / z, np.ones(n))
    wrong = make_pose(so3_exp(np.array([0.0, 0.035, 0.0])), np.array([0.08, -0.02, 0.05]))
    T_alone, _ = optimize_pose(T_true, X_w, obs, CAM, BF)
    T_prior, _ = optimize_pose(T_true, X_w, obs, CAM, BF, dense=MotionPrior(wrong, (0.02, 1.0)))
    assert np.linalg.norm(se3_inv(T_alone)[:3, 3] - se3_inv(T_prior)[:3, 3]) < 1e-3


@pytest.mark.parametrize("field,value", [("motion_prior_m", -0.01), ("motion_prior_deg", 0.0)])
def test_the_prior_settings_are_checked(field, value):
    with pytest.raises(ValueError, match="motion_prior"):
        TrackingConfig(**{field: value})
