"""The keypoint budget and a dynamic region (``extract_features(region=..., region_share=...)``):
the quota a region gives up goes to the pixels outside it; without a region nothing changes."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dynslam_lab.features.orb import OrbConfig, extract_features, level_quotas, region_quotas


def _textured(seed: int = 3, shape=(480, 640)) -> np.ndarray:
    """Fine noise on the left half, stronger (higher-contrast) noise on the right half: left alone,
    the right half would win most of the budget by response."""
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur((rng.random(shape) * 255).astype(np.uint8), (5, 5), 1.2).astype(np.float64)
    half = shape[1] // 2
    img[:, :half] = 128 + 0.35 * (img[:, :half] - 128)
    img[:, half:] = np.clip(128 + 2.0 * (img[:, half:] - 128), 0, 255)
    return img.astype(np.uint8)


def _right_half(shape=(480, 640)) -> np.ndarray:
    region = np.zeros(shape, bool)
    region[:, shape[1] // 2 :] = True
    return region


def _signature(f) -> np.ndarray:
    return np.concatenate([f.uv.ravel(), f.octave, f.angle, f.response, f.descriptors.ravel()])


def test_without_a_region_the_extraction_is_unchanged():
    img = _textured()
    cfg = OrbConfig()
    plain = extract_features(img, cfg)
    for kwargs in ({"region": None}, {"region": np.zeros(img.shape, bool), "region_share": 0.0},
                   {"region": _right_half(), "region_share": 1.0}):
        np.testing.assert_array_equal(_signature(extract_features(img, cfg, **kwargs)), _signature(plain))


@pytest.mark.parametrize("share", [0.0, 0.25])
def test_the_region_gives_its_quota_to_the_other_half(share):
    img = _textured()
    cfg = OrbConfig()
    region = _right_half()
    plain = extract_features(img, cfg)
    right_plain = int((plain.uv[:, 0] >= 320).sum())
    assert right_plain > 0.7 * len(plain)  # the high-contrast half takes most of the plain budget

    f = extract_features(img, cfg, region=region, region_share=share)
    r, cover = region_quotas(region, cfg, share)
    np.testing.assert_allclose(cover.reshape(cfg.grid_rows, cfg.grid_cols)[:, : cfg.grid_cols // 2], 0.0)
    np.testing.assert_allclose(cover.reshape(cfg.grid_rows, cfg.grid_cols)[:, cfg.grid_cols // 2 :], 1.0)
    # the region's quota: share x its area (one half) x each level's quota
    np.testing.assert_array_equal(r, np.round(share * 0.5 * level_quotas(cfg)).astype(np.int64))
    right = f.uv[:, 0] >= 319.5  # keypoint pixel (nearest integer) inside the region
    assert int(right.sum()) <= int(r.sum())
    # per level: the region keeps at most its quota, the left half fills the rest of the level's quota
    lvl_right = np.bincount(f.octave[right], minlength=cfg.n_levels)
    lvl_left = np.bincount(f.octave[~right], minlength=cfg.n_levels)
    assert np.all(lvl_right <= r)
    left_plain = len(plain) - right_plain
    assert int((~right).sum()) >= 0.95 * (cfg.n_features - int(right.sum()))  # the left half has the corners to fill it
    assert int((~right).sum()) > 3 * left_plain
    np.testing.assert_array_less(lvl_left + lvl_right, level_quotas(cfg) + 1)
    if share > 0:
        assert int(right.sum()) >= 0.9 * int(r.sum())  # the region's quota is used: screening keeps keypoints to judge


def test_a_region_and_a_mask_together():
    img = _textured()
    cfg = OrbConfig(n_features=400)
    mask = np.zeros(img.shape, bool)
    mask[:240] = True  # features only in the top half
    f = extract_features(img, cfg, mask=mask, region=_right_half(), region_share=0.0)
    assert len(f) > 300
    assert np.all(np.round(f.uv[:, 1]) < 240) and np.all(np.round(f.uv[:, 0]) < 320)


def test_bad_region_input_is_refused():
    img = _textured()
    with pytest.raises(ValueError, match="region shape"):
        extract_features(img, OrbConfig(), region=np.zeros((10, 10), bool))
    with pytest.raises(ValueError, match="region_share"):
        extract_features(img, OrbConfig(), region=_right_half(), region_share=1.5)
    for field, value in (("truth_region_share", -0.1), ("prior_region_share", 2.0), ("prior_lag", 0), ("prior_dilate_px", -1)):
        with pytest.raises(ValueError, match=field):
            OrbConfig(**{field: value})
