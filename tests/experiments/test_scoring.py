"""The run scorer's split of false positives: movers at rest against things that never move."""

from types import SimpleNamespace

import numpy as np

from dynslam_lab.experiments.scoring import KeypointScorer


def _frame(moving):
    mask = np.zeros((10, 20), np.int32)
    mask[:, 0:5] = 1  # a box
    mask[:, 5:10] = 2  # a person
    # columns 10-19: the room (instance 0)
    return SimpleNamespace(instance_mask=mask, moving_ids=set(moving), instance_classes={1: "box", 2: "person"})


def test_false_positives_on_movers_at_rest_are_counted_apart():
    uv = np.array([[1.0, 1.0], [6.0, 1.0], [12.0, 1.0], [15.0, 1.0]])  # box, person, room, room
    scorer = KeypointScorer()
    # frame 1: the box moves, the person stands still; the screener flags box, person and one room keypoint
    scorer(_frame({1}), SimpleNamespace(uv=uv, dynamic=np.array([True, True, True, False]), timings_ms={}))
    # frame 2: the box stopped, the person walks; flagged: box and person
    scorer(_frame({2}), SimpleNamespace(uv=uv, dynamic=np.array([True, True, False, False]), timings_ms={}))
    s = scorer.score
    # by hand: TP = box@1 + person@2 = 2; FP = person@1 + room@1 + box@2 = 3; FN = 0
    assert (s.tp, s.fp, s.fn, s.tn) == (2, 3, 0, 3)
    assert s.precision == 2 / 5
    # the person (at rest in frame 1) and the box (at rest in frame 2) move in some frame: 2 of the 3 FPs
    assert scorer.fp_at_rest == 2
    assert scorer.precision_at_rest_ok == (2 + 2) / 5


def test_an_instance_that_never_moves_stays_a_false_positive():
    uv = np.array([[1.0, 1.0], [6.0, 1.0]])
    scorer = KeypointScorer()
    for _ in range(3):  # the person never moves; the box always does
        scorer(_frame({1}), SimpleNamespace(uv=uv, dynamic=np.array([True, True]), timings_ms={}))
    assert (scorer.score.tp, scorer.score.fp) == (3, 3)
    assert scorer.fp_at_rest == 0
    assert scorer.precision_at_rest_ok == 0.5
    assert np.isnan(KeypointScorer().precision_at_rest_ok)
