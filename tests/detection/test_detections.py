"""``Detections.grown``: where the objects of an earlier frame can be (``detection.stride``)."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.detection.detections import Detections


def test_grown_boxes_are_clipped_to_the_image_and_masks_dilated_by_a_square():
    masks = np.zeros((2, 40, 60), bool)
    masks[0, 10, 20] = True  # one pixel
    masks[1, 0, 0] = True  # a corner pixel: the dilation stops at the image
    d = Detections(np.array([[20.0, 10.0, 30.0, 15.0], [0.0, 0.0, 5.0, 5.0]]), np.array([0.9, 0.5]), np.array([0, 56]),
                   (40, 60), masks=masks, source="onnx:test")
    g = d.grown(2.0)
    np.testing.assert_allclose(g.boxes, [[18.0, 8.0, 32.0, 17.0], [0.0, 0.0, 7.0, 7.0]])
    assert g.masks[0].sum() == 25 and g.masks[0, 8:13, 18:23].all()
    assert g.masks[1].sum() == 9 and g.masks[1, :3, :3].all()
    np.testing.assert_array_equal(g.scores, d.scores)
    np.testing.assert_array_equal(g.class_ids, d.class_ids)
    assert g.source == "onnx:test" and d.grown(0.0, source="x").source == "x"
    np.testing.assert_allclose(d.boxes[0], [20.0, 10.0, 30.0, 15.0])  # the original is untouched
    far = d.grown(100.0)
    np.testing.assert_allclose(far.boxes, [[0.0, 0.0, 59.0, 39.0]] * 2)
    np.testing.assert_array_equal(d.grown(0.0).masks, masks)


def test_grown_keeps_box_only_and_empty_detections_and_refuses_a_negative_margin():
    d = Detections(np.array([[5.0, 5.0, 9.0, 9.0]]), np.array([0.7]), np.array([0]), (20, 20))
    assert d.grown(3.0).masks is None
    e = Detections.empty((20, 20), with_masks=True)
    assert len(e.grown(4.0)) == 0 and e.grown(4.0).masks.shape == (0, 20, 20)
    with pytest.raises(ValueError, match="margin_px"):
        d.grown(-1.0)
