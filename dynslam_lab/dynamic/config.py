"""Parameters of dynamic-feature screening: one frozen dataclass tree.

Each stage keeps its own parameter dataclass beside its algorithm (unit, default and source
paper on every field); :class:`ScreeningConfig` gathers them, plus the class motion priors of
the detection stage and the stage lists of the named filters. Change a value with
``dataclasses.replace`` (what a notebook slider does) or from TOML::

    [screening.depth_ransac]
    var_threshold = 0.43
    [screening.multiview]
    reprojection_px = 4.0
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from ..detection.config import MotionPriorConfig
from .depth_noise import DepthNoiseConfig
from .depth_ransac import DepthRansacConfig
from .epipolar import EpipolarConfig, LkConfig
from .flow import FlowConfig
from .motion_probability import RestorationConfig
from .multiframe import MultiFrameConfig
from .multiview import MultiViewConfig
from .reference_pose import ReferencePoseConfig
from .regions import RegionConfig
from .semantic import SemanticConfig
from .temporal import TemporalConfig

__all__ = ["ScreeningConfig", "STAGES", "FILTER_PRESETS", "PRESET_OVERRIDES"]

#: Every stage a screener can chain, in the order they run.
STAGES = ("semantic", "depth_ransac", "epipolar", "multiview", "multiframe", "flow", "temporal", "regions",
          "level_rule", "restoration")

#: The stages that judge keypoints against a reference pose and earlier frames (no detector needed).
GEOMETRY_STAGES = ("epipolar", "multiview", "multiframe", "temporal", "regions")

#: Named filters (``dynslam run --filters NAME``) -> stages. ``oracle`` is handled apart.
FILTER_PRESETS: dict[str, tuple[str, ...]] = {
    "none": (),
    "semantic": ("semantic",),  # YOLO-SLAM "D", Chang et al. 2021 "only with YOLACT"
    "depth_ransac": ("semantic", "depth_ransac"),  # YOLO-SLAM "D + G" (boxes + depth-RANSAC)
    # Chang et al. 2021 "only with multi-view geometry", extended: DynaSLAM's multi-frame test, temporal
    # consistency and region growing (docs/robustness.md)
    "geometry": GEOMETRY_STAGES,
    "full": ("semantic", "depth_ransac", *GEOMETRY_STAGES[:3], "flow", *GEOMETRY_STAGES[3:], "restoration"),
}

#: Parameters a named filter sets in the configuration it is built with (``build_screener``), in
#: the form of ``dynslam_lab.config.with_overrides``. ``depth_ransac`` is YOLO-SLAM's "D + G", which
#: works on person boxes: masks of the detector are not used. The screener's ``config`` shows the
#: values it runs with.
PRESET_OVERRIDES: dict[str, dict] = {
    "depth_ransac": {"semantic": {"use_masks": False}},
}


@dataclass(frozen=True)
class ScreeningConfig:
    """All screening parameters (all four papers)."""

    semantic: SemanticConfig = field(default_factory=SemanticConfig)  # semantic prior (all seeds)
    depth_ransac: DepthRansacConfig = field(default_factory=DepthRansacConfig)  # YOLO-SLAM (Wu et al. 2022)
    lk: LkConfig = field(default_factory=LkConfig)  # LK matches with the previous frame (Ge et al. 2024)
    epipolar: EpipolarConfig = field(default_factory=EpipolarConfig)  # epipolar check (Zhang et al. 2023, Chang et al. 2021 and Ge et al. 2024)
    multiview: MultiViewConfig = field(default_factory=MultiViewConfig)  # RGB-D multi-view check (Chang et al. 2021)
    flow: FlowConfig = field(default_factory=FlowConfig)  # adaptive-threshold Farneback flow (Chang et al. 2021)
    restoration: RestorationConfig = field(default_factory=RestorationConfig)  # motion probability (Ge et al. 2024)
    reference: ReferencePoseConfig = field(default_factory=ReferencePoseConfig)  # reference pose on the map (DynaSLAM's low-cost tracking)
    multiframe: MultiFrameConfig = field(default_factory=MultiFrameConfig)  # free-space test vs earlier frames (DynaSLAM, Bescos et al. 2018)
    temporal: TemporalConfig = field(default_factory=TemporalConfig)  # map points seen moving, the previous region as a prior (ours)
    regions: RegionConfig = field(default_factory=RegionConfig)  # region growing from the evidence over depth (ours, after DynaSLAM)
    depth_noise: DepthNoiseConfig = field(default_factory=DepthNoiseConfig)  # the depth noise measured, the depth margins follow it (ours)
    priors: MotionPriorConfig = field(default_factory=MotionPriorConfig)  # class tables (detection.coco)
    # Stages of the "full" filter; add "level_rule" for Zhang et al.'s level rule. Default: see FILTER_PRESETS.
    full_stages: tuple[str, ...] = FILTER_PRESETS["full"]
    # How epipolar and multi-view verdicts combine: "any" (either test), "both" (both must flag), or "auto":
    # "both" when the semantic stage runs (masks already hold the people; each test alone flags 1-2.5% of
    # static keypoints on synthetic walking, mostly at people's occlusion edges, together 0.3%), else "any"
    # (geometry is the only signal). Ours, "auto".
    geometric_vote: str = "auto"
    # Geometric flags within this distance of an a-priori dynamic mask/box are ignored when the semantic stage
    # runs: there the mask decides, and the keypoint patch straddles a moving edge (px). Ours, 10; 0 = off.
    geometry_mask_margin_px: int = 10
    # The perfect masks (--filters oracle) also judge dynamic the keypoints within this distance of a moving
    # instance: a corner whose FAST circle (radius 3 px, Rosten and Drummond 2006) reaches across a moving
    # outline moves with the mover. In image pixels at every resolution (a corner's support is), so not scaled
    # by for_width. Ours, measured (docs/robustness.md "Perfect masks and the corners on their outlines"); 0 = the
    # pixel alone.
    oracle_margin_px: int = 4
    # With masks from the detector, also run depth-RANSAC inside them (else only mask-less boxes). Ours, False.
    depth_ransac_with_masks: bool = False
    # The image width (px) the extents above are set for: on images of another width W, the parameters that are
    # distances in the image (how far a mover gets in a frame, the grid's cell, the margins), not measurement noise,
    # scale by W / reference_width (for_width; docs/robustness.md "Another resolution"). Ours, 640 (TUM RGB-D, Bonn,
    # our renderer: unchanged there); 0 = never scale.
    reference_width: int = 640

    def __post_init__(self) -> None:
        if self.geometric_vote not in ("any", "both", "auto"):
            raise ValueError(f"ScreeningConfig.geometric_vote must be 'any', 'both' or 'auto', got {self.geometric_vote!r}")
        if self.geometry_mask_margin_px < 0:
            raise ValueError(f"ScreeningConfig.geometry_mask_margin_px must be >= 0, got {self.geometry_mask_margin_px}")
        if self.oracle_margin_px < 0:
            raise ValueError(f"ScreeningConfig.oracle_margin_px must be >= 0 px (0 = the pixel alone), got {self.oracle_margin_px}")
        if self.reference_width < 0:
            raise ValueError(f"ScreeningConfig.reference_width must be >= 0 px (0 = never scale), got {self.reference_width}")
        unknown = [s for s in self.full_stages if s not in STAGES]
        if unknown:
            raise ValueError(f"ScreeningConfig.full_stages: unknown stages {unknown}; known: {list(STAGES)}")

    def for_width(self, width: int) -> "ScreeningConfig":
        """This configuration for images ``width`` px wide. With ``s = width / reference_width``, the parameters that
        are distances in the image scale by ``s``: the reduced grid's ``multiframe.factor`` (a cell covers the same
        angle: 160x120 cells at 640x480, 320x240 and 960x720 alike) and its ``min_filter_px``, the reference pose's
        ``search_radius_px`` and ``gate_px`` (a mover walking 1 m/s at 2 m moves ~9 px a frame at 640 px and ~4 px at
        320: beyond the 6 px gate at 640, inside it at 320, where it pulls the pose), the epipolar ``border_px`` and
        ``geometry_mask_margin_px``. Thresholds on residuals stay in pixels: a keypoint's position is as noisy in
        pixels at every size. The result's ``reference_width`` is ``width`` (what ``summary.json`` records: run again
        from it, nothing is scaled twice). The same object at the reference width, or with ``reference_width`` 0."""
        if not self.reference_width or int(width) == self.reference_width:
            return self
        s = int(width) / self.reference_width
        mf, ref, ep = self.multiframe, self.reference, self.epipolar
        return replace(
            self,
            multiframe=replace(mf, factor=max(1, round(mf.factor * s)), min_filter_px=max(0, round(mf.min_filter_px * s))),
            reference=replace(ref, search_radius_px=ref.search_radius_px * s, gate_px=ref.gate_px * s),
            epipolar=replace(ep, border_px=ep.border_px * s),
            geometry_mask_margin_px=max(0, round(self.geometry_mask_margin_px * s)),
            reference_width=int(width),  # the values are now those of this width: scaling again changes nothing
        )

    def for_depth_noise(self, scale: float) -> "ScreeningConfig":
        """This configuration for a depth sensor ``scale`` times noisier than the Kinect model the margins were set
        for (:class:`~dynslam_lab.dynamic.depth_noise.DepthNoiseMeter` measures it): the depth margins that grow
        with the sensor's noise, ``depth_quadratic`` of the multi-frame free-space test and of the multi-view depth
        test, are multiplied by ``scale``, and the reference pose's ``room_depth_noise`` (step 3c: the room's depth
        alignment weighs and judges its distances against that noise) is ``scale``; the floors ``depth_m`` (a motion's
        size, not the noise) stay. The result measures nothing more (``depth_noise.frames`` 0: what ``summary.json``
        records; run again from it, nothing is scaled twice). The same object at ``scale`` 1 or when measuring is off."""
        if scale == 1.0 or self.depth_noise.frames == 0:
            return self
        if not scale > 0:
            raise ValueError(f"ScreeningConfig.for_depth_noise: scale must be > 0, got {scale}")
        mf, mv = self.multiframe, self.multiview
        return replace(
            self,
            multiframe=replace(mf, depth_quadratic=mf.depth_quadratic * scale),
            multiview=replace(mv, depth_quadratic=mv.depth_quadratic * scale),
            reference=replace(self.reference, room_depth_noise=self.reference.room_depth_noise * scale),
            depth_noise=replace(self.depth_noise, frames=0),
        )

