"""Parameters of the detection stage: one frozen dataclass tree.

:class:`DetectionConfig` holds the thresholds of every backend, the kind of non-maximum
suppression, the imperfections of the oracle, and the class motion-prior tables of the
papers. Change a value with ``dataclasses.replace`` (a notebook slider) or from TOML::

    [detection]
    score_threshold = 0.4
    nms = "soft"
    [detection.oracle]
    miss_rate = 0.2
    [detection.priors.asg_probabilities]
    human = 0.8
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .coco import APRIORI_DYNAMIC, ASG_CATEGORY_OF, ASG_PROBABILITIES, DYNAMIC_LEVEL_OF, class_id

__all__ = ["DetectionConfig", "OracleConfig", "MotionPriorConfig", "NMS_KINDS", "PREPROCESS_KINDS"]

NMS_KINDS = ("hard", "soft", "none")
PREPROCESS_KINDS = ("auto", "letterbox", "letterbox_topleft", "stretch")


@dataclass(frozen=True)
class OracleConfig:
    """An imperfect detector built from the synthetic renderer's true instance masks."""

    # Probability that a true instance is not reported (0..1). Default 0.0: perfect recall.
    miss_rate: float = 0.0
    # Standard deviation of the box corner jitter as a fraction of box width/height (0..).
    # Default 0.0. The mask is shifted with the box centre.
    jitter: float = 0.0
    # Expected number of false-positive boxes per frame (Poisson mean). Default 0.0.
    false_positives: float = 0.0
    # COCO class name given to false positives. Default "person" (the class that matters).
    false_positive_class: str = "person"
    # Smallest instance area reported, pixels. Default 20 (a few pixels is no detection).
    min_area: int = 20
    # Seed of the oracle's random generator (one stream per frame index). Default 0.
    seed: int = 0


@dataclass(frozen=True)
class MotionPriorConfig:
    """Which COCO classes may move, after the papers (tables in :mod:`.coco`)."""

    # A-priori dynamic classes, Chang et al. 2021 (Chang et al. 2021) Sec. III-A. Default: their 19.
    apriori_dynamic: tuple[str, ...] = APRIORI_DYNAMIC
    # COCO class -> ASG-SLAM category (Ge et al. 2024 Sec. 2.4, six categories; split is ours).
    asg_category_of: dict[str, str] = field(default_factory=lambda: dict(ASG_CATEGORY_OF))
    # ASG-SLAM category -> prior motion probability in 0..1 (our reading of Fig. 3).
    asg_probabilities: dict[str, float] = field(default_factory=lambda: dict(ASG_PROBABILITIES))
    # COCO class -> "high" | "medium" | "low" dynamic level (Zhang et al. 2023 Sec. 4; split is ours).
    dynamic_level_of: dict[str, str] = field(default_factory=lambda: dict(DYNAMIC_LEVEL_OF))

    def __post_init__(self) -> None:
        for c in self.apriori_dynamic:
            class_id(c)
        for c, p in self.asg_probabilities.items():
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"priors.asg_probabilities.{c}: {p} is outside [0, 1]")
        for c, cat in self.asg_category_of.items():
            if cat not in self.asg_probabilities:
                raise ValueError(f"priors.asg_category_of.{c}: category {cat!r} has no probability in asg_probabilities "
                                 f"({sorted(self.asg_probabilities)})")
        for c, level in self.dynamic_level_of.items():
            if level not in ("high", "medium", "low"):
                raise ValueError(f"priors.dynamic_level_of.{c}: {level!r} is not 'high', 'medium' or 'low'")


@dataclass(frozen=True)
class DetectionConfig:
    """Thresholds and options of every detector backend."""

    # Keep detections with confidence >= this (0..1). Default 0.3 (YOLOX demo uses 0.3,
    # Ultralytics 0.25; the papers do not state theirs).
    score_threshold: float = 0.3
    # Non-maximum suppression: "hard" (Zhang et al. 2023 eq. 5), "soft" (Gaussian-weighted soft-NMS
    # of the improved YOLOv5, Zhang et al. 2023 Sec. 2.2; Bodla et al. 2017) or "none". Default "hard".
    nms: str = "hard"
    # IoU above which hard NMS removes a box (N_t in Zhang et al. 2023 eq. 5). Default 0.45 (YOLOv5).
    nms_iou: float = 0.45
    # Gaussian soft-NMS decay s_i <- s_i exp(-IoU^2 / sigma). Default 0.5 (Bodla et al. 2017).
    soft_nms_sigma: float = 0.5
    # Suppress across classes too (one box per object whatever its class). Default False.
    class_agnostic: bool = False
    # Keep at most this many detections per image. Default 100.
    max_detections: int = 100
    # Report only these COCO class names (empty = all 80). Default () = all.
    classes: tuple[str, ...] = ()
    # Mask probability above which a pixel belongs to an instance (YOLOv8-seg). Default 0.5.
    mask_threshold: float = 0.5
    # Image preprocessing: "auto" (each family's own: letterbox centred for YOLOv5/v8,
    # letterbox at the top-left for YOLOX, stretch for NanoDet / NanoDet-Plus), or force one.
    # Default "auto".
    preprocess: str = "auto"
    # Network input (height, width) for models whose input size is dynamic, pixels.
    # Default (640, 640). Ignored when the model fixes its input size.
    input_size: tuple[int, int] = (640, 640)
    # NanoDet anchor-point offset in strides: centre = (x + offset) * stride. Default None:
    # the family's own, 0.5 for the legacy GFL head (NanoDet-m), 0.0 for NanoDet-Plus.
    nanodet_center_offset: float | None = None
    # NanoDet distribution bins minus one: box outputs have 4 * (reg_max + 1) channels.
    # Default 7 (NanoDet-m: 32 channels).
    nanodet_reg_max: int = 7
    # onnxruntime intra-op threads; 0 = onnxruntime's default (all cores). Default 0.
    num_threads: int = 0
    # Detect every `stride`-th frame (frame index divisible by it); each frame between takes the
    # last detection's boxes and masks grown by `carry_margin_px` per frame since (objects move),
    # as Detect-SLAM (Zhong et al. 2018) and RDS-SLAM (Liu and Miura 2021) run semantics on some
    # frames only. 1 = every frame. Default 1 (docs/speed.md, "Detection stride").
    stride: int = 1
    # Pixels a carried box (and mask) grows per frame since its detection. Default 12.
    carry_margin_px: float = 12.0
    # The oracle backend's imperfections.
    oracle: OracleConfig = field(default_factory=OracleConfig)
    # Class motion-prior tables (Zhang et al. 2023, 003, 004).
    priors: MotionPriorConfig = field(default_factory=MotionPriorConfig)

    def __post_init__(self) -> None:
        if self.nms not in NMS_KINDS:
            raise ValueError(f"detection.nms: {self.nms!r} is not one of {NMS_KINDS}")
        if self.preprocess not in PREPROCESS_KINDS:
            raise ValueError(f"detection.preprocess: {self.preprocess!r} is not one of {PREPROCESS_KINDS}")
        for name in ("score_threshold", "nms_iou", "mask_threshold"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"detection.{name}: {v} is outside [0, 1]")
        if self.soft_nms_sigma <= 0:
            raise ValueError(f"detection.soft_nms_sigma: {self.soft_nms_sigma} must be > 0")
        if self.max_detections < 1:
            raise ValueError(f"detection.max_detections: {self.max_detections} must be >= 1")
        if len(self.input_size) != 2 or min(self.input_size) < 32:
            raise ValueError(f"detection.input_size: {self.input_size} must be (height, width) >= 32")
        o = self.oracle
        if not 0.0 <= o.miss_rate <= 1.0:
            raise ValueError(f"detection.oracle.miss_rate: {o.miss_rate} is outside [0, 1]")
        if o.jitter < 0 or o.false_positives < 0:
            raise ValueError("detection.oracle: jitter and false_positives must be >= 0")
        if o.min_area < 0:
            raise ValueError(f"detection.oracle.min_area: {o.min_area} must be >= 0 pixels")
        if self.nanodet_reg_max < 1:
            raise ValueError(f"detection.nanodet_reg_max: {self.nanodet_reg_max} must be >= 1")
        if self.stride < 1:
            raise ValueError(f"detection.stride: {self.stride} must be >= 1 (1 = detect every frame)")
        if self.carry_margin_px < 0:
            raise ValueError(f"detection.carry_margin_px: {self.carry_margin_px} must be >= 0 pixels")
        if self.num_threads < 0:
            raise ValueError(f"detection.num_threads: {self.num_threads} must be >= 0 (0 = onnxruntime's default)")
        for c in self.classes:
            class_id(c)
        class_id(o.false_positive_class)
