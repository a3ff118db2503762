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


def test_false_positives_are_split_by_distance_from_the_moving_outline():
    mask = np.zeros((30, 100), np.int32)
    mask[:, 0:10] = 1  # a mover, columns 0-9
    mask[:, 50:56] = 2  # an object that moves only in the second frame
    uv = np.array([[12.0, 5.0], [18.0, 5.0], [40.0, 5.0], [80.0, 5.0], [52.0, 5.0], [3.0, 5.0]])
    frame1 = SimpleNamespace(instance_mask=mask, moving_ids={1}, instance_classes={})
    frame2 = SimpleNamespace(instance_mask=mask, moving_ids={2}, instance_classes={})
    scorer = KeypointScorer()
    # frame 1: every keypoint flagged; the last is on the mover (a true positive)
    scorer(frame1, SimpleNamespace(uv=uv, dynamic=np.ones(6, bool), timings_ms={}))
    # frame 2: nothing flagged; object 2 moves, so its false positive of frame 1 was a mover at rest
    scorer(frame2, SimpleNamespace(uv=uv, dynamic=np.zeros(6, bool), timings_ms={}))
    # by hand: 3, 9, 31 and 71 px from column 9 (the outline); the keypoint on object 2 is at rest
    assert scorer.fp_by_kind == {"at rest": 1, "< 4 px": 1, "4-12 px": 1, "12-40 px": 1, "> 40 px": 1}
    assert sum(scorer.fp_by_kind.values()) == scorer.score.fp == 5
    # no instance moving in a frame: every false positive on a thing that never moves is far from any mover
    alone = KeypointScorer()
    alone(SimpleNamespace(instance_mask=mask, moving_ids=set(), instance_classes={}),
          SimpleNamespace(uv=uv[:2], dynamic=np.ones(2, bool), timings_ms={}))
    assert alone.fp_by_kind["> 40 px"] == 2


def test_misses_are_split_into_the_silhouette_and_the_inside():
    mask = np.zeros((30, 100), np.int32)
    mask[:, 20:40] = 1  # a mover, columns 20-39
    # inside the mover: 1 px, 3 px, 6 px and 10 px from its outline (distance to the nearest outside pixel,
    # columns 19 or 40); then a keypoint on the room
    uv = np.array([[20.0, 15.0], [37.0, 15.0], [25.0, 15.0], [29.0, 15.0], [60.0, 15.0]])
    scorer = KeypointScorer()
    frame = SimpleNamespace(instance_mask=mask, moving_ids={1}, instance_classes={})
    scorer(frame, SimpleNamespace(uv=uv, dynamic=np.array([False, False, False, True, False]), timings_ms={}))
    assert (scorer.score.tp, scorer.score.fn) == (1, 3)
    assert scorer.fn_by_kind == {"silhouette < 4 px": 2, "inside": 1}
