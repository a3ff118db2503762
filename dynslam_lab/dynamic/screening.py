"""The screener: the dynamic-feature stages chained by configuration.

``build_screener(filters, config)`` returns a :class:`Screener` whose ``screen(frame, uv,
detections, context)`` fills one :class:`~dynslam_lab.dynamic.table.KeypointTable` per frame
(contract in ``docs/architecture.md``). ``filters`` is a named preset or a comma-separated stage list:

=================  =====================================================================
``none``           no screening (``build_screener`` returns None)
``semantic``       semantic prior: keypoints on a-priori dynamic detections (YOLO-SLAM "D")
``depth_ransac``   person boxes + depth-RANSAC (YOLO-SLAM "D + G", Wu et al. 2022)
``geometry``       no detector: epipolar + multi-view against the previous frame (Chang et al.
                   2021 "multi-view only"), the free-space test against several earlier frames
                   (DynaSLAM, Bescos et al. 2018), all judged against the reference pose of the
                   map, then temporal consistency and region growing (ours)
``full``           semantic (masks), depth-RANSAC for box-only detections, the geometry stages,
                   adaptive flow, motion-probability restoration
``oracle``         the synthetic renderer's truly moving instances (perfect masks)
``a,b,c``          any of :data:`~dynslam_lab.dynamic.config.STAGES`
=================  =====================================================================

Each stage is a function of :mod:`.stages` that adds its column; the screener runs the stages of
its filter in the order of ``STAGES`` and combines the columns (per keypoint):

* ``prior`` = on an a-priori dynamic detection (``semantic``), narrowed to the depth-RANSAC
  consensus set inside boxes when ``depth_ransac`` runs;
* ``geometric`` = ``epipolar`` and ``multiview`` when the semantic stage runs, either of them
  otherwise (``ScreeningConfig.geometric_vote="auto"``; ``"both"`` / ``"any"`` force one rule),
  from LK pairs with the previous frame; when the semantic stage runs, flags within
  ``geometry_mask_margin_px`` of an a-priori dynamic detection are dropped; a test that cannot
  run (too few pairs, camera at rest for F) does not vote;
* ``evidence`` = ``geometric`` or ``flow`` (inside a human-driven flow region) or ``multiframe``
  (in space an earlier frame saw through) or ``temporal`` (matched to a map point seen moving)
  or ``regions`` (inside a region grown from that evidence);
* ``dynamic = prior or evidence`` (with ``level_rule``: ``prior`` is replaced by "high/medium
  level", Zhang et al.'s rule);
* ``restoration`` gives back prior-only keypoints while the static ratio is below ``delta_1``.

The geometric stages judge the frame against a **reference pose** (:mod:`.reference_pose`): the
SLAM system's prediction refined on map points, handed over in a
:class:`~dynslam_lab.dynamic.context.ScreeningContext`; without one (frames screened by hand)
they estimate the camera motion from the previous frame by RANSAC, as the papers do. The
screener keeps the last frames (:mod:`.history`) and the map points seen moving between calls;
``reset()`` forgets them (the first frame after a reset has no geometric verdict).
"""

from __future__ import annotations

import time

import dataclasses

import numpy as np

from ..geometry.se3 import se3_inv, transform_points
from .config import FILTER_PRESETS, PRESET_OVERRIDES, STAGES, ScreeningConfig
from .context import ScreeningContext
from .depth_noise import DepthNoiseMeter
from .history import FarFrames, FrameHistory
from .oracle import OracleScreener
from .stages import DETECTION_STAGES, STAGE_FUNCTIONS, FrameWork, ScreenerMemory, combine, finish, restoration_stage
from .table import KeypointTable, check_uv
from .reference_pose import ReferencePose
from .regions import splat
from .temporal import MovingMapPoints

__all__ = ["Screener", "build_screener", "parse_filters", "preset_config", "FILTERS"]

#: The named filters.
FILTERS = (*FILTER_PRESETS, "oracle")

#: Stages that use the SLAM system's context (reference pose, earlier frames' poses).
CONTEXT_STAGES = ("epipolar", "multiview", "multiframe", "temporal", "regions", "flow")


def parse_filters(filters: str, config: ScreeningConfig | None = None) -> tuple[str, ...]:
    """Stage list of a filter name or comma-separated stage list (``oracle`` -> ``("oracle",)``)."""
    config = config or ScreeningConfig()
    name = str(filters).strip().lower()
    if name == "oracle":
        return ("oracle",)
    if name == "full":
        return tuple(s for s in STAGES if s in config.full_stages)  # run order
    if name in FILTER_PRESETS:
        return FILTER_PRESETS[name]
    parts = tuple(p.strip() for p in name.split(",") if p.strip())
    bad = [p for p in parts if p not in STAGES]
    if not parts or bad:
        raise ValueError(
            f"--filters {filters!r}: unknown filter or stage {bad or [filters]}; use one of {list(FILTERS)} "
            f"or a comma-separated list of stages {list(STAGES)}"
        )
    return tuple(s for s in STAGES if s in parts)  # run order


def _apply(cfg, overrides: dict):
    changes = {}
    for key, value in overrides.items():
        current = getattr(cfg, key)
        changes[key] = _apply(current, value) if isinstance(value, dict) else value
    return dataclasses.replace(cfg, **changes)


def preset_config(filters: str, config: ScreeningConfig | None = None) -> ScreeningConfig:
    """The configuration a named filter runs with: ``config`` with the filter's
    :data:`~dynslam_lab.dynamic.config.PRESET_OVERRIDES` applied (unchanged for other filters)."""
    config = config or ScreeningConfig()
    overrides = PRESET_OVERRIDES.get(str(filters).strip().lower())
    return _apply(config, overrides) if overrides else config


def stale_map_points(ref: ReferencePose, map_ids: np.ndarray) -> np.ndarray:
    """Ids of the map points whose stored positions a frame's reference pose ``ref`` found stale: those matched
    on the surfaces it found moving against the room, when the room decided (step 3b's room test, ``ref.room``,
    or step 3c, the room's depth, ``ref.room_depth``); ``map_ids`` are the context's map point ids, which
    ``ref.map_index`` indexes. Empty otherwise: a surface that only moved against the rest of the matches
    (step 3b's leave-one-out) is not culled (every such surface culled: ``carried_xyz`` 0.09 -> 0.45 m), nor
    are points the room did not judge. Culling step 3c's too: ``random_204`` 0.260 -> 0.035 m (the person
    mapped at rest stayed in the map, and tracking followed its stale points)."""
    if not (ref.room or ref.room_depth):
        return np.zeros(0, np.int64)
    moved = ref.surface_moved & (ref.map_index >= 0)
    return np.unique(np.asarray(map_ids)[ref.map_index[moved]]) if moved.any() else np.zeros(0, np.int64)


class Screener:
    """Screening stages chained in run order, with the memory of earlier frames.

    Parameters
    ----------
    stages : stage names (see :data:`dynslam_lab.dynamic.config.STAGES`).
    config : all parameters (``Screener.config`` is what it runs with on images of ``config.reference_width``;
        :meth:`config_for` on others).
    name : label for tables and summaries (the filter name).
    """

    def __init__(self, stages: tuple[str, ...], config: ScreeningConfig | None = None, name: str | None = None):
        self.config = config or ScreeningConfig()
        bad = [s for s in stages if s not in STAGES]
        if bad:
            raise ValueError(f"Screener: unknown stages {bad}; known: {list(STAGES)}")
        self.stages = tuple(s for s in STAGES if s in stages)
        self.name = name or ",".join(self.stages)
        cfg = self.config
        self.memory = ScreenerMemory(FrameHistory(cfg.multiframe.history_length + 1),
                                     MovingMapPoints(cfg.temporal.max_moving_points), cfg.depth_ransac.seed,
                                     FarFrames(cfg.multiframe.far_every, cfg.multiframe.far_count))
        #: the reference pose (:class:`~dynslam_lab.dynamic.reference_pose.ReferencePose`) the last frame was
        #: judged against, or None
        self.last_reference = None
        #: the last frame's reduced-grid evidence (``FrameWork.grid_evidence``; ``plots.draw_grid`` shows it)
        self.last_grid: dict[str, np.ndarray] = {}
        #: ids of map points on surfaces the last frame found moving against the room (reference pose, step 3b,
        #: a surface holding most matches): their stored positions are stale, the SLAM system removes them
        self.moved_map_ids = np.zeros(0, np.int64)
        #: the depth noise of the first frames, against the Kinect model (``depth_noise.ratio``; module depth_noise)
        self.depth_noise = DepthNoiseMeter()
        self._run_config: tuple[int, float, ScreeningConfig, ScreeningConfig] | None = None  # (width, scale, config, result)

    def config_for(self, width: int) -> ScreeningConfig:
        """The configuration the stages run with on images ``width`` px wide (:meth:`ScreeningConfig.for_width`:
        the pixel extents scaled to the image; ``config`` itself at its reference width) from a depth sensor as noisy
        as measured (:meth:`ScreeningConfig.for_depth_noise`; unchanged at the Kinect's noise). Follows ``config``
        when it is replaced (a notebook's slider)."""
        scale = self.depth_noise.scale(self.config.depth_noise)
        cached = self._run_config
        if cached is None or cached[0] != int(width) or cached[1] != scale or cached[2] is not self.config:
            result = self.config.for_width(int(width)).for_depth_noise(scale)
            cached = self._run_config = (int(width), scale, self.config, result)
        return cached[3]

    def __repr__(self) -> str:
        return f"Screener({self.name!r}, stages={self.stages})"

    @property
    def uses_context(self) -> bool:
        """Whether the SLAM system should build a :class:`ScreeningContext` for each frame."""
        return any(s in CONTEXT_STAGES for s in self.stages)

    @property
    def history_length(self) -> int:
        """How many earlier frames the screener keeps (the poses the context should carry)."""
        return self.memory.history.length

    def reset(self) -> None:
        """Forget the earlier frames, the map points seen moving (and restart the random stream)."""
        self.memory.reset()

    def screen(self, frame, uv: np.ndarray, detections=None, context: ScreeningContext | None = None) -> KeypointTable:
        """Judge every keypoint of ``frame``.

        Parameters
        ----------
        frame : :class:`~dynslam_lab.datasets.frame.Frame` (rgb, depth in metres, camera).
        uv : ``(N, 2)`` keypoint pixels.
        detections : :class:`~dynslam_lab.detection.detections.Detections`; required by the
            ``semantic`` and ``depth_ransac`` stages (an empty one when nothing was detected).
        context : what the SLAM system knows before tracking the frame (prediction, poses of the
            earlier frames, local map), or None (frames screened by hand).

        Returns
        -------
        KeypointTable with one column per stage that ran and the final ``dynamic``.
        """
        needs = [s for s in self.stages if s in DETECTION_STAGES]
        if needs and detections is None:
            raise ValueError(
                f"screening stages {needs} judge keypoints from detections, but none were given for frame "
                f"{frame.index}; pass the detector's output (an empty Detections when nothing was found), "
                "or use --filters geometry, which needs no detector"
            )
        uv = check_uv(uv)
        t0 = time.perf_counter()
        mem = self.memory
        last = mem.history.last
        if last is not None and last.gray.shape != frame.gray.shape:
            self.reset()  # a new image size: the history does not apply
            self.depth_noise.reset()  # nor, perhaps, the camera
        noise_ms = None
        if self.depth_noise.wants(self.config.depth_noise):
            t = time.perf_counter()
            self.depth_noise.add(frame.depth, self.config.depth_noise)
            noise_ms = _ms(t)
        if context is not None:
            correction = mem.history.update_poses(context.poses)
            if correction is not None and np.linalg.norm(correction[:3, 3]) > self.config.multiframe.far_reset_m:
                mem.far.clear()  # a loop closure moved the world: the far frames' poses are stale
        w = FrameWork(frame, uv, detections, context, self.config_for(frame.gray.shape[1]), mem)
        if noise_ms is not None:
            w.timings["depth_noise"] = noise_ms
        if "epipolar" in self.stages or "multiview" in self.stages:
            w.start_pairs()  # LK with the previous frame beside the stages before them
        for name in self.stages:
            fn = STAGE_FUNCTIONS.get(name)
            if fn is not None:
                t = time.perf_counter()
                fn(w)
                w.timings[name] = w.timings.get(name, 0.0) + _ms(t)
            if name == "semantic" and "flow" in self.stages and w.sem.dynamic_detections.any():
                w.start_flow()  # dense flow beside the geometric stages (the flow stage needs a-priori dynamic detections)
        on = set(self.stages)
        combine(w, on)
        if "restoration" in on:
            restoration_stage(w)
        reason, region_mask = finish(w, on, STAGES)
        self._remember(w, context)
        w.timings["total"] = _ms(t0)
        return KeypointTable(
            uv=uv, depth=w.z, class_id=w.sem.class_id, instance=w.sem.instance, motion_prob=w.sem.motion_prob,
            dynamic=w.dynamic, reason=reason, stages=w.stages, values=w.values, restored=w.restored,
            region_mask=region_mask, timings_ms=w.timings,
        )

    def _release_still(self, w: FrameWork, ref, context: ScreeningContext) -> np.ndarray:
        """Map points seen moving whose keypoints now stand still in the world (``temporal.release_frames``):
        forgotten as moving, returned to be culled from the map (docs/robustness.md, "Points seen moving that
        stand still"). A static point whose stored position was off (made from a depth edge, or while the pose
        was wrong) misses its map point by more than ``reference.inlier_px`` for ever, and was judged moving
        again on every frame; a mover at rest is static while it stands. Empty when off or without a pose."""
        cfg = self.config.temporal
        if cfg.release_frames <= 0 or ref.T_c_w is None or ref.source != "map":
            return np.zeros(0, np.int64)
        k = np.flatnonzero(ref.known_moving & (ref.map_index >= 0) & np.isfinite(w.z) & (w.z > 0))
        ids = context.map_ids[ref.map_index[k]]
        z = w.z[k]
        P_w = transform_points(se3_inv(ref.T_c_w), w.camera.backproject(w.uv_undistorted[k], z))
        tol = cfg.release_tolerance_m + cfg.release_depth_share * z
        return self.memory.moving_points.release_still(ids, P_w, tol, cfg.release_frames, int(w.frame.index))

    def _remember(self, w: FrameWork, context: ScreeningContext | None) -> None:
        """Keep this frame for the next ones; remember the map points matched to dynamic keypoints."""
        mem = self.memory
        ref = w.reference_if_computed
        self.last_reference = ref  # for notebooks and diagnostics: the reference pose of the last frame
        self.last_grid = w.grid_evidence()
        self.moved_map_ids = np.zeros(0, np.int64)
        if ref is not None and context is not None:
            moving = w.stages.get("temporal", np.zeros(w.n, bool)) & ~ref.known_moving & (ref.map_index >= 0)
            if moving.any():
                mem.moving_points.add(context.map_ids[ref.map_index[moving]])
            if self.config.temporal.cull_moved_points:
                self.moved_map_ids = stale_map_points(ref, context.map_ids)
            released = self._release_still(w, ref, context)
            if len(released):
                self.moved_map_ids = np.union1d(self.moved_map_ids, released)
        region = w.grid_region
        if region is None and w.dynamic.any() and "multiframe" in self.stages:
            region = splat(w.uv, w.dynamic, w.config.multiframe.factor, w.small_depth.shape)
        T_w_c = None
        if context is None and self.uses_context:  # no SLAM system: the screener chains its own rough poses
            if ref is not None and ref.T_c_w is not None:
                T_w_c = np.linalg.inv(ref.T_c_w)
            else:
                for past in mem.history:  # a break in the chain: start a new one here
                    past.T_w_c = None
                T_w_c = np.eye(4)
        w.remember(region, T_w_c)


def build_screener(filters: str, config: ScreeningConfig | None = None) -> Screener | OracleScreener | None:
    """The screener of a filter name (``none`` -> None); see the module docstring."""
    config = preset_config(filters, config)
    stages = parse_filters(filters, config)
    if stages == ("oracle",):
        return OracleScreener(config)
    if not stages:
        return None
    return Screener(stages, config, name=str(filters).strip().lower())


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1000.0
