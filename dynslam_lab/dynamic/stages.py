"""The screening stages as functions, each adding its columns to one frame's keypoint table.

A stage reads the frame, the context of the SLAM system and what the earlier stages wrote, and
adds its own column (the keypoints it judges dynamic) and measurements; it changes no other
stage's column or parameters. :class:`~dynslam_lab.dynamic.screening.Screener` runs the stages
of its filter in the order of :data:`~dynslam_lab.dynamic.config.STAGES`, then
:func:`combine` makes the verdict of the columns (the rule is in the module docstring of
:mod:`.screening`), :func:`restoration_stage` may give some back and :func:`finish` names the reason. What several stages share is computed once per frame, on first use, by
:class:`FrameWork`: the LK pyramids and the LK pairs with the previous frame, the reference
pose, the reduced depth grid.

==============  ==================================================  ====================
stage           column (keypoints judged dynamic)                   paper
==============  ==================================================  ====================
semantic        on an a-priori dynamic detection                    all four
depth_ransac    in the consensus depth set of a person box          Wu et al. 2022
epipolar        far from the epipolar line (previous frame)         Zhang 2023, Chang 2021, Ge 2024
multiview       reprojection / depth error (previous frame)         Chang et al. 2021 eq. 2
multiframe      in space an earlier frame saw through               Bescos et al. 2018 (DynaSLAM)
flow            in a human-driven flow region                       Chang et al. 2021 eq. 3
temporal        matched to a map point seen moving                  ours
regions         in a region grown from the evidence                 ours, after DynaSLAM
level_rule      Zhang et al.'s high/medium levels or geometry       Zhang et al. 2023
restoration     given back while the static ratio is low            Ge et al. 2024 eq. 3
==============  ==================================================  ====================
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..geometry.se3 import se3_inv, transform_points
from .config import ScreeningConfig
from .depth_ransac import screen_boxes
from .epipolar import epipolar_check, fundamental_from_pose, track_lk, track_lk_async
from .flow import farneback_flow_async, flow_regions
from .geometric_rule import level_rule_verdict
from .history import FarFrames, FrameHistory, PastFrame, reduce_depth
from .motion_probability import restore_by_motion_probability
from .multiframe import eroded_depth, free_space_test, grid_points, vanished_test
from .multiview import multiview_check
from .reference_pose import ReferencePose, map_reference_pose
from .room_depth import RoomDepth, reference_grid, room_labels, room_points
from .regions import cells_at, depth_continuity, follows_the_mover, grow_regions, on_region, prior_on_fresh_surfaces, splat, supported_regions, surface_segments, whole_surfaces
from .semantic import LEVEL_CODES, SemanticResult, semantic_prior
from .table import depth_at, values_at
from .temporal import MovingMapPoints, warp_region

__all__ = ["FrameWork", "ScreenerMemory", "STAGE_FUNCTIONS", "combine", "restoration_stage", "finish", "DETECTION_STAGES"]

#: Stages that judge keypoints from detections: they need the detector's output.
DETECTION_STAGES = ("semantic", "depth_ransac")


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1000.0


@dataclass
class ScreenerMemory:
    """What a screener keeps between frames: the earlier frames, the map points seen moving and the
    random stream of depth-RANSAC. ``reset()`` forgets everything."""

    history: FrameHistory
    moving_points: MovingMapPoints
    seed: int
    far: FarFrames = field(default_factory=lambda: FarFrames(1, 0))  # frames older than the history (multiframe)
    rng: np.random.Generator = field(init=False)
    own_pose: np.ndarray | None = None  # T_w_c chained from two-frame rough poses when no SLAM context comes
    held: tuple[int, np.ndarray, int] | None = None  # (frame index, (h, w) cells, frames since fresh) of surfaces seen moving

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)

    def reset(self) -> None:
        self.history.clear()
        self.far.clear()
        self.moving_points.clear()
        self.rng = np.random.default_rng(self.seed)
        self.own_pose = None
        self.held = None


class FrameWork:
    """One frame's screening in progress: the inputs, the products the stages share (computed once,
    on first use) and the columns written so far.

    Attributes written by the stages (all ``(N,)`` unless noted)
    -------------------------------------------------------------
    stages : stage name -> bool column; values : name -> float column.
    sem : the semantic stage's :class:`~dynslam_lab.dynamic.semantic.SemanticResult` (a neutral one
        without that stage); candidate : keypoints on a-priori dynamic detections (left out of F
        and of the rough pose); prior : the a-priori verdict (narrowed by depth-RANSAC);
        ran_box : keypoints whose prior depth-RANSAC decided.
    votes : two-frame geometric verdicts that could run (name, column).
    region_parts : ``(H, W)`` bool masks of the dynamic region; box_regions : detection -> box depth region.
    grid_region : ``(h, w)`` bool dynamic cells of the region stage, or None.
    """

    def __init__(self, frame, uv: np.ndarray, detections, context, config: ScreeningConfig, memory: ScreenerMemory):
        self.frame = frame
        self.uv = uv
        self.n = len(uv)
        self.detections = detections
        self.context = context
        self.config = config
        self.memory = memory
        self.gray = frame.gray
        self.shape = self.gray.shape
        self.camera = frame.camera
        self.z = depth_at(frame.depth, uv)
        self.timings: dict[str, float] = {}
        self.stages: dict[str, np.ndarray] = {}
        self.values: dict[str, np.ndarray] = {}
        n = self.n
        self.sem = SemanticResult(np.full(n, -1), np.full(n, -1), np.zeros(n), np.zeros(n, np.int8),
                                  np.zeros(n, bool), np.zeros(0, bool))
        self.candidate = np.zeros(n, bool)
        self.prior = np.zeros(n, bool)
        self.ran_box = np.zeros(n, bool)
        self.votes: list[tuple[str, np.ndarray]] = []
        self.geometric = np.zeros(n, bool)
        self.evidence = np.zeros(n, bool)
        self.dynamic = np.zeros(n, bool)
        self.restored = np.zeros(n, bool)
        self.flow_flag = np.zeros(n, bool)
        self.region_parts: list[np.ndarray] = []
        self.box_regions: dict[int, np.ndarray] = {}
        self.grid_region: np.ndarray | None = None
        self.fresh_cells: list[np.ndarray] = []  # (h, w) bool fresh evidence for the region stage
        self.prior_cells: np.ndarray | None = None  # (h, w) bool temporal prior
        self.static_cells: np.ndarray | None = None  # (h, w) bool confirmed static by the multi-frame test
        self.vanished_cells: np.ndarray | None = None  # (h, w) bool: an earlier frame's point there is seen through
        self._cache: dict[str, object] = {}
        self._pairs_future = None  # the LK pass with the previous frame, when started ahead (start_pairs)
        self._flow_future = None  # the dense flow with the previous frame, when started ahead (start_flow)
        prev = memory.history.last
        self.prev: PastFrame | None = prev if prev is not None and prev.gray.shape == self.shape else None

    # ------------------------------------------------------------- shared products
    def _timed(self, key: str, fn):
        if key not in self._cache:
            t0 = time.perf_counter()
            self._cache[key] = fn()
            self.timings[key] = self.timings.get(key, 0.0) + _ms(t0)
        return self._cache[key]

    def start_pairs(self) -> None:
        """Start the LK pass with the previous frame in a worker thread (:func:`~.epipolar.track_lk_async`):
        the stages before the first that needs the pairs (the reference pose) run beside it. Same pairs."""
        if self.prev is not None and self._pairs_future is None and "lk" not in self._cache:
            self._pairs_future = track_lk_async(self.prev.gray, self.gray, self.uv, self.config.lk)

    def start_flow(self) -> None:
        """Start the dense flow with the previous frame in the worker thread (after the LK pass), for the flow stage."""
        if self.prev is not None and self._flow_future is None:
            self._flow_future = farneback_flow_async(self.gray, self.prev.gray, self.config.flow)

    def pairs(self) -> tuple[np.ndarray, np.ndarray] | None:
        """LK pairs with the previous frame ``(uv_prev (N, 2), matched (N,))``, or None without one:
        one forward-backward LK pass per frame, shared by every stage that needs pairs (OpenCV's
        Python binding takes no prebuilt pyramid, so the pass itself is what is shared). Timings: ``lk``
        the pass, ``lk_wait`` how long the stages waited for it when it was started ahead."""
        if self.prev is None:
            return None
        if self._pairs_future is not None:
            t0 = time.perf_counter()
            self._cache["lk"], self.timings["lk"] = self._pairs_future.result()
            self.timings["lk_wait"] = _ms(t0)
            self._pairs_future = None
        return self._timed("lk", lambda: track_lk(self.prev.gray, self.gray, self.uv, self.config.lk))

    @property
    def uv_undistorted(self) -> np.ndarray:
        return self._timed("undistort", lambda: self.camera.undistort_points(self.uv))

    def reference(self) -> ReferencePose:
        """The pose the frame is judged against (:mod:`.reference_pose`): the SLAM map's, else the
        previous frame's pose moved by the two-frame rough pose."""

        def run():
            labels = self.surfaces()  # also caches the cells of each surface
            room, room_ids = self._room_depth()
            ref = map_reference_pose(self.context, self.uv_undistorted, self.camera, self.config.reference,
                                     exclude_ids=self.memory.moving_points.array(), surfaces=labels,
                                     surface_cells=self._cache["surface_cells"], room_depth=room, room_ids=room_ids)
            if ref.T_c_w is None:
                ref = self._two_frame_reference()
            return ref

        return self._timed("reference_pose", run)

    def _room_depth(self) -> tuple[RoomDepth | None, np.ndarray | None]:
        """The room's depth points and the oldest earlier frame with a pose (step 3c of the reference pose,
        :mod:`.room_depth`), and the labels of the room's surfaces (those holding ``room_depth_min_share`` of
        the grid's depth cells, less those lying mostly inside the previous frame's dynamic region);
        ``(None, None)`` when off or without an earlier frame."""
        cfg = self.config.reference
        refs = self.references()
        if cfg.room_depth_gain <= 0 or not refs or self.context is None or self.context.T_c_w_pred is None:
            return None, None
        past = refs[-1]
        f = self.config.multiframe.factor
        cam = self.grid_camera
        grid_labels = self.surface_grid()
        # a surface lying mostly inside the previous frame's dynamic region is a mover, not the room (the
        # temporal prior; the share of TemporalConfig.hold_overlap)
        ids = room_labels(self.small_depth, self._cache["surface_cells"], cfg.room_depth_min_share, grid_labels,
                          self.prev.region if self.prev is not None else None, self.config.temporal.hold_overlap,
                          cfg.room_depth_max_front, self.config.regions.continuity_rel, self.surfaces())
        X = room_points(self.small_depth, grid_labels, ids, cam)
        grid = _cached(past, "normal_grid", lambda: reference_grid(_past_small_depth(past, f), cam))
        return RoomDepth(X, grid, se3_inv(past.T_w_c), cam), ids

    def surface_grid(self) -> np.ndarray:
        """``(h, w)`` int surface label of each reduced-grid cell (0 = none; :meth:`surfaces`)."""
        self.surfaces()
        return self._cache["surface_labels"]

    def _two_frame_reference(self) -> ReferencePose:
        """Without a SLAM system: chain the two-frame rough pose (Chang et al. 2021's "slightly
        tracking", by PnP-RANSAC on the LK pairs outside the prior and the previous region)."""
        ref = ReferencePose.none(self.n)
        prev = self.prev
        pairs = self.pairs()
        if prev is None or pairs is None or prev.T_w_c is None:
            return ref
        uv_prev, matched = pairs
        exclude = self.candidate.copy()
        if prev.region is not None:
            r, c, inside = cells_at(uv_prev, self.config.multiframe.factor, prev.region.shape)
            exclude |= inside & prev.region[r, c]
        z_prev = depth_at(prev.depth, np.nan_to_num(uv_prev, nan=-1.0))
        mv = multiview_check(self.uv, self.z, uv_prev, z_prev, matched, exclude, self.camera, self.config.multiview)
        if mv.T_c_p is None:
            return ref
        ref.T_c_w = mv.T_c_p @ se3_inv(prev.T_w_c)
        ref.source = "two_frame"
        return ref

    @property
    def reference_if_computed(self) -> ReferencePose | None:
        """The reference pose when a stage needed it, else None (not computed)."""
        return self._cache.get("reference_pose")

    def motion_from_previous(self) -> np.ndarray | None:
        """``T_c_p`` (previous camera -> current camera) of the reference pose, when both are known."""
        ref = self.reference()
        if ref.T_c_w is None or self.prev is None or self.prev.T_w_c is None:
            return None
        return ref.T_c_w @ self.prev.T_w_c

    @property
    def grid_camera(self):
        f = self.config.multiframe.factor
        return self._timed("grid_camera", lambda: self.camera.scaled(1.0 / f))

    @property
    def small_depth(self) -> np.ndarray:
        """The current depth on the reduced grid (:func:`~dynslam_lab.dynamic.history.reduce_depth`)."""
        return self._timed("reduce_depth", lambda: reduce_depth(self.frame.depth, self.config.multiframe.factor))

    def surfaces(self) -> np.ndarray:
        """``(N,)`` int label of the surface each keypoint lies on (:func:`~dynslam_lab.dynamic.regions.surface_segments`
        on the reduced grid; 0 = none, or a keypoint off its cell's depth)."""

        def run():
            cfg = self.config.regions
            small = self.small_depth
            n_labels, labels = surface_segments(small, self.grid_camera, cfg.continuity_rel, cfg.crease_deg)
            self._cache["surface_cells"] = np.bincount(labels.ravel(), minlength=n_labels + 1)
            self._cache["surface_labels"] = labels
            r, c, inside = cells_at(self.uv, self.config.multiframe.factor, small.shape)
            zc = small[r, c]
            with np.errstate(invalid="ignore"):
                on = inside & (zc > 0) & ~(np.abs(self.z - zc) > 2 * cfg.continuity_rel * zc)
            return np.where(on, labels[r, c], 0)

        return self._timed("surfaces", run)

    def grid_points(self) -> tuple[np.ndarray, np.ndarray]:
        """Camera points of the reduced grid's cells with depth, and their flat indices."""
        return self._timed("grid_points", lambda: grid_points(self.small_depth, self.grid_camera))

    def references(self) -> list[PastFrame]:
        """Earlier frames with a pose at the configured offsets (newest first)."""
        return [f for f in self.memory.history.with_pose(self.config.multiframe.offsets) if f.depth.shape == self.shape]

    def grid_evidence(self) -> dict[str, np.ndarray]:
        """The reduced-grid products of the geometry stages that ran (for figures): ``depth``, ``fresh``
        evidence, cells confirmed ``static``, ``vanished`` cells, the temporal ``prior`` and the grown ``region``."""
        out: dict[str, np.ndarray] = {}
        if "reduce_depth" in self._cache:
            out["depth"] = self._cache["reduce_depth"]
            out["fresh"] = _union(self.fresh_cells, out["depth"].shape)
        for key, value in (("static", self.static_cells), ("vanished", self.vanished_cells), ("prior", self.prior_cells),
                           ("region", self.grid_region)):
            if value is not None:
                out[key] = value
        return out

    def remember(self, region: np.ndarray | None, T_w_c: np.ndarray | None) -> None:
        """Push this frame into the history; the frame that falls out of it may become a far frame."""
        evicted = self.memory.history.push(self.past_frame(region, T_w_c))
        if evicted is not None and evicted.depth.shape == self.shape:
            f = self.config.multiframe.factor
            r = self.config.multiframe.far_min_filter_cells
            self.memory.far.offer(evicted.index, evicted.T_w_c, lambda: eroded_depth(_past_small_depth(evicted, f), r))

    def past_frame(self, region: np.ndarray | None, T_w_c: np.ndarray | None) -> PastFrame:
        """This frame as the memory keeps it for the next ones."""
        past = PastFrame(self.frame.index, float(self.frame.timestamp), self.gray, self.frame.depth,
                         small_depth=self._cache.get("reduce_depth"), region=region, T_w_c=T_w_c)
        if "grid_points" in self._cache:
            past.cache["grid_points"] = self._cache["grid_points"][0]
        return past


# ---------------------------------------------------------------------- helpers
def _cached(past: PastFrame, key: str, fn):
    if key not in past.cache:
        past.cache[key] = fn()
    return past.cache[key]


def _window_span(depth: np.ndarray, uv: np.ndarray, radius: int) -> np.ndarray:
    """``(M,)`` max - min depth over the ``(2 r + 1)^2`` window around each pixel ``uv (M, 2)``; inf where a
    pixel of the window has no depth or lies off the image (one gather of ``M (2 r + 1)^2`` values)."""
    h, w = depth.shape
    r0 = np.rint(uv[:, 1]).astype(np.int64)
    c0 = np.rint(uv[:, 0]).astype(np.int64)
    inside = (r0 >= radius) & (r0 < h - radius) & (c0 >= radius) & (c0 < w - radius)
    d = np.arange(-radius, radius + 1)
    offsets = (d[:, None] * w + d[None, :]).reshape(-1)  # the window as flat offsets
    centre = np.where(inside, r0 * w + c0, radius * w + radius)
    z = np.asarray(depth).reshape(-1).take(centre[:, None] + offsets[None, :])
    span = z.max(axis=1) - z.min(axis=1)
    return np.where(inside & (z.min(axis=1) > 0), span, np.inf)


def _past_small_depth(past: PastFrame, factor: int) -> np.ndarray:
    if past.small_depth is None:
        past.small_depth = reduce_depth(past.depth, factor)
    return past.small_depth


def _union(masks: list[np.ndarray], shape: tuple[int, int]) -> np.ndarray:
    out = np.zeros(shape, bool)
    for m in masks:
        out |= m
    return out


def _near_mask(dets, sem: SemanticResult, use_masks: bool, margin: int) -> np.ndarray:
    """``(H, W)`` bool: within ``margin`` px of an a-priori dynamic detection (mask, else box)."""
    sel = np.flatnonzero(sem.dynamic_detections)
    union = (dets.masks[sel] if dets.masks is not None and use_masks else dets.region_masks()[sel]).any(axis=0)
    k = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * margin + 1, 2 * margin + 1))  # a square: separable, fast
    return cv2.dilate(union.astype(np.uint8), k).astype(bool)


def _box_depth_region(depth: np.ndarray, box: np.ndarray, depth_range: tuple[float, float], margin: float = 0.1):
    """Pixels of ``box`` whose depth lies in the consensus range (+- ``margin`` m): the person."""
    h, w = depth.shape
    x1, y1, x2, y2 = np.round(np.asarray(box, float)).astype(int)
    x1, y1 = max(x1, 0), max(y1, 0)
    x2, y2 = min(x2, w - 1), min(y2, h - 1)
    out = np.zeros((h, w), bool)
    if x2 < x1 or y2 < y1:
        return out
    sub = depth[y1 : y2 + 1, x1 : x2 + 1]
    out[y1 : y2 + 1, x1 : x2 + 1] = (sub >= depth_range[0] - margin) & (sub <= depth_range[1] + margin)
    return out


# ----------------------------------------------------------------------- stages
def semantic_stage(w: FrameWork) -> None:
    """Keypoints on a-priori dynamic detections (``SemanticConfig``: masks or boxes, prior set)."""
    cfg = w.config
    w.sem = semantic_prior(w.uv, w.detections, cfg.semantic, cfg.priors)
    w.candidate = w.sem.flagged.copy()
    w.prior = w.sem.flagged.copy()
    w.stages["semantic"] = w.sem.flagged.copy()


def depth_ransac_stage(w: FrameWork) -> None:
    """YOLO-SLAM's depth-RANSAC inside each a-priori dynamic box without a mask (all of them with
    ``depth_ransac_with_masks``): the consensus set is the person, the rest of the box static."""
    cfg, dets, sem = w.config, w.detections, w.sem
    dr = np.zeros(w.n, bool)
    if dets is not None and len(dets):
        has_mask = dets.masks is not None and cfg.semantic.use_masks
        run = sem.dynamic_detections & (not has_mask or cfg.depth_ransac_with_masks)
        for d in np.flatnonzero(run):
            members = sem.instance == d
            dyn_d, res = screen_boxes(w.uv[members], w.z[members], dets.boxes[d : d + 1], cfg.depth_ransac,
                                      w.memory.rng, depth_image=w.frame.depth)
            dr[np.flatnonzero(members)[dyn_d]] = True
            if res[0] is not None and res[0].depth_range is not None:
                w.box_regions[int(d)] = _box_depth_region(w.frame.depth, dets.boxes[d], res[0].depth_range)
        w.ran_box = run[np.maximum(sem.instance, 0)] & (sem.instance >= 0)
        w.prior = np.where(w.ran_box, dr, w.prior)
    w.stages["depth_ransac"] = dr


def epipolar_stage(w: FrameWork) -> None:
    """Distance to the epipolar line in the previous frame (eq. 17). F from the reference pose when
    there is one, else by RANSAC from the pairs outside the prior (Ge et al. 2024)."""
    if w.prev is None:
        return
    T_c_p = w.motion_from_previous()  # first: the LK pass, when started ahead, runs meanwhile
    uv_prev, matched = w.pairs()
    F = None
    if T_c_p is not None:
        # the epipolar constraint needs parallax: a baseline of |t| shifts a point at the median depth by
        # fx |t| / z pixels; below min_parallax_px (a rotating camera) the test cannot tell, and does not vote
        z_med = np.nanmedian(w.z) if np.isfinite(w.z).any() else np.inf
        if w.camera.fx * np.linalg.norm(T_c_p[:3, 3]) / z_med < w.config.epipolar.min_parallax_px:
            return
        F = fundamental_from_pose(T_c_p, w.camera.K)
    ep = epipolar_check(w.uv, uv_prev, matched, w.candidate, w.shape, w.config.epipolar, F=F)
    w.stages["epipolar"] = ep.dynamic
    w.values["epipolar_px"] = ep.distance
    if ep.F is not None:  # a test that could not run does not vote
        w.votes.append(("epipolar", ep.dynamic))


def multiview_stage(w: FrameWork) -> None:
    """Chang et al.'s eq. 2 against the previous frame: 4 px / 0.1 m. The motion is the reference
    pose's when there is one, else the rough PnP-RANSAC pose of the pairs outside the prior."""
    pairs = w.pairs()
    if pairs is None:
        return
    uv_prev, matched = pairs
    z_prev = depth_at(w.prev.depth, np.nan_to_num(uv_prev, nan=-1.0))
    mv = multiview_check(w.uv, w.z, uv_prev, z_prev, matched, w.candidate, w.camera, w.config.multiview,
                         T_c_p=w.motion_from_previous())
    w._cache["T_c_p"] = mv.T_c_p
    w.stages["multiview"] = mv.dynamic
    w.values["reprojection_px"] = mv.reprojection_px
    w.values["depth_error_m"] = mv.depth_error_m
    if mv.T_c_p is not None:
        w.votes.append(("multiview", mv.dynamic))


def multiframe_stage(w: FrameWork) -> None:
    """DynaSLAM's multi-view test against several earlier frames (:mod:`.multiframe`): every keypoint
    at full resolution, every cell of the reduced grid for the region stage."""
    cfg = w.config.multiframe
    ref = w.reference()
    refs = w.references()
    n = w.n
    col = np.zeros(n, bool)
    w.stages["multiframe"] = col
    if ref.T_c_w is None or not refs:
        return
    T_w_c = se3_inv(ref.T_c_w)
    # keypoints, full resolution
    ok = np.isfinite(w.z)
    X_w = transform_points(T_w_c, w.camera.backproject(w.uv_undistorted[ok], w.z[ok]))
    kp_refs = [(f.T_w_c, _cached(f, "depth_min", lambda f=f: eroded_depth(f.depth, cfg.min_filter_px))) for f in refs]
    fs = free_space_test(X_w, kp_refs, w.camera, cfg)
    col[ok] = fs.violations > 0
    margin = np.full(n, np.nan)
    margin[ok] = fs.margin_m
    w.values["free_space_m"] = margin
    older_lk = _start_older_frame_lk(w, refs, X_w, ok)  # in the worker thread while the grid tests run
    # the reduced grid
    cam = w.grid_camera
    small = w.small_depth
    P, keep = w.grid_points()
    grid_refs = [(f.T_w_c, _cached(f, "small_min", lambda f=f: eroded_depth(_past_small_depth(f, cfg.factor), 1)))
                 for f in refs]
    P_w = transform_points(T_w_c, P)
    g = free_space_test(P_w, grid_refs, cam, cfg, margin=False)
    h, wd = small.shape
    viol = np.zeros(h * wd, np.int64)
    viol[keep] = g.violations
    # far frames (older than the history, reduced depth only): they saw the place before a slow mover
    # covered it; violations only (their agreement would confirm a mover that has stood there since)
    far_refs = [(f.T_w_c, f.depth_min) for f in w.memory.far if f.depth_min.shape == small.shape]
    if far_refs:
        t0 = time.perf_counter()
        fk = free_space_test(X_w, far_refs, cam, cfg, margin=False)
        far_viol = np.zeros(n)
        far_viol[ok] = fk.violations
        col |= far_viol > 0
        w.values["far_violations"] = far_viol
        viol[keep] += free_space_test(P_w, far_refs, cam, cfg, margin=False).violations
        w.timings["far_frames"] = _ms(t0)
    moved_2d = _older_frame_2d_test(w, X_w, ok, older_lk)
    col |= moved_2d
    agree = np.zeros(h * wd, np.int64)
    agree[keep] = g.agreements
    occluded = np.full(h * wd, len(refs), np.int64)
    occluded[keep] = g.occlusions
    # the backward test against the older frames only (what vanished in one or two frames shows in them too)
    older = [f for f in refs if w.frame.index - f.index >= 4] or refs[-1:]
    pts_refs = [(f.T_w_c, _cached(f, "grid_points", lambda f=f: grid_points(_past_small_depth(f, cfg.factor), cam)[0]))
                for f in older]
    van = vanished_test(pts_refs, T_w_c, eroded_depth(small, 1), cam, cfg).reshape(-1)
    need = min(w.config.regions.static_min_agree, len(refs))  # one earlier frame: its agreement must do
    static = (viol == 0) & (van == 0) & (agree >= need) & (agree >= occluded)
    static = static.reshape(h, wd) & ~splat(w.uv, moved_2d, cfg.factor, (h, wd))
    w.static_cells = static
    w.fresh_cells.append((viol > 0).reshape(h, wd))
    w.vanished_cells = (van > 0).reshape(h, wd)


def _start_older_frame_lk(w: FrameWork, refs: list[PastFrame], X_w: np.ndarray, ok: np.ndarray):
    """The guided LK pass of :func:`_older_frame_2d_test`, started in the screener's worker thread
    (:func:`~.epipolar.track_lk_async`): ``(future, idx, uv_j)`` (keypoints tracked and their static
    predictions in the older frame), or None when there is nothing to track."""
    cfg = w.config.multiframe
    if cfg.lk_offset <= 0 or not refs:
        return None
    target = max(w.frame.index - cfg.lk_offset, -1)
    past = min(refs, key=lambda f: abs(f.index - target))
    T_j_w = se3_inv(past.T_w_c)
    uv_j, z_j = w.camera.project(transform_points(T_j_w, X_w))
    d_j = _cached(past, "depth_min", lambda: eroded_depth(past.depth, cfg.min_filter_px))
    zm = depth_at(d_j, np.nan_to_num(uv_j, nan=-1.0))
    tau = np.maximum(cfg.depth_m, cfg.depth_quadratic * z_j**2)
    # keypoints whose LK window straddles a depth edge are left out: their depth may belong to the other
    # layer, and a wrong depth makes a parallax error that grows with the baseline like a motion would.
    # "Flat": every pixel of the LK window has depth, within tau of the others.
    span = _window_span(w.frame.depth, w.uv[ok], w.config.lk.win_size // 2)
    with np.errstate(invalid="ignore"):
        flat = span <= np.maximum(cfg.depth_m, cfg.depth_quadratic * w.z[ok] ** 2)
        seen = w.camera.in_image(uv_j, 8) & (np.abs(zm - z_j) <= tau) & flat
    idx = np.flatnonzero(ok)[seen]
    if len(idx) == 0:
        return None
    uv_j = uv_j[seen]
    future = track_lk_async(past.gray, w.gray, w.uv[idx], w.config.lk, guess=uv_j)
    return future, idx, uv_j


def _older_frame_2d_test(w: FrameWork, X_w: np.ndarray, ok: np.ndarray, started) -> np.ndarray:
    """Chang et al.'s eq. 2 against an older frame (:mod:`.multiframe`): ``(N,)`` bool, keypoints found by
    guided LK (``started``: :func:`_start_older_frame_lk`) more than ``reprojection_px`` from their static
    prediction where that frame saw them. Timings: ``lk_older`` the LK pass, ``lk_older_wait`` how long the
    stage waited for it."""
    cfg = w.config.multiframe
    n = w.n
    moved = np.zeros(n, bool)
    if started is None:
        return moved
    future, idx, uv_j = started
    t0 = time.perf_counter()
    (uv_lk, tracked), w.timings["lk_older"] = future.result()
    w.timings["lk_older_wait"] = _ms(t0)
    err = np.full(n, np.nan)
    r_old = np.full((n, 2), np.nan)
    r_old[idx[tracked]] = uv_lk[tracked] - uv_j[tracked]
    err = np.linalg.norm(r_old, axis=1)
    w.values["older_reprojection_px"] = err
    with np.errstate(invalid="ignore"):
        moved = err > cfg.reprojection_px
    # a mover keeps its direction: its displacement against the previous frame points the same way and
    # carries a share of it; LK locked on the wrong repeat of a pattern in the older frame does not
    pairs, prev = w.pairs(), w.prev
    if moved.any() and pairs is not None and prev is not None and prev.T_w_c is not None:
        uv_p_hat, _ = w.camera.project(transform_points(se3_inv(prev.T_w_c), X_w))
        r_prev = np.full((n, 2), np.nan)
        r_prev[ok] = pairs[0][ok] - uv_p_hat
        with np.errstate(invalid="ignore", divide="ignore"):
            along = np.einsum("ij,ij->i", r_prev, r_old) / err
            moved &= along > np.maximum(cfg.direction_min_px, err / (4.0 * max(cfg.lk_offset, 1)))
    return moved


def flow_stage(w: FrameWork) -> None:
    """Chang et al.'s human-driven regions: Farneback flow (camera motion removed with the reference
    or rough pose) faster than twice the person mask's mean flow, touching the mask."""
    flag = np.zeros(w.n, bool)
    dets, sem = w.detections, w.sem
    if w.prev is not None and dets is not None and len(dets) and sem.dynamic_detections.any():
        person = _union(list(dets.region_masks()[sem.dynamic_detections]), w.shape)
        if person.any():
            T_c_p = w._cache.get("T_c_p")
            if T_c_p is None:
                T_c_p = w.motion_from_previous()
            dense = None
            if w._flow_future is not None:  # started ahead by the screener
                t0 = time.perf_counter()
                dense = w._flow_future.result()
                w.timings["flow_wait"] = _ms(t0)
            fr = flow_regions(w.gray, w.prev.gray, person, w.frame.depth, w.camera, T_c_p, w.config.flow, flow=dense)
            flag = values_at(fr.region, w.uv, outside=False).astype(bool)
            w.region_parts.append(fr.region)
            w.values["flow_threshold_px"] = np.full(w.n, fr.threshold_px)
    w.flow_flag = flag
    w.stages["flow"] = flag


def temporal_stage(w: FrameWork) -> None:
    """Keypoints matched to map points seen moving; the previous region carried into this frame."""
    ref = w.reference()
    # a point seen moving that still misses its map point; a surface moving against the rest; a
    # keypoint far from its map point that another test also finds moving
    fresh = np.zeros(w.n, bool)
    for name in ("epipolar", "multiview", "multiframe"):
        fresh |= w.stages.get(name, fresh)
    with np.errstate(invalid="ignore"):
        still_off = ref.residual_px > w.config.reference.inlier_px
    col = (ref.known_moving & still_off) | ref.surface_moved | (ref.moved & fresh)
    col |= _held_surfaces(w, ref)
    w.stages["temporal"] = col
    prev = w.prev
    if prev is None or prev.region is None or prev.T_w_c is None or ref.T_c_w is None:
        return
    T_p_c = se3_inv(prev.T_w_c) @ se3_inv(ref.T_c_w)
    prev_small = _past_small_depth(prev, w.config.multiframe.factor)
    w.prior_cells = warp_region(prev.region, T_p_c, w.small_depth, w.grid_camera, w.config.temporal.dilate_cells,
                                prev_depth=prev_small, depth_m=w.config.multiframe.depth_m)


def _held_surfaces(w: FrameWork, ref: ReferencePose) -> np.ndarray:
    """Surfaces seen moving against the static world stay dynamic (ours): the cells of the surfaces the
    reference pose found moving (step 3b) are carried into the next frame along the camera motion
    (:func:`~dynslam_lab.dynamic.temporal.warp_region`); a surface of this frame lying at least
    ``hold_overlap`` inside them is the same object, and its keypoints are dynamic, matched to the map or
    not, until ``hold_frames`` frames have passed without a fresh verdict. The object's map points are
    gone (culled, :attr:`Screener.moved_map_ids`), so without this memory its next frame would carry no
    evidence against it. Returns ``(N,)`` bool; updates the memory."""
    cfg = w.config.temporal
    mem = w.memory
    out = np.zeros(w.n, bool)
    if cfg.hold_frames <= 0 or "surface_labels" not in w._cache or ref.T_c_w is None:
        mem.held = None
        return out
    grid = w.surface_grid()
    labels = w.surfaces()
    fresh = np.unique(labels[ref.surface_moved & (labels > 0)])
    held = np.zeros(0, np.int64)
    age = 0
    prev = w.prev
    if mem.held is not None and prev is not None and prev.index == mem.held[0] and prev.T_w_c is not None:
        T_p_c = se3_inv(prev.T_w_c) @ se3_inv(ref.T_c_w)
        carried = warp_region(mem.held[1], T_p_c, w.small_depth, w.grid_camera)
        n_lab = int(grid.max()) + 1
        inside = np.bincount(grid[carried], minlength=n_lab)
        cells = w._cache["surface_cells"][:n_lab]
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = inside / cells
        held = np.flatnonzero(frac >= cfg.hold_overlap)
        held = held[held > 0]
        age = mem.held[2] + 1
    if len(fresh):
        age = 0
    keep = np.union1d(fresh, held) if age <= cfg.hold_frames else fresh
    if len(keep):
        out = np.isin(labels, keep) & (labels > 0)
        mem.held = (w.frame.index, np.isin(grid, keep), age)
    else:
        mem.held = None
    return out


def regions_stage(w: FrameWork) -> None:
    """Region growing from the evidence over the depth image (:mod:`.regions`)."""
    cfg = w.config.regions
    small = w.small_depth
    shape = small.shape
    factor = w.config.multiframe.factor
    fresh = _union(w.fresh_cells, shape)
    if cfg.seed_keypoints:
        kp = _geometric(w, set(w.stages))
        for name in ("multiframe", "temporal"):
            if name in w.stages:
                kp |= w.stages[name]
        fresh |= splat(w.uv, kp, factor, shape)
    prior = w.prior_cells if w.prior_cells is not None else np.zeros(shape, bool)
    vanished = w.vanished_cells if w.vanished_cells is not None else np.zeros(shape, bool)
    allowed = small > 0
    if w.static_cells is not None:
        reopen = prior
        if cfg.prior_on_fresh_surfaces and prior.any():
            reopen = prior_on_fresh_surfaces(prior, fresh, w.surface_grid(), cfg.min_fresh_cells)
        allowed &= ~w.static_cells | reopen
    allowed &= ~(vanished & ~prior)  # background a mover has just uncovered
    continuity = depth_continuity(small, cfg.continuity_rel)
    grown = grow_regions(fresh, allowed | fresh, continuity, cfg.steps)
    region = supported_regions(grown, fresh, cfg.min_fresh_cells, continuity)
    if cfg.surface_share > 0 and region.any():
        region = whole_surfaces(region, w.surface_grid(), w._cache["surface_cells"], cfg.surface_share)
    w.grid_region = region
    r, c, inside = cells_at(w.uv, factor, shape)
    # a keypoint takes its cell's verdict when it lies on the cell's surface (on_region)
    w.stages["regions"] = inside & on_region(region, small, r, c, w.z, cfg.continuity_rel, cfg.edge_cells)
    if region.any():
        H, W = w.shape
        full = cv2.resize(region.astype(np.uint8), (shape[1] * factor, shape[0] * factor), interpolation=cv2.INTER_NEAREST)
        out = np.zeros((H, W), bool)
        hh, ww = min(H, full.shape[0]), min(W, full.shape[1])
        out[:hh, :ww] = full[:hh, :ww].astype(bool)
        w.region_parts.append(out)
        if cfg.silhouette_px > 0:
            w.stages["regions"] |= _silhouette_keypoints(w, out)


def _silhouette_keypoints(w: FrameWork, region: np.ndarray) -> np.ndarray:
    """``(N,)`` bool: keypoints without depth within ``silhouette_px`` of the grown ``region (H, W)`` whose flow
    with the previous frame follows the dynamic keypoints around them (:func:`~.regions.follows_the_mover`;
    ``RegionConfig.silhouette_px``). Their static prediction takes the farthest reduced depth within two cells
    (the background behind a silhouette); none without LK pairs or a motion from the previous frame."""
    cfg = w.config.regions
    none = np.zeros(w.n, bool)
    pairs = w.pairs()
    T_c_p = w.motion_from_previous()
    if pairs is None or T_c_p is None:
        return none
    uv_prev, matched = pairs
    dist = cv2.distanceTransform((~region).astype(np.uint8), cv2.DIST_L2, 3)
    cand = ~(w.z > 0) & matched & (values_at(dist, w.uv, outside=np.inf) <= cfg.silhouette_px)
    if not cand.any():
        return none
    dynamic = w.stages["regions"].copy()
    for name in ("multiframe", "temporal"):
        if name in w.stages:
            dynamic |= w.stages[name]
    dynamic &= w.z > 0
    small = w.small_depth
    far = cv2.dilate(small.astype(np.float32), np.ones((5, 5), np.uint8))
    r, c, _ = cells_at(w.uv, w.config.multiframe.factor, small.shape)
    idx = np.flatnonzero(cand)
    z = far[r[idx], c[idx]].astype(np.float64)
    z[~(z > 0)] = 1e3  # no depth anywhere near: the camera's rotation alone
    X_p = transform_points(se3_inv(T_c_p), w.camera.backproject(w.uv_undistorted[idx], z))
    static_prev = np.full((w.n, 2), np.nan)
    p, zp = w.camera.project(X_p)
    ok = zp > 0
    static_prev[idx[ok]] = p[ok]
    prev_und = np.full((w.n, 2), np.nan)  # in the undistorted pixels of the prediction
    prev_und[matched] = w.camera.undistort_points(uv_prev[matched])
    return follows_the_mover(w.uv_undistorted, prev_und, static_prev, cand, dynamic,
                             cfg.silhouette_reach_px, cfg.silhouette_min_px, cfg.silhouette_ratio)


#: Evidence stage name -> function, in run order (``config.STAGES``). ``level_rule`` changes how
#: :func:`combine` weighs the columns and ``restoration`` (:func:`restoration_stage`) runs after it.
STAGE_FUNCTIONS = {
    "semantic": semantic_stage,
    "depth_ransac": depth_ransac_stage,
    "epipolar": epipolar_stage,
    "multiview": multiview_stage,
    "multiframe": multiframe_stage,
    "flow": flow_stage,
    "temporal": temporal_stage,
    "regions": regions_stage,
}


# ---------------------------------------------------------------------- verdict
def _geometric(w: FrameWork, on: set[str]) -> np.ndarray:
    """The two-frame vote (epipolar, multi-view) with the margin around a-priori dynamic masks."""
    cfg = w.config
    if not w.votes:
        return np.zeros(w.n, bool)
    vote = cfg.geometric_vote
    if vote == "auto":  # "any" only when the two-frame tests are the only geometric signal
        vote = "both" if on & {"semantic", "multiframe", "regions"} else "any"
    cols = [c for _, c in w.votes]
    if vote == "both" and len(cols) < 2:
        return np.zeros(w.n, bool)  # "both" needs both tests: one alone (the other could not run) does not decide
    geometric = np.logical_and.reduce(cols) if vote == "both" else np.logical_or.reduce(cols)
    dets = w.detections
    if "semantic" in on and cfg.geometry_mask_margin_px > 0 and dets is not None and w.sem.dynamic_detections.any():
        near = _near_mask(dets, w.sem, cfg.semantic.use_masks, cfg.geometry_mask_margin_px)
        geometric &= ~values_at(near, w.uv, outside=False).astype(bool)
    return geometric


def combine(w: FrameWork, on: set[str]) -> None:
    """The verdict from the columns (rule: :mod:`.screening`); with ``level_rule`` Zhang et al.'s
    levels replace the prior. Sets ``w.dynamic``, ``w.evidence`` (geometric and flow evidence of
    motion) and ``w.prior`` (what the prior alone decided)."""
    geometric = _geometric(w, on)
    w.geometric = geometric
    evidence = geometric | w.flow_flag
    for name in ("multiframe", "temporal", "regions"):
        if name in w.stages:
            evidence |= w.stages[name]
    w.evidence = evidence
    if "level_rule" in on:
        level_dyn = w.sem.level >= LEVEL_CODES["medium"]
        level_dyn &= ~(w.ran_box & ~w.prior)  # depth-RANSAC background inside a box: judged by geometry
        lvl = np.where(level_dyn, w.sem.level, np.minimum(w.sem.level, LEVEL_CODES["low"]))
        w.dynamic = level_rule_verdict(lvl, evidence)
        w.stages["level_rule"] = w.dynamic.copy()
        w.prior = w.prior & level_dyn
    else:
        w.dynamic = w.prior | evidence


def restoration_stage(w: FrameWork) -> None:
    """ASG-SLAM's restoration (Ge et al. 2024 eq. 3): prior-only keypoints come back, least probable
    movers first, while the static ratio is below ``delta_1``; evidence of motion vetoes."""
    rr = restore_by_motion_probability(w.dynamic, w.prior, w.sem.motion_prob, w.evidence, w.config.restoration)
    w.restored = rr.restored
    w.dynamic = w.dynamic & ~rr.restored
    w.stages["restoration"] = rr.restored


def finish(w: FrameWork, on: set[str], order: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray | None]:
    """The ``reason`` column (the earliest stage in ``order`` that made a keypoint dynamic) and the
    region mask (dynamic detections still dynamic, their box-depth regions, flow and grown regions)."""
    n = w.n
    dynamic = w.dynamic
    reason = np.full(n, "", dtype=object)
    decided = {
        "semantic": w.prior & ~w.ran_box,
        "depth_ransac": w.prior & w.ran_box,
        "epipolar": w.stages.get("epipolar", np.zeros(n, bool)) & w.geometric,
        "multiview": w.stages.get("multiview", np.zeros(n, bool)) & w.geometric,
    }
    for name in ("multiframe", "flow", "temporal", "regions"):
        if name in w.stages:
            decided[name] = w.stages[name]
    for name in reversed(order):  # the earliest stage wins: set last
        if name in decided:
            reason[decided[name] & dynamic] = name
    if "level_rule" in w.stages:
        reason[dynamic & (reason == "")] = "level_rule"
    reason[w.restored] = "restored"
    region_parts = list(w.region_parts)
    dets = w.detections
    if dets is not None and len(dets) and "semantic" in on:
        keep_det = np.zeros(len(dets), bool)
        keep_det[np.unique(w.sem.instance[dynamic & w.prior])] = True
        keep_det &= w.sem.dynamic_detections
        for d in np.flatnonzero(keep_det):
            if int(d) in w.box_regions:
                region_parts.append(w.box_regions[int(d)])
            elif dets.masks is not None and w.config.semantic.use_masks:
                region_parts.append(dets.masks[d])
            else:
                region_parts.append(dets.region_masks()[d])
    region_mask = None
    if region_parts:
        region_mask = _union(region_parts, w.shape)
    elif "semantic" in on:
        region_mask = np.zeros(w.shape, bool)
    return reason, region_mask
