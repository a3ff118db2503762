"""The checks that keep false loops out (spread, depth spread, drift bound, neighbours), the
background correction against the synchronous one, and the place-recognition measure."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.geometry.se3 import make_pose, so3_exp
from dynslam_lab.slam.loop_closing import (
    LoopClosingConfig,
    correction_size,
    depth_spread,
    image_spread,
    path_length,
)
from dynslam_lab.slam.loop_closing.place_recognition import (
    best_candidates,
    normalised_scores,
    precision_recall,
    revisit_truth,
)
from dynslam_lab.slam.map import Map
from tests.slam.test_loop_closing import run_loop_scene


def test_image_spread_by_hand():
    ref = np.array([[10, 10], [630, 10], [10, 470], [630, 470], [320, 240]], float)  # 5 cells of a 4x4 grid
    assert image_spread(ref, ref, 640, 480, 4) == 1.0
    assert image_spread(ref[:1], ref, 640, 480, 4) == pytest.approx(1 / 5)
    # matches where the reference has no keypoints do not count
    assert image_spread(np.array([[330.0, 10.0]]), ref, 640, 480, 4) == 0.0
    assert image_spread(ref, np.zeros((0, 2)), 640, 480, 4) == 0.0


def test_depth_spread_is_the_10_90_range():
    z = np.linspace(1.0, 3.0, 101)
    assert depth_spread(z) == pytest.approx(1.6)
    assert depth_spread(np.full(50, 2.0)) == 0.0
    assert depth_spread(np.array([1.0, np.nan])) == 0.0


def test_correction_size_and_path_length():
    C = make_pose(so3_exp([0.0, np.radians(10), 0.0]), [0.3, 0.4, 0.0])
    t, r = correction_size(C)
    assert t == pytest.approx(0.5) and r == pytest.approx(10.0)

    class KF:  # the path only needs centres
        def __init__(self, c):
            self.center = np.asarray(c, float)

    mp = Map()
    for k, c in enumerate([[0, 0, 0], [1, 0, 0], [1, 1, 0], [5, 5, 5]]):
        mp.keyframes[k] = KF(c)
    assert path_length(mp, 0, 2) == pytest.approx(2.0)
    assert path_length(mp, 2, 0) == pytest.approx(2.0)
    del mp.keyframes[1]  # a culled keyframe: the chain skips it
    assert path_length(mp, 0, 2) == pytest.approx(np.sqrt(2))


def test_drift_bound_rejects_a_loop_the_odometry_cannot_explain():
    """The same drifting loop scene as the closer's test: accepted with the default bound, rejected
    when the bound is far below the drift the loop has to correct (the check that refuses to bend a
    map dragged by movers)."""
    _, _, _, _, results = run_loop_scene(400.0, 44, config=LoopClosingConfig(global_ba=False, background=False))
    assert len(results) == 1
    t, r = correction_size(results[0].correction)
    assert results[0].checks["path"] > 4.0 and t > 0.02
    tight = LoopClosingConfig(global_ba=False, background=False, drift_abs=0.0, drift_rel=0.1 * t / results[0].checks["path"])
    closer, _, _, _, none = run_loop_scene(400.0, 44, config=tight)
    assert none == [] and any(reason == "drift" for _, _, reason, _ in closer.rejected)


def test_neighbours_must_agree():
    """Neighbour agreement on: the true loop passes with its neighbours' matches recorded; demanding
    more matches than a neighbour can have rejects it with the reason named."""
    _, _, _, _, results = run_loop_scene(400.0, 44, config=LoopClosingConfig(global_ba=False, background=False))
    nb = results[0].checks["neighbour_matches"]
    assert len(nb) == 2 and min(nb) >= 30
    strict = LoopClosingConfig(global_ba=False, background=False, min_neighbour_matches=100_000)
    closer, _, _, _, none = run_loop_scene(400.0, 44, config=strict)
    assert none == [] and any(reason == "neighbours" for _, _, reason, _ in closer.rejected)


def test_background_correction_equals_the_synchronous_one():
    """The worker thread computes on a snapshot; applied at the next poll, the keyframe poses are the
    ones the synchronous path gives (no keyframe is added in between here)."""
    cfg = LoopClosingConfig(global_ba=False, background=False)
    _, mp_sync, _, _, res_sync = run_loop_scene(400.0, 44, config=cfg)
    closer, mp_bg, _, _, res_bg = run_loop_scene(400.0, 44, config=LoopClosingConfig(global_ba=False, background=True),
                                                apply_in_loop=True)
    assert [(r.query_kf_id, r.loop_kf_id) for r in res_bg] == [(r.query_kf_id, r.loop_kf_id) for r in res_sync]
    assert res_bg[0].applied and not closer.busy
    for k in mp_sync.keyframes:
        np.testing.assert_allclose(mp_bg.keyframes[k].T_w_c, mp_sync.keyframes[k].T_w_c, atol=1e-9)


# --------------------------------------------------------------------------- place recognition
def test_revisit_truth_and_candidates_by_hand():
    # four poses: 0 and 3 at the same place looking the same way, 1 far, 2 same place turned 90 deg
    P = np.stack([make_pose(np.eye(3), [0, 0, 0]), make_pose(np.eye(3), [3, 0, 0]),
                  make_pose(so3_exp([0, np.pi / 2, 0]), [0, 0, 0]), make_pose(np.eye(3), [0.1, 0, 0])])
    T = revisit_truth(P, 0.5, 30.0)
    assert T[0, 3] and T[3, 0] and not T[0, 1] and not T[0, 2]
    S = np.array([[1, .1, .1, .5], [.1, 1, .2, .1], [.1, .2, 1, .3], [.5, .1, .3, 1]])
    j, s = best_candidates(S, np.arange(4.0), min_gap=2.0)  # frame 3 may match 0 or 1
    assert j.tolist() == [-1, -1, 0, 0] and s[3] == 0.5
    eta = normalised_scores(S)
    assert eta[3, 0] == pytest.approx(0.5 / 0.3) and eta[0, 0] == 0.0


def test_precision_recall_by_hand():
    # frames 4 and 5 revisit 0 and 1; frame 3 has no revisit
    n = 6
    truth = np.zeros((n, n), bool)
    truth[4, 0] = truth[0, 4] = truth[5, 1] = truth[1, 5] = True
    S = np.full((n, n), 0.1)
    S[4, 0] = 0.9   # a true candidate with a high score
    S[5, 1] = 0.5   # a true candidate with a lower score
    S[3, 0] = 0.7   # a false candidate in between
    pr = precision_recall(S, truth, np.arange(n, dtype=float), min_gap=2.0, normalise=False)
    assert pr.n_queries_with_revisit == 2
    # thresholds 0.9 -> P 1, R 0.5; 0.7 -> P 0.5, R 0.5; 0.5 -> P 2/3, R 1
    k = {round(a, 3): (p, r) for a, p, r in zip(pr.alpha, pr.precision, pr.recall)}
    assert k[0.9] == (1.0, 0.5) and k[0.7] == (0.5, 0.5) and k[0.5] == pytest.approx((2 / 3, 1.0))
    assert pr.recall_at_full_precision == 0.5


# --------------------------------------------------------------------------- verification off the frame loop
def test_verification_on_a_frozen_view_equals_the_live_map_and_ignores_later_changes():
    """The worker verifies on a view frozen when the candidates are handed over: the same check as on
    the live map, and unchanged when the frame loop then moves poses and points and rewrites observations."""
    from dynslam_lab.slam.loop_closing.frozen import freeze_for_verification
    from dynslam_lab.slam.loop_closing.verification import verify_candidate

    cfg = LoopClosingConfig(global_ba=False, background=False)
    closer, mp, _, _, res = run_loop_scene(400.0, 44, config=cfg)
    assert res
    q, c = res[0].query_kf_id, res[0].loop_kf_id
    kf = mp.keyframes[q]
    cov = {q: mp.covisibility(q), c: mp.covisibility(c)}
    view = freeze_for_verification(mp, q, [c], cov, cfg.loop_group_size)
    live = verify_candidate(kf, mp, c, cfg, closer.camera, closer.bf, np.random.default_rng(3))
    frozen = verify_candidate(view.keyframes[q], view, c, cfg, closer.camera, closer.bf, np.random.default_rng(3))
    assert live.accepted and frozen.accepted
    np.testing.assert_array_equal(frozen.T_q_c, live.T_q_c)
    np.testing.assert_array_equal(frozen.ip, live.ip)
    # the frame loop goes on: poses move, points move, observations of the loop group are dropped
    shift = make_pose(so3_exp([0.0, 0.3, 0.0]), [1.0, 0.0, 0.0])
    frozen_ids = sorted(view.keyframes)
    centres = {k: mp.keyframes[k].center for k in frozen_ids}
    for k in list(mp.keyframes):
        mp.keyframes[k].T_w_c = shift @ mp.keyframes[k].T_w_c
        mp.keyframes[k].map_point_ids[::2] = -1
    mp.xyz[mp.point_ids()] += 0.5
    mp.invalidate()
    again = verify_candidate(view.keyframes[q], view, c, cfg, closer.camera, closer.bf, np.random.default_rng(3))
    np.testing.assert_array_equal(again.T_q_c, live.T_q_c)
    np.testing.assert_array_equal(again.correction, live.correction)
    # every keyframe's pose as frozen (views made on first read, after the change), none added or lost
    mp.remove_keyframe(frozen_ids[len(frozen_ids) // 2])  # culled in the live map after freezing
    assert sorted(view.keyframes) == frozen_ids
    for k in frozen_ids:
        np.testing.assert_array_equal(view.keyframes[k].center, centres[k])
    np.testing.assert_array_equal(view.keyframes.centres(frozen_ids), np.array([centres[k] for k in frozen_ids]))
    assert again.stats["path"] == live.stats["path"] > 0  # the path length from the frozen centres
    # a point outside the frozen loop groups is never read silently
    with pytest.raises(KeyError):
        view.xyz[np.array([mp.n_points_total + 10])]
