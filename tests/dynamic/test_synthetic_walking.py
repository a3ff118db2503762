"""The whole screener on the synthetic walking sequence, scored against the renderer's truth."""

from __future__ import annotations

import numpy as np
import pytest

N_FRAMES = 30


@pytest.fixture(scope="module")
def walking():
    from dynslam_lab.datasets import synthetic
    from dynslam_lab.datasets.tum import TumSequence
    from dynslam_lab.detection import build_detector
    from dynslam_lab.features.orb import extract_features

    seq = TumSequence(synthetic.synthetic_sequence("walking_xyz", n_frames=N_FRAMES, seed=0))
    det = build_detector("oracle")
    return [(f, extract_features(f.gray).uv.astype(float), det.detect(f)) for f in (seq[i] for i in range(len(seq)))]


def _score(name, data, config=None):
    from dynslam_lab.experiments.scoring import ScoringScreener
    from dynslam_lab.dynamic.screening import build_screener

    s = ScoringScreener(build_screener(name, config))
    tables = [s.screen(f, uv, d) for f, uv, d in data]
    return s, tables


@pytest.mark.slow
def test_full_filter_meets_the_keypoint_targets(walking):
    s, tables = _score("full", walking)
    assert s.score.tp + s.score.fn > 200  # enough truly moving keypoints to judge
    assert s.score.recall >= 0.95
    assert s.score.precision >= 0.9
    # every stage of the chain ran after the first frame
    assert {"semantic", "epipolar", "multiview", "flow", "restoration"} <= set(tables[-1].stages)
    # the region mask covers the moving people
    from dynslam_lab.dynamic.oracle import moving_mask

    f = walking[-1][0]
    m = moving_mask(f)
    assert (tables[-1].region_mask & m).sum() >= 0.95 * m.sum()


@pytest.mark.slow
def test_oracle_is_perfect_and_geometry_alone_finds_movers(walking):
    from dynslam_lab.dynamic.oracle import moving_mask, truth_dynamic
    from dynslam_lab.experiments.scoring import OUTLINE_BAND_PX, signed_outline_distance

    s, tables = _score("oracle", walking)
    # never a mover's keypoint missed; static keypoints flagged only within the margin of a moving outline
    # (ScreeningConfig.oracle_margin_px: corners there move with the mover): beyond it the verdict is the truth
    assert s.score.recall == 1.0
    for (f, _, _), t in zip(walking, tables):
        away = np.abs(signed_outline_distance(moving_mask(f), t.uv)) > OUTLINE_BAND_PX
        np.testing.assert_array_equal(t.dynamic[away], truth_dynamic(f, t.uv)[away])
    g, _ = _score("geometry", walking)
    n_true = g.score.tp + g.score.fn
    base_rate = n_true / (n_true + g.score.fp + g.score.tn)
    assert g.score.precision > 2 * base_rate  # far better than flagging at random
    assert g.score.recall > 0.3
