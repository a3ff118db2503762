"""The TUM-layout loader: association, depth scale, and clear errors on bad input."""

import cv2
import numpy as np
import pytest

from dynslam_lab.datasets import DatasetError, TumSequence, associate, load_depth, read_file_list
from tests.conftest import shared_file


def _write_seq(root, n=5, depth_offset=0.004, gt=True):
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb_lines, d_lines, gt_lines = ["# rgb"], ["# depth"], ["# gt"]
    for i in range(n):
        t = 100.0 + i / 30
        img = np.full((48, 64, 3), i * 10, np.uint8)
        cv2.imwrite(str(root / f"rgb/{t:.6f}.png"), img)
        d = np.full((48, 64), 5000 + 100 * i, np.uint16)
        cv2.imwrite(str(root / f"depth/{t + depth_offset:.6f}.png"), d)
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
        d_lines.append(f"{t + depth_offset:.6f} depth/{t + depth_offset:.6f}.png")
        gt_lines.append(f"{t + 0.001:.6f} {i * 0.1} 0 0 0 0 0 1")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(d_lines) + "\n")
    if gt:
        (root / "groundtruth.txt").write_text("\n".join(gt_lines) + "\n")


def test_associate_like_tum_script():
    a = np.array([0.0, 1.0, 2.0, 3.0])
    b = np.array([0.015, 1.5, 1.995, 2.01, 3.03])
    pairs = associate(a, b, max_diff=0.02)
    # 0.0-0.015 ok; 1.0 has none; 2.0 pairs with the nearest 1.995; 3.03 is too far.
    assert pairs.tolist() == [[0, 0], [2, 2]]


def test_associate_each_stamp_used_once():
    a = np.array([0.0, 0.01])
    b = np.array([0.005])
    assert associate(a, b).tolist() == [[0, 0]]


def test_sequence_loads_frames_in_metres(tmp_path):
    _write_seq(tmp_path / "seq")
    seq = TumSequence(tmp_path / "seq")
    assert len(seq) == 5
    f = seq[2]
    assert f.rgb.shape == (48, 64, 3) and f.rgb.dtype == np.uint8
    assert f.depth.dtype == np.float32
    assert f.depth[0, 0] == pytest.approx((5000 + 200) / 5000)
    np.testing.assert_allclose(f.T_w_c_gt[:3, 3], [0.2, 0, 0])
    assert [fr.index for fr in seq] == list(range(5))


def test_no_association_is_a_clear_error(tmp_path):
    _write_seq(tmp_path / "seq", depth_offset=0.5)
    with pytest.raises(DatasetError, match="no colour/depth pairs"):
        TumSequence(tmp_path / "seq")


def test_timestamps_in_nanoseconds_are_named_as_such(tmp_path):
    _write_seq(tmp_path / "seq")
    for name in ("rgb.txt", "depth.txt"):
        p = tmp_path / "seq" / name
        rows = [ln.split() for ln in p.read_text().splitlines() if ln and not ln.startswith("#")]
        p.write_text("".join(f"{round(float(t) * 1e9 + 1.6e18)} {f}\n" for t, f in rows))
    with pytest.raises(DatasetError, match=r"no colour/depth pairs.*rgb.txt's timestamps look like nanoseconds "
                                           r"\(1.6e\+18, which is 1.6e\+09 s.*divide them by 1e\+09"):
        TumSequence(tmp_path / "seq")


def test_malformed_list_line_names_file_and_line(tmp_path):
    _write_seq(tmp_path / "seq")
    p = tmp_path / "seq" / "rgb.txt"
    p.write_text(p.read_text() + "notanumber rgb/x.png\n")
    with pytest.raises(DatasetError, match=r"rgb.txt:7: timestamp 'notanumber'"):
        TumSequence(tmp_path / "seq")
    p.write_text("# only\n100.0\n")
    with pytest.raises(DatasetError, match=r"rgb.txt:2: expected at least 2 fields"):
        read_file_list(p)


def test_missing_list_and_folder(tmp_path):
    with pytest.raises(DatasetError, match="sequence folder not found"):
        TumSequence(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="rgb.txt: file not found"):
        TumSequence(tmp_path / "empty")


def test_corrupt_and_wrong_type_images(tmp_path):
    _write_seq(tmp_path / "seq")
    seq = TumSequence(tmp_path / "seq")
    e = seq._entries[0]
    e.rgb.write_bytes(b"not a png")
    with pytest.raises(DatasetError, match="cannot decode colour image"):
        seq[0]
    cv2.imwrite(str(seq._entries[1].depth), np.zeros((48, 64), np.uint8))
    with pytest.raises(DatasetError, match="must be 16-bit"):
        seq[1]
    seq._entries[2].depth.unlink()
    with pytest.raises(DatasetError, match="depth image not found"):
        seq[2]


def test_real_tum_depth_frame_scale():
    p = shared_file("tum/frames/fr3_walking_xyz_1341846313.592088_depth.png")
    d = load_depth(p)
    assert d.shape == (480, 640)
    valid = d[d > 0]
    # An office seen by a Kinect: readings between ~0.4 m and ~8 m, most within 1-5 m.
    assert 0.3 < valid.min() and valid.max() < 10.0
    assert 1.0 < np.median(valid) < 5.0
    assert (d == 0).mean() < 0.5


def test_real_association_files_parse():
    p = shared_file("tum/associations/fr3_walking_xyz.txt")
    ts, rows = read_file_list(p, min_fields=4)
    assert len(ts) > 800 and np.all(np.diff(ts) > 0)
    d_ts = np.array([float(r[1]) for r in rows])
    pairs = associate(ts, d_ts, 0.02)
    assert len(pairs) == len(ts)  # the published association pairs every line


def test_load_rgb_gives_rgb_channel_order(tmp_path):
    """Whichever decoding path OpenCV offers (straight to RGB, or BGR then converted): red stays red."""
    from dynslam_lab.datasets.tum import load_rgb

    bgr = np.zeros((4, 6, 3), np.uint8)
    bgr[..., 2] = 200  # red in OpenCV's BGR order
    bgr[0, 0] = (10, 20, 30)
    cv2.imwrite(str(tmp_path / "red.png"), bgr)
    rgb = load_rgb(tmp_path / "red.png")
    assert rgb.shape == (4, 6, 3) and rgb[1, 1].tolist() == [200, 0, 0] and rgb[0, 0].tolist() == [30, 20, 10]
