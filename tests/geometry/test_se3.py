import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dynslam_lab.geometry import se3 as G


def _random_pose(rng):
    R = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    return G.make_pose(R, rng.normal(size=3))


def test_inverse_and_compose():
    rng = np.random.default_rng(0)
    T = _random_pose(rng)
    np.testing.assert_allclose(T @ G.se3_inv(T), np.eye(4), atol=1e-12)
    stack = np.stack([_random_pose(rng) for _ in range(5)])
    np.testing.assert_allclose(G.se3_inv(stack), np.linalg.inv(stack), atol=1e-12)


def test_tum_roundtrip_and_quaternion_order():
    # A 90 deg rotation about z: quaternion (0, 0, sin45, cos45) in x, y, z, w order.
    row = np.array([1.0, 2.0, 3.0, 0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)])
    T = G.pose_from_tum(row)
    np.testing.assert_allclose(T[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(G.pose_to_tum(T), row, atol=1e-12)


def test_so3_exp_matches_opencv_rodrigues():
    rng = np.random.default_rng(1)
    w = rng.normal(size=3)
    R_cv, _ = cv2.Rodrigues(w)
    np.testing.assert_allclose(G.so3_exp(w), R_cv, atol=1e-12)
    np.testing.assert_allclose(G.so3_log(R_cv), w if np.linalg.norm(w) < np.pi else G.so3_log(R_cv), atol=1e-9)
    assert G.rotation_angle_deg(R_cv) == pytest.approx(np.degrees(np.linalg.norm(w)), abs=1e-9)


def test_transform_points_and_relative_pose():
    rng = np.random.default_rng(2)
    A, B = _random_pose(rng), _random_pose(rng)
    X = rng.normal(size=(10, 3))
    T_a_b = G.relative_pose(A, B)
    np.testing.assert_allclose(G.transform_points(A, G.transform_points(T_a_b, X)), G.transform_points(B, X), atol=1e-12)


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match="4 components"):
        G.quat_xyzw_to_matrix(np.zeros(3))
    with pytest.raises(ValueError, match="zero"):
        G.quat_xyzw_to_matrix(np.zeros(4))
    with pytest.raises(ValueError, match="7 values"):
        G.pose_from_tum(np.zeros(6))
