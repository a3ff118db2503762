"""The viser scene: quaternion convention (checked with viser's own SO3), frustum geometry
(checked with OpenCV's projection), run loading, and the live scene's nodes and playback."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dynslam_lab.geometry.se3 import make_pose, so3_exp
from tests.fixtures.demo_run import write_demo_run
from dynslam_lab.viz.viser_scene import (
    SceneConfig,
    build_scene,
    free_port,
    frustum_segments,
    load_run,
    polyline_segments,
    start_viewer,
    wxyz_from_matrix,
)


def test_wxyz_agrees_with_viser_so3():
    tf = pytest.importorskip("viser.transforms")
    rng = np.random.default_rng(0)
    R = np.stack([so3_exp(rng.normal(size=3)) for _ in range(20)])
    q = wxyz_from_matrix(R)
    assert q.shape == (20, 4)
    for Rk, qk in zip(R, q):
        np.testing.assert_allclose(tf.SO3(qk).as_matrix(), Rk, atol=1e-9)
    np.testing.assert_allclose(wxyz_from_matrix(np.eye(3)), [1, 0, 0, 0])


def test_frustum_corners_project_to_image_corners():
    W, H = 640, 480
    f = 525.0
    fov_y = 2 * np.arctan(H / 2 / f)
    T = make_pose(so3_exp(np.array([0.3, -0.1, 0.2])), np.array([1.0, 2.0, -0.5]))
    segs = frustum_segments(T[None], fov_y, W / H, 0.2)
    assert segs.shape == (8, 2, 3)
    np.testing.assert_allclose(segs[:4, 0], np.tile(T[:3, 3], (4, 1)))  # apex = camera centre
    corners = np.ascontiguousarray(segs[:4, 1])
    T_c_w = np.linalg.inv(T)
    rvec, _ = cv2.Rodrigues(T_c_w[:3, :3])
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])
    uv, _ = cv2.projectPoints(corners, rvec, T_c_w[:3, 3], K, None)
    np.testing.assert_allclose(uv.reshape(-1, 2), [[0, 0], [W, 0], [W, H], [0, H]], atol=1e-6)
    # the rectangle closes: each corner starts one edge and ends another
    np.testing.assert_allclose(segs[4:, 0], corners)
    np.testing.assert_allclose(segs[4:, 1], corners[[1, 2, 3, 0]])


def test_polyline_segments():
    P = np.arange(12.0).reshape(4, 3)
    s = polyline_segments(P)
    assert s.shape == (3, 2, 3)
    np.testing.assert_array_equal(s[:, 0], P[:-1])
    np.testing.assert_array_equal(s[:, 1], P[1:])


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    return write_demo_run(tmp_path_factory.mktemp("run"), n_frames=120, keyframe_every=10, n_map_points=500,
                          n_dense_points=5000)


def test_load_run_reads_every_file_and_aligns_ground_truth(demo):
    run = load_run(demo)
    assert len(run.trajectory) == 120 and run.n_keyframes == 12
    assert run.map_xyz.shape == (500, 3) and run.dense_xyz.shape == (5000, 3)
    assert len(run.thumbs) == 12 and run.loop_edges.tolist() == [[11, 0]]
    # ground truth was brought into the estimate's frame: the drift (<= 6.4 cm) is all that separates them
    d = np.linalg.norm(run.ground_truth.positions - run.trajectory.positions, axis=1)
    assert d.max() < 0.065 and np.median(d) < 0.04


def test_load_run_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="run folder not found"):
        load_run(tmp_path / "nope")
    with pytest.raises(FileNotFoundError, match="nothing to show"):
        load_run(tmp_path)
    np.savez(tmp_path / "keyframes.npz", ids=np.arange(3), frame_index=np.arange(3), poses=np.eye(4))
    with pytest.raises(ValueError, match="keyframes.npz.*poses"):
        load_run(tmp_path)


def test_scene_nodes_and_playback(demo):
    server, h = start_viewer(demo, config=SceneConfig(max_image_frustums=5))
    try:
        assert "dense" not in h.nodes  # held back until a browser connects (first picture first)
        h.add_deferred()
        for key in ("dense", "sparse", "dynamic", "ground_truth", "estimate", "keyframes", "loops", "current"):
            assert key in h.nodes, key
        assert sum(k.startswith("kf") for k in h.nodes) == 5
        assert server.get_host() == "127.0.0.1"
        run = load_run(demo)
        np.testing.assert_allclose(h.nodes["estimate"].points.reshape(-1, 3)[0], run.trajectory.positions[0], atol=1e-5)
        assert h.nodes["keyframes"].points.shape == (8 * 12, 2, 3)
        h.set_frame(57)
        np.testing.assert_allclose(h.nodes["current"].position, run.trajectory.positions[57], atol=1e-6)
        np.testing.assert_allclose(h.nodes["current"].wxyz, wxyz_from_matrix(run.trajectory.poses[57, :3, :3]), atol=1e-6)
        assert h.slider.value == 57
    finally:
        server.stop()


def test_layers_stream_in_stages(demo):
    """Stages follow each other with their delays once started (a browser's connection starts
    them: tests/viz/test_view_browser.py checks that with a real browser)."""
    import time

    cfg = SceneConfig(max_image_frustums=3, defer_layers=0.4, defer_dense=0.4)
    server, h = start_viewer(demo, config=cfg)
    try:
        first = {"estimate", "ground_truth", "loops", "current"}
        assert first <= set(h.nodes)
        assert not {"keyframes", "sparse", "dynamic", "dense"} & set(h.nodes)
        time.sleep(1.0)  # nothing more is sent while no browser is there
        assert "keyframes" not in h.nodes and not h.wait_complete(0)
        h.start_stream()
        h.start_stream()  # a second browser does not start a second stream
        t0 = time.monotonic()
        while len(h.stage_seconds) < 2 and time.monotonic() - t0 < 10:  # stage 2 sent
            time.sleep(0.02)
        t_kf = time.monotonic() - t0
        assert "keyframes" in h.nodes and "sparse" in h.nodes and "dynamic" in h.nodes and "dense" not in h.nodes
        assert h.wait_complete(10)
        t_dense = time.monotonic() - t0
        assert 0.3 < t_kf < 5 and t_dense - t_kf > 0.3, (t_kf, t_dense)
        assert h.errors == [] and len(h.stage_seconds) == 3
        assert np.asarray(h.nodes["dense"].points).shape == (5000, 3)
    finally:
        h.close()
        server.stop()


def test_hidden_layers_stay_hidden_when_they_arrive(demo):
    server, h = start_viewer(demo, config=SceneConfig(max_image_frustums=3))
    try:
        h.set_visible("keyframes", False)
        h.set_visible("estimate", False)
        assert h.nodes["estimate"].visible is False
        h.add_deferred()
        assert h.nodes["keyframes"].visible is False
        assert all(h.nodes[k].visible is False for k in h.nodes if k.startswith("kf"))
        assert h.nodes["dense"].visible is True
    finally:
        server.stop()


def test_dense_map_read_lazily_and_errors_kept_to_its_layer(demo, tmp_path):
    import shutil

    from dynslam_lab.mapping.ply import PlyError, read_ply

    run = load_run(demo, dense=False)
    assert run.dense_xyz is None and run.dense_count == 5000
    run.load_dense()
    xyz, rgb = read_ply(demo / "map.ply")
    np.testing.assert_array_equal(run.dense_xyz, xyz)
    # a map.ply cut short: the header is fine, so the viewer starts; the dense layer reports the error
    bad = tmp_path / "run"
    shutil.copytree(demo, bad)
    data = (bad / "map.ply").read_bytes()
    (bad / "map.ply").write_bytes(data[: len(data) // 2])
    server, h = start_viewer(bad, config=SceneConfig(max_image_frustums=0))
    try:
        h.add_deferred()
        assert "dense" not in h.nodes and "keyframes" in h.nodes
        assert len(h.errors) == 1 and "map.ply: truncated" in h.errors[0]
    finally:
        server.stop()
    # a header that is not PLY at all is refused when the run is loaded, naming the file
    (bad / "map.ply").write_bytes(b"not a ply file\n")
    with pytest.raises(PlyError, match="map.ply: not a PLY file"):
        load_run(bad, dense=False)


def test_scene_config_errors():
    with pytest.raises(ValueError, match="SceneConfig.defer_dense"):
        SceneConfig(defer_dense=-1)
    with pytest.raises(ValueError, match="SceneConfig.max_path_points"):
        SceneConfig(max_path_points=1)


def test_dense_cap_is_a_seeded_subset(demo):
    import viser

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        h = build_scene(server, load_run(demo), SceneConfig(max_dense_points=1000, gui=False))
        pts = np.asarray(h.nodes["dense"].points, dtype=np.float64)
        assert pts.shape == (1000, 3)
        assert h.slider is None
    finally:
        server.stop()


def test_long_paths_are_thinned_for_display():
    P = np.cumsum(np.ones((10_000, 3)), axis=0)
    s = polyline_segments(P, max_points=100)
    assert s.shape == (99, 2, 3)
    np.testing.assert_array_equal(s[0, 0], P[0])
    np.testing.assert_array_equal(s[-1, 1], P[-1])
    np.testing.assert_array_equal(s[1:, 0], s[:-1, 1])  # still one connected path


def test_view_command_reports_bad_folders(tmp_path, capsys):
    from dynslam_lab.cli import main

    assert main(["view", str(tmp_path / "missing"), "--timeout", "0"]) == 1
    assert "missing: run folder not found" in capsys.readouterr().err
    assert main(["view", str(tmp_path), "--port", "0"]) == 2  # a usage error (docs/reliability.md)
    assert "--port must be in 1..65535" in capsys.readouterr().err


def test_view_command_serves_and_stops(demo, capsys):
    from dynslam_lab.cli import main

    assert main(["view", str(demo), "--port", str(free_port()), "--timeout", "0.5"]) == 0
    out = capsys.readouterr().out
    assert "120 poses, 12 keyframes, 500 map points, 5000 dense points" in out
    assert "open http://127.0.0.1:" in out
