"""RPE: pairing rules, hand-computed drift (frames and seconds), agreement with evo to 1e-6."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dynslam_lab.evaluation import Trajectory, TrajectoryError, compute_rpe, read_tum_trajectory, rpe_pairs
from tests.conftest import shared_file
from tests.evaluation.evo_reference import REAL_IDS, REAL_PAIRS, assert_stats_match, evo_synced


def test_pairs_frames():
    t = np.arange(10.0)
    i, j = rpe_pairs(t, 3, "frames")
    assert list(zip(i, j)) == [(0, 3), (3, 6), (6, 9)]
    i, j = rpe_pairs(t, 3, "frames", all_pairs=True)
    assert list(zip(i, j)) == [(k, k + 3) for k in range(7)]
    with pytest.raises(ValueError, match="whole number"):
        rpe_pairs(t, 1.5, "frames")
    with pytest.raises(ValueError, match="delta_unit"):
        rpe_pairs(t, 1, "metres")
    with pytest.raises(ValueError, match="delta must be > 0"):
        rpe_pairs(t, 0, "frames")


def test_pairs_seconds_hand_case():
    # A 2 Hz trajectory with a gap between 2.0 and 3.6 s.
    t = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 3.6, 4.1, 4.6, 5.1])
    i, j = rpe_pairs(t, 1.0, "seconds", all_pairs=True)
    # 0->1.0, 0.5->1.5, 1.0->2.0; 1.5 -> 2.5 has no pose within 0.1 s; 2.0 -> 3.0 neither;
    # 3.6->4.6, 4.1->5.1.
    assert list(zip(i, j)) == [(0, 2), (1, 3), (2, 4), (5, 7), (6, 8)]
    i, j = rpe_pairs(t, 1.0, "seconds")
    assert list(zip(i, j)) == [(0, 2), (2, 4), (5, 7)]
    # A looser tolerance accepts shorter or longer pairs near the gap and at the end.
    i, j = rpe_pairs(t, 1.0, "seconds", all_pairs=True, delta_tol=0.65)
    assert list(zip(i, j)) == [(0, 2), (1, 3), (2, 4), (3, 4), (4, 5), (5, 7), (6, 8), (7, 8)]


def _drift_pair(rate=2.0, n=11, v=1.0, v_est=1.1, yaw_rate_deg=1.0):
    """Ground truth moves along x at v m/s; the estimate at v_est and yawing at yaw_rate deg/s."""
    t = np.arange(n) / rate
    Q = np.tile(np.eye(4), (n, 1, 1))
    Q[:, 0, 3] = v * t
    P = np.tile(np.eye(4), (n, 1, 1))
    P[:, 0, 3] = v_est * t
    P[:, :3, :3] = Rotation.from_euler("z", (yaw_rate_deg * t)[:, None], degrees=True).as_matrix()
    return Trajectory(t, Q), Trajectory(t, P)


def test_seconds_hand_computed_drift():
    gt, est = _drift_pair()
    r = compute_rpe(gt, est, delta=1.0, delta_unit="seconds", align="none", associate=False)
    # Pairs (0,2), (2,4), ... (8,10): each spans 1 s. E = Q_rel^-1 P_rel: Q_rel = trans(1, 0, 0);
    # P_rel = [Rz(1 deg) | R_i^T (1.1, 0, 0)], so trans(E) = R_i^T (1.1, 0, 0) - (1, 0, 0).
    assert r.pairs.tolist() == [[0, 2], [2, 4], [4, 6], [6, 8], [8, 10]]
    expected_t = []
    for i in r.pairs[:, 0]:
        a = np.radians(i / 2.0)
        expected_t.append(np.hypot(1.1 * np.cos(a) - 1.0, 1.1 * np.sin(a)))
    np.testing.assert_allclose(r.trans_errors, expected_t, atol=1e-12)
    np.testing.assert_allclose(r.rot_errors, 1.0, atol=1e-9)
    assert r.rot.rmse == pytest.approx(1.0)
    # 2 s: half as many pairs, twice the yaw error.
    r2 = compute_rpe(gt, est, delta=2.0, delta_unit="seconds", align="none", associate=False)
    assert r2.pairs.tolist() == [[0, 4], [4, 8]]
    np.testing.assert_allclose(r2.rot_errors, 2.0, atol=1e-9)


def test_frames_equal_seconds_on_uniform_rate():
    gt, est = _drift_pair(rate=10.0, n=101)
    a = compute_rpe(gt, est, delta=10, delta_unit="frames", align="none", associate=False)
    b = compute_rpe(gt, est, delta=1.0, delta_unit="seconds", align="none", associate=False)
    np.testing.assert_array_equal(a.pairs, b.pairs)
    np.testing.assert_allclose(a.trans_errors, b.trans_errors)


def test_rigid_alignment_does_not_change_rpe(synth):
    make, noisy = synth
    gt = make(n=120)
    est = noisy(gt, seed=4)
    S = np.eye(4)
    S[:3, :3] = Rotation.from_rotvec([1.0, 0.2, -0.5]).as_matrix()
    S[:3, 3] = [3.0, 0.0, 1.0]
    a = compute_rpe(gt, est.transformed(S), align="none")
    b = compute_rpe(gt, est, align="se3")
    np.testing.assert_allclose(a.trans_errors, b.trans_errors, atol=1e-10)
    np.testing.assert_allclose(a.rot_errors, b.rot_errors, atol=1e-8)


def test_too_short_for_delta(synth):
    make, _ = synth
    gt = make(n=5)
    with pytest.raises(TrajectoryError, match="no pose pairs 10 frames apart"):
        compute_rpe(gt, gt, delta=10)


def _evo_rpe(gt, est, align, delta, all_pairs, relation):
    metrics = pytest.importorskip("evo.core.metrics")
    rel = metrics.PoseRelation.translation_part if relation == "trans" else metrics.PoseRelation.rotation_angle_deg
    m = metrics.RPE(rel, delta, metrics.Unit.frames, all_pairs=all_pairs)
    m.process_data(evo_synced(gt, est, align))
    return m


def _check(r, gt, est, align, delta, all_pairs):
    for rel, stats, errors in (("trans", r.trans, r.trans_errors), ("rot", r.rot, r.rot_errors)):
        m = _evo_rpe(gt, est, align, delta, all_pairs, rel)
        assert_stats_match(stats, m.get_all_statistics(), rel)
        np.testing.assert_allclose(errors, m.error, atol=1e-6)


@pytest.mark.parametrize("align", ["se3", "sim3"])
@pytest.mark.parametrize("delta, all_pairs", [(1, False), (5, False), (5, True)])
def test_matches_evo_synthetic(synth, align, delta, all_pairs):
    make, noisy = synth
    gt = make(n=400, rate=100.0, seed=3)
    est = noisy(make(n=120, rate=30.0, seed=3), sigma_t=0.01, sigma_r=0.02, seed=9).transformed(np.eye(4), 1.3)
    r = compute_rpe(gt, est, delta=delta, all_pairs=all_pairs, align=align)
    _check(r, gt, est, align, delta, all_pairs)


@pytest.mark.needs_shared
@pytest.mark.parametrize("gt_rel, est_rel", REAL_PAIRS, ids=REAL_IDS)
def test_matches_evo_real(gt_rel, est_rel):
    pytest.importorskip("evo")
    gt = read_tum_trajectory(shared_file(gt_rel), duplicates="first")  # fr2/desk repeats one stamp
    est = read_tum_trajectory(shared_file(est_rel))
    for align, delta, all_pairs in (("se3", 1, False), ("sim3", 10, True)):
        r = compute_rpe(gt, est, delta=delta, all_pairs=all_pairs, align=align)
        _check(r, gt, est, align, delta, all_pairs)
