"""The run scorer's split of false positives: movers at rest against things that never move."""

from types import SimpleNamespace

import numpy as np

from dynslam_lab.experiments.scoring import OUTLINE_BAND_PX, KeypointScorer, recall_by_image_speed


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


def test_scores_away_from_the_outlines_misses_without_depth_and_keypoints_per_instance():
    mask = np.zeros((30, 100), np.int32)
    mask[:, 20:40] = 1  # a mover, columns 20-39
    depth = np.full((30, 100), 2.0)
    depth[:, 19:21] = 0.0  # the sensor loses depth at its left outline
    # on the mover: 0 px (no depth), 10 px inside, 3 px inside (column 37); on the room: 2 px and 30 px outside
    uv = np.array([[20.0, 15.0], [29.0, 15.0], [37.0, 15.0], [41.0, 15.0], [70.0, 15.0]])
    assert OUTLINE_BAND_PX == 4.0
    scorer = KeypointScorer()
    frame = SimpleNamespace(instance_mask=mask, moving_ids={1}, instance_classes={}, depth=depth, index=7)
    # flagged: the inner keypoint, the room keypoint beside the outline and the far room keypoint
    scorer(frame, SimpleNamespace(uv=uv, dynamic=np.array([False, True, False, True, True]), timings_ms={}))
    assert (scorer.score.tp, scorer.score.fp, scorer.score.fn) == (1, 2, 2)
    assert scorer.fn_without_depth == 1  # the miss at column 20 had no depth; the one at 37 had
    # away from the outlines: only columns 29 (10 px inside) and 70 (30 px outside) count
    away = scorer.away_from_outlines
    assert (away.tp, away.fp, away.fn, away.tn) == (1, 1, 0, 0)
    assert scorer.by_instance == {(7, 1): [3, 1]}


def test_recall_by_image_speed_bins_each_instance_by_f_v_dt_over_z():
    # frames 0-2 at 30 Hz; instance 1 at 2 m moving 0.1 m/s (525 * 0.1 / 30 / 2 = 0.875 px a frame) in frame 1
    # and 0.8 m/s (7 px) in frame 2; instance 2 unseen (depth nan) in frame 2
    coverage = {"timestamp": np.array([0.0, 1 / 30, 2 / 30]),
                "speed_1": np.array([0.0, 0.1, 0.8]), "depth_1": np.array([2.0, 2.0, 2.0]),
                "speed_2": np.array([0.0, 0.0, 2.0]), "depth_2": np.array([3.0, 3.0, np.nan])}
    by_instance = {(1, 1): [10, 2], (2, 1): [20, 18], (2, 2): [4, 0]}
    rows = recall_by_image_speed(by_instance, coverage, fx=525.0)
    assert [r["bin"] for r in rows] == ["0-0.5", "0.5-1", "1-2", "2-4", "4-8", ">= 8"]
    got = {r["bin"]: (r["keypoints"], r["dynamic"]) for r in rows if r["keypoints"]}
    assert got == {"0-0.5": (4, 0), "0.5-1": (10, 2), "4-8": (20, 18)}
    assert rows[1]["recall"] == 0.2 and np.isnan(rows[2]["recall"])
    assert rows[1]["miss_share"] == 8 / 14 and rows[0]["miss_share"] == 4 / 14
    # the misses by how much of their mover the frame found: instance 2 not at all (4), instance 1 in frame 1 in
    # part (2 of 10: 8 missed), in frame 2 mostly (18 of 20: 2 missed)
    split = {r["bin"]: (r["miss_unfound"], r["miss_in_part"], r["miss_mostly_found"]) for r in rows if r["keypoints"]}
    assert split == {"0-0.5": (4, 0, 0), "0.5-1": (0, 8, 0), "4-8": (0, 0, 2)}
    half = recall_by_image_speed({(1, 1): [10, 5], (2, 1): [9, 4]}, coverage, fx=525.0)  # exactly half is mostly found
    assert [(r["miss_in_part"], r["miss_mostly_found"]) for r in half if r["keypoints"]] == [(0, 5), (5, 0)]
    import pytest

    with pytest.raises(ValueError, match="speed_3"):
        recall_by_image_speed({(0, 3): [1, 0]}, coverage, 525.0)


def test_corners_just_off_a_moving_outline_move_with_the_mover_on_a_camera_at_rest():
    """The premise of the perfect masks' margin (``ScreeningConfig.oracle_margin_px``), on the renderer's frames:
    with the camera at rest (``fast_static``: a hand-held tremor of ~0.1 px a frame), an ORB corner whose pixel
    is on the background within 4 px of a moving outline moves as the mover does; one farther than 12 px stays."""
    import pytest

    from dynslam_lab.datasets.synthetic import synthetic_sequence
    from dynslam_lab.datasets.tum import TumSequence
    from dynslam_lab.dynamic.config import ScreeningConfig
    from dynslam_lab.experiments.scoring import corner_motion_at_outlines

    seq = TumSequence(synthetic_sequence("fast_static", n_frames=30))
    dist, motion = corner_motion_at_outlines(seq)
    on_mover, outline, far = motion[dist <= 0], motion[(dist > 0) & (dist <= 4)], motion[dist > 12]
    assert len(on_mover) > 100 and len(outline) > 300 and len(far) > 5000
    assert np.median(on_mover) > 5 and np.median(outline) > 5  # px a frame: with the mover
    assert np.mean(outline > 1) > 0.6
    assert np.median(far) < 0.2 and np.mean(far > 1) < 0.1  # the room stays
    assert ScreeningConfig().oracle_margin_px >= 4  # so perfect masks take that band
    moved = [seq[0], seq[1]]
    moved[1].T_w_c_gt = moved[1].T_w_c_gt.copy()
    moved[1].T_w_c_gt[0, 3] += 0.01
    with pytest.raises(ValueError, match="camera at rest; frame 1"):
        corner_motion_at_outlines(moved)
