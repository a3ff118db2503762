"""The loop closer: detection, verification and correction for each new keyframe.

``LoopCloser.on_keyframe(keyframe, map)`` is called by the system for every new keyframe: it
queries the keyframe database and checks consistency (:mod:`.detection`), verifies the consistent
candidates (:mod:`.verification`) and, for an accepted loop, snapshots the map and starts the
correction (:mod:`.correction`), in a worker thread by default. ``LoopCloser.poll(map)``, called
by the system before each frame, applies the corrections that have finished; ``wait(map)`` applies
all of them (end of a run).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ...camera import PinholeCamera
from ...geometry.se3 import se3_inv
from ..keyframe_database import KeyframeDatabase, LoopCandidate, static_bow
from ..vocabulary import BowVector, Vocabulary, default_vocabulary
from .config import LoopClosingConfig
from .frozen import freeze_for_verification
from .correction import LoopCorrector, apply_correction, run_global_ba, run_loop_correction, take_snapshot
from .detection import LoopDetector
from .verification import CandidateCheck, verify_candidate

__all__ = ["LoopResult", "LoopCloser"]


@dataclass
class LoopResult:
    """An accepted loop.

    Attributes
    ----------
    query_kf_id : the new keyframe that closed the loop.
    loop_kf_id : the old keyframe it matched.
    T_query_loop : ``(4, 4)`` verified relative pose (loop camera in the query camera).
    correction : ``(4, 4)`` ``T_w_query^new (T_w_query^old)^-1`` the loop implies.
    n_matches, n_inliers, n_map_matches : descriptor matches, RANSAC inliers, map point matches.
    checks : the verification's measurements (spread, depth spread, path, correction size, neighbours).
    n_fused : map points merged when the correction was applied.
    corrected_kf_ids : keyframes the correction moved (filled when applied).
    applied : the pose-graph correction has been applied to the map; ``global_ba_applied`` likewise.
    timings_ms : ``query``, ``verify``, ``snapshot`` (frame loop), ``correct`` (worker: pose graph),
        ``apply`` (frame loop), ``global_ba`` (worker), ``apply_global_ba`` (frame loop).
    """

    query_kf_id: int
    loop_kf_id: int
    T_query_loop: np.ndarray
    correction: np.ndarray
    n_matches: int
    n_inliers: int
    n_map_matches: int
    checks: dict = field(default_factory=dict)
    n_fused: int = 0
    corrected_kf_ids: list[int] = field(default_factory=list)
    applied: bool = False
    global_ba_applied: bool = False
    timings_ms: dict[str, float] = field(default_factory=dict)

    @property
    def keyframe_ids(self) -> tuple[int, int]:
        """The loop edge of the keyframe graph, older keyframe first: ``(loop_kf_id, query_kf_id)``."""
        return (min(self.loop_kf_id, self.query_kf_id), max(self.loop_kf_id, self.query_kf_id))


def _timed_verification(fn, job: tuple):
    """``fn(*job)`` (a verification, in the worker) with its duration (ms) appended to its output."""
    def run():
        t0 = time.perf_counter()
        out = fn(*job)
        return (*out, 1e3 * (time.perf_counter() - t0))
    return run


def _timed(fn, key: str, result: LoopResult):
    """``fn`` wrapped to record its duration in ``result.timings_ms[key]`` (runs in the worker)."""
    def run():
        t0 = time.perf_counter()
        out = fn()
        result.timings_ms[key] = 1e3 * (time.perf_counter() - t0)
        return out
    return run


class LoopCloser:
    """ORB-SLAM2's loop closing: detection and verification per keyframe, correction off the frame loop.

    Parameters
    ----------
    config : thresholds (:class:`~.config.LoopClosingConfig`).
    camera : the sequence's intrinsics (refinement and global BA reproject with them).
    bf : virtual stereo baseline x fx (px m) of the ``u_R`` residual: the tracking's ``bf``.
    vocabulary : the binary vocabulary; default: the one shipped with the package.

    Attributes
    ----------
    database : the keyframe database (static words of every keyframe seen).
    loops : accepted loops, in order.
    query_ms : ``(kf_id, ms)`` of every candidate query (BoW + database + consistency).
    stage_ms : ``(kf_id, ms)`` of every ``on_keyframe`` call (the loop stage of the frame loop).
    stage_parts_ms : ``(kf_id, bow, detect, freeze, cpu)`` ms of every ``on_keyframe`` call: the static
        BoW vector, database prune + query + consistency (:class:`~.detection.LoopDetector`), the frozen
        view of the map handed to verification (0 when nothing is verified), all wall-clock, and the
        CPU time of the calling thread for the whole call (``time.thread_time``: without the waits for
        the CPU or the GIL that a busy machine or the verification worker add to the wall-clock).
    rejected : ``(query id, candidate id, reason, stats)`` of every candidate that failed verification.
    """

    def __init__(self, config: LoopClosingConfig, camera: PinholeCamera, bf: float, vocabulary: Vocabulary | None = None):
        self.config = config
        self.camera = camera
        self.bf = float(bf)
        self.vocabulary = vocabulary if vocabulary is not None else default_vocabulary()
        self.database = KeyframeDatabase(self.vocabulary.n_words)
        self.detector = LoopDetector(config, self.database)
        self.corrector = LoopCorrector(config.background)
        self.loops: list[LoopResult] = []
        self.query_ms: list[tuple[int, float]] = []
        self.stage_ms: list[tuple[int, float]] = []
        self.stage_parts_ms: list[tuple[int, float, float, float]] = []
        self.rejected: list[tuple[int, int, str, dict]] = []
        self.errors: list[str] = []
        self._last_loop_kf = -1
        self._epoch = 0  # accepted loops so far: verifications begun before the last one are dropped
        self._rng = np.random.default_rng(self.config.seed)
        # a verified loop whose pose the matches fix poorly, waiting for a better one: (query id, candidate id,
        # check, frozen poses, query ms, verify ms, keyframes waited)
        self._pending: tuple | None = None

    @property
    def last_candidates(self) -> list[LoopCandidate]:
        """The database's candidates for the last keyframe queried."""
        return self.detector.last_candidates

    @property
    def loop_edges(self) -> list[tuple[int, int]]:
        """``(query_kf_id, loop_kf_id)`` of every accepted loop."""
        return [(r.query_kf_id, r.loop_kf_id) for r in self.loops]

    @property
    def busy(self) -> bool:
        """A correction is being computed or waits to be applied."""
        return self.corrector.busy

    def keyframe_bow(self, kf) -> BowVector:
        """BoW vector of a keyframe from its static keypoints only."""
        return static_bow(self.vocabulary, kf)

    # ------------------------------------------------------------------ frame loop
    def on_keyframe(self, keyframe, map) -> LoopResult | None:  # noqa: A002 - the contract's name
        """Detect loop candidates for a new keyframe (already inserted in ``map``) and hand them to verification.

        The frame loop only queries the database and checks consistency; the consistent candidates
        (the ``config.max_verified`` best of them by accumulated score, all when it is 0) are verified
        on a frozen view of the map (:func:`.frozen.freeze_for_verification`) by the worker, and
        :meth:`poll` starts the correction of an accepted one. The keyframe is added to
        the database whatever the outcome. No loop is searched while a correction is pending.
        With ``config.background`` False verification and correction run at once and the loop
        accepted for this keyframe (applied) is returned; else None (:meth:`poll` returns it later).
        """
        cfg = self.config
        if not cfg.enabled:
            return None
        t0, c0 = time.perf_counter(), time.thread_time()
        bow = self.keyframe_bow(keyframe)
        t_bow = time.perf_counter()
        self.database.prune(map.keyframes)
        far_enough = keyframe.id >= max(cfg.min_keyframes_between, self._last_loop_kf + cfg.min_keyframes_between)
        n_loops = len(self.loops)
        t_detect = t_freeze = t_bow
        if not self._correcting and far_enough and len(map.keyframes) > cfg.min_keyframes_between and len(bow):
            accepted = self.detector.detect(keyframe, map, bow)
            t_detect = t_freeze = time.perf_counter()
            q_ms = 1e3 * (t_detect - t0)
            self.query_ms.append((int(keyframe.id), q_ms))
            if cfg.max_verified:  # best accumulated score first (the database's order, kept by consistency)
                accepted = accepted[: cfg.max_verified]
            if accepted:
                view = freeze_for_verification(map, keyframe.id, accepted, self.detector.last_covisibility,
                                               cfg.loop_group_size)
                t_freeze = time.perf_counter()
                job = (view.keyframes[keyframe.id], view, list(accepted), self._epoch)
                self.corrector.submit(_timed_verification(self._verify, job), ("verify", (job, q_ms)))
        if keyframe.id not in self.database:
            self.database.add(keyframe.id, bow)
        if not cfg.background and self.busy:
            self.poll(map)
        self._age_pending(map)
        t1 = time.perf_counter()
        self.stage_ms.append((int(keyframe.id), 1e3 * (t1 - t0)))
        self.stage_parts_ms.append((int(keyframe.id), 1e3 * (t_bow - t0), 1e3 * (t_detect - t_bow),
                                    1e3 * (t_freeze - t_detect), 1e3 * (time.thread_time() - c0)))
        return self.loops[-1] if len(self.loops) > n_loops else None

    def close_pending(self, mp) -> bool:
        """Close the loop kept waiting for a better-conditioned one now (the run ends: none will come).
        True when a correction was started (apply it with :meth:`wait`)."""
        if self._pending is None or not self.config.enabled:
            return False
        self.poll(mp, wait=True)  # verifications still running may bring a better one, or a loop
        if self._pending is None:
            return self.busy
        return self._close_pending_now(mp)

    def _age_pending(self, mp) -> None:
        """A loop kept for its weak conditioning (``max_loop_sigma``) is closed after ``defer_keyframes``
        more keyframes brought no better-conditioned one (ours; docs/loop_closing.md "A loop pose the
        matches determine")."""
        if self._pending is None or self._correcting:
            return
        query_id, cand_id, check, frozen, q_ms, v_ms, age = self._pending
        if age < self.config.defer_keyframes:
            self._pending = (query_id, cand_id, check, frozen, q_ms, v_ms, age + 1)
            return
        self._close_pending_now(mp)
        if not self.config.background and self.busy:
            self.poll(mp)

    def _close_pending_now(self, mp) -> bool:
        """Accept the kept loop as it is (marked ``deferred``); True when its correction was started."""
        query_id, cand_id, check, frozen, q_ms, v_ms, _ = self._pending
        self._pending = None
        check.accepted = True
        check.stats["deferred"] = True
        return self._accept(mp, query_id, cand_id, check, frozen, q_ms, v_ms) is not None

    @property
    def _correcting(self) -> bool:
        """A pose-graph or global-BA correction is pending (verification jobs do not count)."""
        return self.corrector.pending("pose_graph") + self.corrector.pending("global_ba") > 0

    def _verify(self, query, view, candidates: list[int], epoch: int) -> tuple[int, CandidateCheck | None, list, tuple]:
        """Worker: verify the candidates in order on the frozen view; the first accepted wins.
        Returns ``(candidate id or -1, its check, [(candidate, reason, stats) of the rejected],
        (frozen query pose, frozen candidate pose), weak)``; ``weak`` is ``(candidate id, check, frozen
        poses)`` of the best-conditioned candidate that failed only ``max_loop_sigma`` (None if none)."""
        rejected, weak = [], None
        for cand_id in candidates:
            check = verify_candidate(query, view, cand_id, self.config, self.camera, self.bf, self._rng)
            frozen = (query._T_w_c, view.keyframes[cand_id]._T_w_c)
            if check.accepted:
                return int(cand_id), check, rejected, frozen, None
            rejected.append((int(cand_id), check.reason, check.stats))
            if check.reason == "conditioning" and (weak is None or check.stats["loop_sigma_m"] < weak[1].stats["loop_sigma_m"]):
                weak = (int(cand_id), check, frozen)
        return -1, None, rejected, (), weak

    def _accept(self, mp, query_id: int, cand_id: int, check: CandidateCheck, frozen: tuple, q_ms: float,
                v_ms: float) -> LoopResult | None:
        """Frame loop: start the correction of a verified loop, or None when one of its two keyframes
        was culled since it was verified."""
        kf, cand = mp.keyframes.get(query_id), mp.keyframes.get(cand_id)
        if kf is None or cand is None:
            self.rejected.append((int(query_id), int(cand_id), "culled", dict(check.stats)))
            return None
        frozen_q, frozen_c = frozen
        if not (kf._T_w_c is frozen_q and cand._T_w_c is frozen_c):
            # local BA moved a pose since verification: the same relative pose on the current ones
            check.correction = cand.T_w_c @ se3_inv(check.T_q_c) @ kf.T_c_w
        result = self._start(kf, mp, cand_id, check, q_ms, v_ms)
        self.loops.append(result)
        self._last_loop_kf = int(query_id)
        self._epoch += 1
        self.detector.reset()
        return result

    def _start(self, kf, mp, cand_id: int, check: CandidateCheck, q_ms: float, v_ms: float) -> LoopResult:
        t0 = time.perf_counter()
        snap = take_snapshot(mp)
        current_group = [kf.id] + [k for k in mp.covisibility(kf.id)]
        result = LoopResult(
            query_kf_id=int(kf.id), loop_kf_id=int(cand_id), T_query_loop=check.T_q_c, correction=check.correction,
            n_matches=int(check.stats.get("matches", 0)), n_inliers=int(check.stats.get("inliers", 0)),
            n_map_matches=int(len(check.ip)), checks=dict(check.stats),
            timings_ms={"query": q_ms, "verify": v_ms},
        )
        job = (snap, int(kf.id), int(cand_id), check.correction, current_group, check.group, check.pids[check.ip],
               check.ik, self.config, self.camera, self.bf)
        result.timings_ms["snapshot"] = 1e3 * (time.perf_counter() - t0)
        self.corrector.submit(_timed(lambda: run_loop_correction(*job), "correct", result), ("pose_graph", result))
        return result

    def poll(self, map, wait: bool = False) -> list[LoopResult]:  # noqa: A002 - the contract's name
        """Handle the worker's finished jobs in order (all pending ones when ``wait``): a finished
        verification starts the correction of its accepted loop (or records the rejections); a finished
        correction is applied. Returns the loops whose pose-graph or global-BA correction was applied
        now. The global BA of a loop starts (on a fresh snapshot) once its pose-graph correction is
        applied; a verification begun before the last accepted loop is dropped (its map is gone)."""
        applied: list[LoopResult] = []
        while True:
            done = self.corrector.poll(wait=wait)
            if not done:
                return applied
            for out, (kind, tag) in done:
                if kind == "verify":
                    (query, _view, _cands, epoch), q_ms = tag
                    cand_id, check, rejected, frozen, weak, v_ms = out
                    self.rejected.extend((int(query.id), c, r, st) for c, r, st in rejected)
                    if epoch != self._epoch:
                        continue
                    if check is not None:
                        self._pending = None
                        self._accept(map, int(query.id), cand_id, check, frozen, q_ms, v_ms)
                    elif weak is not None and (self._pending is None or
                                               weak[1].stats["loop_sigma_m"] < self._pending[2].stats["loop_sigma_m"]):
                        # a loop that passed every check but the conditioning: kept, in case no better one comes
                        self._pending = (int(query.id), *weak, q_ms, v_ms, 0)
                    continue
                result = tag
                t0 = time.perf_counter()
                changed = apply_correction(map, out)
                ms = 1e3 * (time.perf_counter() - t0)
                if kind == "pose_graph":
                    result.applied, result.corrected_kf_ids = True, changed
                    result.n_fused = int(out.stats.get("fused", 0))
                    result.timings_ms["apply"] = ms
                    if self.config.global_ba:
                        self._start_global_ba(map, result)
                else:
                    result.global_ba_applied = True
                    result.checks.update({k: v for k, v in out.stats.items() if k.startswith("gba")})
                    result.timings_ms["apply_global_ba"] = ms
                if not any(r is result for r in applied):
                    applied.append(result)

    def _start_global_ba(self, mp, result: LoopResult) -> None:
        snap = take_snapshot(mp)
        fixed = {result.loop_kf_id}
        cam, bf, it, weak = self.camera, self.bf, self.config.global_ba_iterations, self.config.global_ba_min_observations
        parts = self.config.global_ba_part_weight
        self.corrector.submit(_timed(lambda: run_global_ba(snap, fixed, cam, bf, it, weak, parts), "global_ba", result),
                              ("global_ba", result))

    def wait(self, map) -> list[LoopResult]:  # noqa: A002 - the contract's name
        """Block until every pending correction is computed, and apply them all."""
        return self.poll(map, wait=True)

    def close(self) -> None:
        """Stop the worker thread (pending jobs finish first)."""
        self.corrector.close()
