"""Run any common ONNX export of a COCO detector with onnxruntime.

The papers find a-priori dynamic objects with one-stage CNNs: Darknet19-YOLOv3 boxes
(YOLO-SLAM, Wu et al. 2022, Sec. 3.2), YOLOv5 boxes plus a segmentation head (Zhang et al. 2023), YOLACT
masks (Chang et al. 2021), YOLOv8 instance segmentation (ASG-SLAM, Ge et al. 2024). Their exports differ
only in preprocessing and in the layout of the output tensors, so one class serves them all:

1. :func:`recognise_layout` reads the model's inputs and outputs and names the family
   (``yolov8``, ``yolov8-seg``, ``yolov5``, ``yolox``, ``nanodet``, ``nanodet-plus``); anything else is refused
   with a message listing what was found;
2. the image is letterboxed or stretched to the input size, put in the family's channel
   order and value range (:mod:`.preprocess`);
3. the outputs are decoded into candidate boxes (:mod:`.decode`), suppressed (:mod:`.nms`),
   mapped back to image pixels, and for segmentation models turned into instance masks.

Each :class:`Detections` carries ``timings_ms`` with ``preprocess``, ``inference`` and
``decode`` (decoding + NMS + masks) so benchmarks can compare the network with our numpy.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..datasets.frame import Frame
from .coco import class_ids_of
from .config import DetectionConfig
from .decode import (
    STRIDES,
    Candidates,
    anchor_count,
    decode_masks,
    decode_nanodet,
    decode_yolov5,
    decode_yolov8,
    decode_yolox,
)
from .detections import Detections
from .nms import suppress
from .preprocess import fit_image

__all__ = ["ModelLayout", "LayoutError", "recognise_layout", "OnnxDetector"]

# Family -> (channel order, value scaling, default preprocessing)
_FAMILY_INPUT = {
    "yolov8": ("rgb", "unit", "letterbox"),
    "yolov8-seg": ("rgb", "unit", "letterbox"),
    "yolov5": ("rgb", "unit", "letterbox"),
    "yolox": ("bgr", "raw", "letterbox_topleft"),
    "nanodet": ("bgr", "meanstd", "stretch"),
    "nanodet-plus": ("bgr", "meanstd", "stretch"),
}
# Anchor-centre offset (in strides) of each NanoDet generation: the legacy GFL head puts the
# centre in the middle of a cell, NanoDet-Plus at its top-left corner.
_NANODET_OFFSET = {"nanodet": 0.5, "nanodet-plus": 0.0}
# NanoDet's ImageNet mean / std in BGR order (its config's ``normalize``), 0..255 units.
_NANODET_MEAN = np.array([103.53, 116.28, 123.675], dtype=np.float32)
_NANODET_STD = np.array([57.375, 57.12, 58.395], dtype=np.float32)


class LayoutError(ValueError):
    """The model's inputs/outputs match no known detector layout."""


@dataclass(frozen=True)
class ModelLayout:
    """What :func:`recognise_layout` found in a model.

    family : ``"yolov8"``, ``"yolov8-seg"``, ``"yolov5"``, ``"yolox"``, ``"nanodet"`` or
        ``"nanodet-plus"``.
    input_name : name of the image input.
    input_size : ``(H, W)`` of the image input, pixels.
    num_classes : classes the head predicts (80 for COCO).
    outputs : output names in the order the decoder wants them (head first; for
        ``yolov8-seg`` head then prototypes; for ``nanodet`` class outputs then box outputs,
        both ordered by stride).
    strides : FPN strides of the anchor points.
    num_masks : mask coefficients per box (segmentation only).
    reg_max : NanoDet distribution bins - 1.
    """

    family: str
    input_name: str
    input_size: tuple[int, int]
    num_classes: int
    outputs: tuple[str, ...]
    strides: tuple[int, ...] = STRIDES
    num_masks: int = 0
    reg_max: int = 0


def _describe(inputs, outputs) -> str:
    fmt = lambda items: ", ".join(f"{n} {list(s)}" for n, s in items) or "none"  # noqa: E731
    return f"inputs: {fmt(inputs)}; outputs: {fmt(outputs)}"


def recognise_layout(
    inputs: list[tuple[str, tuple[int, ...]]],
    outputs: list[tuple[str, tuple[int, ...]]],
    reg_max: int = 7,
    where: str = "model",
) -> ModelLayout:
    """Name the detector family from the shapes of a model's inputs and outputs.

    Parameters
    ----------
    inputs : ``(name, shape)`` of each graph input; one ``[1, 3, H, W]`` image.
    outputs : ``(name, shape)`` of each output, with integer dims.
    reg_max : NanoDet's distribution size (box outputs have ``4 (reg_max + 1)`` channels).
    where : the model's file, for error messages.

    Rules (``A = sum_s (H/s)(W/s)`` anchor points of strides 8/16/32):

    * one ``[1, C, A]`` output, ``C > 4``: YOLOv8 detection, ``nc = C - 4``;
    * ``[1, C, A]`` plus ``[1, nm, H/4, W/4]``: YOLOv8-seg, ``nc = C - 4 - nm``;
    * one ``[1, A, C]`` output: YOLOX (raw grid outputs), ``nc = C - 5``;
    * one ``[1, 3A, C]`` output: YOLOv5 (three anchors per cell), ``nc = C - 5``;
    * ``2L`` outputs ``[1, N_s, nc]`` and ``[1, N_s, 4 (reg_max + 1)]`` whose ``N_s`` are the
      cells of ``L`` strides: NanoDet (legacy GFL head, e.g. NanoDet-m);
    * one ``[1, A_4, nc + 4 (reg_max + 1)]`` output, ``A_4`` the anchor points of strides
      8/16/32/64: NanoDet-Plus (class scores and distributions concatenated).

    Raises
    ------
    LayoutError naming the model and every input and output shape found.
    """
    found = _describe(inputs, outputs)
    if len(inputs) != 1 or len(inputs[0][1]) != 4 or inputs[0][1][1] != 3:
        raise LayoutError(f"{where}: expected one image input [1, 3, H, W]; {found}")
    name, shape = inputs[0]
    H, W = int(shape[2]), int(shape[3])
    A = anchor_count((H, W))
    shapes = [tuple(int(d) for d in s) for _, s in outputs]
    names = [n for n, _ in outputs]
    if len(outputs) == 1 and len(shapes[0]) == 3 and shapes[0][0] == 1:
        _, d1, d2 = shapes[0]
        if d2 == A and d1 > 4:
            return ModelLayout("yolov8", name, (H, W), d1 - 4, (names[0],))
        if d1 == A and d2 > 5:
            return ModelLayout("yolox", name, (H, W), d2 - 5, (names[0],))
        if d1 == 3 * A and d2 > 5:
            return ModelLayout("yolov5", name, (H, W), d2 - 5, (names[0],))
        plus = (8, 16, 32, 64)
        if d1 == anchor_count((H, W), plus) and d2 > 4 * (reg_max + 1):
            return ModelLayout(
                "nanodet-plus", name, (H, W), d2 - 4 * (reg_max + 1), (names[0],), strides=plus, reg_max=reg_max
            )
    if len(outputs) == 2:
        r3 = [i for i, s in enumerate(shapes) if len(s) == 3]
        r4 = [i for i, s in enumerate(shapes) if len(s) == 4]
        if len(r3) == 1 and len(r4) == 1:
            head, proto = shapes[r3[0]], shapes[r4[0]]
            nm = proto[1]
            if head[2] == A and proto[2] * 4 == H and proto[3] * 4 == W and head[1] > 4 + nm:
                return ModelLayout(
                    "yolov8-seg", name, (H, W), head[1] - 4 - nm, (names[r3[0]], names[r4[0]]), num_masks=nm
                )
    if len(outputs) >= 2 and len(outputs) % 2 == 0 and all(len(s) == 3 and s[0] == 1 for s in shapes):
        reg_ch = 4 * (reg_max + 1)
        cells = {-(-H // s) * -(-W // s): s for s in (8, 16, 32, 64, 128)}
        cls_out, reg_out = {}, {}
        for n, s in zip(names, shapes):
            stride = cells.get(s[1])
            if stride is None:
                break
            (reg_out if s[2] == reg_ch else cls_out)[stride] = (n, s[2])
        else:
            ncs = {c for _, c in cls_out.values()}
            paired = len(cls_out) + len(reg_out) == len(outputs) and sorted(cls_out) == sorted(reg_out)
            if cls_out and paired and len(ncs) == 1:
                strides = tuple(sorted(cls_out))
                return ModelLayout(
                    "nanodet", name, (H, W), ncs.pop(),
                    tuple(cls_out[s][0] for s in strides) + tuple(reg_out[s][0] for s in strides),
                    strides=strides, reg_max=reg_max,
                )
    raise LayoutError(
        f"{where}: unknown detector layout ({found}). Known: YOLOv8/YOLO11 [1, 4+nc, {A}] "
        f"(+ prototypes [1, 32, {H // 4}, {W // 4}] for -seg), YOLOv5 [1, {3 * A}, 5+nc], "
        f"YOLOX [1, {A}, 5+nc], NanoDet per-stride [1, N_s, nc] + [1, N_s, {4 * (reg_max + 1)}], "
        f"NanoDet-Plus [1, {anchor_count((H, W), (8, 16, 32, 64))}, nc+{4 * (reg_max + 1)}]"
    )


class OnnxDetector:
    """A COCO detector from an ONNX file, any layout :func:`recognise_layout` knows.

    Parameters
    ----------
    path : the ``.onnx`` file.
    config : thresholds, NMS kind, preprocessing; defaults when None.

    Examples
    --------
    >>> det = OnnxDetector("../shared/data/models/yolov8n_int8_640.onnx")  # doctest: +SKIP
    >>> det.detect(frame).names                                              # doctest: +SKIP
    ['person', 'person', 'tv', ...]
    """

    def __init__(self, path: str | Path, config: DetectionConfig | None = None) -> None:
        import onnxruntime as ort

        self.path = Path(path)
        self.config = config or DetectionConfig()
        if not self.path.is_file():
            raise FileNotFoundError(f"{self.path}: ONNX model not found")
        opts = ort.SessionOptions()
        opts.log_severity_level = 3  # old exports list initialisers as inputs: ort warns per tensor
        if self.config.num_threads > 0:
            opts.intra_op_num_threads = self.config.num_threads
        # No spin-waiting of the intra-op threads between operators: the detector runs beside ORB and
        # tracking (System.prepare), and spinning burnt the core they need (walking_xyz `full`, 150
        # frames: process CPU 30 s -> 20 s, docs/speed.md); same detections.
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            self.session = ort.InferenceSession(str(self.path), opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types
            raise ValueError(f"{self.path}: onnxruntime cannot load the model ({exc})") from exc
        self.layout = self._recognise()
        order, scale, pre = _FAMILY_INPUT[self.layout.family]
        self.channel_order, self.value_scale = order, scale
        self.preprocess_kind = pre if self.config.preprocess == "auto" else self.config.preprocess
        self._allowed = class_ids_of(self.config.classes) if self.config.classes else None
        if self._allowed is not None and self._allowed.max() >= self.layout.num_classes:
            raise ValueError(f"{self.path}: class filter {self.config.classes} beyond the model's {self.layout.num_classes} classes")
        self.source = f"onnx:{self.path.stem}"

    # -- layout -----------------------------------------------------------------------------
    def _recognise(self) -> ModelLayout:
        ins = [(i.name, tuple(i.shape)) for i in self.session.get_inputs()]
        outs = [(o.name, tuple(o.shape)) for o in self.session.get_outputs()]
        where = str(self.path)
        if len(ins) != 1 or len(ins[0][1]) != 4:
            raise LayoutError(f"{where}: expected one image input [1, 3, H, W]; {_describe(ins, outs)}")
        name, shape = ins[0]
        dynamic_in = not all(isinstance(d, int) for d in shape)  # e.g. a symbolic batch or size
        H = shape[2] if isinstance(shape[2], int) else self.config.input_size[0]
        W = shape[3] if isinstance(shape[3], int) else self.config.input_size[1]
        ins = [(name, (1, 3, H, W))]
        if dynamic_in or not all(isinstance(d, int) for _, s in outs for d in s):
            # Symbolic dims: run once on a blank image to learn the concrete output shapes.
            res = self.session.run(None, {name: np.zeros((1, 3, H, W), np.float32)})
            outs = [(n, r.shape) for (n, _), r in zip(outs, res)]
        return recognise_layout(ins, outs, reg_max=self.config.nanodet_reg_max, where=where)

    # -- pipeline ---------------------------------------------------------------------------
    def preprocess(self, rgb: np.ndarray):
        """``(1, 3, H_in, W_in)`` float32 input tensor and the image-to-input transform."""
        img, tf = fit_image(rgb, self.layout.input_size, self.preprocess_kind)
        if self.channel_order == "bgr":
            img = img[:, :, ::-1]
        x = np.empty((1, 3, *img.shape[:2]), dtype=np.float32)
        for ch in range(3):  # channel planes: contiguous writes, no transposed copy
            plane = x[0, ch]
            plane[...] = img[:, :, ch]
            if self.value_scale == "unit":
                plane *= np.float32(1.0 / 255.0)
            elif self.value_scale == "meanstd":
                plane -= _NANODET_MEAN[ch]
                plane *= np.float32(1.0 / _NANODET_STD[ch])
        return x, tf

    def infer(self, tensor: np.ndarray) -> list[np.ndarray]:
        """Raw outputs in the order of ``layout.outputs``."""
        return self.session.run(list(self.layout.outputs), {self.layout.input_name: tensor})

    def decode(self, outputs: list[np.ndarray]) -> Candidates:
        """Candidate boxes (network-input pixels) above the score threshold."""
        L, c = self.layout, self.config
        thr = c.score_threshold
        if L.family in ("yolov8", "yolov8-seg"):
            return decode_yolov8(outputs[0], L.num_classes, thr, L.num_masks, self._allowed)
        if L.family == "yolov5":
            return decode_yolov5(outputs[0], L.num_classes, thr, self._allowed)
        if L.family == "yolox":
            return decode_yolox(outputs[0], L.input_size, L.num_classes, thr, self._allowed, L.strides)
        offset = _NANODET_OFFSET[L.family] if c.nanodet_center_offset is None else c.nanodet_center_offset
        if L.family == "nanodet-plus":  # one tensor: split it into levels and columns
            ends = np.cumsum([-(-L.input_size[0] // s) * -(-L.input_size[1] // s) for s in L.strides])
            starts = np.concatenate([[0], ends[:-1]])
            o, nc = outputs[0], L.num_classes
            cls = [o[:, a:b, :nc] for a, b in zip(starts, ends)]
            reg = [o[:, a:b, nc:] for a, b in zip(starts, ends)]
            return decode_nanodet(cls, reg, L.strides, L.input_size, thr, L.reg_max, offset, self._allowed)
        k = len(L.strides)
        return decode_nanodet(
            outputs[:k], outputs[k:], L.strides, L.input_size, thr, L.reg_max, offset, self._allowed
        )

    def postprocess(self, outputs: list[np.ndarray], transform) -> Detections:
        """Decode, suppress, map to image pixels and build masks from raw ``outputs``.

        ``transform`` is the :class:`~.preprocess.InputTransform` of :meth:`preprocess`.
        Run the network once and call this with different configs (see :meth:`with_config`)
        to compare thresholds or NMS kinds without re-running inference.
        """
        c = self.config
        cand = self.decode(outputs)
        finite = np.isfinite(cand.boxes).all(axis=1) & np.isfinite(cand.scores)
        if cand.coeffs is not None:
            finite &= np.isfinite(cand.coeffs).all(axis=1)
        if not finite.all():  # a broken or mis-quantised model: such rows are not detections
            cand = cand.select(finite)
        keep, scores = suppress(
            cand.boxes, cand.scores, cand.class_ids, c.nms, c.nms_iou, c.soft_nms_sigma,
            c.score_threshold, c.class_agnostic, c.max_detections,
        )
        cand = cand.select(keep)
        boxes = transform.to_image(cand.boxes)
        masks = None
        if self.layout.family == "yolov8-seg":
            thr = float(np.clip(c.mask_threshold, 1e-6, 1 - 1e-6))
            masks = decode_masks(cand.coeffs, outputs[1], boxes, transform, thr)
        return Detections(boxes, scores, cand.class_ids, transform.image_size, masks=masks, source=self.source)

    def detect_image(self, rgb: np.ndarray) -> Detections:
        """Detect in an ``(H, W, 3)`` uint8 RGB image."""
        t0 = time.perf_counter()
        tensor, tf = self.preprocess(rgb)
        t1 = time.perf_counter()
        outputs = self.infer(tensor)
        t2 = time.perf_counter()
        det = self.postprocess(outputs, tf)
        t3 = time.perf_counter()
        det.timings_ms = {"preprocess": (t1 - t0) * 1e3, "inference": (t2 - t1) * 1e3, "decode": (t3 - t2) * 1e3}
        return det

    def with_config(self, config: DetectionConfig) -> "OnnxDetector":
        """A detector sharing this one's onnxruntime session, with other thresholds / NMS.

        The model's layout does not change, so ``config.nanodet_reg_max`` and
        ``config.input_size`` must be those this detector was built with.
        """
        other = object.__new__(OnnxDetector)
        other.__dict__.update(self.__dict__)
        other.config = config
        other.preprocess_kind = (
            _FAMILY_INPUT[self.layout.family][2] if config.preprocess == "auto" else config.preprocess
        )
        other._allowed = class_ids_of(config.classes) if config.classes else None
        return other

    def detect(self, frame: Frame) -> Detections:
        """Detect in ``frame.rgb`` (the :class:`Detector` contract)."""
        return self.detect_image(frame.rgb)

    def __repr__(self) -> str:
        L = self.layout
        return f"OnnxDetector({self.path.name}: {L.family}, input {L.input_size}, {L.num_classes} classes)"
