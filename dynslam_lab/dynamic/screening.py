"""The screener: the dynamic-feature stages chained by configuration.

``build_screener(filters, config)`` returns a :class:`Screener` whose ``screen(frame, uv,
detections)`` fills one :class:`~dynslam_lab.dynamic.table.KeypointTable` per frame (contract
in ``docs/architecture.md``). ``filters`` is a named preset or a comma-separated stage list:

=================  =====================================================================
``none``           no screening (``build_screener`` returns None)
``semantic``       semantic prior: keypoints on a-priori dynamic detections (YOLO-SLAM "D")
``depth_ransac``   person boxes + depth-RANSAC (YOLO-SLAM "D + G", Wu et al. 2022)
``geometry``       epipolar + multi-view checks, no detector (Chang et al. 2021 "multi-view only")
``full``           semantic (masks), depth-RANSAC for box-only detections, epipolar,
                   multi-view, adaptive flow, motion-probability restoration
``oracle``         the synthetic renderer's truly moving instances (perfect masks)
``a,b,c``          any of ``semantic, depth_ransac, epipolar, multiview, flow, level_rule, restoration``
=================  =====================================================================

How the columns combine into the verdict (per keypoint):

* ``prior`` = on an a-priori dynamic detection (``semantic``), narrowed to the depth-RANSAC
  consensus set inside boxes when ``depth_ransac`` runs;
* ``geometric`` = ``epipolar`` and ``multiview`` when the semantic stage runs, either of them
  otherwise (``ScreeningConfig.geometric_vote="auto"``; ``"both"`` / ``"any"`` force one rule), from LK pairs with the previous frame; pairs on a-priori dynamic
  detections are left out of F and of the rough pose; a test that cannot run (too few pairs, camera
  at rest for F) does not vote;
* ``flow`` = inside a human-driven flow region;
* ``dynamic = prior or geometric or flow`` (with ``level_rule``: ``prior`` is replaced by
  "high/medium level", Zhang et al.'s rule);
* ``restoration`` gives back prior-only keypoints while the static ratio is below ``delta_1``.

The screener keeps the previous grey image and depth between calls; ``reset()`` forgets them
(the first frame after a reset has no geometric/flow verdict).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from .config import FILTER_PRESETS, STAGES, ScreeningConfig
from .oracle import OracleScreener
from .table import KeypointTable, check_uv, depth_at

__all__ = ["Screener", "build_screener", "parse_filters", "FILTERS"]

#: The named filters.
FILTERS = (*FILTER_PRESETS, "oracle")


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


class Screener:
    """Chained screening stages with one frame of history.

    Parameters
    ----------
    stages : stage names (see :data:`dynslam_lab.dynamic.config.STAGES`).
    config : all parameters.
    name : label for tables and summaries (the filter name).
    """

    def __init__(self, stages: tuple[str, ...], config: ScreeningConfig | None = None, name: str | None = None):
        self.config = config or ScreeningConfig()
        bad = [s for s in stages if s not in STAGES]
        if bad:
            raise ValueError(f"Screener: unknown stages {bad}; known: {list(STAGES)}")
        self.stages = tuple(stages)
        self.name = name or ",".join(stages)
        self._prev_gray: np.ndarray | None = None
        self._prev_depth: np.ndarray | None = None
        self._rng = np.random.default_rng(self.config.depth_ransac.seed)

    def __repr__(self) -> str:
        return f"Screener({self.name!r}, stages={self.stages})"

    def reset(self) -> None:
        """Forget the previous frame (and restart the random stream)."""
        self._prev_gray = None
        self._prev_depth = None
        self._rng = np.random.default_rng(self.config.depth_ransac.seed)

    # ------------------------------------------------------------------ the chain
    def screen(self, frame, uv: np.ndarray, detections=None) -> KeypointTable:
        """Judge every keypoint of ``frame``.

        Parameters
        ----------
        frame : :class:`~dynslam_lab.datasets.frame.Frame` (rgb, depth in metres, camera).
        uv : ``(N, 2)`` keypoint pixels.
        detections : :class:`~dynslam_lab.detection.detections.Detections` or None.

        Returns
        -------
        KeypointTable with one column per stage that ran and the final ``dynamic``.
        """
        from .semantic import semantic_prior

        cfg = self.config
        uv = check_uv(uv)
        n = len(uv)
        gray = frame.gray
        shape = gray.shape
        if self._prev_gray is not None and self._prev_gray.shape != shape:
            self.reset()  # a new image size: the history does not apply
        timings: dict[str, float] = {}
        stages: dict[str, np.ndarray] = {}
        values: dict[str, np.ndarray] = {}
        t0 = time.perf_counter()
        z = depth_at(frame.depth, uv)
        on = set(self.stages)

        # 1. semantic prior ------------------------------------------------------
        use_level_rule = "level_rule" in on
        sem_cfg = cfg.semantic
        if "depth_ransac" in on and "epipolar" not in on and "flow" not in on:
            sem_cfg = replace(sem_cfg, use_masks=False)  # YOLO-SLAM works on boxes
        if use_level_rule:
            sem_cfg = replace(sem_cfg, prior="levels")
        dets = detections if "semantic" in on else None
        sem = semantic_prior(uv, dets, sem_cfg, cfg.priors)
        candidate = sem.flagged.copy()  # on a potentially moving detection (left out of F / pose)
        prior = sem.flagged.copy()
        if "semantic" in on:
            stages["semantic"] = sem.flagged.copy()
        timings["semantic"] = _ms(t0)

        # 2. depth-RANSAC inside boxes ------------------------------------------
        region_parts: list[np.ndarray] = []
        box_regions: dict[int, np.ndarray] = {}
        ran = np.zeros(n, bool)  # keypoints whose prior depth-RANSAC decided
        if "depth_ransac" in on and dets is not None and len(dets):
            t = time.perf_counter()
            from .depth_ransac import screen_boxes

            has_mask = dets.masks is not None and sem_cfg.use_masks
            run = sem.dynamic_detections & (not has_mask or cfg.depth_ransac_with_masks)
            dr = np.zeros(n, bool)
            for d in np.flatnonzero(run):
                members = sem.instance == d
                dyn_d, res = screen_boxes(uv[members], z[members], dets.boxes[d : d + 1], cfg.depth_ransac, self._rng,
                                          depth_image=frame.depth)
                dr[np.flatnonzero(members)[dyn_d]] = True
                if res[0] is not None and res[0].depth_range is not None:
                    box_regions[int(d)] = _box_depth_region(frame.depth, dets.boxes[d], res[0].depth_range)
            ran = run[np.maximum(sem.instance, 0)] & (sem.instance >= 0)
            prior = np.where(ran, dr, prior)
            stages["depth_ransac"] = dr
            timings["depth_ransac"] = _ms(t)

        # 3./4. epipolar and multi-view checks against the previous frame -------
        geometric = np.zeros(n, bool)
        votes: list[np.ndarray] = []
        T_c_p = None
        need_pairs = on & {"epipolar", "multiview", "flow"}
        if need_pairs and self._prev_gray is not None:
            t = time.perf_counter()
            from .epipolar import epipolar_check, track_lk

            uv_prev, matched = track_lk(self._prev_gray, gray, uv, cfg.lk)
            timings["lk"] = _ms(t)
            if "epipolar" in on:
                t = time.perf_counter()
                ep = epipolar_check(uv, uv_prev, matched, candidate, shape, cfg.epipolar)
                stages["epipolar"] = ep.dynamic
                values["epipolar_px"] = ep.distance
                if ep.F is not None:  # a test that could not run does not vote
                    votes.append(ep.dynamic)
                timings["epipolar"] = _ms(t)
            if on & {"multiview", "flow"}:
                t = time.perf_counter()
                from .multiview import multiview_check

                z_prev = depth_at(self._prev_depth, np.nan_to_num(uv_prev, nan=-1.0))
                mv = multiview_check(uv, z, uv_prev, z_prev, matched, candidate, frame.camera, cfg.multiview)
                T_c_p = mv.T_c_p
                if "multiview" in on:
                    stages["multiview"] = mv.dynamic
                    values["reprojection_px"] = mv.reprojection_px
                    values["depth_error_m"] = mv.depth_error_m
                    if mv.T_c_p is not None:
                        votes.append(mv.dynamic)
                timings["multiview"] = _ms(t)
            if votes:
                vote = cfg.geometric_vote
                if vote == "auto":
                    vote = "both" if "semantic" in on else "any"
                geometric = np.logical_and.reduce(votes) if vote == "both" else np.logical_or.reduce(votes)
                if "semantic" in on and cfg.geometry_mask_margin_px > 0 and dets is not None and sem.dynamic_detections.any():
                    near = _near_mask(dets, sem, sem_cfg, shape, cfg.geometry_mask_margin_px)
                    from .table import values_at

                    geometric &= ~values_at(near, uv, outside=False).astype(bool)

        # 5. adaptive-threshold dense flow --------------------------------------
        flow_flag = np.zeros(n, bool)
        if "flow" in on and self._prev_gray is not None and dets is not None and len(dets):
            t = time.perf_counter()
            from .flow import flow_regions
            from .table import values_at

            person = _union(dets.region_masks()[sem.dynamic_detections], shape) if sem.dynamic_detections.any() else None
            if person is not None and person.any():
                fr = flow_regions(gray, self._prev_gray, person, frame.depth, frame.camera, T_c_p, cfg.flow)
                flow_flag = values_at(fr.region, uv, outside=False).astype(bool)
                region_parts.append(fr.region)
                values["flow_threshold_px"] = np.full(n, fr.threshold_px)
            stages["flow"] = flow_flag
            timings["flow"] = _ms(t)

        # 6. Zhang et al.'s rule, the verdict, and motion-probability restoration ---
        if use_level_rule:
            from .geometric_rule import level_rule_verdict

            lvl = sem.level.copy()
            lvl[~prior & (lvl >= 2)] = 1  # depth-RANSAC background inside a box: judged geometrically
            dynamic = level_rule_verdict(lvl, geometric) | flow_flag
            stages["level_rule"] = dynamic.copy()
            prior = prior & (lvl >= 2)
        else:
            dynamic = prior | geometric | flow_flag
        restored = np.zeros(n, bool)
        if "restoration" in on:
            from .motion_probability import restore_by_motion_probability

            rr = restore_by_motion_probability(dynamic, prior, sem.motion_prob, geometric | flow_flag, cfg.restoration)
            restored = rr.restored
            dynamic = dynamic & ~restored
            stages["restoration"] = restored

        reason = np.full(n, "", dtype=object)
        for st in ("flow", "multiview", "epipolar", "depth_ransac", "semantic"):  # first stage wins: set last
            if st == "semantic":
                col = prior & ~ran
            elif st == "depth_ransac":
                col = prior & ran
            else:
                col = stages.get(st, np.zeros(n, bool))
                if st in ("epipolar", "multiview"):
                    col = col & geometric  # with geometric_vote="both" a lone flag does not decide
            reason[col & dynamic] = st
        if "level_rule" in stages:
            reason[dynamic & (reason == "")] = "level_rule"
        reason[restored] = "restored"

        # region mask: the dynamic detections still dynamic, their box-depth regions, flow regions
        region_mask = None
        if dets is not None and len(dets) and "semantic" in on:
            keep_det = np.zeros(len(dets), bool)
            inst_dyn = sem.instance[dynamic & prior]
            keep_det[np.unique(inst_dyn)] = True
            keep_det &= sem.dynamic_detections
            for d in np.flatnonzero(keep_det):
                if int(d) in box_regions:
                    region_parts.append(box_regions[int(d)])
                elif dets.masks is not None and sem_cfg.use_masks:
                    region_parts.append(dets.masks[d])
                else:
                    region_parts.append(dets.region_masks()[d])
        if region_parts:
            region_mask = _union(np.asarray(region_parts), shape)
        elif self.stages and "semantic" in on:
            region_mask = np.zeros(shape, bool)

        self._prev_gray = gray
        self._prev_depth = frame.depth
        timings["total"] = _ms(t0)
        return KeypointTable(
            uv=uv, depth=z, class_id=sem.class_id, instance=sem.instance, motion_prob=sem.motion_prob,
            dynamic=dynamic, reason=reason, stages=stages, values=values, restored=restored,
            region_mask=region_mask, timings_ms=timings,
        )


def build_screener(filters: str, config: ScreeningConfig | None = None) -> Screener | OracleScreener | None:
    """The screener of a filter name (``none`` -> None); see the module docstring."""
    config = config or ScreeningConfig()
    stages = parse_filters(filters, config)
    if stages == ("oracle",):
        return OracleScreener(config)
    if not stages:
        return None
    return Screener(stages, config, name=str(filters).strip().lower())


# ---------------------------------------------------------------------- helpers
def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1000.0


def _union(masks: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    masks = np.asarray(masks, bool)
    if masks.size == 0:
        return np.zeros(shape, bool)
    return masks.any(axis=0)


def _near_mask(dets, sem, sem_cfg, shape, margin: int) -> np.ndarray:
    """``(H, W)`` bool: within ``margin`` px of an a-priori dynamic detection (mask, else box)."""
    import cv2

    sel = sem.dynamic_detections
    if dets.masks is not None and sem_cfg.use_masks:
        union = dets.masks[np.flatnonzero(sel)].any(axis=0)
    else:
        union = dets.region_masks()[sel].any(axis=0)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
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
