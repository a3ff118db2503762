"""A mover mapped while it stood still that starts slowly (the room test, ``ReferencePoseConfig.room_test``, on by
default) (the mechanism traced on random_108/109/112,
docs/robustness.md): geometry without a detector must find it, keep the camera on the static world, and leave
the static keypoints alone. Rendered scene ``random_109``: a textured cart 1.3 m in front of a static camera,
mapped at frame 0 with half the keypoints, starts at frame 23."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dynslam_lab.config import Config
from dynslam_lab.datasets import stress
from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.datasets.tum import TumSequence
from dynslam_lab.dynamic.oracle import truth_dynamic
from dynslam_lab.geometry.se3 import se3_inv
from dynslam_lab.pipeline import build_pipeline

N_FRAMES = 36


@pytest.mark.slow
@pytest.mark.parametrize("prior_share", [1.0, 0.25], ids=["plain-extraction", "budget-prior"])
def test_a_cart_that_stood_still_and_starts_slowly_is_flagged_and_not_followed(prior_share):
    """``prior_share``: ``orb.prior_region_share``; 1 = the plain extraction, 0.25 (the default) = the cart's region
    of frame t - 2 keeps a quarter of its share of keypoints (docs/robustness.md, "ORB budget")."""
    seq = TumSequence(synthetic_sequence(stress.random_scene_preset(109, name="random_109", n_frames=N_FRAMES)))
    cfg = Config()  # the room test is on by default, the held surfaces for 3 frames (docs/robustness.md)
    cfg = replace(cfg, orb=replace(cfg.orb, prior_region_share=prior_share))
    system = build_pipeline(cfg, seq.camera, detector="none", filters="geometry", loop_closing=False)
    T0 = None
    errors, tp, fp, fn, cart_in_map = [], 0, 0, 0, []
    for i in range(len(seq)):
        frame = seq[i]
        res = system.process(frame)
        T0 = frame.T_w_c_gt if T0 is None else T0
        assert res.T_w_c is not None, f"frame {i} lost"
        truth_rel = se3_inv(T0) @ frame.T_w_c_gt
        errors.append(np.linalg.norm(res.T_w_c[:3, 3] - truth_rel[:3, 3]))
        if i >= 26:  # the cart has moved 2-10 cm since it was mapped
            truth = truth_dynamic(frame, res.uv)
            dyn = np.asarray(res.dynamic, bool)
            tp += int((dyn & truth).sum())
            fp += int((dyn & ~truth).sum())
            fn += int((~dyn & truth).sum())
    errors = np.array(errors)
    # before this mechanism the tracker followed the cart: 2.2 cm at frame 26, 7.6 cm at 30, 14 cm at 35 (and on).
    # Measured with the defaults (2026-12-02) on two renders of the scene (the renderer's textures through OpenCV
    # 5.0 / 5.1, which CI installs; the frames differ slightly): plain extraction, peak 1.7 / 3.0 cm at frames
    # 27-28, then 2-4 mm / 1.4-1.9 cm; with the budget prior the cart keeps a quarter of its keypoints, mostly where
    # frame t - 2 missed it, and is found at frame 30: peak 6.1 cm at frame 29 (both), then 1-5 mm / 3-10 mm
    assert errors[:23].max() < 0.01
    peak, settle = (0.05, 29) if prior_share == 1.0 else (0.08, 30)
    assert errors[26:].max() < peak and errors[settle:].max() < 0.025, errors[23:]
    # the cart's keypoints are dynamic, most of the static world's are not (frames 26-35; measured precision /
    # recall 0.93 / 0.76 and 0.91 / 0.75 plain, 0.79 / 0.39 and 0.78 / 0.38 with the budget prior, where recall is
    # counted on the quarter of keypoints left on the cart)
    min_precision, min_recall = (0.75, 0.5) if prior_share == 1.0 else (0.65, 0.25)
    assert tp / (tp + fp) >= min_precision and tp / (tp + fn) >= min_recall, (tp, fp, fn, tp / (tp + fp), tp / (tp + fn))
