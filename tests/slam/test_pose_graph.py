"""Pose graph optimisation: exact recovery, a linear reference, loop drift removal, point correction."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.geometry.se3 import make_pose, relative_pose, se3_inv, so3_exp, transform_points
from dynslam_lab.slam.pose_graph import PoseGraphConfig, correct_points, edge_residuals, optimize_pose_graph


def circle_poses(n: int, radius: float = 2.0) -> np.ndarray:
    """Cameras on a horizontal circle, looking at its centre (a closed loop)."""
    out = []
    for a in np.linspace(0, 2 * np.pi, n, endpoint=False):
        c = radius * np.array([np.cos(a), 0.0, np.sin(a)])
        z = -c / np.linalg.norm(c)
        x = np.cross([0.0, 1.0, 0.0], z)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        out.append(make_pose(np.stack([x, y, z], axis=1), c))
    return np.stack(out)


def chain_edges(n: int) -> np.ndarray:
    return np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)


def test_residual_zero_for_consistent_measurements():
    T = circle_poses(8)
    e = chain_edges(8)
    Z = relative_pose(T[e[:, 0]], T[e[:, 1]])
    r = edge_residuals(T[:, :3, :3], T[:, :3, 3], e, Z, np.ones(len(e)), PoseGraphConfig().rotation_weight)
    assert r.shape == (7, 6)
    np.testing.assert_allclose(r, 0, atol=1e-12)


def test_recovers_ground_truth_from_perturbed_start():
    rng = np.random.default_rng(1)
    T_gt = circle_poses(20)
    e = np.concatenate([chain_edges(20), [[19, 0], [0, 10], [5, 15]]])
    Z = relative_pose(T_gt[e[:, 0]], T_gt[e[:, 1]])
    T0 = T_gt.copy()
    for k in range(1, 20):
        T0[k] = make_pose(so3_exp(rng.normal(0, 0.05, 3)), rng.normal(0, 0.1, 3)) @ T0[k]
    res = optimize_pose_graph(T0, e, Z, fixed=[0])
    np.testing.assert_allclose(res.poses, T_gt, atol=1e-5)
    assert res.final_cost < 1e-9 < res.initial_cost


def test_translation_only_graph_matches_linear_least_squares():
    """With rotations pinned to the identity (a stiff rotation weight) the problem is linear in the
    translations: compare with numpy's lstsq."""
    rng = np.random.default_rng(2)
    n = 12
    t_gt = rng.normal(0, 1, (n, 3))
    e = np.concatenate([chain_edges(n), [[0, 6], [3, 11], [2, 9]]])
    meas = t_gt[e[:, 1]] - t_gt[e[:, 0]] + rng.normal(0, 0.05, (len(e), 3))
    w = rng.uniform(0.5, 2.0, len(e))
    Z = np.tile(np.eye(4), (len(e), 1, 1))
    Z[:, :3, 3] = meas
    T0 = np.tile(np.eye(4), (n, 1, 1))
    T0[0, :3, 3] = t_gt[0]
    res = optimize_pose_graph(T0, e, Z, fixed=[0], weights=w, config=PoseGraphConfig(max_iterations=50, rotation_weight=1e4))
    # reference: unknowns t_1..t_{n-1}, rows sqrt(w) (t_j - t_i) = sqrt(w) meas
    A = np.zeros((len(e), n))
    A[np.arange(len(e)), e[:, 1]] += 1
    A[np.arange(len(e)), e[:, 0]] -= 1
    b = meas - A[:, :1] * t_gt[0]
    sw = np.sqrt(w)[:, None]
    ref, *_ = np.linalg.lstsq(A[:, 1:] * sw, b * sw, rcond=None)
    np.testing.assert_allclose(res.poses[1:, :3, 3], ref, atol=1e-4)
    np.testing.assert_allclose(res.poses[:, :3, :3], np.tile(np.eye(3), (n, 1, 1)), atol=1e-5)


def test_loop_edge_removes_drift():
    rng = np.random.default_rng(3)
    n = 40
    T_gt = circle_poses(n)
    e = chain_edges(n)
    Z = relative_pose(T_gt[e[:, 0]], T_gt[e[:, 1]])
    # odometry with a systematic bias (drift) plus noise
    bias = make_pose(so3_exp([0.0, 0.004, 0.0]), [0.004, 0.0, 0.0])
    Zn = np.stack([z @ bias @ make_pose(so3_exp(rng.normal(0, 1e-3, 3)), rng.normal(0, 1e-3, 3)) for z in Z])
    T_odo = [T_gt[0]]
    for z in Zn:
        T_odo.append(T_odo[-1] @ z)
    T_odo = np.stack(T_odo)
    loop = np.array([[0, n - 1]])
    Z_loop = relative_pose(T_gt[0], T_gt[n - 1])[None]
    res = optimize_pose_graph(T_odo, np.concatenate([e, loop]), np.concatenate([Zn, Z_loop]), fixed=[0])
    err_before = np.linalg.norm(T_odo[:, :3, 3] - T_gt[:, :3, 3], axis=1)
    err_after = np.linalg.norm(res.poses[:, :3, 3] - T_gt[:, :3, 3], axis=1)
    assert err_before.max() > 0.1
    assert np.sqrt(np.mean(err_after**2)) < 0.25 * np.sqrt(np.mean(err_before**2))
    # the loop edge is satisfied after optimisation
    Z_after = relative_pose(res.poses[0], res.poses[n - 1])
    assert np.linalg.norm(Z_after[:3, 3] - Z_loop[0, :3, 3]) < 0.02


def test_correct_points_move_with_reference_keyframe():
    rng = np.random.default_rng(4)
    T_old = circle_poses(3)
    corr = make_pose(so3_exp([0.1, -0.2, 0.05]), [0.3, 0.0, -0.1])
    T_new = T_old.copy()
    T_new[2] = corr @ T_old[2]
    X = rng.normal(0, 1, (5, 3))
    ref = np.array([0, 2, 2, 1, 0])
    Y = correct_points(X, ref, T_old, T_new)
    np.testing.assert_allclose(Y[ref != 2], X[ref != 2], atol=1e-12)
    np.testing.assert_allclose(Y[ref == 2], transform_points(corr, X[ref == 2]), atol=1e-12)
    # the point keeps its camera-frame coordinates in its reference keyframe
    np.testing.assert_allclose(
        transform_points(se3_inv(T_new[2]), Y[1:2]), transform_points(se3_inv(T_old[2]), X[1:2]), atol=1e-12
    )


def test_bad_input_errors():
    T = circle_poses(4)
    e = chain_edges(4)
    Z = relative_pose(T[e[:, 0]], T[e[:, 1]])
    with pytest.raises(ValueError, match="fixed"):
        optimize_pose_graph(T, e, Z, fixed=[])
    with pytest.raises(ValueError, match="edge indices"):
        optimize_pose_graph(T, e + 1, Z)
    with pytest.raises(ValueError, match="measurements"):
        optimize_pose_graph(T, e, Z[:2])
    with pytest.raises(ValueError, match="weights"):
        optimize_pose_graph(T, e, Z, weights=-np.ones(3))
    with pytest.raises(ValueError, match="loss"):
        PoseGraphConfig(loss="l3")


@pytest.mark.parametrize("rotation_weight", [1.0, PoseGraphConfig().rotation_weight])
def test_reaches_the_scipy_minimum_on_a_noisy_graph(rotation_weight):
    """Our Levenberg-Marquardt and scipy's least_squares on the same inconsistent graph (ORB-SLAM2's
    identity weight and the default)."""
    from dynslam_lab.slam.scipy_reference import pose_graph_least_squares

    rng = np.random.default_rng(7)
    T_gt = circle_poses(15)
    e = np.concatenate([chain_edges(15), [[14, 0], [0, 7], [3, 11]]])
    Z = relative_pose(T_gt[e[:, 0]], T_gt[e[:, 1]])
    Z = np.stack([make_pose(so3_exp(rng.normal(0, 0.02, 3)), rng.normal(0, 0.03, 3)) @ z for z in Z])
    w = rng.uniform(0.5, 2.0, len(e))
    res = optimize_pose_graph(T_gt, e, Z, fixed=[0], weights=w,
                              config=PoseGraphConfig(max_iterations=50, rotation_weight=rotation_weight))
    T_ref, cost_ref = pose_graph_least_squares(T_gt, e, Z, [0], w, rotation_weight=rotation_weight)
    assert res.final_cost == pytest.approx(0.5 * cost_ref, rel=1e-6)
    np.testing.assert_allclose(res.poses, T_ref, atol=1e-5)  # scipy differentiates numerically


def test_rotation_weight_is_the_displacement_of_a_point_that_far():
    """Hand-computed: an edge whose error is a rotation of 0.01 rad about z has the rotation residual
    ``rotation_weight * 0.01``, which is (to first order) how far that rotation moves a point
    ``rotation_weight`` metres from the camera."""
    cfg = PoseGraphConfig()
    T_i, T_j = np.eye(4), make_pose(so3_exp(np.array([0.0, 0.0, 0.01])), np.zeros(3))
    R, t = np.stack([T_i[:3, :3], T_j[:3, :3]]), np.zeros((2, 3))
    r = edge_residuals(R, t, np.array([[0, 1]]), np.eye(4)[None], np.ones(1), cfg.rotation_weight)
    np.testing.assert_allclose(r[0, :3], [0.0, 0.0, 0.01 * cfg.rotation_weight], atol=1e-12)
    np.testing.assert_allclose(r[0, 3:], 0.0, atol=1e-12)
    X = np.array([cfg.rotation_weight, 0.0, 0.0])  # a point rotation_weight metres away, moved by the rotation
    assert np.linalg.norm(T_j[:3, :3] @ X - X) == pytest.approx(np.linalg.norm(r[0, :3]), rel=1e-4)


def _random_information(rng, n: int) -> np.ndarray:
    """SPD 6 x 6 matrices with condition numbers up to ~1e4 (one weak direction each, as a loop seen
    at one depth gives)."""
    A = rng.normal(size=(n, 6, 6))
    Q = np.linalg.qr(A)[0]
    ev = np.exp(rng.uniform(np.log(1e1), np.log(1e5), size=(n, 6)))
    return Q @ (ev[:, :, None] * np.swapaxes(Q, 1, 2))


@pytest.mark.parametrize("rotation_weight", [1.0, PoseGraphConfig().rotation_weight])
def test_information_reaches_the_scipy_minimum(rotation_weight):
    """Full 6 x 6 information per edge: our Levenberg-Marquardt against scipy's least_squares on the same
    whitened residuals; with information the rotation weight changes nothing but the scaling."""
    from dynslam_lab.slam.scipy_reference import pose_graph_least_squares

    rng = np.random.default_rng(11)
    T_gt = circle_poses(12)
    e = np.concatenate([chain_edges(12), [[11, 0], [0, 6], [2, 9]]])
    Z = relative_pose(T_gt[e[:, 0]], T_gt[e[:, 1]])
    Z = np.stack([make_pose(so3_exp(rng.normal(0, 0.02, 3)), rng.normal(0, 0.03, 3)) @ z for z in Z])
    info = _random_information(rng, len(e))
    w = np.ones(len(e))
    res = optimize_pose_graph(T_gt, e, Z, fixed=[0], weights=w, information=info,
                              config=PoseGraphConfig(max_iterations=100, rotation_weight=rotation_weight))
    T_ref, cost_ref = pose_graph_least_squares(T_gt, e, Z, [0], w, rotation_weight=rotation_weight, information=info,
                                               max_nfev=200)
    assert res.final_cost == pytest.approx(0.5 * cost_ref, rel=1e-5)
    assert res.final_cost <= 0.5 * cost_ref * (1 + 1e-9)  # ours is not worse (scipy differentiates numerically)
    np.testing.assert_allclose(res.poses, T_ref, atol=1e-4)  # weak directions of condition ~1e4: looser than above
    other = optimize_pose_graph(T_gt, e, Z, fixed=[0], weights=w, information=info,
                                config=PoseGraphConfig(max_iterations=100, rotation_weight=7.0))
    np.testing.assert_allclose(other.poses, res.poses, atol=1e-6)


def test_information_decides_which_edge_takes_the_misclosure():
    """Hand-made: a triangle of poses whose three edges disagree by 10 cm along x. The edge whose
    information is weak along x (1 against 1e6) takes the whole misclosure; with identity information
    it is shared equally (a third each)."""
    T_gt = np.stack([make_pose(np.eye(3), np.array([x, 0.0, 0.0])) for x in (0.0, 1.0, 2.0)])
    e = np.array([[0, 1], [1, 2], [0, 2]])
    Z = relative_pose(T_gt[e[:, 0]], T_gt[e[:, 1]])
    Z[2] = make_pose(np.eye(3), np.array([2.1, 0.0, 0.0]))  # the long edge says 2.1 m
    info = np.tile(1e6 * np.eye(6), (3, 1, 1))
    info[1, 3, 3] = 1.0  # edge 1 -> 2 is weak along x
    res = optimize_pose_graph(T_gt, e, Z, fixed=[0], information=info, config=PoseGraphConfig(max_iterations=50))
    assert res.poses[1, 0, 3] == pytest.approx(1.0, abs=1e-4)
    assert res.poses[2, 0, 3] == pytest.approx(2.1, abs=1e-4)
    plain = optimize_pose_graph(T_gt, e, Z, fixed=[0], config=PoseGraphConfig(max_iterations=50))
    assert plain.poses[1, 0, 3] == pytest.approx(1.0 + 0.1 / 3, abs=1e-4)
    assert plain.poses[2, 0, 3] == pytest.approx(2.0 + 0.2 / 3, abs=1e-4)


def test_information_must_be_positive_definite():
    T = circle_poses(3)
    e = chain_edges(3)
    Z = relative_pose(T[e[:, 0]], T[e[:, 1]])
    with pytest.raises(ValueError, match="positive definite"):
        optimize_pose_graph(T, e, Z, information=np.zeros((2, 6, 6)))
    with pytest.raises(ValueError, match=r"\(2, 6, 6\)"):
        optimize_pose_graph(T, e, Z, information=np.tile(np.eye(6), (3, 1, 1)))
