"""ORB extraction: spread over grid and pyramid, OpenCV descriptors, clear errors."""

from __future__ import annotations

import threading

import cv2
import numpy as np
import pytest

from dynslam_lab.features import orb as orb_module
from dynslam_lab.features.orb import Features, OrbConfig, extract_features, level_quotas, scale_factors
from tests.conftest import shared_file


@pytest.fixture(scope="module")
def gray():
    img = cv2.imread(str(shared_file("tum/frames/fr3_walking_xyz_1341846313.553992_rgb.png")), cv2.IMREAD_GRAYSCALE)
    assert img is not None
    return img


def test_level_quotas_geometric_series():
    cfg = OrbConfig(n_features=1000, scale_factor=1.2, n_levels=8)
    q = level_quotas(cfg)
    assert q.sum() == 1000
    # n_s / n_{s+1} = f (up to rounding), the series of ORB-SLAM2.
    ratios = q[:-2] / q[1:-1]
    assert np.allclose(ratios, 1.2, atol=0.03)
    first = 1000 * (1 - 1 / 1.2) / (1 - (1 / 1.2) ** 8)
    assert abs(q[0] - first) <= 0.5
    assert np.allclose(scale_factors(cfg), 1.2 ** np.arange(8))


def test_real_frame_count_spread_and_levels(gray):
    cfg = OrbConfig()
    f = extract_features(gray, cfg)
    assert 950 <= len(f) <= cfg.n_features
    assert f.uv.dtype == np.float32 and f.uv.shape == (len(f), 2)
    assert f.descriptors.shape == (len(f), 32) and f.descriptors.dtype == np.uint8
    assert np.all((f.angle >= 0) & (f.angle < 360))
    # per-level counts follow the quotas (the TUM office frame has corners enough)
    counts = np.bincount(f.octave, minlength=cfg.n_levels)
    assert np.all(np.abs(counts - level_quotas(cfg)) <= 0.1 * level_quotas(cfg) + 2)
    # spread: features in most cells of a coarse 8x6 grid (plain ORB clusters on texture)
    h, w = gray.shape
    cells = set(zip((f.uv[:, 0] * 8 // w).astype(int), (f.uv[:, 1] * 6 // h).astype(int)))
    plain = cv2.ORB_create(nfeatures=1000).detect(gray, None)
    pc = set(zip((np.array([k.pt[0] for k in plain]) * 8 // w).astype(int), (np.array([k.pt[1] for k in plain]) * 6 // h).astype(int)))
    assert len(cells) >= 40 and len(cells) >= len(pc)


def test_descriptors_match_opencv_on_same_keypoints(gray):
    f = extract_features(gray, OrbConfig(n_features=300))
    kps = [cv2.KeyPoint(float(u), float(v), 31.0 * 1.2**o, float(a), float(r), int(o))
           for (u, v), o, a, r in zip(f.uv, f.octave, f.angle, f.response)]
    _, ref = cv2.ORB_create(nfeatures=300, edgeThreshold=19, patchSize=31).compute(gray, kps)
    assert ref is not None and len(ref) == len(f)
    assert np.mean(np.all(ref == f.descriptors, axis=1)) > 0.95


def test_mask_and_blank_image(gray):
    mask = np.zeros_like(gray, bool)
    mask[:, : gray.shape[1] // 2] = True
    f = extract_features(gray, OrbConfig(n_features=400), mask=mask)
    assert len(f) > 100 and np.all(f.uv[:, 0] < gray.shape[1] // 2 + 1)
    blank = np.full((120, 160), 128, np.uint8)
    e = extract_features(blank, OrbConfig(n_features=100))
    assert len(e) == 0 and e.descriptors.shape == (0, 32)


def test_bad_input_errors(gray):
    with pytest.raises(ValueError, match="grey image"):
        extract_features(np.dstack([gray] * 3))
    with pytest.raises(ValueError, match="uint8"):
        extract_features(gray.astype(np.float32))
    with pytest.raises(ValueError, match="mask shape"):
        extract_features(gray, mask=np.ones((10, 10), bool))
    with pytest.raises(ValueError, match="scale_factor"):
        OrbConfig(scale_factor=1.0)
    with pytest.raises(ValueError, match="Features.octave"):
        Features(np.zeros((3, 2)), np.zeros(2), np.zeros(3), np.zeros(3), np.zeros((3, 32), np.uint8))


def test_reused_orb_object_gives_the_same_features_as_a_fresh_one(gray):
    """The per-thread cv2.ORB cache: an extraction after others (other images, other thresholds in
    between) equals one made with new ORB objects, and another thread gets its own object."""
    cfg = OrbConfig(n_features=500)
    orb_module._ORB_OBJECTS.by_key = {}
    fresh = extract_features(gray, cfg)
    extract_features(np.ascontiguousarray(gray[::-1]), cfg)  # other images through the same objects
    extract_features(gray, OrbConfig(n_features=200, fast_threshold=12))
    again = extract_features(gray, cfg)
    for name in ("uv", "octave", "angle", "response", "descriptors"):
        np.testing.assert_array_equal(getattr(again, name), getattr(fresh, name))
    mine = orb_module._orb_object(cfg, cfg.fast_threshold)
    theirs = []
    t = threading.Thread(target=lambda: theirs.append(orb_module._orb_object(cfg, cfg.fast_threshold)))
    t.start()
    t.join()
    assert theirs[0] is not mine and orb_module._orb_object(cfg, cfg.fast_threshold) is mine


def _strong_and_faint(shape=(480, 640), seed=7) -> np.ndarray:
    """High-contrast noise on the left half, faint noise on the right half: at FAST threshold 20 the
    right half has next to no corners, at 7 it has many (a weakly textured wall beside a textured object)."""
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur((rng.random(shape) * 255).astype(np.uint8), (5, 5), 1.2).astype(np.float64)
    half = shape[1] // 2
    img[:, :half] = np.clip(128 + 2.5 * (img[:, :half] - 128), 0, 255)
    img[:, half:] = 128 + 0.3 * (img[:, half:] - 128)
    return img.astype(np.uint8)


def test_cells_without_corners_are_searched_again_at_min_fast_threshold():
    """ORB-SLAM2's per-cell retry (cell_retry=1): the faint half gets keypoints where the detection at 20 left
    its cells empty; the corners added are those of OpenCV's own detection at 7 masked to the empty cells."""
    img = _strong_and_faint()
    h, w = img.shape
    off = extract_features(img, OrbConfig(cell_retry=0))
    on = extract_features(img, OrbConfig(cell_retry=1))
    right_off = int((off.uv[:, 0] >= w // 2).sum())
    right_on = int((on.uv[:, 0] >= w // 2).sum())
    # the independent count: FAST at 20 finds almost nothing on the faint half, FAST at 7 a lot
    fast20 = cv2.FastFeatureDetector_create(20, True).detect(img[:, w // 2 + 20 :])
    fast7 = cv2.FastFeatureDetector_create(7, True).detect(img[:, w // 2 + 20 :])
    assert len(fast20) < 50 and len(fast7) > 2000
    assert right_off < 60 and right_on > 100, (right_off, right_on)
    cfg = OrbConfig(cell_retry=1)
    cells_right = {c for c in orb_module._cells(on.uv, img.shape, cfg).tolist() if c % cfg.grid_cols >= cfg.grid_cols // 2}
    assert len(cells_right) >= 50, len(cells_right)  # of the ~130 inner cells of the faint half (none without the retry)
    # retry_cells against OpenCV: the detection at 7 masked to the cells the detection at 20 left empty
    first = orb_module._detect(img, cfg, cfg.fast_threshold)[1]
    uv0 = cv2.KeyPoint_convert(first).reshape(-1, 2)
    extra = orb_module.retry_cells(img, cfg, uv0)
    counts = np.bincount(orb_module._cells(uv0, img.shape, cfg), minlength=cfg.grid_cols * cfg.grid_rows)
    empty = (counts == 0).reshape(cfg.grid_rows, cfg.grid_cols)
    empty[[0, -1], :] = False  # the grid's outer cells: less than half of them inside OpenCV's 19-px border
    empty[:, [0, -1]] = False
    inner = np.zeros((h, w), np.uint8)
    inner[19 : h - 19, 19 : w - 19] = 1
    mask = np.kron(empty, np.ones((h // cfg.grid_rows, w // cfg.grid_cols), np.uint8)).astype(np.uint8) * inner * 255
    n = max(int(np.ceil(1000 * cfg.oversample * empty.mean())), 64)
    ref = cv2.ORB_create(nfeatures=n, scaleFactor=1.2, nlevels=8, edgeThreshold=19, patchSize=31, fastThreshold=7).detect(img, mask)
    ref_uv = cv2.KeyPoint_convert(ref).reshape(-1, 2)
    ref_uv = ref_uv[empty.reshape(-1)[orb_module._cells(ref_uv, img.shape, cfg)]]
    got = sorted(map(tuple, cv2.KeyPoint_convert(extra).reshape(-1, 2).round(3).tolist()))
    assert len(got) > 200 and got == sorted(map(tuple, ref_uv.round(3).tolist()))
    assert empty.reshape(-1)[orb_module._cells(cv2.KeyPoint_convert(extra).reshape(-1, 2), img.shape, cfg)].all()


def test_cell_retry_is_validated():
    with pytest.raises(ValueError, match="cell_retry"):
        OrbConfig(cell_retry=-1)
