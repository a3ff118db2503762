"""Loop closing and relocalisation end to end on rendered sequences, checked against the renderer's
ground truth: the SLAM system (the code path of ``dynslam run``) with and without loop closing on the
synthetic ``loop`` preset (the correction computed in the loop closer's worker thread), and
relocalisation of a lost and of a kidnapped camera through the keyframe database. No loop on
sequences that do not come back: ``test_loop_false.py``.

The sequences are rendered once into the test cache (``synthetic_sequence``; ``$DYNSLAM_CACHE``) and
each SLAM run is shared by the tests of this module.
"""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.config import Config
from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.datasets.tum import TumSequence
from dynslam_lab.evaluation import compute_ate
from dynslam_lab.features.orb import extract_features
from dynslam_lab.geometry.se3 import se3_inv
from dynslam_lab.pipeline import build_pipeline
from dynslam_lab.slam.frame import make_slam_frame
from dynslam_lab.slam.tracking import Tracker, TrackState
from dynslam_lab.threads import blas_single_thread

pytestmark = pytest.mark.slow

N_LOOP = 300  # frames of the loop preset: once round the room (the preset's own length is 600)
N_MAP = 150  # frames mapped before the relocalisation tests: the first half of the circle


def _sequence(preset: str, n: int) -> TumSequence:
    return TumSequence(synthetic_sequence(preset, n, 0))


def _run(seq: TumSequence, loop: bool, n: int | None = None):
    """The system over the first ``n`` frames; returns ``(system, loop closer or None)``."""
    system = build_pipeline(Config(), seq.camera, loop_closing=loop)
    closer = system.loop_closer
    with blas_single_thread():
        for i in range(len(seq) if n is None else n):
            system.process(seq[i])
    return system, closer


def _gt_pose(seq: TumSequence, timestamp: float) -> np.ndarray:
    i = int(np.argmin(np.abs(seq.groundtruth.timestamps - timestamp)))
    assert abs(seq.groundtruth.timestamps[i] - timestamp) < 1e-6
    return seq.groundtruth.poses[i]


def seq_ts(seq: TumSequence, index: int) -> float:
    """Timestamp of frame ``index``."""
    return float(seq.timestamps[index])


def _pose_error(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """Translation (m) and rotation (deg) of ``T_a^-1 T_b``."""
    E = se3_inv(T_a) @ T_b
    cos = np.clip((np.trace(E[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(E[:3, 3])), float(np.degrees(np.arccos(cos)))


def _in_map_frame(seq: TumSequence, timestamp: float) -> np.ndarray:
    """True pose of a frame in the map's world frame (the first frame's camera, as the system sets it)."""
    return se3_inv(_gt_pose(seq, seq.timestamps[0])) @ _gt_pose(seq, timestamp)


@pytest.fixture(scope="module")
def loop_seq() -> TumSequence:
    return _sequence("loop", N_LOOP)


@pytest.fixture(scope="module")
def with_loop(loop_seq):
    return _run(loop_seq, loop=True)


@pytest.fixture(scope="module")
def without_loop(loop_seq):
    return _run(loop_seq, loop=False)


# --------------------------------------------------------------------------- loop closing
def test_loop_closed_once_at_the_revisit_and_ate_drops(loop_seq, with_loop, without_loop):
    system, closer = with_loop
    plain, _ = without_loop
    assert not system.lost_frames and not plain.lost_frames
    # exactly one loop: a keyframe of the last quarter of the circle to one of its first tenth
    assert len(system.loop_results) == 1
    r = system.loop_results[0]
    q, l = system.map.keyframes[r.query_kf_id], system.map.keyframes[r.loop_kf_id]
    assert q.frame_index > 0.75 * N_LOOP and l.frame_index < 0.1 * N_LOOP
    assert r.n_inliers >= 20 and r.n_map_matches >= 40
    # the two keyframes see the same place: their true poses are within the overlap of their views
    T_q, T_l = _gt_pose(loop_seq, q.timestamp), _gt_pose(loop_seq, l.timestamp)
    dist, ang = _pose_error(T_q, T_l)
    assert dist < 0.4 and ang < 25.0
    # the verified relative pose (what the correction uses) is the true one to a few mm / 0.3 deg
    dt, dr = _pose_error(se3_inv(T_q) @ T_l, r.T_query_loop)
    assert dt < 0.01 and dr < 0.3
    assert (min(q.id, l.id), max(q.id, l.id)) in {tuple(e) for e in system.keyframe_arrays()["loop_edges"].tolist()}
    # ATE (SE(3)-aligned) with the loop clearly below the one without
    gt = loop_seq.groundtruth
    ate_loop = compute_ate(gt, system.trajectory(), align="se3").stats.rmse
    ate_plain = compute_ate(gt, plain.trajectory(), align="se3").stats.rmse
    assert ate_loop < 0.8 * ate_plain and ate_loop < 0.006
    # the drift the loop removes: the last frame relative to the first (the path is closed)
    def closure_error(traj):
        T_est = se3_inv(traj.poses[0]) @ traj.poses[-1]
        T_true = se3_inv(_gt_pose(loop_seq, traj.timestamps[0])) @ _gt_pose(loop_seq, traj.timestamps[-1])
        return _pose_error(T_true, T_est)

    end_loop, end_plain = closure_error(system.trajectory()), closure_error(plain.trajectory())
    assert end_loop[0] < 0.3 * end_plain[0] and end_loop[0] < 0.003


# --------------------------------------------------------------------------- relocalisation
@pytest.fixture(scope="module")
def half_map(loop_seq):
    """The system after the first half of the circle."""
    return _run(loop_seq, loop=True, n=N_MAP)


def _nearest_keyframe(seq, mp, T_true: np.ndarray) -> int:
    """Keyframe whose true pose is nearest (metres + radians of the relative pose)."""
    def cost(kf):
        d, a = _pose_error(_gt_pose(seq, kf.timestamp), T_true)
        return d + np.radians(a)

    return min(mp.keyframes.values(), key=cost).id


def _relocalise(seq, system, closer, index: int):
    """A new tracker on the system's map and the loop closer's database, lost, given frame ``index``."""
    tracker = Tracker(system.camera, system.map, system.config.tracking, system.config.orb.scale_factor)
    tracker.database, tracker.vocabulary = closer.database, closer.vocabulary
    tracker.state = TrackState.LOST
    frame = seq[index]
    sf = make_slam_frame(frame, extract_features(frame.gray, system.config.orb))
    state = tracker.track(sf)
    return tracker, sf, state


def _map_error(seq, mp) -> tuple[float, float]:
    """Largest error (m, deg) of the map's keyframes against the truth: what a pose found in this map
    cannot be expected to beat."""
    errs = [_pose_error(_in_map_frame(seq, kf.timestamp), kf.T_w_c) for kf in mp.keyframes.values()]
    return max(e[0] for e in errs), max(e[1] for e in errs)


def test_relocalisation_of_a_lost_frame_from_the_middle(loop_seq, half_map):
    system, closer = half_map
    keyframe_indices = {kf.frame_index for kf in system.map.keyframes.values()}
    index = next(i for i in range(N_MAP // 2 + 1, N_MAP) if i not in keyframe_indices)  # a frame the map never kept
    map_t, map_r = _map_error(loop_seq, system.map)
    tracker, sf, state = _relocalise(loop_seq, system, closer, index)
    assert state == TrackState.RELOCALIZED and tracker.method == "relocalization"
    # The candidates: a handful of keyframes (brute force would try 20), the true nearest among them.
    T_true = _gt_pose(loop_seq, seq_ts(loop_seq, index))
    assert _nearest_keyframe(loop_seq, system.map, T_true) in tracker.last_reloc_candidates
    assert 1 <= len(tracker.last_reloc_candidates) <= 5
    # Tolerance: the map's own error (its worst keyframe, about 1 cm / 0.2 deg on this half circle)
    # plus 5 mm / 0.1 deg for a pose from hundreds of PnP + motion-only BA inliers.
    dt, dr = _pose_error(_in_map_frame(loop_seq, seq_ts(loop_seq, index)), sf.T_w_c)
    assert dt < map_t + 0.005 and dr < map_r + 0.1
    assert tracker.n_inliers >= system.config.tracking.min_local_inliers_reloc


def test_kidnapped_camera_relocalises_through_the_database(loop_seq, half_map):
    """The mapped camera is carried from half way round the circle to near its start: tracking is lost,
    the next frame's bag of words finds the keyframes of the start and the pose is recovered."""
    system, closer = half_map
    assert system.tracker.database is closer.database  # the system shares the loop closer's database
    kidnap = N_LOOP - 12
    lost = system.process(loop_seq[kidnap])
    assert lost.state == TrackState.LOST and lost.T_w_c is None
    res = system.process(loop_seq[kidnap + 1])
    assert res.state == TrackState.RELOCALIZED and res.method == "relocalization"
    T_true = _gt_pose(loop_seq, seq_ts(loop_seq, kidnap + 1))
    # the same tolerance as above: the map's error plus 5 mm / 0.1 deg
    map_t, map_r = _map_error(loop_seq, system.map)
    dt, dr = _pose_error(_in_map_frame(loop_seq, seq_ts(loop_seq, kidnap + 1)), res.T_w_c)
    assert dt < map_t + 0.005 and dr < map_r + 0.1
    cands = system.tracker.last_reloc_candidates
    assert _nearest_keyframe(loop_seq, system.map, T_true) in cands
    # the candidates are at the start of the circle, not where the camera was before the kidnap
    first = system.map.keyframes[cands[0]]
    assert _pose_error(_gt_pose(loop_seq, first.timestamp), T_true)[0] < 0.5
    # tracking goes on from there
    after = [system.process(loop_seq[i]) for i in range(kidnap + 2, kidnap + 6)]
    assert all(a.tracked for a in after)


def test_kidnapped_camera_relocalises_without_loop_closing(loop_seq):
    """With loop closing off the system keeps its own keyframe database (static words of every
    keyframe, culled ones dropped), so relocalisation still goes through the bag of words."""
    system, closer = _run(loop_seq, loop=False, n=N_MAP)
    assert closer is None and system.tracker.database is not None
    assert set(system.tracker.database.ids()) == set(system.map.keyframes)
    kidnap = N_LOOP - 12
    assert system.process(loop_seq[kidnap]).state == TrackState.LOST
    res = system.process(loop_seq[kidnap + 1])
    assert res.state == TrackState.RELOCALIZED and res.method == "relocalization"
    assert 1 <= len(system.tracker.last_reloc_candidates) <= 5  # BoW candidates, not the 20 of brute force
    map_t, map_r = _map_error(loop_seq, system.map)
    dt, dr = _pose_error(_in_map_frame(loop_seq, seq_ts(loop_seq, kidnap + 1)), res.T_w_c)
    assert dt < map_t + 0.005 and dr < map_r + 0.1
