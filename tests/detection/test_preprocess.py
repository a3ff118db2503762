"""Letterbox and stretch: where an image pixel lands in the network input, and back."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.detection.preprocess import fit_image, letterbox, stretch


def _image_with_square(h=480, w=640, box=(100, 50, 200, 150)):
    img = np.zeros((h, w, 3), np.uint8)
    x1, y1, x2, y2 = box
    img[y1:y2, x1:x2] = 255
    return img


def _bright_box(img):
    ys, xs = np.nonzero(img[:, :, 0] > 127)
    return np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], float)


@pytest.mark.parametrize("kind", ["letterbox", "letterbox_topleft", "stretch"])
def test_transform_maps_a_square_to_where_the_resize_put_it(kind):
    img = _image_with_square()
    out, tf = fit_image(img, (320, 320), kind)
    assert out.shape == (320, 320, 3)
    np.testing.assert_allclose(tf.to_input([[100, 50, 200, 150]])[0], _bright_box(out), atol=1.0)
    back = tf.to_image(tf.to_input([[100, 50, 200, 150]]))
    np.testing.assert_allclose(back[0], [100, 50, 200, 150], atol=1e-4)


def test_letterbox_padding_and_scale():
    out, tf = letterbox(_image_with_square(), (640, 640))
    assert (tf.sx, tf.sy, tf.px, tf.py) == (1.0, 1.0, 0.0, 80.0)
    assert np.all(out[:80] == 114) and np.all(out[560:] == 114)
    out, tf = letterbox(_image_with_square(), (416, 416), centre=False)
    assert tf.py == 0.0 and np.all(out[312:] == 114)
    _, tf = stretch(_image_with_square(), (320, 320))
    assert (tf.sx, tf.sy) == (0.5, 320 / 480)
    clipped = tf.to_image([[-10, -10, 400, 400]])
    np.testing.assert_allclose(clipped[0], [0, 0, 640, 480])


def test_bad_image_is_refused():
    with pytest.raises(ValueError, match=r"expected \(H, W, 3\) uint8"):
        letterbox(np.zeros((10, 10), np.uint8), (32, 32))
    with pytest.raises(ValueError, match="preprocess kind 'crop'"):
        fit_image(np.zeros((10, 10, 3), np.uint8), (32, 32), "crop")
