"""Motion-probability restoration (ASG-SLAM eq. 3) and Zhang et al.'s rule, by hand."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.dynamic.geometric_rule import level_rule_verdict
from dynslam_lab.dynamic.motion_probability import RestorationConfig, restore_by_motion_probability, static_ratio


def test_static_ratio_eq3():
    assert static_ratio(np.array([True, False, False, False])) == 0.75
    assert static_ratio(np.zeros(0, bool)) == 1.0


def test_restores_least_probable_classes_first_until_delta_1():
    # 10 keypoints: 2 static, 3 on a keyboard (p=0.2), 2 on a bag (p=0.6), 3 on a person (p=0.9)
    dynamic = np.array([0, 0, 1, 1, 1, 1, 1, 1, 1, 1], bool)
    semantic = dynamic.copy()
    prob = np.array([0, 0, 0.2, 0.2, 0.2, 0.6, 0.6, 0.9, 0.9, 0.9])
    r = restore_by_motion_probability(dynamic, semantic, prob, None, RestorationConfig(delta_1=0.5))
    assert r.delta_before == pytest.approx(0.2)
    assert r.groups == [0.2]  # 2 + 3 = 5 static of 10: delta = 0.5 reached
    assert r.restored.tolist() == [0, 0, 1, 1, 1, 0, 0, 0, 0, 0]
    assert r.delta_after == pytest.approx(0.5)
    r2 = restore_by_motion_probability(dynamic, semantic, prob, None, RestorationConfig(delta_1=0.6))
    assert r2.groups == [0.2, 0.6] and r2.delta_after == pytest.approx(0.7)


def test_geometric_evidence_is_never_restored_and_enough_static_restores_nothing():
    dynamic = np.array([0, 1, 1, 1], bool)
    prob = np.array([0, 0.9, 0.9, 0.9])
    veto = np.array([0, 1, 0, 0], bool)
    r = restore_by_motion_probability(dynamic, dynamic, prob, veto, RestorationConfig(delta_1=1.0))
    assert r.restored.tolist() == [False, False, True, True]
    r_off = restore_by_motion_probability(dynamic, dynamic, prob, veto, RestorationConfig(delta_1=1.0, geometric_veto=False))
    assert r_off.restored[1]
    r_none = restore_by_motion_probability(dynamic, dynamic, prob, None, RestorationConfig(delta_1=0.25))
    assert not r_none.restored.any()
    with pytest.raises(ValueError, match="delta_1"):
        RestorationConfig(delta_1=1.5)
    with pytest.raises(ValueError, match="motion_prob"):
        restore_by_motion_probability(dynamic, dynamic, prob[:2])


def test_level_rule():
    level = np.array([3, 2, 1, 1, 0, 0])  # high, medium, low, low, none, none
    geometric = np.array([0, 0, 1, 0, 1, 0], bool)
    assert level_rule_verdict(level, geometric).tolist() == [True, True, True, False, True, False]
    with pytest.raises(ValueError, match="level codes"):
        level_rule_verdict(np.array([4]), np.array([False]))
