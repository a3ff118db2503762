"""Camera effects on a sequence (``datasets.camera_effects``): each effect checked on a hand-made TUM-layout
sequence against what it must do pixel by pixel, the thinned lists and ``moving.txt`` against hand-computed
rows, the safety rules (a new folder only, nothing left behind on failure), and the benchmark's tables."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pandas as pd
import pytest

from dynslam_lab.datasets.camera_effects import CameraEffects, _blur_kernel, apply_camera_effects
from dynslam_lab.datasets.tum import DatasetError, TumSequence
from dynslam_lab.experiments.camera_effects import ORIGINAL, camera_effects_markdown, camera_effects_summary, with_ratios

N = 7


def _sequence(root, n=N):
    """A tiny sequence: ``n`` colour frames of a pattern with sharp edges (values 40-200), depth 2 m, ground truth, and a
    ``moving.txt`` where instance 3 moves in frames 1 and 4 and instance 5 in frame 2."""
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    yy, xx = np.mgrid[:48, :64]
    rgb_lines, depth_lines, gt, moving = ["# colour"], ["# depth"], ["# timestamp tx ty tz qx qy qz qw"], ["# moving"]
    for i in range(n):
        ts = 100.0 + i / 30
        img = (120 + 80 * np.sign(np.sin(xx / 5.0 + i) * np.cos(yy / 7.0))).astype(np.uint8)
        cv2.imwrite(str(root / f"rgb/{ts:.6f}.png"), cv2.merge([img, img // 2 + 20, 255 - img]))
        cv2.imwrite(str(root / f"depth/{ts:.6f}.png"), np.full((48, 64), 10000, np.uint16))
        rgb_lines.append(f"{ts:.6f} rgb/{ts:.6f}.png")
        depth_lines.append(f"{ts:.6f} depth/{ts:.6f}.png")
        gt.append(f"{ts:.6f} {0.01 * i:.4f} 0 0 0 0 0 1")
        ids = {1: "3", 2: "5", 4: "3"}.get(i, "")
        moving.append(f"{ts:.6f} {ids}".rstrip())
    for name, lines in (("rgb.txt", rgb_lines), ("depth.txt", depth_lines), ("groundtruth.txt", gt), ("moving.txt", moving)):
        (root / name).write_text("\n".join(lines) + "\n")
    return root


def _frames(root):
    lines = [l for l in (root / "rgb.txt").read_text().splitlines() if l and not l.startswith("#")]
    return [cv2.imread(str(root / l.split()[1]), cv2.IMREAD_UNCHANGED).astype(np.float64) for l in lines]


def test_exposure_scales_each_frame_by_the_gain_it_records(tmp_path):
    src = _sequence(tmp_path / "src")
    out = apply_camera_effects(src, tmp_path / "out", CameraEffects(exposure=0.05, exposure_jump_rate=0.5, seed=4))
    stats = pd.read_csv(out / "camera_effects.csv")
    assert len(stats) == N and stats["gain"].between(0.7, 1.3).all()
    assert stats["gain"].std() > 0.02  # it does drift
    for a, b, g in zip(_frames(src), _frames(out), stats["gain"]):
        ok = a * g < 254  # not clipped
        assert np.abs(b[ok] - np.rint(a[ok] * g)).max() <= 1.0
    # depth, ground truth and the lists are the source's
    assert (out / "groundtruth.txt").read_text() == (src / "groundtruth.txt").read_text()
    assert (out / "rgb.txt").read_text() == (src / "rgb.txt").read_text()
    assert len(TumSequence(out)) == N
    meta = json.loads((out / "camera_effects.json").read_text())
    assert meta["exposure"] == 0.05 and meta["source"] == str(src)


def test_the_same_seed_gives_the_same_copy_and_no_effect_changes_no_pixel(tmp_path):
    src = _sequence(tmp_path / "src")
    eff = CameraEffects(exposure=0.03, motion_blur_px=5.0, noise=3.0, seed=9)
    a = apply_camera_effects(src, tmp_path / "a", eff)
    b = apply_camera_effects(src, tmp_path / "b", eff)
    assert all(np.array_equal(x, y) for x, y in zip(_frames(a), _frames(b)))
    c = apply_camera_effects(src, tmp_path / "c", CameraEffects())
    assert all(np.array_equal(x, y) for x, y in zip(_frames(src), _frames(c)))


def test_motion_blur_is_a_normalised_line_and_blurs_along_it(tmp_path):
    k = _blur_kernel(6.0, 0.0)
    assert math.isclose(k.sum(), 1.0, rel_tol=1e-6)
    rows = np.flatnonzero(k.sum(axis=1))
    assert len(rows) == 1 and np.count_nonzero(k) == 7  # one horizontal row, 7 px long
    v = _blur_kernel(4.0, math.pi / 2)
    assert len(np.flatnonzero(v.sum(axis=0))) == 1  # vertical
    src = _sequence(tmp_path / "src")
    out = apply_camera_effects(src, tmp_path / "out", CameraEffects(motion_blur_px=8.0, seed=1))
    lengths = pd.read_csv(out / "camera_effects.csv")["blur_px"]
    assert lengths.between(4.0, 8.0).all()
    grad = lambda im: (np.diff(im[..., 0], axis=1) ** 2).mean() + (np.diff(im[..., 0], axis=0) ** 2).mean()  # edge energy
    assert all(grad(b) < 0.6 * grad(a) for a, b in zip(_frames(src), _frames(out)))


def test_vignette_and_response_darken_the_corners_not_the_centre(tmp_path):
    src = _sequence(tmp_path / "src")
    out = apply_camera_effects(src, tmp_path / "out", CameraEffects(vignette=0.4, gamma=1.0))
    for a, b in zip(_frames(src), _frames(out)):
        assert np.abs(b[24, 32] - a[24, 32]).max() <= 1.0  # r = 0 at the centre
        corner = a[0, 0] > 20
        assert np.all(np.abs(b[0, 0][corner] - np.rint(a[0, 0][corner] * (1 - 0.4 * (32 ** 2 + 24 ** 2) / (32 ** 2 + 24 ** 2)))) <= 1.0)
    g = apply_camera_effects(src, tmp_path / "g", CameraEffects(gamma=0.5))
    a, b = _frames(src)[0], _frames(g)[0]
    assert np.abs(b - np.rint(255 * np.sqrt(a / 255))).max() <= 1.0


def test_a_lower_frame_rate_thins_the_lists_and_merges_the_movers_between(tmp_path):
    src = _sequence(tmp_path / "src")
    out = apply_camera_effects(src, tmp_path / "out", CameraEffects(every=2))
    ts = [float(l.split()[0]) for l in (out / "rgb.txt").read_text().splitlines() if l and not l.startswith("#")]
    assert np.allclose(ts, [100 + i / 30 for i in (0, 2, 4, 6)])
    assert (out / "rgb.txt").read_text().startswith("# colour")
    assert len(TumSequence(out)) == 4
    rows = [l.split() for l in (out / "moving.txt").read_text().splitlines() if l and not l.startswith("#")]
    # frame 2 keeps what moved in frames 1 and 2 (3 and 5), frame 4 what moved in 3 and 4 (3), frame 6 nothing
    assert [r[1:] for r in rows] == [[], ["3", "5"], ["3"], []]
    assert np.array_equal(_frames(src)[2], _frames(out)[1])  # colour untouched: linked, not rewritten


def test_writes_a_new_folder_only_and_leaves_nothing_behind_on_a_bad_frame(tmp_path):
    src = _sequence(tmp_path / "src")
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "mine.txt").write_text("keep")
    with pytest.raises(FileExistsError, match="taken"):
        apply_camera_effects(src, tmp_path / "taken", CameraEffects(exposure=0.03))
    assert (tmp_path / "taken" / "mine.txt").read_text() == "keep"
    bad = sorted((src / "rgb").iterdir())[3]
    bad.write_bytes(b"not a png")
    with pytest.raises(DatasetError, match=bad.name):
        apply_camera_effects(src, tmp_path / "out", CameraEffects(exposure=0.03))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["src", "taken"]  # no half copy, no temporary folder
    with pytest.raises(DatasetError, match="TUM layout"):
        apply_camera_effects(tmp_path / "taken", tmp_path / "x", CameraEffects())
    with pytest.raises(ValueError, match="every"):
        CameraEffects(every=0)
    with pytest.raises(ValueError, match="vignette"):
        CameraEffects(vignette=1.2)


def test_summary_counts_runs_within_the_bound_and_ratios_to_the_original():
    rows = []
    for seq, base, exp in (("a", 0.004, 0.006), ("b", 0.010, 0.080)):
        rows.append({"sequence": seq, "effect": ORIGINAL, "filter": "geometry", "ate_rmse_m": base, "lost": 0, "precision": 0.8, "recall": 0.7})
        rows.append({"sequence": seq, "effect": "exposure", "filter": "geometry", "ate_rmse_m": exp, "lost": 2, "precision": 0.8, "recall": 0.7})
    df = with_ratios(pd.DataFrame(rows))
    assert np.allclose(df["ate_vs_original"], [1.0, 1.5, 1.0, 8.0])
    s = camera_effects_summary(df).set_index("effect")
    assert s.loc["exposure", "within"] == 1 and s.loc[ORIGINAL, "within"] == 2
    assert math.isclose(s.loc["exposure", "ratio_median"], 4.75) and math.isclose(s.loc["exposure", "ratio_worst"], 8.0)
    assert math.isclose(s.loc["exposure", "ate_worst"], 0.08) and s.loc["exposure", "lost"] == 4
    md = camera_effects_markdown(df)
    assert "| exposure | geometry | 2 | 1 | 0.0430 | 0.0800 | 4.75 | 8.00 | 4 |" in md
    assert md.index(f"| {ORIGINAL} |") < md.index("| exposure |")


def test_a_lower_frame_rate_keeps_the_depth_frames_that_pair_with_the_kept_colour_frames(tmp_path):
    """As in a real TUM sequence, the depth list does not pair with the colour list line by line (one depth frame
    more at the start, each 10 ms later): the kept depth frames are those nearest the kept colour frames, and an
    association file keeps the rows of the kept colour frames."""
    src = _sequence(tmp_path / "src")
    stamps = [100.0 - 1 / 30 + 0.01] + [100.0 + i / 30 + 0.01 for i in range(N)]
    lines = ["# depth"]
    for k, ts in enumerate(stamps):
        name = f"depth/{ts:.6f}.png"
        cv2.imwrite(str(src / name), np.full((48, 64), 10000 + k, np.uint16))
        lines.append(f"{ts:.6f} {name}")
    (src / "depth.txt").write_text("\n".join(lines) + "\n")
    rgb = [l.split() for l in (src / "rgb.txt").read_text().splitlines() if l and not l.startswith("#")]
    (src / "associations.txt").write_text("".join(f"{r[0]} {r[1]} {stamps[i + 1]:.6f} depth/{stamps[i + 1]:.6f}.png\n"
                                                  for i, r in enumerate(rgb)))
    out = apply_camera_effects(src, tmp_path / "out", CameraEffects(every=2))
    kept_depth = [float(l.split()[0]) for l in (out / "depth.txt").read_text().splitlines() if l and not l.startswith("#")]
    assert np.allclose(kept_depth, [100 + i / 30 + 0.01 for i in (0, 2, 4, 6)])
    assert len((out / "associations.txt").read_text().splitlines()) == 4
    seq = TumSequence(out)
    assert len(seq) == 4
    assert len(TumSequence(out, associations=False)) == 4  # rgb.txt and depth.txt alone associate too


def test_scale_resizes_every_image_and_the_camera_and_leaves_the_source_alone(tmp_path):
    """``scale = 0.5``: colour by area averaging, depth and masks by the nearest pixel (every second pixel of each
    row and column, as OpenCV picks them), the intrinsics of the half-size image in ``camera.json``; the source's
    files are byte for byte what they were (the copy links unchanged files, and must not write through them)."""
    from dynslam_lab.camera import PinholeCamera, save_camera_json

    src = _sequence(tmp_path / "src")
    save_camera_json(PinholeCamera(fx=50.0, fy=52.0, cx=31.5, cy=23.5, width=64, height=48, name="tiny"), src / "camera.json")
    (src / "masks").mkdir()
    rels = [l.split()[1] for l in (src / "rgb.txt").read_text().splitlines() if l and not l.startswith("#")]
    yy, xx = np.mgrid[:48, :64]
    for rel in rels:
        cv2.imwrite(str(src / "masks" / rel.split("/")[-1]), ((xx // 9 + yy // 7) % 3).astype(np.uint16))
    before = {p: p.read_bytes() for p in src.rglob("*") if p.is_file()}
    dst = apply_camera_effects(src, tmp_path / "half", CameraEffects(scale=0.5))
    assert {p: p.read_bytes() for p in src.rglob("*") if p.is_file()} == before
    seq = TumSequence(dst)
    cam = seq.camera
    assert (cam.width, cam.height) == (32, 24) and cam.fx == 25.0 and cam.fy == 26.0
    assert cam.cx == pytest.approx(15.5) and cam.cy == pytest.approx(11.5)
    for rel in rels:
        name = rel.split("/")[-1]
        rgb = cv2.imread(str(src / rel), cv2.IMREAD_UNCHANGED)
        # area averaging by 2 is the mean of each 2x2 block (rounded to the nearest grey level)
        block = rgb.reshape(24, 2, 32, 2, 3).astype(np.float64).mean(axis=(1, 3))
        assert np.abs(cv2.imread(str(dst / rel), cv2.IMREAD_UNCHANGED) - block).max() <= 0.5 + 1e-9
        for sub in ("depth", "masks"):
            a = cv2.imread(str(src / sub / name), cv2.IMREAD_UNCHANGED)
            b = cv2.imread(str(dst / sub / name), cv2.IMREAD_UNCHANGED)
            assert b.dtype == np.uint16 and np.array_equal(b, a[::2, ::2])
    f = seq[0]
    assert f.rgb.shape == (24, 32, 3) and f.depth.shape == (24, 32) and np.allclose(f.depth, 2.0)
    with pytest.raises(ValueError, match="scale"):
        CameraEffects(scale=0.0)


def test_depth_noise_grows_with_depth_squared_and_a_shift_moves_depth_off_the_colour(tmp_path):
    """``depth_noise = 0.005``: at 2 m the extra noise has a standard deviation of 0.005 x 4 = 2 cm (measured over the
    frames' pixels, to 5 %), no bias, and a pixel without a reading keeps none; ``depth_shift_px = 2``: every depth pixel
    two columns to the right, none where the shift uncovers the image; colour untouched, the source unchanged."""
    src = _sequence(tmp_path / "src")
    first = sorted((src / "depth").glob("*.png"))[0]
    d0 = cv2.imread(str(first), cv2.IMREAD_UNCHANGED)
    d0[10:20, 10:20] = 0  # no reading there
    cv2.imwrite(str(first), d0)
    before = {p: p.read_bytes() for p in src.rglob("*") if p.is_file()}
    noisy = apply_camera_effects(src, tmp_path / "noisy", CameraEffects(depth_noise=0.005, seed=3))
    z = []
    for p in sorted((src / "depth").glob("*.png")):
        a = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        b = cv2.imread(str(noisy / "depth" / p.name), cv2.IMREAD_UNCHANGED)
        assert b.dtype == np.uint16 and np.array_equal(b == 0, a == 0)
        z.append((b[a > 0].astype(np.float64) - a[a > 0]) / 5000.0)
    z = np.concatenate(z)
    assert z.std() == pytest.approx(0.02, rel=0.05) and abs(z.mean()) < 0.002
    assert all((noisy / rel).read_bytes() == (src / rel).read_bytes() for rel in
               [l.split()[1] for l in (src / "rgb.txt").read_text().splitlines() if l and not l.startswith("#")])
    again = apply_camera_effects(src, tmp_path / "again", CameraEffects(depth_noise=0.005, seed=3))
    assert all((again / "depth" / p.name).read_bytes() == (noisy / "depth" / p.name).read_bytes()
               for p in (src / "depth").glob("*.png"))
    shifted = apply_camera_effects(src, tmp_path / "shifted", CameraEffects(depth_shift_px=2.0))
    b0 = cv2.imread(str(shifted / "depth" / first.name), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(b0[:, 2:], d0[:, :-2]) and not b0[:, :2].any()
    assert {p: p.read_bytes() for p in src.rglob("*") if p.is_file()} == before
