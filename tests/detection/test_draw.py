"""Drawing detections: colours land on the box outline and inside masks."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.detection import Detections, class_colour, draw_detections


def test_boxes_and_masks_are_drawn_where_they_belong():
    rgb = np.zeros((60, 80, 3), np.uint8)
    mask = np.zeros((1, 60, 80), bool)
    mask[0, 30:40, 30:40] = True
    det = Detections([[20, 20, 50, 50]], [0.9], [0], (60, 80), masks=mask)
    out = draw_detections(rgb, det, mask_alpha=0.5, thickness=1, labels=False)
    col = np.array(class_colour(0))
    np.testing.assert_array_equal(out[35, 20], col)  # left edge of the box
    np.testing.assert_array_equal(out[49, 35], col)  # bottom edge (x2, y2 exclusive)
    np.testing.assert_allclose(out[35, 35], col * 0.5, atol=1)  # mask blended 50 %
    assert not out[5, 5].any() and not out[25, 25].any()  # outside / inside box, off mask
    assert not rgb.any()  # input untouched
    assert class_colour(0) != class_colour(1)


def test_size_mismatch_is_refused():
    det = Detections.empty((10, 10))
    with pytest.raises(ValueError, match=r"refer to a \(10, 10\) image"):
        draw_detections(np.zeros((20, 20, 3), np.uint8), det)
