"""A loop closed through rooms the default vocabulary never saw (issue 12), end to end.

``loop_noise`` and ``loop_photo`` of the stress suite (:data:`dynslam_lab.datasets.stress.STRESS_LOOPS`):
randomised rooms with noise textures / photographs, no movers, the camera circling once and returning to
its start, rendered with 300 frames. The system as ``dynslam run`` builds it (loop closing in its worker
thread: verification and correction) must track every frame, close exactly one loop, from the last part
of the circle to its start, and the trajectory after closure must be no worse than without loop closing
and within the issue's 2 cm. About 1.5 minutes per room on 2 cores with the render cached.

``loop_photo`` lost frames before the revisit (relocalised there, so no loop) until keyframes made points
of far keypoints too (``tracking.new_point_depth``); both rooms run with the default settings, under which
the far points and the automatic dense term engage because no screener judges anything dynamic
(``tracking.static_scene_frames``). ``loop_pattern`` (a style the vocabulary was trained on) and
``loop_flat`` (closed, ATE 20-29 mm on seeds 0-3: the plain wall is tracked by depth alone) are measured on three sensor
seeds in docs/loop_closing.md, "Unseen scenes: the loop found", not here (CI time).
"""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.config import Config
from dynslam_lab.datasets.stress import stress_suite
from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.datasets.tum import TumSequence
from dynslam_lab.evaluation import compute_ate
from dynslam_lab.pipeline import build_pipeline
from dynslam_lab.threads import blas_single_thread

pytestmark = pytest.mark.slow

N = 300


def _run(seq: TumSequence, loop: bool):
    system = build_pipeline(Config(), seq.camera, loop_closing=loop)
    with blas_single_thread():
        for i in range(len(seq)):
            system.process(seq[i])
    system.finish_loop_closing()
    if system.loop_closer is not None:
        system.loop_closer.close()
    return system


@pytest.mark.parametrize("room", ["loop_noise", "loop_photo"])
def test_loop_found_in_an_unseen_room(room):
    preset = {q.name: q for q in stress_suite(n_frames=N, loops=True)}[room]
    seq = TumSequence(synthetic_sequence(preset))
    with_loop, without = _run(seq, True), _run(seq, False)
    assert not with_loop.lost_frames and not without.lost_frames
    assert len(with_loop.loop_results) == 1, [(r.query_kf_id, r.loop_kf_id) for r in with_loop.loop_results]
    r = with_loop.loop_results[0]
    assert r.applied and with_loop.loop_closer.errors == [] and with_loop.loop_errors == []
    q, l = with_loop.map.keyframes[r.query_kf_id], with_loop.map.keyframes[r.loop_kf_id]
    assert q.frame_index > 0.75 * N and l.frame_index < 0.1 * N
    # the two keyframes' true poses are close: the same place seen again
    gt = seq.groundtruth
    T_q = gt.poses[int(np.argmin(np.abs(gt.timestamps - q.timestamp)))]
    T_l = gt.poses[int(np.argmin(np.abs(gt.timestamps - l.timestamp)))]
    assert np.linalg.norm(T_q[:3, 3] - T_l[:3, 3]) < 0.4
    ate_loop = compute_ate(gt, with_loop.trajectory(), align="se3").stats.rmse
    ate_plain = compute_ate(gt, without.trajectory(), align="se3").stats.rmse
    assert ate_loop <= ate_plain + 1e-4 and ate_loop <= 0.02, (ate_loop, ate_plain)
