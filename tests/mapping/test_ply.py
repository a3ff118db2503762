"""PLY writer/reader: round trips, an independent reader (trimesh), and clear errors."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.mapping.ply import PlyError, read_ply, write_ply


@pytest.fixture
def cloud():
    rng = np.random.default_rng(3)
    return rng.normal(size=(500, 3)) * [2.0, 1.0, 0.5], rng.integers(0, 256, (500, 3)).astype(np.uint8)


@pytest.mark.parametrize("binary", [True, False])
def test_round_trip(tmp_path, cloud, binary):
    xyz, rgb = cloud
    p = write_ply(tmp_path / "m.ply", xyz, rgb, binary=binary, comment="test cloud")
    xyz2, rgb2 = read_ply(p)
    np.testing.assert_allclose(xyz2, xyz.astype(np.float32), rtol=0, atol=1e-6)
    np.testing.assert_array_equal(rgb2, rgb)


def test_binary_layout_by_hand(tmp_path):
    """15 bytes per vertex after the header: 3 little-endian float32 and 3 uint8."""
    xyz = np.array([[1.0, -2.0, 3.5], [0.25, 0.0, -1.0]])
    rgb = np.array([[255, 0, 10], [1, 2, 3]], np.uint8)
    p = write_ply(tmp_path / "m.ply", xyz, rgb)
    raw = p.read_bytes()
    header, body = raw.split(b"end_header\n", 1)
    assert b"format binary_little_endian 1.0" in header and b"element vertex 2" in header
    assert len(body) == 2 * 15
    assert np.frombuffer(body[:12], "<f4").tolist() == [1.0, -2.0, 3.5]
    assert list(body[12:15]) == [255, 0, 10]


def test_no_colour_and_empty(tmp_path):
    p = write_ply(tmp_path / "a.ply", np.zeros((0, 3)))
    xyz, rgb = read_ply(p)
    assert xyz.shape == (0, 3) and rgb is None
    p = write_ply(tmp_path / "b.ply", np.eye(3), binary=False)
    xyz, rgb = read_ply(p)
    np.testing.assert_array_equal(xyz, np.eye(3))
    assert rgb is None


@pytest.mark.parametrize("binary", [True, False])
def test_trimesh_reads_our_files(tmp_path, cloud, binary):
    trimesh = pytest.importorskip("trimesh")
    xyz, rgb = cloud
    p = write_ply(tmp_path / "m.ply", xyz, rgb, binary=binary)
    pc = trimesh.load(p, process=False)
    np.testing.assert_allclose(np.asarray(pc.vertices), xyz.astype(np.float32), atol=1e-6)
    np.testing.assert_array_equal(np.asarray(pc.colors)[:, :3], rgb)


def test_we_read_trimesh_files(tmp_path, cloud):
    trimesh = pytest.importorskip("trimesh")
    xyz, rgb = cloud
    pc = trimesh.PointCloud(xyz, colors=np.hstack([rgb, np.full((len(rgb), 1), 255, np.uint8)]))
    p = tmp_path / "t.ply"
    pc.export(p)
    xyz2, rgb2 = read_ply(p)
    np.testing.assert_allclose(xyz2, xyz, atol=1e-6)
    np.testing.assert_array_equal(rgb2, rgb)


def test_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"not a ply\n")
    with pytest.raises(PlyError, match="bad.ply.*not a PLY"):
        read_ply(bad)
    trunc = tmp_path / "trunc.ply"
    write_ply(trunc, np.ones((10, 3)))
    trunc.write_bytes(trunc.read_bytes()[:-5])
    with pytest.raises(PlyError, match="trunc.ply.*truncated"):
        read_ply(trunc)
    with pytest.raises(PlyError, match="not found"):
        read_ply(tmp_path / "missing.ply")
    with pytest.raises(ValueError, match="shape"):
        write_ply(tmp_path / "x.ply", np.ones((4, 2)))
    with pytest.raises(ValueError, match="non-finite"):
        write_ply(tmp_path / "x.ply", np.array([[0.0, np.nan, 1.0]]))
