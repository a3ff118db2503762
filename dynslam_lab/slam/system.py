"""The RGB-D SLAM system: one call per frame, all stages in order
(ORB-SLAM2, Mur-Artal and Tardos, T-RO 2017, Fig. 1, run in a single thread).

Per frame::

    ORB extraction || detector.detect(frame)  (side by side: the detector in a worker thread;
                                               both may start ahead, from ``prepare(frame)``)
      -> screener.screen(frame, uv, detections)
      -> tracking with the static keypoints only -> keyframe decision
      -> local mapping (new points, fusion, culling, local BA) for a new keyframe
      -> loop_closer.on_keyframe(keyframe, map) for a new keyframe

Map initialisation (ORB-SLAM2 ``StereoInitialization``): the first frame with at least
``init_min_points`` static keypoints with depth becomes keyframe 0 at the world origin and every
such keypoint a map point. A frame of weak texture, with fewer than ``init_min_points`` keypoints with
depth in all, starts the map with ``init_weak_min_points`` static ones (ours: ORB-SLAM2 never starts
there; the dense term of tracking carries the plain room).

Every tracked frame's pose is stored relative to its reference keyframe, ``T_ref_c``, so that
keyframe corrections (local BA, loop closing) reach the trajectory: ``T_w_c = T_w_ref T_ref_c``.
"""

from __future__ import annotations

import threading
import time
import weakref
from concurrent.futures import CancelledError, Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from ..camera import PinholeCamera
from ..datasets.frame import Frame
from ..dynamic.context import ScreeningContext
from ..dynamic.history import reduce_depth
from ..evaluation.trajectory import Trajectory
from ..features.orb import Features, extract_features
from ..geometry.se3 import se3_inv, transform_points
from .frame import KeyFrame, SlamFrame, make_slam_frame
from .keyframe_database import KeyframeDatabase, static_bow
from .local_mapping import LocalMapper, create_points_from_depth
from .map import Map
from .tracking import Tracker, TrackState
from .vocabulary import default_vocabulary

__all__ = ["System", "FrameResult"]


def _run_now(fn, *args) -> Future:
    """``fn(*args)`` run here and now, as a finished future (its result or its exception)."""
    future: Future = Future()
    try:
        future.set_result(fn(*args))
    except Exception as exc:  # raised again by future.result(), where the frame is processed
        future.set_exception(exc)
    return future


@dataclass
class _Prepared:
    """What :meth:`System.prepare` started for one frame ahead of :meth:`System.process`: its ORB
    extraction (a future of ``(features, ms)``; None while it waits for the prior region of an earlier
    frame, see :meth:`System._prior_index`) and its detection (a future of ``(detections, ms)``, None
    without a detector)."""

    frame: Frame
    features: Future | None
    detection: Future | None

    def cancel(self) -> None:
        """Drop the work not started yet (a frame that will not be processed)."""
        for f in (self.features, self.detection):
            if f is not None:
                f.cancel()


@dataclass
class FrameResult:
    """What :meth:`System.process` tells about one frame.

    Attributes
    ----------
    index, timestamp : the frame.
    state : tracking state after the frame (``TrackState``: ``ok``, ``relocalized``, ``lost``,
        ``not_initialized``).
    T_w_c : ``(4, 4)`` pose, or None when not tracked.
    is_keyframe : a keyframe was made from this frame (``keyframe_id``, else -1).
    method : how the pose was found (``motion_model``, ``reference_keyframe``,
        ``relocalization``, ``initialization`` or ``""``).
    n_features, n_dynamic, n_inliers : keypoints, keypoints judged dynamic, pose inliers.
    timings_ms : per stage milliseconds (``orb``, ``detect``, ``screen``, ``track``,
        ``local_mapping``, ``loop``, ``total`` = the wall time of ``process``; ``detect`` overlaps
        ``orb``, so the stages may sum to more than ``total``).
    uv : ``(N, 2)`` keypoints; dynamic : ``(N,)`` bool verdict used.
    table : the screener's keypoint table (or None); region_mask : ``(H, W)`` bool or None.
    dynamic_xyz : ``(D, 3)`` world points of dynamic keypoints with depth (tracked frames only).
    loop : the loop closer's result for this frame's keyframe, or None.
    error : message when a stage failed without losing the frame (the loop closer).
    local_mapping : statistics of local mapping for a new keyframe (``fused``, ``ba_points``,
        ``ba_outliers``, ``ba_cost_before``/``after``, ``culled_keyframes``).
    """

    index: int
    timestamp: float
    state: str
    T_w_c: np.ndarray | None
    is_keyframe: bool = False
    keyframe_id: int = -1
    method: str = ""
    n_features: int = 0
    n_dynamic: int = 0
    n_inliers: int = 0
    timings_ms: dict[str, float] = field(default_factory=dict)
    uv: np.ndarray | None = None
    dynamic: np.ndarray | None = None
    table: Any = None
    region_mask: np.ndarray | None = None
    dynamic_xyz: np.ndarray | None = None
    loop: Any = None
    error: str = ""
    local_mapping: dict = field(default_factory=dict)

    @property
    def tracked(self) -> bool:
        return self.T_w_c is not None


class System:
    """ORB-SLAM2-style RGB-D SLAM, single-threaded.

    Parameters
    ----------
    camera : intrinsics of the sequence.
    config : the root :class:`dynslam_lab.config.Config` (uses ``orb``, ``tracking``,
        ``local_mapping``; the other stages are built from it by
        :func:`dynslam_lab.pipeline.build_pipeline`).
    detector : object with ``detect(frame) -> Detections``, or None.
    screener : object with ``screen(frame, uv, detections) -> table`` (``.dynamic (N,)`` bool,
        ``.region_mask``), or None (all keypoints static).
    loop_closer : a :class:`~dynslam_lab.slam.loop_closing.LoopCloser`, or None; relocalisation
        queries its keyframe database (else the system keeps its own).
    """

    def __init__(self, camera: PinholeCamera, config, detector=None, screener=None, loop_closer=None) -> None:
        if loop_closer is not None and loop_closer.bf != config.tracking.bf:
            raise ValueError(f"System: the loop closer's bf ({loop_closer.bf}) differs from tracking.bf "
                             f"({config.tracking.bf}); build both from one config (dynslam_lab.pipeline.build_pipeline)")
        self.camera = camera
        self.config = config
        self.detector = detector
        self.screener = screener
        self.loop_closer = loop_closer
        #: how the stages were chosen (detector spec, filter name, loop closing), for summaries
        self.description: dict[str, Any] = {}
        orb = config.orb
        self.map = Map(orb.scale_factor, orb.n_levels)
        self.tracker = Tracker(camera, self.map, config.tracking, orb.scale_factor)
        # Relocalisation queries the loop closer's keyframe database (ORB-SLAM2 shares one
        # database between tracking and loop closing); without one the system keeps its own.
        self._own_database = None  # the system's BoW index when no loop closer keeps one
        if loop_closer is not None and loop_closer.config.enabled:
            self.tracker.database, self.tracker.vocabulary = loop_closer.database, loop_closer.vocabulary
        elif config.tracking.bow_relocalisation:
            voc = default_vocabulary()
            self._own_database = KeyframeDatabase(voc.n_words)
            self.tracker.database, self.tracker.vocabulary = self._own_database, voc
        tc = config.tracking
        self.close_depth = tc.th_depth * tc.bf / camera.fx
        # keyframe points are made from depth up to here (ours: no triangulation of far points)
        self.new_point_depth = max(self.close_depth, tc.new_point_depth)
        self.mapper = LocalMapper(self.map, camera, config.local_mapping, tc.bf, self.close_depth, orb.scale_factor)
        # Per tracked frame: (timestamp, reference keyframe id, T_ref_c).
        self._anchors: list[tuple[float, int, np.ndarray]] = []
        self.lost_frames: list[int] = []
        self.loop_results: list[Any] = []
        self.loop_edges: list[tuple[int, int]] = []
        self.loop_errors: list[str] = []  # loop corrections that failed when applied at the end of a run
        self._pools: dict[str, ThreadPoolExecutor] = {}  # one-thread workers: "detect" (beside ORB), "orb" (ahead)
        self._fresh: tuple[int, Future] | None = None  # the last frame given to the detector: (index, its detection)
        self._prepared: dict[int, _Prepared] = {}  # frame index -> work started ahead by prepare()
        # The screened regions of the last frames (frame index -> (H, W) bool or None), the prior of the
        # extraction of frame index + orb.prior_lag, and the index of the last frame process() began.
        self._regions: dict[int, np.ndarray | None] = {}
        self._started = -(2**62)
        self._lock = threading.Lock()  # prepare() runs in the reader thread: guards the four above

    def effective_config(self):
        """The configuration every stage actually runs with: :attr:`config` with the detection,
        screening and loop-closing sections taken from the stage objects themselves (what
        ``summary.json`` records, so a hand-built stage cannot be misreported)."""
        changes = {}
        if self.detector is not None:
            changes["detection"] = self.detector.config
        if self.screener is not None:  # at the camera's image width (ScreeningConfig.for_width)
            config_for = getattr(self.screener, "config_for", None)
            changes["screening"] = config_for(self.camera.width) if config_for is not None else self.screener.config
        if self.loop_closer is not None:
            changes["loop_closing"] = self.loop_closer.config
        return replace(self.config, **changes)

    # --------------------------------------------------------------- helpers
    def _detect(self, frame: Frame) -> tuple[Any, float]:
        """The detector on one frame, and its time (ms; in whichever thread runs it)."""
        t0 = time.perf_counter()
        detections = self.detector.detect(frame)
        return detections, 1e3 * (time.perf_counter() - t0)

    def _worker(self, name: str) -> ThreadPoolExecutor:
        """The one-thread pool ``dynslam-NAME`` (made on first use, shut down with the system)."""
        with self._lock:
            pool = self._pools.get(name)
            if pool is None:
                pool = self._pools[name] = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"dynslam-{name}")
                weakref.finalize(self, pool.shutdown, wait=False)
            return pool

    def _submit_detection(self, frame: Frame) -> Future | None:
        """Start the frame's detection in the detection worker (``tracking.overlap_detection``), else None."""
        if self.detector is None or not self.config.tracking.overlap_detection:
            return None
        return self._start_detection(frame, self._worker("detect").submit)

    def _start_detection(self, frame: Frame, submit) -> Future:
        """The future ``(detections, ms)`` of one frame: ``detector.detect(frame)``, or, between two
        detected frames (``detection.stride``), the last detection carried over (:meth:`_carried`).
        ``submit(fn, *args)`` runs the job (the worker's ``submit``, or :func:`_run_now`). Frames must
        be started in order; which frames are detected depends on their indices only."""
        src = self._carry_source(frame)
        if src is not None:
            return submit(self._carried, src[1], int(frame.index) - src[0], frame)
        future = submit(self._detect, frame)
        with self._lock:
            self._fresh = (int(frame.index), future)
        return future

    def _carry_source(self, frame: Frame) -> tuple[int, Future] | None:
        """``(index, future)`` of the detected frame whose detections ``frame`` takes, or None to
        detect it: with ``detection.stride = s > 1`` a frame whose index is not a multiple of ``s``
        takes those of the last frame detected, when that one is fewer than ``s`` frames back."""
        stride = int(getattr(getattr(self.detector, "config", None), "stride", 1))
        i = int(frame.index)
        with self._lock:
            src = self._fresh
        if stride <= 1 or i % stride == 0 or src is None or not 0 < i - src[0] < stride:
            return None
        return src

    def _carried(self, source: Future, gap: int, frame: Frame) -> tuple[Any, float]:
        """The detections of the frame ``gap`` frames back (``source``) grown by ``gap x
        detection.carry_margin_px`` (:meth:`Detections.grown`): where its objects can be now. When
        that frame's detection failed or was dropped (a skipped frame), this frame is detected."""
        t0 = time.perf_counter()
        try:
            detections, _ = source.result()
        except (Exception, CancelledError):
            return self._detect(frame)
        if hasattr(detections, "grown"):
            margin = gap * float(self.detector.config.carry_margin_px)
            detections = detections.grown(margin, source=f"{detections.source} (carried from frame {int(frame.index) - gap})")
        return detections, 1e3 * (time.perf_counter() - t0)

    def _extract(self, frame: Frame, prior: np.ndarray | None = None) -> tuple[Features, float]:
        """ORB features of one frame, and the extraction's time (ms; in whichever thread runs it).

        The keypoint budget leaves the dynamic region (docs/robustness.md, "ORB budget"): the region
        the screener knows in the frame itself (the oracle's masks, ``orb.truth_region_share``), else
        ``prior``, the region screened on frame ``index - orb.prior_lag``, grown by
        ``orb.prior_dilate_px`` (``orb.prior_region_share``)."""
        t0 = time.perf_counter()
        orb = self.config.orb
        region, share = None, 1.0
        if self._truth_region():
            region, share = self.screener.known_region(frame), orb.truth_region_share
        elif prior is not None and prior.any():
            region, share = prior, orb.prior_region_share
            if orb.prior_dilate_px > 0:
                k = np.ones((2 * orb.prior_dilate_px + 1,) * 2, np.uint8)  # a square: separable, ~0.3 ms (an ellipse: 8 ms)
                region = cv2.dilate(prior.astype(np.uint8), k)
        feats = extract_features(frame.gray, orb, region=region, region_share=share)
        return feats, 1e3 * (time.perf_counter() - t0)

    def _truth_region(self) -> bool:
        """Whether the screener knows each frame's dynamic pixels before extraction (the oracle) and
        the budget leaves them (``orb.truth_region_share < 1``)."""
        return self.config.orb.truth_region_share < 1.0 and hasattr(self.screener, "known_region")

    def _prior_index(self, frame: Frame) -> int | None:
        """The frame whose screened region is the prior of this frame's extraction (``index -
        orb.prior_lag``), or None when the extraction uses no prior (``orb.prior_region_share`` 1, no
        screener, or a screener that knows the frame's own region: the oracle, ``orb.truth_region_share``)."""
        orb = self.config.orb
        if self.screener is None or orb.prior_region_share >= 1.0 or hasattr(self.screener, "known_region"):
            return None
        return int(frame.index) - orb.prior_lag

    def _prior(self, k: int) -> tuple[bool, np.ndarray | None]:
        """``(resolved, region)`` of frame ``k`` (caller holds the lock): resolved once the frame was
        screened, or once a later frame began (a frame skipped, lost or failed before screening gives
        no prior). Which region an extraction gets thus depends on the order of the frames only, never
        on thread timing."""
        if k in self._regions:
            return True, self._regions[k]
        return k < self._started, None

    def _start_waiting(self) -> None:
        """Start the extractions :meth:`prepare` held back whose prior region is now resolved (in
        frame order: the ORB worker runs them in that order)."""
        pool = self._worker("orb")  # before the lock: _worker takes it
        with self._lock:
            for i in sorted(self._prepared):
                prep = self._prepared[i]
                if prep.features is not None:
                    continue
                resolved, region = self._prior(self._prior_index(prep.frame))
                if not resolved:
                    break  # the later frames need later regions
                prep.features = pool.submit(self._extract, prep.frame, region)

    def prepare(self, frame: Frame) -> None:
        """Start ahead what :meth:`process` needs from the images alone: the ORB extraction in the
        ``dynslam-orb`` worker thread and the detection in the ``dynslam-detect`` one. Safe to call
        from another thread while :meth:`process` runs on an earlier frame: the runner's reader
        thread calls it for frames ``t+1 ..`` as it decodes them, so extraction and detection run
        while frame ``t`` is tracked (OpenCV's ORB and onnxruntime release the GIL: they use the
        second core). :meth:`process` of this same frame object then waits for that work instead of
        redoing it; the results are identical (extraction and detection depend on the frame only).
        An extraction or detection error is raised by :meth:`process`, for that frame. With a prior
        region (``orb.prior_region_share < 1``) the extraction of frame ``t`` starts once frame ``t -
        orb.prior_lag`` is screened (:meth:`_prior`)."""
        pool = self._worker("orb")
        prep = _Prepared(frame, None, self._submit_detection(frame))
        k = self._prior_index(frame)
        with self._lock:
            if k is None:
                prep.features = pool.submit(self._extract, frame)
            self._prepared[int(frame.index)] = prep
        if k is not None:
            self._start_waiting()

    def _take_prepared(self, frame: Frame) -> _Prepared | None:
        """The work :meth:`prepare` did for this frame object (and forget it, and any left for
        earlier frames, e.g. frames a caller skipped), or None."""
        with self._lock:
            prep = self._prepared.pop(int(frame.index), None)
            for k in [k for k in self._prepared if k < frame.index]:
                self._prepared.pop(k).cancel()
        if prep is not None and prep.frame is not frame:  # another frame with the same index: not its work
            prep.cancel()
            return None
        return prep

    def _orb_and_detect(self, frame: Frame, t: dict) -> tuple[Features, Any]:
        """ORB extraction and detection of one frame; with ``tracking.overlap_detection`` the
        detector runs in a worker thread meanwhile (onnxruntime and OpenCV release the GIL), so
        ``t["orb"] + t["detect"]`` may exceed the time both took. After :meth:`prepare` both were
        started ahead in worker threads: ``t["orb"]`` and ``t["detect"]`` are then their times in
        those threads, and only the wait for them is in ``t["total"]``."""
        with self._lock:
            self._started = max(self._started, int(frame.index))  # the frames before it are resolved
        self._start_waiting()
        prep = self._take_prepared(frame)
        future = prep.detection if prep is not None else self._submit_detection(frame)
        try:
            if prep is not None and prep.features is not None:
                feats, t["orb"] = prep.features.result()
            else:
                k = self._prior_index(frame)
                with self._lock:
                    region = self._prior(k)[1] if k is not None else None
                feats, t["orb"] = self._extract(frame, region)
        finally:
            detections = None
            if future is not None:  # waited for even when ORB failed: one frame's detection at a time
                detections, t["detect"] = future.result()
        if self.detector is not None and future is None:
            detections, t["detect"] = self._start_detection(frame, _run_now).result()
        return feats, detections

    def _screen(self, frame: Frame, feats: Features, detections: Any, t: dict) -> tuple[np.ndarray, Any]:
        dynamic = np.zeros(len(feats), bool)
        table = None
        if self.screener is not None:
            t0 = time.perf_counter()
            # screeners that judge against the map and earlier frames get the system's knowledge
            extra = {"context": self._screening_context(feats, float(frame.timestamp))} if getattr(self.screener, "uses_context", False) else {}
            table = self.screener.screen(frame, feats.uv, detections, **extra)
            self.tracker.reference_start = self._reference_start(extra.get("context"))
            t["screen"] = 1e3 * (time.perf_counter() - t0)
            dynamic = np.asarray(table.dynamic, bool).reshape(-1)
            if len(dynamic) != len(feats):
                raise ValueError(f"screener returned {len(dynamic)} verdicts for {len(feats)} keypoints (frame {frame.index})")
            moved = getattr(self.screener, "moved_map_ids", None)  # map points the screener saw move: stale positions
            if moved is not None and len(moved):
                self.map.remove_points(moved[self.map.alive[moved]])
        return dynamic, table

    def _reference_start(self, context: ScreeningContext | None):
        """The screener's reference pose of the frame as tracking's start (``tracking.start_from_reference``):
        ``(T_c_w, keypoint indices, map point ids)`` of its inlier matches to the local map, or None when
        the screener refined no pose on the map (no context, no prediction, too few matches)."""
        ref = getattr(self.screener, "last_reference", None)
        if context is None or ref is None or ref.source != "map" or not self.config.tracking.start_from_reference:
            return None
        if ref.room or ref.surface_moved.any():  # a surface moved against the rest: let the motion model decide
            return None
        kp = np.flatnonzero(ref.inliers)
        return ref.T_c_w, kp, context.map_ids[ref.map_index[kp]]

    def _record_region(self, frame: Frame, table: Any) -> None:
        """Keep the screened region of this frame as the prior of frame ``index + orb.prior_lag``, and
        start the extractions that waited for it."""
        if self._prior_index(frame) is None:
            return
        region = getattr(table, "region_mask", None)
        with self._lock:
            self._regions[int(frame.index)] = None if region is None else np.asarray(region, bool)
            for k in [k for k in self._regions if k < int(frame.index) - self.config.orb.prior_lag]:
                del self._regions[k]  # older than any prior still needed
        self._start_waiting()

    def _screening_context(self, feats: Features, timestamp: float) -> ScreeningContext:
        """What the screener may use before tracking (``dynamic.context``): the constant-velocity
        prediction for the frame at ``timestamp`` (the tracker's own, scaled to the frame interval), the
        poses of the last tracked frames (by timestamp) and the local map points."""
        tr = self.tracker
        T_pred = None  # constant velocity; constant position while the velocity is unknown (frame 1, after relocalisation)
        if tr.state in (TrackState.OK, TrackState.RELOCALIZED) and tr.last is not None and tr.last.T_w_c is not None:
            T_pred = se3_inv(tr.last.T_w_c) if tr.velocity is None else tr.predict_pose(timestamp)
        poses = {ts: self.map.keyframe_pose(ref) @ T_ref_c for ts, ref, T_ref_c in self._anchors[-self.screener.history_length:]}
        ids = self.map.points_of([k for k in tr.local_kf_ids if k in self.map.keyframes])
        return ScreeningContext(T_pred, poses, ids, self.map.xyz[ids], self.map.descriptors[ids], feats.descriptors, feats.octave,
                                self.config.orb.scale_factor)

    def _new_keyframe(self, sf: SlamFrame, frame: Frame, all_points: bool = False,
                      region: np.ndarray | None = None) -> tuple[KeyFrame, np.ndarray]:
        """Insert a keyframe made from ``sf`` with new points from depth (all of them at the
        initialisation, as ORB-SLAM2's ``StereoInitialization``; else close ones first). ``region``: the
        frame's screened dynamic region ``(H, W)`` bool, left out of the depth the keyframe keeps."""
        thumb = cv2.resize(frame.rgb, (160, 120), interpolation=cv2.INTER_AREA)
        kf = KeyFrame.from_frame(self.map.new_keyframe_id(), sf, thumbnail=thumb)
        lc = self.loop_closer.config if self.loop_closer is not None else None
        if lc is not None and lc.enabled and lc.dense_factor > 0 and frame.depth is not None:
            depth = frame.depth
            if region is not None and region.shape == depth.shape and region.any():
                depth = np.where(region, 0.0, depth)  # movers are no evidence of the place
            kf.depth_small = reduce_depth(depth, lc.dense_factor)  # the loop pose's depth alignment
        self.map.add_keyframe(kf)
        # far points only while the screening judges the scene static (Tracker.scene_static; ours)
        close = np.inf if all_points else (self.new_point_depth if self.tracker.scene_static(sf.index) else self.close_depth)
        new = create_points_from_depth(self.map, kf, close, self.config.tracking.kf_new_points_min, frame.rgb)
        sf.map_point_ids = kf.map_point_ids.copy()
        sf.outlier[:] = False
        self.tracker.ref_kf = kf
        self.tracker.last_kf_frame = sf.index
        return kf, new

    def _index_keyframe(self, kf: KeyFrame) -> None:
        """Add a keyframe's BoW vector (static keypoints only, as the loop closer does) to the
        system's own database, and drop the keyframes local mapping has culled."""
        db = self._own_database
        db.prune(self.map.keyframes)
        bow = static_bow(self.tracker.vocabulary, kf)
        if len(bow) and kf.id not in db:
            db.add(kf.id, bow)

    def _initialize(self, sf: SlamFrame, frame: Frame) -> bool:
        cfg = self.config.tracking
        has_depth = np.isfinite(sf.depth)
        n = int((sf.static & has_depth).sum())
        weak = 0 < cfg.init_weak_min_points <= n and int(has_depth.sum()) < cfg.init_min_points
        if n < cfg.init_min_points and not weak:
            return False
        sf.T_w_c = np.eye(4)
        kf, _ = self._new_keyframe(sf, frame, all_points=True)
        # the first keyframe is the local map of the next frame: the screener's reference pose of frame 1
        # needs it (tracking sets the local keyframes only when it tracks the local map)
        self.tracker.local_kf_ids = [kf.id]
        self.tracker.last = sf
        self.tracker.state = TrackState.OK
        self.tracker.velocity = None
        return True

    # ------------------------------------------------------------------ main
    def process(self, frame: Frame) -> FrameResult:
        """Track one RGB-D frame; returns its :class:`FrameResult`."""
        t: dict[str, float] = {"orb": 0.0, "detect": 0.0, "screen": 0.0, "track": 0.0, "local_mapping": 0.0, "loop": 0.0}
        t_start = time.perf_counter()
        loop_errors: list[str] = []
        self._apply_loop_corrections(t, loop_errors)
        feats, detections = self._orb_and_detect(frame, t)
        dynamic, table = self._screen(frame, feats, detections, t)
        self._record_region(frame, table)
        tc = self.config.tracking
        region = getattr(table, "region_mask", None)
        sf = make_slam_frame(frame, feats, static=~dynamic, min_depth=tc.min_depth, max_depth=tc.max_depth,
                             dynamic_region=region)
        res = FrameResult(frame.index, float(frame.timestamp), TrackState.LOST, None, n_features=len(feats),
                          n_dynamic=int(dynamic.sum()), uv=feats.uv, dynamic=dynamic, table=table,
                          region_mask=region, error="; ".join(loop_errors))
        t0 = time.perf_counter()
        kf = None
        new_pts = np.zeros(0, np.int64)
        if self.tracker.state == TrackState.NOT_INITIALIZED:
            if self._initialize(sf, frame):
                res.method = "initialization"
                kf = self.tracker.ref_kf
                res.state = TrackState.OK
            else:
                res.state = TrackState.NOT_INITIALIZED
        else:
            res.state = self.tracker.track(sf)
            res.method = self.tracker.method
            res.n_inliers = self.tracker.n_inliers
            if sf.T_w_c is not None and self.tracker.need_keyframe(sf):
                kf, new_pts = self._new_keyframe(sf, frame, region=res.region_mask)
        t["track"] = 1e3 * (time.perf_counter() - t0)
        if kf is not None and res.method != "initialization":
            t0 = time.perf_counter()
            res.local_mapping = self.mapper.process(kf, new_pts, capped=self.tracker.in_bad_stretch(sf.index))
            t["local_mapping"] = 1e3 * (time.perf_counter() - t0)
        if kf is not None:
            res.is_keyframe, res.keyframe_id = True, kf.id
            if self._own_database is not None:
                self._index_keyframe(kf)
            if self.loop_closer is not None:
                t0 = time.perf_counter()
                T_ref_c = kf.T_c_w @ sf.T_w_c if sf.T_w_c is not None else None
                try:
                    loop = self.loop_closer.on_keyframe(kf, self.map)
                except Exception as exc:  # the tracked pose must not be lost with it
                    loop = None
                    res.error = f"loop closing failed: {type(exc).__name__}: {exc}"
                if loop is not None or res.error:  # a loop applied at once (or a failure half-way) changed the map;
                    self.map.invalidate()  # else the caches (observation table, covisibility) stay valid for tracking
                t["loop"] += 1e3 * (time.perf_counter() - t0)
                if loop is not None:
                    res.loop = loop
                    self._record_loop(loop)
                    if getattr(loop, "applied", True) and T_ref_c is not None and kf.id in self.map.keyframes:
                        # Corrected at once (no worker): re-anchor the current frame on its keyframe.
                        sf.T_w_c = self.map.keyframes[kf.id].T_w_c @ T_ref_c
        if sf.T_w_c is not None:
            ref = self.tracker.ref_kf
            ref_id = ref.id if ref is not None else kf.id
            T_w_ref = self.map.keyframe_pose(ref_id)
            self._anchors.append((float(frame.timestamp), ref_id, se3_inv(T_w_ref) @ sf.T_w_c))
            res.T_w_c = sf.T_w_c.copy()
            if dynamic.any():
                dz = sf.points_c[dynamic]
                dz = dz[np.isfinite(dz).all(axis=1)]
                res.dynamic_xyz = transform_points(sf.T_w_c, dz) if len(dz) else np.zeros((0, 3))
        else:  # lost, or not initialised yet (too few keypoints with depth): no pose
            self.lost_frames.append(frame.index)
        t["total"] = 1e3 * (time.perf_counter() - t_start)
        res.timings_ms = t
        return res

    def _record_loop(self, loop) -> None:
        self.loop_results.append(loop)
        ids = [int(i) for i in np.asarray(getattr(loop, "keyframe_ids", ()), dtype=np.int64).reshape(-1)]
        if len(ids) >= 2:
            self.loop_edges.append((ids[0], ids[1]))

    def _apply_loop_corrections(self, t: dict, errors: list, wait: bool = False) -> None:
        """Apply the loop corrections the loop closer's worker has finished (all of them when ``wait``),
        between two frames, and move the last tracked frame with its reference keyframe (ORB-SLAM2
        keeps each frame relative to its reference keyframe for this)."""
        if self.loop_closer is None or not getattr(self.loop_closer, "busy", False):
            return
        t0 = time.perf_counter()
        try:
            applied = self.loop_closer.poll(self.map, wait=wait)
        except Exception as exc:  # a failed correction must not stop tracking
            applied = []
            errors.append(f"loop correction failed: {type(exc).__name__}: {exc}")
        for loop in getattr(self.loop_closer, "loops", [])[len(self.loop_results):]:
            self._record_loop(loop)  # accepted by the worker's verification (background)
        if applied:
            self.map.invalidate()
            last = self.tracker.last
            if last is not None and last.T_w_c is not None and self._anchors:
                _, ref, T_ref_c = self._anchors[-1]
                last.T_w_c = self.map.keyframe_pose(ref) @ T_ref_c
        t["loop"] = t.get("loop", 0.0) + 1e3 * (time.perf_counter() - t0)

    def finish_loop_closing(self) -> None:
        """Wait for the loop closer's pending corrections and apply them (the outputs call this first);
        a correction that failed is recorded in :attr:`loop_errors`."""
        self._apply_loop_corrections({}, self.loop_errors, wait=True)
        close = getattr(self.loop_closer, "close_pending", None)
        if close is not None and close(self.map):  # a loop kept waiting for a better-conditioned one
            self._apply_loop_corrections({}, self.loop_errors, wait=True)

    def mark_lost(self, index: int) -> None:
        """Record a frame that could not be processed at all (unreadable image)."""
        self.lost_frames.append(int(index))

    # --------------------------------------------------------------- outputs
    def trajectory(self, wait: bool = True) -> Trajectory:
        """Every tracked frame, ``T_w_c = T_w_ref T_ref_c`` with the current keyframe poses; ``wait``:
        the pending loop corrections first (False: as the map stands, without waiting for the loop
        closer's worker: what a partial flush during a run writes)."""
        if wait:
            self.finish_loop_closing()
        if not self._anchors:
            return Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
        ts = np.array([a[0] for a in self._anchors])
        cache: dict[int, np.ndarray] = {}
        poses = []
        for _, ref, T_ref_c in self._anchors:  # one matrix product per frame
            if ref not in cache:
                cache[ref] = self.map.keyframe_pose(ref)
            poses.append(cache[ref] @ T_ref_c)
        return Trajectory(ts, np.stack(poses))

    def keyframe_arrays(self, wait: bool = True) -> dict[str, np.ndarray]:
        """Arrays of ``keyframes.npz``: ids, frame_index, timestamps, poses, loop_edges (``wait``: as
        :meth:`trajectory`)."""
        if wait:
            self.finish_loop_closing()
        kfs = [self.map.keyframes[k] for k in sorted(self.map.keyframes)]
        edges = set(self.loop_edges)
        for kf in kfs:
            for o in kf.loop_edges:
                edges.add((min(kf.id, o), max(kf.id, o)))
        return {
            "ids": np.array([k.id for k in kfs], np.int64),
            "frame_index": np.array([k.frame_index for k in kfs], np.int64),
            "timestamps": np.array([k.timestamp for k in kfs], np.float64),
            "poses": np.stack([k.T_w_c for k in kfs]) if kfs else np.zeros((0, 4, 4)),
            "loop_edges": np.array(sorted(edges), np.int64).reshape(-1, 2),
        }

    def map_point_arrays(self, wait: bool = True) -> dict[str, np.ndarray]:
        """Arrays of ``map_points.npz``: xyz, rgb, n_obs of the alive points (``wait``: as :meth:`trajectory`)."""
        if wait:
            self.finish_loop_closing()
        ids = self.map.point_ids()
        return {"xyz": self.map.xyz[ids].copy(), "rgb": self.map.rgb[ids].copy(), "n_obs": self.map.n_obs(ids)}
