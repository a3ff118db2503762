"""Per-keypoint precision and recall of the dynamic verdict against the synthetic truth.

None of the papers can measure this: TUM has no per-pixel motion labels. The synthetic
renderer (``dynslam_lab.datasets.synthetic``) writes an instance-id image per frame and the
list of instances that truly move in each frame (``moving.txt``, read by ``read_moving``).

Truth. A keypoint is **truly dynamic** when its pixel (nearest integer position) lies on an
instance that moves in that frame. A sitting person counts as dynamic only in the frames where
the renderer moves them (a shifting arm or head); in the frames where they sit still their
keypoints are static, so a filter that removes every person pays in precision on sitting
sequences. Instances that never move (chairs, monitors) are static.

With ``TP`` dynamic keypoints judged dynamic, ``FP`` static judged dynamic and ``FN`` dynamic
judged static::

    precision = TP / (TP + FP),     recall = TP / (TP + FN)

summed over all frames of a run (micro-average), so frames with many keypoints weigh more.

**Movers at rest.** A box that stops, or a person who stands still between two walks, is static
in those frames, so a screener that keeps it out (DynaSLAM's and our temporal consistency: "a map
point seen moving stays dynamic", which the tracker needs: a mover mapped while it rests pulls the
pose when it starts again) pays in precision. :class:`KeypointScorer` therefore also counts the
false positives on instances that move in some frame of the run (``fp_at_rest``) and reports
``precision_at_rest_ok = (TP + FP_at_rest) / (TP + FP)``: the precision when keeping a mover at rest
out is counted as right. Only false positives on things that never move lower it. The strict
``precision`` stays the headline number.

**Where the other false positives lie.** ``fp_by_kind`` splits the false positives by the distance (px)
from the nearest instance moving in that frame (``FP_DISTANCE_EDGES_PX``: the outline within 4 px, where a
corner on an occluding contour moves with the mover though its pixel centre is on the background; 4-12 px;
12-40 px; farther, where a whole static region was judged moving), after those on movers at rest.
``fn_by_kind`` splits the misses the same way from the inside: a keypoint on a moving instance within 4 px of
its outline (the silhouette, whose cell of the reduced depth straddles the depth edge) or deeper inside;
``fn_without_depth`` counts the misses where the sensor gave no depth.

**Away from the outlines.** A corner on a mover's outline is made by the mover's edge and the background behind
it; it moves with the mover whichever side of the outline its pixel centre falls on, and the sensor often gives
it no depth. The truth calls it dynamic or static by that centre alone. ``away_from_outlines`` therefore also
scores only the keypoints farther than :data:`OUTLINE_BAND_PX` from every moving outline (either side): what a
filter does where the truth is not a matter of a pixel. The strict scores stay the headline numbers.

**By the movers' image speed.** ``by_instance`` keeps, per frame and moving instance, the keypoints on it and
how many were judged dynamic; :func:`recall_by_image_speed` bins them by ``f v dt / z`` (the instance's speed
``v`` of its reference point and mean depth ``z`` from the renderer's ``coverage.csv``): roughly how far the mover
moved in the image since the previous frame (a motion along the line of sight moves it less; a walking person's
limbs or a swinging door's free edge move more). An instance whose depth the renderer did not record in a frame
counts as still there. Each bin's misses are also split by how much of their mover that frame found (none of its
keypoints judged dynamic, fewer than half, half or more): a mover not found at all and the rest of a mover found in
part call for different work (docs/robustness.md, "What the misses are made of").
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..dynamic.oracle import moving_mask, truth_dynamic
from ..dynamic.table import KeypointTable, depth_at, values_at
from ..features.orb import OrbConfig, extract_features
from ..geometry.se3 import rotation_angle_deg

__all__ = ["KeypointScore", "score_keypoints", "signed_outline_distance", "corner_motion_at_outlines", "ScoringScreener",
           "KeypointScorer", "recall_by_image_speed", "FP_DISTANCE_EDGES_PX", "FP_KINDS", "FN_KINDS", "OUTLINE_BAND_PX", "IMAGE_SPEED_EDGES_PX"]

#: Bin edges (px) of a false positive's distance from the nearest moving instance (``KeypointScorer.fp_by_kind``).
FP_DISTANCE_EDGES_PX = (4.0, 12.0, 40.0)
#: The kinds of ``KeypointScorer.fp_by_kind``, in order: movers at rest, then the distance bins.
FP_KINDS = ("at rest", "< 4 px", "4-12 px", "12-40 px", "> 40 px")
#: The kinds of ``KeypointScorer.fn_by_kind``: missed keypoints within the first edge of ``FP_DISTANCE_EDGES_PX``
#: of their moving instance's outline (inside it), and deeper.
FN_KINDS = ("silhouette < 4 px", "inside")
#: Keypoints within this distance (px) of a moving instance's outline, on either side, are left out of
#: ``KeypointScorer.away_from_outlines`` (module docstring).
OUTLINE_BAND_PX = 4.0
#: Bin edges (px a frame) of :func:`recall_by_image_speed`.
IMAGE_SPEED_EDGES_PX = (0.5, 1.0, 2.0, 4.0, 8.0)


def signed_outline_distance(moving: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``(N,)`` distance (px) from each keypoint ``uv`` to the nearest outline of the ``(H, W)`` bool mask
    ``moving``: negative on the mask (its pixel, as :func:`~dynslam_lab.dynamic.oracle.truth_dynamic` reads
    it), positive off it; ``+inf`` everywhere when the mask is empty."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    if not moving.any():
        return np.full(len(uv), np.inf)
    on = values_at(moving, uv, outside=False).astype(bool)
    inner = cv2.distanceTransform(moving.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    outer = cv2.distanceTransform((~moving).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return np.where(on, -values_at(inner, uv, outside=0.0), values_at(outer, uv, outside=np.inf))


def corner_motion_at_outlines(frames, orb_config=None, lk_window: int = 21) -> tuple[np.ndarray, np.ndarray]:
    """How far the ORB corners of a camera at rest move between consecutive frames, by their distance to the
    moving outlines: ``(distance, motion)``, both ``(N,)`` over all frames after the first, ``distance`` as
    :func:`signed_outline_distance` (negative on a mover) and ``motion`` the pyramidal Lucas-Kanade displacement
    (px) to the previous frame of each corner it tracked. A camera at rest leaves a static corner where it was;
    a corner whose pixel lies on the background but whose FAST circle (radius 3 px) reaches across a moving
    outline moves with the mover (docs/robustness.md, "Perfect masks and the corners on their outlines").

    ``frames``: renderer frames (with ``instance_mask``, ``moving_ids`` and ``T_w_c_gt``) of a camera at rest;
    a ValueError names the frame whose camera moved more than 1 mm or 0.05 deg since the one before (a hand-held
    camera's tremor, as the renderer's ``*_static`` presets have, stays well below), or that has no masks."""
    cfg = orb_config or OrbConfig()
    dist, motion = [], []
    prev, T0 = None, None  # the previous frame's grey image and pose
    for f in frames:
        gray = f.gray
        if f.T_w_c_gt is not None:
            if T0 is not None:
                angle = rotation_angle_deg(T0[:3, :3].T @ f.T_w_c_gt[:3, :3])
                if np.linalg.norm(f.T_w_c_gt[:3, 3] - T0[:3, 3]) > 1e-3 or angle > 0.05:
                    raise ValueError(f"corner_motion_at_outlines needs a camera at rest; frame {f.index} "
                                     f"({f.rgb_path}) moved more than 1 mm or 0.05 deg from the one before")
            T0 = f.T_w_c_gt
        moving = moving_mask(f)
        if moving is None:
            raise ValueError(f"corner_motion_at_outlines needs the renderer's instance masks; frame {f.index} "
                             f"({f.rgb_path}) has none")
        if prev is not None and moving.any():
            uv = extract_features(gray, cfg).uv.astype(np.float32)
            if len(uv):
                back, status, _ = cv2.calcOpticalFlowPyrLK(gray, prev, uv, None, winSize=(lk_window, lk_window),
                                                          maxLevel=3)
                ok = status.ravel() == 1
                dist.append(signed_outline_distance(moving, uv[ok]))
                motion.append(np.linalg.norm(back[ok] - uv[ok], axis=1))
        prev = gray
    if not dist:
        return np.zeros(0), np.zeros(0)
    return np.concatenate(dist), np.concatenate(motion)


@dataclass
class KeypointScore:
    """Confusion counts of the dynamic verdict (keypoints)."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    tn: int = 0

    @property
    def precision(self) -> float:
        """``TP / (TP + FP)``; nan when nothing was judged dynamic."""
        d = self.tp + self.fp
        return self.tp / d if d else float("nan")

    @property
    def recall(self) -> float:
        """``TP / (TP + FN)``; nan when nothing was truly dynamic."""
        d = self.tp + self.fn
        return self.tp / d if d else float("nan")

    def __add__(self, other: "KeypointScore") -> "KeypointScore":
        return KeypointScore(self.tp + other.tp, self.fp + other.fp, self.fn + other.fn, self.tn + other.tn)

    def to_dict(self) -> dict:
        return {"tp": self.tp, "fp": self.fp, "fn": self.fn, "tn": self.tn,
                "precision": self.precision, "recall": self.recall}


def score_keypoints(predicted: np.ndarray, truth: np.ndarray) -> KeypointScore:
    """Confusion counts of ``predicted (N,)`` bool against ``truth (N,)`` bool."""
    p = np.asarray(predicted, bool).reshape(-1)
    t = np.asarray(truth, bool).reshape(-1)
    if p.shape != t.shape:
        raise ValueError(f"score_keypoints: {p.shape[0]} predictions, {t.shape[0]} truths")
    return KeypointScore(int((p & t).sum()), int((p & ~t).sum()), int((~p & t).sum()), int((~p & ~t).sum()))


@dataclass
class ScoringScreener:
    """Wraps a screener and scores every table it returns against the synthetic truth.

    For screening on its own (notebooks, tests, ``benchmarks/screening_speed.py``): call
    ``screen`` frame by frame; ``score`` holds the summed counts and ``per_frame`` one
    :class:`KeypointScore` per frame that had truth. With ``inner=None`` (the ``none`` filter)
    every keypoint is judged static. A whole run is scored by :class:`KeypointScorer`.
    """

    inner: object | None
    score: KeypointScore = field(default_factory=KeypointScore)
    per_frame: list[KeypointScore] = field(default_factory=list)
    timings_ms: list[dict[str, float]] = field(default_factory=list)

    @property
    def name(self) -> str:
        return getattr(self.inner, "name", "none")

    def reset(self) -> None:
        if self.inner is not None:
            self.inner.reset()

    def screen(self, frame, uv, detections=None):
        if self.inner is None:
            table = KeypointTable.blank(uv, depth_at(frame.depth, uv))
        else:
            table = self.inner.screen(frame, uv, detections)
        truth = truth_dynamic(frame, table.uv)
        if truth is not None:
            s = score_keypoints(table.dynamic, truth)
            self.per_frame.append(s)
            self.score = self.score + s
        self.timings_ms.append(dict(table.timings_ms))
        return table


@dataclass
class KeypointScorer:
    """Scores the verdicts of a whole run: pass it as ``run_sequence(..., on_frame=scorer)``.

    After the run ``score`` holds the summed counts of the frames that had truth, ``per_frame``
    one :class:`KeypointScore` each, and ``screen_ms`` the screening time of every frame;
    ``fp_at_rest`` / ``precision_at_rest_ok`` split the false positives on movers at rest from
    those on things that never move (module docstring).
    """

    score: KeypointScore = field(default_factory=KeypointScore)
    per_frame: list[KeypointScore] = field(default_factory=list)
    screen_ms: list[float] = field(default_factory=list)
    fp_by_instance: Counter = field(default_factory=Counter)  # instance id -> false positives on it
    moving_instances: set = field(default_factory=set)  # instances that moved in some frame of the run
    fp_by_place: Counter = field(default_factory=Counter)  # (instance id, distance bin) -> false positives
    fp_by_stage: Counter = field(default_factory=Counter)  # stage that flagged them (the table's reason) -> false positives
    fn_by_kind: Counter = field(default_factory=Counter)  # FN_KINDS -> missed keypoints
    fn_without_depth: int = 0  # missed keypoints where the sensor gave no depth
    away_from_outlines: KeypointScore = field(default_factory=KeypointScore)  # keypoints beyond OUTLINE_BAND_PX of every moving outline
    by_instance: dict = field(default_factory=dict)  # (frame index, moving instance id) -> [keypoints on it, judged dynamic]

    @property
    def fp_at_rest(self) -> int:
        """False positives on instances that move in some frame of the run (movers at rest)."""
        return int(sum(c for i, c in self.fp_by_instance.items() if i in self.moving_instances))

    @property
    def precision_at_rest_ok(self) -> float:
        """``(TP + FP_at_rest) / (TP + FP)``: precision when keeping a mover at rest out counts as right; nan
        when nothing was judged dynamic."""
        d = self.score.tp + self.score.fp
        return (self.score.tp + self.fp_at_rest) / d if d else float("nan")

    @property
    def fp_by_kind(self) -> dict[str, int]:
        """False positives by kind (:data:`FP_KINDS`): on movers at rest, else by the distance bin from the
        nearest instance moving in their frame (module docstring)."""
        out = dict.fromkeys(FP_KINDS, 0)
        for (inst, b), c in self.fp_by_place.items():
            out[FP_KINDS[0] if inst in self.moving_instances else FP_KINDS[1 + b]] += int(c)
        return out

    def __call__(self, frame, result) -> None:
        self.screen_ms.append(float(result.timings_ms.get("screen", float("nan"))))
        moving = moving_mask(frame)  # the truth's own mask (a-priori classes without moving_ids), made once
        truth = truth_dynamic(frame, result.uv, mask=moving)
        if truth is not None:
            s = score_keypoints(result.dynamic, truth)
            self.per_frame.append(s)
            self.score = self.score + s
            self.moving_instances.update(int(i) for i in (frame.moving_ids or ()))
            dyn = np.asarray(result.dynamic, bool)
            uv = np.asarray(result.uv)
            table = getattr(result, "table", None)
            fp = dyn & ~truth
            fn = truth & ~dyn
            # each keypoint's distance to the nearest moving outline, from either side (inf without a mover)
            to_outline = np.abs(signed_outline_distance(moving, uv))
            away = to_outline > OUTLINE_BAND_PX
            self.away_from_outlines = self.away_from_outlines + score_keypoints(dyn[away], truth[away])
            if fn.any():
                edge = to_outline[fn] < FP_DISTANCE_EDGES_PX[0]
                self.fn_by_kind.update({FN_KINDS[0]: int(edge.sum()), FN_KINDS[1]: int((~edge).sum())})
                depth = getattr(frame, "depth", None)
                z = np.asarray(table.depth) if table is not None else depth_at(depth, uv) if depth is not None else None
                if z is not None:
                    self.fn_without_depth += int((~(z[fn] > 0)).sum())
            if truth.any():
                ids = values_at(frame.instance_mask, uv[truth], outside=0)
                hit = dyn[truth]
                k = int(getattr(frame, "index", len(self.per_frame) - 1))
                for i in np.unique(ids[ids > 0]):
                    on = ids == i
                    self.by_instance[(k, int(i))] = [int(on.sum()), int(hit[on].sum())]
            if fp.any():
                ids = values_at(frame.instance_mask, uv[fp], outside=0)
                self.fp_by_instance.update(int(i) for i in ids[ids > 0])
                # a false positive is off the truth's mask: its distance to the outline is from outside (inf alone)
                bins = np.searchsorted(np.asarray(FP_DISTANCE_EDGES_PX), to_outline[fp], side="right")
                self.fp_by_place.update(zip((int(i) for i in ids), (int(b) for b in bins)))
                if table is not None:
                    self.fp_by_stage.update(str(r) for r in np.asarray(table.reason)[fp])


def recall_by_image_speed(by_instance: dict, coverage: dict[str, np.ndarray], fx: float,
                          edges=IMAGE_SPEED_EDGES_PX) -> list[dict]:
    """Recall of the keypoints on moving instances binned by the instance's image speed (module docstring).

    ``by_instance``: :attr:`KeypointScorer.by_instance`; ``coverage``: the sequence's ``coverage.csv``
    (:func:`~dynslam_lab.datasets.synthetic.read_coverage`; row ``k`` is frame ``k``); ``fx``: the focal length (px).
    Returns one dict per bin of ``edges`` (px a frame; the first from 0, the last open), in order: ``bin``,
    ``keypoints``, ``dynamic`` (judged dynamic), ``recall`` (nan when empty), ``miss_share`` (its share of all
    misses), and its misses split by how much of their mover the frame found: ``miss_unfound`` (no keypoint of the
    instance judged dynamic in that frame), ``miss_in_part`` (some, fewer than half) and ``miss_mostly_found`` (half or
    more). An instance or frame missing from ``coverage`` is a ValueError naming it.
    """
    ts = np.asarray(coverage["timestamp"], np.float64)
    dt = float(np.median(np.diff(ts))) if len(ts) > 1 else float("nan")
    bounds = [0.0, *map(float, edges), np.inf]
    n = np.zeros(len(bounds) - 1, np.int64)
    hit = np.zeros_like(n)
    found = np.zeros((len(n), 3), np.int64)  # misses on instances found not at all / in part / mostly
    for (k, i), (count, judged) in by_instance.items():
        key = f"speed_{i}"
        if key not in coverage or not 0 <= k < len(ts):
            raise ValueError(f"recall_by_image_speed: coverage.csv has no {key} for frame {k}")
        z = float(coverage[f"depth_{i}"][k])
        px = fx * float(coverage[key][k]) * dt / max(z, 0.1) if np.isfinite(z) else 0.0
        b = int(np.searchsorted(bounds, px, side="right")) - 1
        n[b] += count
        hit[b] += judged
        found[b, 0 if judged == 0 else (1 if 2 * judged < count else 2)] += count - judged
    misses = max(int((n - hit).sum()), 1)
    rows = []
    for b in range(len(n)):
        label = f"{bounds[b]:g}-{bounds[b + 1]:g}" if np.isfinite(bounds[b + 1]) else f">= {bounds[b]:g}"
        rows.append({"bin": label, "keypoints": int(n[b]), "dynamic": int(hit[b]),
                     "recall": hit[b] / n[b] if n[b] else float("nan"), "miss_share": (n[b] - hit[b]) / misses,
                     "miss_unfound": int(found[b, 0]), "miss_in_part": int(found[b, 1]),
                     "miss_mostly_found": int(found[b, 2])})
    return rows
