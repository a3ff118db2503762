"""Background inpainting by eq. 4 of Chang et al. 2021 on a scene whose hidden background is known."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.dynamic.inpainting import InpaintingConfig, InpaintSource, inpaint_background
from tests.dynamic.scenes import CAM, two_layer_frames


def test_hidden_wall_is_restored_from_earlier_keyframes():
    # frames with the person, and the same camera path without anyone (box outside the image)
    with_person = two_layer_frames(6, person_shift_px=(25.0, 0.0))
    empty = two_layer_frames(6, person_shift_px=(25.0, 0.0), box=(2000, 2000, 2001, 2001))
    cur, mask, _ = with_person[5]
    truth = empty[5][0].rgb
    sources = [InpaintSource(f.rgb, f.depth, f.T_w_c_gt, m) for f, m, _ in with_person[:5]]
    res = inpaint_background(cur.rgb, cur.depth, mask, cur.T_w_c_gt, sources, CAM)
    assert res.fill_ratio > 0.5  # the person walked sideways: earlier frames saw much of the wall
    err = np.abs(res.rgb[res.filled].astype(int) - truth[res.filled].astype(int))
    assert np.median(err) <= 8  # grey levels: the wall's texture, not the person's
    person_err = np.abs(cur.rgb[res.filled].astype(int) - truth[res.filled].astype(int))
    assert np.median(err) < np.median(person_err)
    assert not res.filled[~mask].any()
    z = res.depth[res.filled]  # the mapped depth is the wall's (3 m left half, 6 m right half)
    assert np.all((np.abs(z - 3.0) < 0.05) | (np.abs(z - 6.0) < 0.05))


def test_config_and_shapes():
    with pytest.raises(ValueError, match="n_keyframes"):
        InpaintingConfig(n_keyframes=0)
    f, m, _ = two_layer_frames(1)[0]
    with pytest.raises(ValueError, match="differ"):
        inpaint_background(f.rgb, f.depth, m[:5], f.T_w_c_gt, [], CAM)
    res = inpaint_background(f.rgb, f.depth, m, f.T_w_c_gt, [], CAM)
    assert res.fill_ratio == 0.0 and (res.rgb == f.rgb).all()
