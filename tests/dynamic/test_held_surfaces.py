"""Surfaces seen moving stay dynamic for a few frames (``TemporalConfig.hold_frames``, 3 by default since
2026-12-07; docs/robustness.md "Held surfaces, three frames").

Rendered scene ``random_438`` (a fresh seed, drawn after the pipeline was last changed): a camera turning in place
in a photo-textured room, a box 0.8 x 0.5 x 1.1 m at 1.3 m holding about an eighth of the keypoints, mapped at rest,
starts at frame 15 and speeds up to 0.56 m/s by frame 29. Step 3b of the reference pose finds it at frame 17 (87 of
its 115 keypoints dynamic; by the leave-one-out test, so no map point is culled); without the hold, the next frame
judges 12 of its 105 keypoints dynamic, matches 35 of them to points mapped at frame 0, and from there on
follows it (error 0.49 m from frame 0 at frame 40, 0.25 m ATE over 240
frames). With the hold its surface stays dynamic between verdicts."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dynslam_lab.config import Config
from dynslam_lab.datasets import stress
from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.datasets.tum import TumSequence
from dynslam_lab.geometry.se3 import se3_inv
from dynslam_lab.pipeline import build_pipeline

N_FRAMES = 42
BOX = 2  # the instance id of the box in random_438


def _run(seq: TumSequence, hold_frames: int | None):
    cfg = Config()
    if hold_frames is not None:
        cfg = replace(cfg, screening=replace(cfg.screening, temporal=replace(cfg.screening.temporal, hold_frames=hold_frames)))
    system = build_pipeline(cfg, seq.camera, detector="none", filters="geometry", loop_closing=False)
    T0, errors, on_box, box_dynamic = None, [], 0, 0
    for i in range(len(seq)):
        frame = seq[i]
        res = system.process(frame)
        assert res.T_w_c is not None, f"frame {i} lost"
        T0 = frame.T_w_c_gt if T0 is None else T0
        errors.append(np.linalg.norm(res.T_w_c[:3, 3] - (se3_inv(T0) @ frame.T_w_c_gt)[:3, 3]))
        if i >= 20:  # the box has moved since step 3b found it at frame 17
            uv = np.round(res.uv).astype(int)
            box = frame.instance_mask[uv[:, 1].clip(0, frame.depth.shape[0] - 1), uv[:, 0].clip(0, frame.depth.shape[1] - 1)] == BOX
            on_box += int(box.sum())
            box_dynamic += int((box & np.asarray(res.dynamic, bool)).sum())
    return np.array(errors), box_dynamic / max(on_box, 1)


@pytest.mark.slow
def test_a_box_found_moving_stays_dynamic_between_verdicts_and_the_camera_stays_on_the_room():
    seq = TumSequence(synthetic_sequence(stress.random_scene_preset(438, name="random_438", n_frames=N_FRAMES)))
    errors, box_recall = _run(seq, None)  # the defaults
    # measured (2026-12-07): at most 4 mm to frame 16, then 4-48 mm (the camera turns in place: a turn and a slide
    # of a few centimetres look alike against walls 2-5 m away); the box's keypoints 80-100 % dynamic
    assert errors[:16].max() < 0.01
    assert errors[16:].max() < 0.1, errors[16:]
    assert box_recall > 0.7, box_recall
    # without the hold the same frames follow the box: 0.49 m at frame 40 (measured), the box mostly static
    errors_off, box_recall_off = _run(seq, 0)
    assert errors_off[-1] > 0.2 and box_recall_off < 0.4, (errors_off[-5:], box_recall_off)
