import cv2
import numpy as np
import pytest

from dynslam_lab.camera import CAMERA_PRESETS, PinholeCamera, camera_for_sequence, load_camera_json, save_camera_json


def test_project_matches_opencv_and_backproject_inverts():
    cam = CAMERA_PRESETS["tum_fr3"]
    rng = np.random.default_rng(0)
    P = np.c_[rng.uniform(-1, 1, (50, 2)), rng.uniform(0.5, 5, 50)]
    uv, z = cam.project(P)
    uv_cv, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), cam.K, None)
    np.testing.assert_allclose(uv, uv_cv.reshape(-1, 2), atol=1e-9)
    np.testing.assert_allclose(cam.backproject(uv, z), P, atol=1e-9)


def test_backproject_depth_grid_and_holes():
    cam = PinholeCamera(500, 500, 2.0, 1.0, width=5, height=3)
    depth = np.full((3, 5), 2.0, np.float32)
    depth[1, 1] = 0
    pts = cam.backproject_depth(depth)
    assert pts.shape == (3, 5, 3)
    assert np.isnan(pts[1, 1]).all()
    np.testing.assert_allclose(pts[0, 0], [(0 - 2) / 500 * 2, (0 - 1) / 500 * 2, 2.0])


def test_undistort_matches_opencv():
    cam = CAMERA_PRESETS["tum_fr1"]
    uv = np.array([[10.0, 20.0], [320.0, 240.0], [600.0, 400.0]])
    ref = cv2.undistortPoints(uv.reshape(-1, 1, 2), cam.K, cam.dist_coeffs, P=cam.K).reshape(-1, 2)
    np.testing.assert_allclose(cam.undistort_points(uv), ref)


@pytest.mark.parametrize(
    "name,preset",
    [
        ("rgbd_dataset_freiburg3_walking_xyz", "tum_fr3"),
        ("rgbd_dataset_freiburg1_xyz", "tum_fr1"),
        ("fr2_desk", "tum_fr2"),
        ("rgbd_bonn_balloon", "bonn"),
        ("my_sequence", "default"),
    ],
)
def test_camera_from_folder_name(tmp_path, name, preset):
    d = tmp_path / name
    d.mkdir()
    assert camera_for_sequence(d) == CAMERA_PRESETS[preset]


def test_camera_json_roundtrip_and_errors(tmp_path):
    cam = CAMERA_PRESETS["bonn"]
    save_camera_json(cam, tmp_path / "camera.json")
    assert load_camera_json(tmp_path / "camera.json") == cam
    assert camera_for_sequence(tmp_path) == cam
    (tmp_path / "bad.json").write_text('{"fx": 1, "bogus": 2}')
    with pytest.raises(ValueError, match="bogus"):
        load_camera_json(tmp_path / "bad.json")
    with pytest.raises(ValueError, match="unknown camera preset"):
        camera_for_sequence(tmp_path, "nope")
    with pytest.raises(ValueError, match="fx"):
        PinholeCamera(0, 1, 0, 0)


def test_a_folder_without_camera_json_or_preset_name_says_its_intrinsics_are_a_guess(tmp_path, caplog):
    import logging

    mine = tmp_path / "my_scene_03"
    mine.mkdir()
    with caplog.at_level(logging.WARNING, logger="dynslam_lab.camera"):
        assert camera_for_sequence(mine).name == "default"
        assert camera_for_sequence(mine).name == "default"  # said once per folder
        assert camera_for_sequence(tmp_path / "rgbd_dataset_freiburg2_desk").name == "tum_fr2"
        assert camera_for_sequence(mine, "bonn").name == "bonn"
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1 and str(mine) in said[0] and "write camera.json or pass --camera" in said[0]
