"""``dynslam detect IMAGE... --model MODEL.onnx [--json]``."""

from __future__ import annotations

import json

import cv2
import numpy as np

from dynslam_lab.cli import main
from dynslam_lab.detection import load_detections

from .test_decode import CHAIR_IMG, _yolov8_head
from .tiny_models import write_constant_model
from tests.conftest import shared_file


def _write_image(path, h=96, w=128):
    cv2.imwrite(str(path), np.zeros((h, w, 3), np.uint8))
    return path


def test_detect_prints_table_and_json(tmp_path, capsys):
    model = write_constant_model(tmp_path / "v8.onnx", {"output0": _yolov8_head()})
    img = _write_image(tmp_path / "a.png")
    assert main(["detect", str(img), str(img), "--model", str(model)]) == 0
    out = capsys.readouterr().out
    assert "yolov8, input 64x64, 80 classes" in out
    assert out.count("person") == 2 and out.count("chair") == 2
    assert "   20.0    16.0    60.0    80.0" in out
    assert main(["detect", str(img), "--model", str(model), "--json", "--classes", "chair",
                 "--save-dir", str(tmp_path / "dets")]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1
    rec = json.loads(lines[0])
    assert rec["image"] == str(img) and rec["family"] == "yolov8" and rec["image_size"] == [96, 128]
    assert [d["class"] for d in rec["detections"]] == ["chair"]
    np.testing.assert_allclose(rec["detections"][0]["box"], CHAIR_IMG, atol=0.05)
    assert rec["detections"][0]["score"] == 0.6
    saved = load_detections(tmp_path / "dets" / "a.npz")
    np.testing.assert_allclose(saved.boxes, [CHAIR_IMG], atol=1e-3)


def test_detect_config_file_and_errors(tmp_path, capsys):
    model = write_constant_model(tmp_path / "v8.onnx", {"output0": _yolov8_head()})
    img = _write_image(tmp_path / "a.png")
    toml = tmp_path / "c.toml"
    toml.write_text("[detection]\nscore_threshold = 0.7\n")
    assert main(["detect", str(img), "--model", str(model), "--config", str(toml), "--json"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert [d["class"] for d in rec["detections"]] == ["person"]
    toml.write_text("[detection]\nscore_treshold = 0.7\n")
    assert main(["detect", str(img), "--model", str(model), "--config", str(toml)]) == 1
    assert "detection.score_treshold: unknown parameter" in capsys.readouterr().err
    assert main(["detect", str(tmp_path / "none.png"), "--model", str(model)]) == 1
    assert "none.png: colour image not found" in capsys.readouterr().err
    assert main(["detect", str(img), "--model", str(tmp_path / "none.onnx")]) == 1
    assert "none.onnx: ONNX model not found" in capsys.readouterr().err


def test_detect_real_frame(capsys):
    img = shared_file("tum/frames/fr3_walking_b_rgb.png")
    model = shared_file("models/yolox_nano.onnx")
    assert main(["detect", str(img), "--model", str(model), "--json", "--classes", "person"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert len(rec["detections"]) == 2 and all(d["score"] > 0.7 for d in rec["detections"])


def test_save_dir_of_tum_named_images_is_a_cache(tmp_path, capsys):
    from dynslam_lab.camera import CAMERA_PRESETS
    from dynslam_lab.datasets.frame import Frame
    from dynslam_lab.detection import build_detector

    model = write_constant_model(tmp_path / "v8.onnx", {"output0": _yolov8_head()})
    img = _write_image(tmp_path / "1341846313.553992.png")
    assert main(["detect", str(img), "--model", str(model), "--save-dir", str(tmp_path / "dets")]) == 0
    capsys.readouterr()
    frame = Frame(0, 1341846313.553992, np.zeros((96, 128, 3), np.uint8), np.zeros((96, 128), np.float32),
                  CAMERA_PRESETS["tum_fr3"])
    d = build_detector(f"cache:{tmp_path / 'dets'}").detect(frame)
    assert d.names == ["person", "chair"]
    np.testing.assert_allclose(d.boxes[1], CHAIR_IMG, atol=1e-3)
