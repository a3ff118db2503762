"""Decoding of every supported layout, on tiny ONNX graphs whose outputs we write by hand.

Input 64 x 64 (anchor points: 8x8 + 4x4 + 2x2 = 84), image 128 x 96 (w x h). Letterbox:
scale 0.5, centred padding 8 px at the top (YOLOv8/v5), none at the top-left (YOLOX);
stretch (NanoDet): x * 0.5, y * 2/3. Each test places known boxes in input pixels and checks
the image-pixel boxes, scores and classes the detector returns.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dynslam_lab.detection import DetectionConfig, LayoutError, OnnxDetector, box_iou, recognise_layout
from dynslam_lab.detection.decode import anchor_count, anchor_grid

from .tiny_models import write_constant_model

H_IMG, W_IMG = 96, 128
NC = 80
A = 84
PERSON_IMG = np.array([20, 16, 60, 80], np.float32)  # x1 y1 x2 y2, image pixels
CHAIR_IMG = np.array([80, 40, 120, 90], np.float32)
CHAIR = 56


def _image() -> np.ndarray:
    return np.zeros((H_IMG, W_IMG, 3), np.uint8)


def _to_input(box, top=8.0):
    b = np.asarray(box, np.float64) * 0.5
    b[[1, 3]] += top
    return b


def _cxcywh(b):
    return [(b[0] + b[2]) / 2, (b[1] + b[3]) / 2, b[2] - b[0], b[3] - b[1]]


def test_anchor_grid_counts_and_order():
    assert anchor_count((640, 640)) == 8400
    assert anchor_count((416, 416)) == 3549
    cells, stride = anchor_grid((64, 64))
    assert len(cells) == A
    # level 8: row-major 8 x 8; first cell of level 16 comes after 64 cells
    assert tuple(cells[9]) == (1, 1) and stride[9] == 8
    assert tuple(cells[64 + 6]) == (2, 1) and stride[64 + 6] == 16
    assert tuple(cells[83]) == (1, 1) and stride[83] == 32


def _yolov8_head(num_masks=0):
    out = np.zeros((1, 4 + NC + num_masks, A), np.float32)
    p = _to_input(PERSON_IMG)
    out[0, :4, 10] = _cxcywh(p)
    out[0, 4 + 0, 10] = 0.9
    out[0, :4, 11] = _cxcywh(p + [1, 0, 1, 0])  # duplicate, shifted 1 px
    out[0, 4 + 0, 11] = 0.8
    out[0, :4, 50] = _cxcywh(_to_input(CHAIR_IMG))
    out[0, 4 + CHAIR, 50] = 0.6
    out[0, :4, 60] = _cxcywh(_to_input(CHAIR_IMG))
    out[0, 4 + 3, 60] = 0.2  # below the threshold
    return out


def test_yolov8_detection_decodes_boxes_scores_classes(tmp_path):
    path = write_constant_model(tmp_path / "v8.onnx", {"output0": _yolov8_head()})
    det = OnnxDetector(path)
    assert det.layout.family == "yolov8" and det.layout.num_classes == 80
    d = det.detect_image(_image())
    assert d.image_size == (H_IMG, W_IMG) and d.masks is None
    np.testing.assert_array_equal(d.class_ids, [0, CHAIR])
    np.testing.assert_allclose(d.scores, [0.9, 0.6], atol=1e-6)
    np.testing.assert_allclose(d.boxes, [PERSON_IMG, CHAIR_IMG], atol=1e-3)
    assert d.names == ["person", "chair"]
    assert set(d.timings_ms) == {"preprocess", "inference", "decode"}


def test_yolov8_soft_nms_keeps_duplicate_with_gaussian_score(tmp_path):
    path = write_constant_model(tmp_path / "v8.onnx", {"output0": _yolov8_head()})
    cfg = DetectionConfig(nms="soft", soft_nms_sigma=0.5, score_threshold=0.1)
    d = OnnxDetector(path, cfg).detect_image(_image())
    p = _to_input(PERSON_IMG)
    # both boxes in input pixels: 20 x 32, shifted by 1 px -> IoU = 19*32 / (2*640 - 19*32)
    iou = 19 * 32 / (2 * 640 - 19 * 32)
    assert iou == pytest.approx(box_iou(p[None], (p + [1, 0, 1, 0])[None])[0, 0])
    expected = 0.8 * np.exp(-(iou**2) / 0.5)
    assert expected == pytest.approx(0.155, abs=1e-3)
    # kept by decreasing decayed score: person, chair, the 0.2 box of class 3, the duplicate
    np.testing.assert_array_equal(d.class_ids, [0, CHAIR, 3, 0])
    np.testing.assert_allclose(d.scores, [0.9, 0.6, 0.2, expected], atol=1e-5)
    np.testing.assert_allclose(d.boxes[3], PERSON_IMG + [2, 0, 2, 0], atol=1e-3)
    hard = OnnxDetector(path, dataclasses.replace(cfg, nms="hard")).detect_image(_image())
    np.testing.assert_array_equal(hard.class_ids, [0, CHAIR, 3])


def test_class_filter_and_agnostic(tmp_path):
    path = write_constant_model(tmp_path / "v8.onnx", {"output0": _yolov8_head()})
    d = OnnxDetector(path, DetectionConfig(classes=("chair",))).detect_image(_image())
    np.testing.assert_array_equal(d.class_ids, [CHAIR])
    # class-agnostic suppression of a chair box lying on the person box
    head = _yolov8_head()
    head[0, :4, 50] = head[0, :4, 10]
    path2 = write_constant_model(tmp_path / "v8b.onnx", {"output0": head})
    aware = OnnxDetector(path2).detect_image(_image())
    agnostic = OnnxDetector(path2, DetectionConfig(class_agnostic=True)).detect_image(_image())
    assert sorted(aware.class_ids.tolist()) == [0, CHAIR]
    assert agnostic.class_ids.tolist() == [0]


def test_yolov5_score_is_objectness_times_class(tmp_path):
    out = np.zeros((1, 3 * A, 5 + NC), np.float32)
    out[0, 100, :4] = _cxcywh(_to_input(PERSON_IMG))
    out[0, 100, 4], out[0, 100, 5 + 0] = 0.95, 0.9
    out[0, 200, :4] = _cxcywh(_to_input(CHAIR_IMG))
    out[0, 200, 4], out[0, 200, 5 + CHAIR] = 0.5, 0.5  # 0.25 < 0.3
    det = OnnxDetector(write_constant_model(tmp_path / "v5.onnx", {"output": out}))
    assert det.layout.family == "yolov5"
    d = det.detect_image(_image())
    np.testing.assert_array_equal(d.class_ids, [0])
    np.testing.assert_allclose(d.scores, [0.95 * 0.9], atol=1e-6)
    np.testing.assert_allclose(d.boxes, [PERSON_IMG], atol=1e-3)


def test_yolox_raw_grid_decoding(tmp_path):
    out = np.zeros((1, A, 5 + NC), np.float32)
    # person: input box (top-left letterbox) [10, 8, 30, 40] -> cx 20, cy 24, w 20, h 32
    # stride 8 cell (2, 3) -> index 3 * 8 + 2 = 26; t = (0.5, 0.0, ln 2.5, ln 4)
    out[0, 26, :4] = [0.5, 0.0, np.log(20 / 8), np.log(32 / 8)]
    out[0, 26, 4], out[0, 26, 5] = 0.9, 0.8
    # chair: input [40, 20, 60, 45] -> cx 50, cy 32.5, w 20, h 25; stride 16 cell (3, 2)
    out[0, 64 + 2 * 4 + 3, :4] = [50 / 16 - 3, 32.5 / 16 - 2, np.log(20 / 16), np.log(25 / 16)]
    out[0, 64 + 11, 4], out[0, 64 + 11, 5 + CHAIR] = 1.0, 0.7
    det = OnnxDetector(write_constant_model(tmp_path / "yolox.onnx", {"output": out}))
    assert det.layout.family == "yolox" and det.preprocess_kind == "letterbox_topleft"
    d = det.detect_image(_image())
    np.testing.assert_array_equal(d.class_ids, [0, CHAIR])
    np.testing.assert_allclose(d.scores, [0.72, 0.7], atol=1e-6)
    np.testing.assert_allclose(d.boxes, [PERSON_IMG, CHAIR_IMG], atol=1e-3)


def test_nanodet_distribution_boxes_with_shuffled_outputs(tmp_path):
    reg_ch = 32
    cls = {s: np.zeros((1, n, NC), np.float32) for s, n in ((8, 64), (16, 16), (32, 4))}
    reg = {s: np.zeros((1, n, reg_ch), np.float32) for s, n in ((8, 64), (16, 16), (32, 4))}
    # stride 16, cell (x=1, y=2) -> index 9, centre ((1.5) 16, (2.5) 16) = (24, 40)
    cls[16][0, 9, 0] = 0.85
    logits = np.zeros((4, 8), np.float32)
    for side, k in enumerate([1, 2, 2, 1]):  # l, t, r, b in strides
        logits[side, k] = 30.0
    reg[16][0, 9] = logits.ravel()
    outputs = {"r32": reg[32], "c8": cls[8], "r8": reg[8], "c16": cls[16], "c32": cls[32], "r16": reg[16]}
    det = OnnxDetector(write_constant_model(tmp_path / "nanodet.onnx", outputs, input_name="input.1"))
    L = det.layout
    assert L.family == "nanodet" and L.strides == (8, 16, 32) and L.num_classes == 80
    assert L.outputs == ("c8", "c16", "c32", "r8", "r16", "r32")
    d = det.detect_image(_image())
    # input box [24-16, 40-32, 24+32, 40+16] = [8, 8, 56, 56]; stretch back: x / 0.5, y / (2/3)
    np.testing.assert_allclose(d.boxes, [[16, 12, 112, 84]], atol=1e-3)
    np.testing.assert_allclose(d.scores, [0.85], atol=1e-6)


def test_nanodet_plus_single_tensor(tmp_path):
    # strides 8/16/32/64 over 64 x 64: 64 + 16 + 4 + 1 = 85 anchor points, 80 + 32 columns
    out = np.zeros((1, 85, NC + 32), np.float32)
    # stride 16, cell (x=1, y=2) -> index 64 + 9; NanoDet-Plus centre (x s, y s) = (16, 32)
    out[0, 73, CHAIR] = 0.75
    logits = np.zeros((4, 8), np.float32)
    for side, k in enumerate([1, 2, 2, 1]):
        logits[side, k] = 30.0
    out[0, 73, NC:] = logits.ravel()
    det = OnnxDetector(write_constant_model(tmp_path / "plus.onnx", {"output": out}, input_name="data"))
    assert det.layout.family == "nanodet-plus" and det.layout.strides == (8, 16, 32, 64)
    d = det.detect_image(_image())
    # input box [16-16, 32-32, 16+32, 32+16] = [0, 0, 48, 48] -> image x / 0.5, y / (2/3)
    np.testing.assert_allclose(d.boxes, [[0, 0, 96, 72]], atol=1e-3)
    np.testing.assert_array_equal(d.class_ids, [CHAIR])
    # forcing the legacy half-cell offset moves the box by half a stride (8 input px)
    legacy = det.with_config(DetectionConfig(nanodet_center_offset=0.5)).detect_image(_image())
    np.testing.assert_allclose(legacy.boxes, [[16, 12, 112, 84]], atol=1e-3)


def test_yolov8_seg_mask_from_prototypes(tmp_path):
    head = _yolov8_head(num_masks=32)
    head[0, 4 + NC + 0, 10] = 1.0  # person uses prototype 0
    head[0, 4 + NC + 1, 50] = 1.0  # chair uses prototype 1 (all negative: empty mask)
    protos = np.full((1, 32, 16, 16), -8.0, np.float32)
    # prototype 0 positive on input x in [8, 36), y in [12, 52) (4 input px per prototype px):
    # image x in [16, 72), y in [8, 88): larger than the person box, so the box crops it
    protos[0, 0, 3:13, 2:9] = 8.0
    det = OnnxDetector(write_constant_model(tmp_path / "seg.onnx", {"output0": head, "output1": protos}))
    assert det.layout.family == "yolov8-seg" and det.layout.num_masks == 32
    d = det.detect_image(_image())
    assert d.masks is not None and d.masks.shape == (2, H_IMG, W_IMG)
    expected = np.zeros((H_IMG, W_IMG), bool)
    expected[16:80, 20:60] = True  # pixel centres inside the box [20, 16, 60, 80]
    np.testing.assert_array_equal(d.masks[0], expected)
    assert not d.masks[1].any()


def test_seg_mask_edge_follows_prototype_boundary(tmp_path):
    head = _yolov8_head(num_masks=32)
    head[0, :4, 10] = _cxcywh(_to_input([0, 0, 128, 96]))  # box = whole image
    head[0, 4 + NC + 0, 10] = 1.0
    protos = np.full((1, 32, 16, 16), -8.0, np.float32)
    protos[0, 0, :, 4:] = 8.0  # positive right of input x = 16 -> image x = 32
    d = OnnxDetector(write_constant_model(tmp_path / "seg.onnx", {"output0": head, "output1": protos})).detect_image(_image())
    cols = np.flatnonzero(d.masks[0].any(axis=0))
    assert cols[0] == 32 and cols[-1] == W_IMG - 1


def test_dynamic_input_uses_configured_size(tmp_path):
    path = write_constant_model(tmp_path / "dyn.onnx", {"output0": _yolov8_head()}, symbolic=True)
    det = OnnxDetector(path, DetectionConfig(input_size=(64, 64)))
    assert det.layout.family == "yolov8" and det.layout.input_size == (64, 64)
    np.testing.assert_allclose(det.detect_image(_image()).boxes, [PERSON_IMG, CHAIR_IMG], atol=1e-3)
    # a symbolic batch alone keeps the model's fixed 64 x 64 size (not input_size)
    batch = write_constant_model(tmp_path / "batch.onnx", {"output0": _yolov8_head()}, symbolic_batch=True)
    assert OnnxDetector(batch).layout.input_size == (64, 64)


@pytest.mark.parametrize(
    "outputs, found",
    [
        ({"logits": np.zeros((1, 7))}, "logits [1, 7]"),
        ({"a": np.zeros((1, 86, 100))}, "a [1, 86, 100]"),
        ({"p": np.zeros((1, 32, 16, 16)), "q": np.zeros((1, 32, 16, 16))}, "p [1, 32, 16, 16]"),
        ({"c8": np.zeros((1, 64, 80)), "d8": np.zeros((1, 64, 80))}, "d8 [1, 64, 80]"),  # no box output
    ],
)
def test_unknown_layout_error_names_what_was_found(tmp_path, outputs, found):
    path = write_constant_model(tmp_path / "odd.onnx", outputs)
    with pytest.raises(LayoutError) as err:
        OnnxDetector(path)
    msg = str(err.value)
    assert str(path) in msg and found in msg and "images [1, 3, 64, 64]" in msg


def test_recognise_layout_real_shapes():
    ins = [("images", (1, 3, 640, 640))]
    assert recognise_layout(ins, [("output0", (1, 84, 8400))]).family == "yolov8"
    assert recognise_layout(ins, [("output0", (1, 25200, 85))]).family == "yolov5"
    assert recognise_layout(ins, [("output", (1, 8400, 85))]).family == "yolox"
    seg = recognise_layout([("images", (1, 3, 320, 320))], [("p", (1, 32, 80, 80)), ("o", (1, 116, 2100))])
    assert (seg.family, seg.num_classes, seg.num_masks, seg.outputs) == ("yolov8-seg", 80, 32, ("o", "p"))
    with pytest.raises(LayoutError, match="expected one image input"):
        recognise_layout([("a", (1, 3, 64, 64)), ("b", (1, 3, 64, 64))], [("o", (1, 84, 84))])


def test_missing_model_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.onnx"):
        OnnxDetector(tmp_path / "nope.onnx")


def test_config_validation():
    with pytest.raises(ValueError, match="detection.nms"):
        DetectionConfig(nms="fast")
    with pytest.raises(ValueError, match="unknown COCO class 'persn'"):
        DetectionConfig(classes=("persn",))
    with pytest.raises(ValueError, match="score_threshold"):
        dataclasses.replace(DetectionConfig(), score_threshold=1.5)


def test_with_config_reuses_the_session_and_postprocesses_raw_outputs(tmp_path):
    det = OnnxDetector(write_constant_model(tmp_path / "v8.onnx", {"output0": _yolov8_head()}))
    tensor, tf = det.preprocess(_image())
    raw = det.infer(tensor)
    soft = det.with_config(DetectionConfig(nms="soft", score_threshold=0.1))
    assert soft.session is det.session and det.config.nms == "hard"
    np.testing.assert_array_equal(soft.postprocess(raw, tf).class_ids, [0, CHAIR, 3, 0])
    np.testing.assert_array_equal(det.postprocess(raw, tf).class_ids, [0, CHAIR])
    only_chair = det.with_config(DetectionConfig(classes=("chair",)))
    np.testing.assert_array_equal(only_chair.postprocess(raw, tf).class_ids, [CHAIR])
