"""The keypoint budget and a dynamic region (``extract_features(region=..., region_share=...)``):
the quota a region gives up goes to the pixels outside it; without a region nothing changes."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dynslam_lab.features.orb import OrbConfig, budget_candidates, extract_features, level_quotas, region_quotas


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


def _opencv(img, n, threshold, mask=None):
    """An independent OpenCV detection with the toolkit's pyramid settings: ``(x, y, octave)`` rows."""
    orb = cv2.ORB_create(nfeatures=n, scaleFactor=1.2, nlevels=8, edgeThreshold=19, patchSize=31, fastThreshold=threshold)
    return sorted((k.pt[0], k.pt[1], k.octave) for k in orb.detect(img, mask))


def _rows(c) -> list:
    return sorted((float(u), float(v), int(o)) for (u, v), o in zip(c.uv, c.octave))


def test_both_sides_share_one_detection_where_neither_crowds_the_other():
    rng = np.random.default_rng(5)
    img = cv2.GaussianBlur((rng.random((480, 640)) * 255).astype(np.uint8), (5, 5), 1.2)  # even texture
    region = np.zeros(img.shape, bool)
    region[100:300, 200:360] = True
    cfg = OrbConfig(cell_retry=0)  # the per-cell retry (below) adds a detection where cells are empty
    r, _ = region_quotas(region, cfg, 0.25)
    orb, ins, outs, n_det = budget_candidates(img, cfg, region, r)
    assert n_det == 1
    # the sides are OpenCV's one detection with region_candidates x 2,500 corners at FAST threshold 20, split
    ref = _opencv(img, int(np.ceil(1000 * 2.5 * cfg.region_candidates)), 20)
    assert len(ins.index) + len(outs.index) == len(ref) > 2500
    assert sorted(_rows(ins) + _rows(outs)) == ref
    xy_in = np.round(ins.uv).astype(int)
    assert region[xy_in[:, 1], xy_in[:, 0]].all()
    xy_out = np.clip(np.round(outs.uv).astype(int), 0, [639, 479])
    assert not region[xy_out[:, 1], xy_out[:, 0]].any()
    # the kept keypoints come from those candidates, and the same call gives the same keypoints
    f = extract_features(img, cfg, region=region, region_share=0.25)
    assert {(float(u), float(v)) for u, v in f.uv} <= {(x, y) for x, y, _ in ref}
    # with the retry, the outside adds corners of the cells its share of the list left empty, and nothing else
    _, ins1, outs1, n1 = budget_candidates(img, OrbConfig(cell_retry=1), region, r)
    assert _rows(ins1) == _rows(ins) and set(_rows(outs)) <= set(_rows(outs1)) and n1 == 1 + (len(outs1.index) > len(outs.index))
    np.testing.assert_array_equal(_signature(f), _signature(extract_features(img, cfg, region=region, region_share=0.25)))


def test_a_side_crowded_out_or_short_gets_its_own_detection():
    """The high-contrast right half as the region: at FAST threshold 20 the low-contrast left half has
    few corners of the shared list, so the outside gets its own detection, masked to it, at threshold 7."""
    img = _textured()
    cfg = OrbConfig()
    region = _right_half()
    r, _ = region_quotas(region, cfg, 0.0)
    _, ins, outs, n_det = budget_candidates(img, cfg, region, r)
    assert n_det == 2 and len(ins.index) == 0  # share 0: no candidates in the region
    assert _rows(outs) == _opencv(img, 2500, 7, (~region).astype(np.uint8) * 255)
    # a mask restricts both the shared detection and the side's own
    mask = np.zeros(img.shape, np.uint8)
    mask[:240] = 1
    _, _, outs, _ = budget_candidates(img, cfg, region, r, mask)
    assert _rows(outs) == _opencv(img, 2500, 7, ((~region) & (mask > 0)).astype(np.uint8) * 255)


def test_region_candidates_is_validated():
    with pytest.raises(ValueError, match="region_candidates"):
        OrbConfig(region_candidates=0.5)
