"""The four small real models of ../shared/data/models on five real TUM fr3 walking frames.

Ground truth: the person boxes we labelled once by hand in ``fixtures/tum_people_boxes.json``
(not derived from any model). Every backend must find all nine required people (IoU >= 0.5
with a person detection), with hard and with soft NMS; the YOLOv8-seg person mask of the
first frame must overlap the YOLACT mask of the same frame by IoU >= 0.85.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from dynslam_lab.datasets import load_rgb
from dynslam_lab.detection import DetectionConfig, OnnxDetector, box_iou

from tests.conftest import shared_file

pytestmark = pytest.mark.needs_shared

FIXTURE = json.loads((Path(__file__).parent / "fixtures" / "tum_people_boxes.json").read_text())
MODELS = {
    "yolox_nano.onnx": "yolox",
    "nanodet_m.onnx": "nanodet",
    "yolov8n_int8_640.onnx": "yolov8",
    "yolov8n-seg_int8_320.onnx": "yolov8-seg",
}
FIRST = "fr3_walking_xyz_1341846313.553992"


@pytest.fixture(scope="module")
def frames():
    return {name: load_rgb(shared_file(f"tum/frames/{name}")) for name in FIXTURE["frames"]}


@pytest.fixture(scope="module", params=sorted(MODELS))
def model_path(request):
    return shared_file(f"models/{request.param}")


def test_fixture_has_nine_required_people():
    required = [p for people in FIXTURE["frames"].values() for p in people if p["required"]]
    assert len(required) == 9


@pytest.mark.parametrize("nms", ["hard", "soft"])
def test_every_model_finds_all_nine_people(model_path, frames, nms):
    det = OnnxDetector(model_path, DetectionConfig(nms=nms, classes=("person",)))
    assert det.layout.family == MODELS[model_path.name]
    found, ious = 0, []
    for name, people in FIXTURE["frames"].items():
        d = det.detect_image(frames[name])
        assert d.image_size == (480, 640)
        assert np.all(d.class_ids == 0)
        gt = np.array([p["box"] for p in people if p["required"]], float)
        iou = box_iou(gt, d.boxes) if len(d) else np.zeros((len(gt), 1))
        best = iou.max(axis=1)
        found += int((best >= FIXTURE["match_iou"]).sum())
        ious.extend(best.tolist())
    assert found == 9, f"{model_path.name} ({nms}): found {found} of 9 people, best IoUs {np.round(ious, 2)}"


def test_yolov8_seg_person_mask_matches_yolact(frames):
    det = OnnxDetector(shared_file("models/yolov8n-seg_int8_320.onnx"))
    d = det.detect_image(frames[f"{FIRST}_rgb.png"])
    assert d.masks is not None and d.masks.shape == (len(d), 480, 640)
    ours = d.masks[d.class_ids == 0].any(axis=0)
    ref = cv2.imread(str(shared_file(f"tum/frames/{FIRST}_person_mask_yolact.png")), cv2.IMREAD_GRAYSCALE) > 0
    iou = (ours & ref).sum() / (ours | ref).sum()
    assert iou >= 0.85, f"person mask IoU with YOLACT {iou:.3f}"
    # each mask lies inside its box
    for box, m in zip(d.boxes, d.masks):
        ys, xs = np.nonzero(m)
        if len(xs):
            assert xs.min() >= box[0] - 1 and xs.max() <= box[2] and ys.min() >= box[1] - 1 and ys.max() <= box[3]


def _mean_person_iou(det, frames):
    ious = []
    for name, people in FIXTURE["frames"].items():
        d = det.detect_image(frames[name])
        gt = np.array([p["box"] for p in people if p["required"]], float)
        ious.extend(box_iou(gt, d.boxes).max(axis=1) if len(d) else np.zeros(len(gt)))
    return float(np.mean(ious))


def test_nanodet_legacy_half_cell_offset_fits_the_hand_boxes(frames):
    det = OnnxDetector(shared_file("models/nanodet_m.onnx"), DetectionConfig(classes=("person",)))
    default = _mean_person_iou(det, frames)  # offset 0.5 (legacy GFL head)
    corner = _mean_person_iou(det.with_config(DetectionConfig(classes=("person",), nanodet_center_offset=0.0)), frames)
    assert default > 0.8 and default > corner + 0.1, (default, corner)
