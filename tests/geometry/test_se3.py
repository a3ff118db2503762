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


def test_quaternion_conversions_match_scipy():
    """Our numpy conversions against scipy's Rotation: random rotations, a batch shape, and the
    hard cases (identity, 180 degrees about each axis and a diagonal, just under 180)."""
    rng = np.random.default_rng(5)
    R = Rotation.random(500, random_state=7).as_matrix()
    hard = [np.eye(3), np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0]),
            Rotation.from_rotvec(np.pi * np.array([1.0, 1.0, 0.0]) / np.sqrt(2)).as_matrix(),
            Rotation.from_rotvec((np.pi - 1e-9) * np.array([0.0, 0.6, 0.8])).as_matrix()]
    R = np.concatenate([R, np.stack(hard)])
    q = G.matrix_to_quat_xyzw(R)
    q_ref = Rotation.from_matrix(R).as_quat()
    q_ref = np.where(q_ref[:, 3:4] < 0, -q_ref, q_ref)
    # at exactly 180 degrees (w = 0) q and -q are the same rotation: compare up to sign there
    sign = np.where(np.sum(q * q_ref, axis=1, keepdims=True) < 0, -1.0, 1.0)
    np.testing.assert_allclose(q, sign * q_ref, atol=1e-12)
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(G.quat_xyzw_to_matrix(q), R, atol=1e-12)
    # unnormalised input is normalised first, like scipy; batch shapes are kept
    qs = (q[:12] * rng.uniform(0.5, 2.0, (12, 1))).reshape(3, 4, 4)
    np.testing.assert_allclose(G.quat_xyzw_to_matrix(qs), Rotation.from_quat(qs.reshape(-1, 4)).as_matrix().reshape(3, 4, 3, 3),
                               atol=1e-12)
    assert G.matrix_to_quat_xyzw(R[:12].reshape(3, 4, 3, 3)).shape == (3, 4, 4)


def test_skew_is_the_cross_product_matrix():
    rng = np.random.default_rng(3)
    v, w = rng.normal(size=(7, 3)), rng.normal(size=(7, 3))
    S = G.skew(v)
    assert S.shape == (7, 3, 3)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", S, w), np.cross(v, w), atol=1e-12)
    np.testing.assert_allclose(G.skew(v[0]), -G.skew(v[0]).T)
    assert G.skew(v[0]).shape == (3, 3)
