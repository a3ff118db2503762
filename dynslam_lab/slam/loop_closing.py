"""Loop closing: detection by bag of words, consistency, geometric verification, correction.

ORB-SLAM2 (Mur-Artal and Tardos, T-RO 2017, Sec. V; ORB-SLAM, T-RO 2015, Sec. VII) closes a
loop for each new keyframe ``K_i`` in four steps; our reading for RGB-D:

1. **Candidates** (Sec. VII-A): the BoW vector of ``K_i`` (only its *static* keypoints: a
   person walking through two views must not make them look alike) is scored against the
   keyframe database; ``s_min`` is the lowest score of ``K_i`` to its covisible neighbours, and
   :meth:`~dynslam_lab.slam.keyframe_database.KeyframeDatabase.detect_loop_candidates` returns
   the keyframes not connected to ``K_i`` that beat it, grouped with their covisible neighbours.
2. **Consistency** (Sec. VII-A): a candidate is accepted only when its covisibility group (it
   and its neighbours) shares a keyframe with a candidate group of the previous keyframe, and
   this chain has lasted ``consistency_threshold`` consecutive keyframes (ORB-SLAM2: 3). A group is
   the candidate and its *connected* keyframes (covisibility weight ``>= 15``, ORB-SLAM2
   ``GetConnectedKeyFrames``).
3. **Geometric verification** (Sec. VII-B): ORB matches between ``K_i`` and the candidate
   (ratio test, rotation consistency), then RANSAC for the relative pose. ORB-SLAM2 estimates a
   Sim(3) (Horn 1987) because monocular scale drifts; RGB-D depth gives metric 3D points in
   both cameras, so the scale is 1 and the model is the rigid SE(3) ``T_ic`` with
   ``X_i = R X_c + t`` from 3 point pairs (:func:`~dynslam_lab.geometry.align.umeyama_alignment`
   on each minimal set, Umeyama 1991). A pair is an inlier when
   ``|R X_c + t - X_i| < inlier_abs + inlier_rel * z``. With enough inliers the pose is refined on
   all of them, and the map points seen by the candidate and its neighbours are brought into
   ``K_i`` with it and matched again (ORB-SLAM2's ``SearchByProjection``; here a search in 3D
   within the same tolerance, descriptor distance ``<= TH_LOW``). The pose of ``K_i`` is then
   refined on those matches by minimising *reprojection* errors (motion-only BA, as ORB-SLAM2's
   ``OptimizeSim3`` refines the Sim(3)), and the points matched again, ``refine_rounds`` times
   (:func:`refine_loop_pose`): a pose fitted to 3D points from depth is centimetres off. The loop
   is accepted with at least ``min_map_matches`` (40) matches.
4. **Correction** (Sec. VII-C/D): ``K_i`` and its neighbours are moved by the loop correction
   ``C = T_w_i^new (T_w_i)^-1`` with ``T_w_i^new = T_w_loop T_ic^-1``; the matched map points of
   the two sides are fused; the essential graph (spanning tree, covisibility edges with
   ``>= 100`` shared points, loop edges) is optimised in SE(3)
   (:func:`~dynslam_lab.slam.pose_graph.optimize_pose_graph`, the loop keyframe fixed), and
   every map point moves with its reference keyframe.
5. **Global BA** (ORB-SLAM2 runs it in a thread after the loop): every keyframe and map point,
   with the SLAM core's bundle adjustment (:func:`global_bundle_adjustment`).

No loop is searched within ``min_keyframes_between`` keyframes of the map's start or the last
loop (ORB-SLAM2: 10). A false loop bends the whole map, so every threshold errs on the strict
side.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from ..camera import PinholeCamera
from ..features.matching import TH_LOW, hamming_pairs, match_descriptors
from ..geometry.align import AlignmentError, ransac_rigid_3d, umeyama_alignment
from ..geometry.se3 import make_pose, se3_inv, transform_points
from .keyframe_database import CandidateQueryConfig, KeyframeDatabase, LoopCandidate, static_bow
from .local_mapping import bundle_adjust_map, replace_points
from .optimize import Observations, optimize_pose
from .pose_graph import PoseGraphConfig, correct_points, optimize_pose_graph
from .vocabulary import BowVector, Vocabulary, bow_score, default_vocabulary

__all__ = [
    "LoopClosingConfig",
    "LoopVerification",
    "LoopResult",
    "LoopCloser",
    "verify_loop",
    "match_points_3d",
    "refine_loop_pose",
    "consistent_candidates",
    "global_bundle_adjustment",
]


@dataclass(frozen=True)
class LoopClosingConfig:
    """Parameters of loop closing (ORB-SLAM2 ``LoopClosing.cc`` unless noted)."""

    enabled: bool = True  # run loop closing at all (``--no-loop`` turns it off)
    min_keyframes_between: int = 10  # no loop search in the first / after a loop for this many keyframes; ORB-SLAM2: 10
    consistency_threshold: int = 3  # consecutive consistent detections; ORB-SLAM2 mnCovisibilityConsistencyTh: 3
    min_neighbour_weight: int = 15  # covisibility weight of the neighbours giving s_min; ORB-SLAM2 connection threshold: 15
    match_ratio: float = 0.75  # best/second Hamming ratio of the loop matches; ORB-SLAM2 ComputeSim3: 0.75
    min_matches: int = 20  # descriptor matches needed before RANSAC; ORB-SLAM2: 20
    min_inliers: int = 20  # RANSAC inliers of the relative pose; ORB-SLAM2 Sim3Solver minInliers: 20
    ransac_iterations: int = 300  # RANSAC hypotheses; ORB-SLAM2 Sim3Solver: 300
    inlier_abs: float = 0.02  # 3D inlier tolerance at zero depth (m); ours (ORB-SLAM2 tests pixels, chi2 9.21)
    inlier_rel: float = 0.02  # 3D inlier tolerance growing with depth (m per m); ours, RGB-D depth noise
    min_map_matches: int = 40  # matches of the loop group's map points after the pose; ORB-SLAM2: 40
    refine_rounds: int = 2  # motion-only BA of the query pose on the loop group's points, then re-matching; ours (ORB-SLAM2: OptimizeSim3 once)
    loop_group_size: int = 10  # covisible neighbours of the loop keyframe whose points are matched; ORB-SLAM2: 10
    loop_edge_weight: float = 1.0  # weight of loop edges relative to odometry edges (ours; ORB-SLAM2: 1)
    fuse_points: bool = True  # fuse the matched map points of the two sides; ORB-SLAM2: always
    global_ba: bool = True  # full bundle adjustment after the pose graph; ORB-SLAM2: yes (in a thread)
    global_ba_iterations: int = 10  # least_squares evaluations of the global BA; ours (ORB-SLAM2: 10 g2o iterations)
    seed: int = 0  # RANSAC random generator seed (ours)
    query: CandidateQueryConfig = field(default_factory=CandidateQueryConfig)
    pose_graph: PoseGraphConfig = field(default_factory=PoseGraphConfig)

    def __post_init__(self) -> None:
        if not 0 < self.match_ratio <= 1:
            raise ValueError(f"LoopClosingConfig.match_ratio must be in (0, 1], got {self.match_ratio}")
        for name in ("min_matches", "min_inliers", "ransac_iterations", "min_map_matches", "consistency_threshold"):
            if getattr(self, name) < 1:
                raise ValueError(f"LoopClosingConfig.{name} must be >= 1, got {getattr(self, name)}")
        if self.min_inliers < 3:
            raise ValueError(f"LoopClosingConfig.min_inliers must be >= 3 (a rigid pose needs 3 points), got {self.min_inliers}")
        if self.inlier_abs < 0 or self.inlier_rel < 0 or self.inlier_abs + self.inlier_rel <= 0:
            raise ValueError(
                f"LoopClosingConfig inlier tolerance must be positive, got inlier_abs={self.inlier_abs}, "
                f"inlier_rel={self.inlier_rel}"
            )
        if self.refine_rounds < 0:
            raise ValueError(f"LoopClosingConfig.refine_rounds must be >= 0, got {self.refine_rounds}")
        if self.min_keyframes_between < 0 or self.loop_group_size < 0:
            raise ValueError("LoopClosingConfig.min_keyframes_between and loop_group_size must be >= 0")
        if self.loop_edge_weight <= 0:
            raise ValueError(f"LoopClosingConfig.loop_edge_weight must be > 0, got {self.loop_edge_weight}")
        if self.global_ba_iterations < 1:
            raise ValueError(f"LoopClosingConfig.global_ba_iterations must be >= 1, got {self.global_ba_iterations}")


@dataclass(frozen=True)
class LoopVerification:
    """Result of :func:`verify_loop`.

    Attributes
    ----------
    accepted : enough matches and RANSAC inliers.
    T_q_c : ``(4, 4)`` pose of the candidate camera in the query camera (``X_q = T_q_c X_c``).
    idx_q, idx_c : ``(K,)`` indices of the descriptor matches (into the arrays given).
    inliers : ``(K,)`` bool, matches consistent with ``T_q_c``.
    """

    accepted: bool
    T_q_c: np.ndarray
    idx_q: np.ndarray
    idx_c: np.ndarray
    inliers: np.ndarray

    @property
    def n_matches(self) -> int:
        return int(len(self.idx_q))

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())


def _tolerance(z: np.ndarray, config: LoopClosingConfig) -> np.ndarray:
    return config.inlier_abs + config.inlier_rel * np.abs(z)


def verify_loop(
    desc_q: np.ndarray,
    pts_q: np.ndarray,
    desc_c: np.ndarray,
    pts_c: np.ndarray,
    config: LoopClosingConfig = LoopClosingConfig(),
    angle_q: np.ndarray | None = None,
    angle_c: np.ndarray | None = None,
    rng: np.random.Generator | int | None = None,
) -> LoopVerification:
    """Geometric verification of a loop candidate from its keypoints with depth.

    Parameters
    ----------
    desc_q, desc_c : ``(N, 32)``, ``(M, 32)`` uint8 descriptors of the query and candidate keyframes.
    pts_q, pts_c : ``(N, 3)``, ``(M, 3)`` camera-frame points (metres); rows with ``nan`` are skipped.
    config : ratio, minimum matches and inliers, RANSAC iterations, 3D tolerance.
    angle_q, angle_c : keypoint angles (degrees) for the rotation-consistency check, or None.
    rng : Generator or seed (default ``config.seed``).

    Returns
    -------
    LoopVerification
    """
    desc_q = np.asarray(desc_q)
    desc_c = np.asarray(desc_c)
    pts_q = np.asarray(pts_q, dtype=np.float64).reshape(-1, 3)
    pts_c = np.asarray(pts_c, dtype=np.float64).reshape(-1, 3)
    if len(pts_q) != len(desc_q) or len(pts_c) != len(desc_c):
        raise ValueError(
            f"verify_loop: {len(desc_q)} query descriptors vs {len(pts_q)} points, "
            f"{len(desc_c)} candidate descriptors vs {len(pts_c)} points"
        )
    empty = np.zeros(0, np.int64)
    reject = LoopVerification(False, np.eye(4), empty, empty, np.zeros(0, bool))
    vq = np.flatnonzero(np.all(np.isfinite(pts_q), axis=1))
    vc = np.flatnonzero(np.all(np.isfinite(pts_c), axis=1))
    if len(vq) < config.min_matches or len(vc) < config.min_matches:
        return reject
    m = match_descriptors(
        desc_q[vq],
        desc_c[vc],
        ratio=config.match_ratio,
        max_distance=TH_LOW,
        angle_a=None if angle_q is None else np.asarray(angle_q)[vq],
        angle_b=None if angle_c is None else np.asarray(angle_c)[vc],
    )
    iq, ic = vq[m.idx_a], vc[m.idx_b]
    if len(iq) < config.min_matches:
        return LoopVerification(False, np.eye(4), iq, ic, np.zeros(len(iq), bool))
    rng = np.random.default_rng(config.seed if rng is None else rng)
    tol = _tolerance(np.maximum(pts_q[iq, 2], pts_c[ic, 2]), config)
    T, inl = ransac_rigid_3d(pts_c[ic], pts_q[iq], tol, config.ransac_iterations, rng)
    return LoopVerification(bool(inl.sum() >= config.min_inliers), T, iq, ic, inl)


def match_points_3d(
    X_q: np.ndarray,
    desc_points: np.ndarray,
    pts_q: np.ndarray,
    desc_q: np.ndarray,
    tolerance_abs: float,
    tolerance_rel: float,
    max_distance: int = TH_LOW,
) -> tuple[np.ndarray, np.ndarray]:
    """Match map points already brought into the query camera to its keypoints, in 3D.

    Each point ``X_q[p]`` is paired with the keypoint of smallest Hamming distance among those
    whose 3D point lies within ``tolerance_abs + tolerance_rel * z`` metres; the distance must be
    ``<= max_distance``, and each keypoint is used once (lowest distance wins).

    Parameters
    ----------
    X_q : ``(P, 3)`` map points in the query camera frame (metres).
    desc_points : ``(P, 32)`` uint8 their descriptors.
    pts_q : ``(N, 3)`` the query keypoints' camera-frame points (``nan`` rows never match).
    desc_q : ``(N, 32)`` uint8 the query descriptors.

    Returns
    -------
    (point_idx (K,), keypoint_idx (K,)) int64.
    """
    X_q = np.asarray(X_q, dtype=np.float64).reshape(-1, 3)
    pts_q = np.asarray(pts_q, dtype=np.float64).reshape(-1, 3)
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64))
    valid = np.flatnonzero(np.all(np.isfinite(pts_q), axis=1))
    okp = np.flatnonzero(np.all(np.isfinite(X_q), axis=1) & (X_q[:, 2] > 0))
    if len(valid) == 0 or len(okp) == 0:
        return empty
    tol = tolerance_abs + tolerance_rel * X_q[okp, 2]
    pairs = cKDTree(X_q[okp]).sparse_distance_matrix(cKDTree(pts_q[valid]), float(tol.max()), output_type="ndarray")
    if len(pairs) == 0:
        return empty
    ip = pairs["i"].astype(np.int64)
    ik = pairs["j"].astype(np.int64)
    keep = pairs["v"] <= tol[ip]
    ip, ik = okp[ip[keep]], valid[ik[keep]]
    if len(ip) == 0:
        return empty
    d = hamming_pairs(np.asarray(desc_points)[ip], np.asarray(desc_q)[ik])
    ok = d <= max_distance
    ip, ik, d = ip[ok], ik[ok], d[ok]
    # best keypoint per point, then each keypoint once
    order = np.lexsort((d, ip))
    ip, ik, d = ip[order], ik[order], d[order]
    first = np.ones(len(ip), bool)
    first[1:] = ip[1:] != ip[:-1]
    ip, ik, d = ip[first], ik[first], d[first]
    order = np.lexsort((d, ik))
    ip, ik = ip[order], ik[order]
    first = np.ones(len(ik), bool)
    first[1:] = ik[1:] != ik[:-1]
    return ip[first], ik[first]


def refine_loop_pose(kf, mp, pids: np.ndarray, T_q_w: np.ndarray, config: LoopClosingConfig, camera: PinholeCamera,
                     bf: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Match the loop group's map points ``pids`` to the query keyframe and refine its pose on them.

    ORB-SLAM2 (``ComputeSim3``) refines the RANSAC estimate by minimising *reprojection* errors
    (``OptimizeSim3``) and then searches the loop group's map points by projection. The RANSAC
    model here is fitted to 3D points from depth, whose error grows with the square of the depth
    (Kinect), so the pose it gives can be centimetres and degrees off (measured 4.7 cm / 2.3 deg
    on the synthetic loop while the drift it should correct was 1.1 cm / 0.2 deg). So, for
    ``config.refine_rounds`` rounds: the map points are brought into the query camera with the
    current pose ``T_q_w``, matched in 3D (:func:`match_points_3d`), and ``T_q_w`` is refined on
    the matches by the SLAM core's motion-only bundle adjustment (pixel and virtual right-pixel
    residuals, Huber kernel, chi^2 outlier rejection: :func:`~dynslam_lab.slam.optimize.optimize_pose`)
    with the sequence's ``camera`` and virtual stereo baseline ``bf`` (px m, the tracking's).

    Returns ``(T_q_w (4, 4), point_idx (K,), keypoint_idx (K,))``: the refined world-to-query
    pose and the inlier matches (indices into ``pids`` and into the query's keypoints).
    """
    static_q = np.asarray(kf.static, bool)
    pts_q = np.where(static_q[:, None], kf.points_c, np.nan)
    ip = ik = np.zeros(0, np.int64)
    for rnd in range(config.refine_rounds + 1):
        X_q = transform_points(T_q_w, mp.xyz[pids])
        ip, ik = match_points_3d(X_q, mp.descriptors[pids], pts_q, kf.descriptors, config.inlier_abs, config.inlier_rel)
        if len(ip) < config.min_map_matches or rnd == config.refine_rounds:
            break
        obs = Observations.from_keypoints(kf.uv[ik], kf.points_c[ik, 2], kf.octave[ik], bf, mp.scale_factor)
        T_q_w, _out = optimize_pose(T_q_w, mp.xyz[pids[ip]], obs, camera, bf)
    return T_q_w, ip, ik


# --------------------------------------------------------------------------- consistency
def consistent_candidates(
    candidate_groups: dict[int, set[int]],
    previous: list[tuple[set[int], int]],
    threshold: int,
) -> tuple[list[int], list[tuple[set[int], int]]]:
    """The consistency check of ORB-SLAM2's ``DetectLoop`` (Sec. VII-A).

    Parameters
    ----------
    candidate_groups : candidate keyframe id -> its group (itself and its covisible keyframes).
    previous : the consistent groups of the previous keyframe, ``(group, consistency)``.
    threshold : consistency needed (3).

    Returns
    -------
    (accepted candidate ids, consistent groups to keep for the next keyframe). A candidate
    whose group shares a keyframe with a previous group continues that group's count (+1); one
    that shares none starts a new group at 0.
    """
    accepted: list[int] = []
    current: list[tuple[set[int], int]] = []
    used_prev = [False] * len(previous)
    for cand, group in candidate_groups.items():  # few candidates, few groups
        enough = False
        consistent = False
        for g, (prev_group, prev_count) in enumerate(previous):
            if group & prev_group:
                consistent = True
                count = prev_count + 1
                if not used_prev[g]:
                    current.append((group, count))
                    used_prev[g] = True
                if count >= threshold and not enough:
                    accepted.append(cand)
                    enough = True
        if not consistent:
            current.append((group, 0))
    return accepted, current


# --------------------------------------------------------------------------- global BA
def global_bundle_adjustment(mp, fixed_kf: int, camera: PinholeCamera, bf: float, iterations: int = 10) -> dict:
    """Bundle adjustment of every keyframe and map point (ORB-SLAM2 ``RunGlobalBundleAdjustment``).

    Uses the SLAM core's :func:`~dynslam_lab.slam.optimize.local_bundle_adjustment` (stereo
    residuals ``(u, v, u_R)``, Huber kernel) with all keyframes free but ``fixed_kf`` (and the map
    origin); poses and points are written back, outlier observations removed. ``camera`` and
    ``bf`` (px m) are the sequence's intrinsics and the tracking's virtual stereo baseline.
    """
    pts = mp.point_ids()
    o_kf, o_pt, o_kp = mp.observations_of(pts)
    if len(o_kf) == 0:
        return {"gba_points": 0}
    kfs = {int(k): mp.keyframes[int(k)] for k in np.unique(o_kf)}
    fixed = {int(fixed_kf), int(min(mp.keyframes))} & set(kfs)
    if not fixed:
        fixed = {min(kfs)}
    upts = np.unique(o_pt)  # the observed points, sorted: the BA's point array
    res = bundle_adjust_map(mp, kfs, fixed, upts, o_kf, o_pt, o_kp, camera, bf, mp.scale_factor, iterations)
    return {"gba_points": int(len(upts)), "gba_keyframes": len(kfs), "gba_outliers": int(res.outlier.sum()),
            "gba_cost_before": res.cost_before, "gba_cost_after": res.cost_after}


# --------------------------------------------------------------------------- the adapter
@dataclass
class LoopResult:
    """An accepted loop.

    Attributes
    ----------
    query_kf_id : the new keyframe that closed the loop.
    loop_kf_id : the old keyframe it matched.
    T_query_loop : ``(4, 4)`` verified relative pose (loop camera in the query camera).
    correction : ``(4, 4)`` ``T_w_query^new (T_w_query^old)^-1`` applied before pose graph optimisation.
    n_matches, n_inliers, n_map_matches : descriptor matches, RANSAC inliers, map point matches.
    n_fused : map points of the query side merged into loop-side points.
    corrected_kf_ids : keyframes whose pose the pose graph changed (all keyframes of the map).
    timings_ms : ``query``, ``verify``, ``correct`` milliseconds.
    """

    query_kf_id: int
    loop_kf_id: int
    T_query_loop: np.ndarray
    correction: np.ndarray
    n_matches: int
    n_inliers: int
    n_map_matches: int
    n_fused: int
    corrected_kf_ids: list[int]
    timings_ms: dict[str, float]

    @property
    def keyframe_ids(self) -> tuple[int, int]:
        """The loop edge of the keyframe graph, older keyframe first: ``(loop_kf_id, query_kf_id)``."""
        return (min(self.loop_kf_id, self.query_kf_id), max(self.loop_kf_id, self.query_kf_id))


class LoopCloser:
    """ORB-SLAM2's loop closing thread, run synchronously for each new keyframe.

    Parameters
    ----------
    config : thresholds (:class:`LoopClosingConfig`).
    camera : the sequence's intrinsics (refinement and global BA reproject with them).
    bf : virtual stereo baseline x fx (px m) of the ``u_R`` residual: the tracking's ``bf``.
    vocabulary : the binary vocabulary; default: the one shipped with the package.

    Attributes
    ----------
    database : the keyframe database (static words of every keyframe seen).
    loops : accepted loops, in order.
    query_ms : ``(kf_id, ms)`` of every candidate query (BoW + database), for benchmarks.
    last_candidates : candidate ids of the last keyframe (for notebooks).
    """

    def __init__(self, config: LoopClosingConfig, camera: PinholeCamera, bf: float, vocabulary: Vocabulary | None = None):
        self.config = config
        self.camera = camera
        self.bf = float(bf)
        self.vocabulary = vocabulary if vocabulary is not None else default_vocabulary()
        self.database = KeyframeDatabase(self.vocabulary.n_words)
        self.loops: list[LoopResult] = []
        self.query_ms: list[tuple[int, float]] = []
        self.last_candidates: list[LoopCandidate] = []
        self._groups: list[tuple[set[int], int]] = []
        self._last_loop_kf = -1
        self._rng = np.random.default_rng(self.config.seed)

    @property
    def loop_edges(self) -> list[tuple[int, int]]:
        """``(query_kf_id, loop_kf_id)`` of every accepted loop."""
        return [(r.query_kf_id, r.loop_kf_id) for r in self.loops]

    def keyframe_bow(self, kf) -> BowVector:
        """BoW vector of a keyframe from its static keypoints only."""
        return static_bow(self.vocabulary, kf)

    # ------------------------------------------------------------------ entry point
    def on_keyframe(self, keyframe, map) -> LoopResult | None:  # noqa: A002 - the contract's name
        """Detect, verify and close a loop for a new keyframe (already inserted in ``map``).

        The keyframe is added to the database whatever the outcome. On an accepted loop every
        keyframe pose and map point is corrected in place and a :class:`LoopResult` returned.
        """
        cfg = self.config
        if not cfg.enabled:
            return None
        t0 = time.perf_counter()
        bow = self.keyframe_bow(keyframe)
        self.database.prune(map.keyframes)
        result = None
        self.last_candidates = []
        far_enough = keyframe.id >= max(cfg.min_keyframes_between, self._last_loop_kf + cfg.min_keyframes_between)
        if far_enough and len(map.keyframes) > cfg.min_keyframes_between and len(bow):
            accepted = self._detect(keyframe, map, bow)
            q_ms = 1e3 * (time.perf_counter() - t0)
            self.query_ms.append((int(keyframe.id), q_ms))
            for cand_id in accepted:
                result = self._try_close(keyframe, map, cand_id, q_ms)
                if result is not None:
                    break
        if keyframe.id not in self.database:
            self.database.add(keyframe.id, bow)
        if result is not None:
            self.loops.append(result)
            self._last_loop_kf = keyframe.id
            self._groups = []
        return result

    # ------------------------------------------------------------------ steps
    def _detect(self, kf, mp, bow: BowVector) -> list[int]:
        cfg = self.config
        cov = mp.covisibility(kf.id)
        strong = [k for k, w in cov.items() if w >= cfg.min_neighbour_weight and k in self.database]
        min_score = 1.0
        for k in strong:  # a few neighbours
            min_score = min(min_score, bow_score(bow, self.database.bow(k)))
        if not strong:
            self._groups = []
            return []
        memo: dict[int, dict[int, int]] = {}

        def covis(i: int) -> dict[int, int]:  # each keyframe's covisibility once per query
            if i not in memo:
                memo[i] = mp.covisibility(i) if i in mp.keyframes else {}
            return memo[i]

        def connected(i: int) -> list[int]:  # ORB-SLAM2 GetConnectedKeyFrames: weight >= 15 (else the best one)
            c = covis(i)
            strong_i = [k for k, w in c.items() if w >= cfg.min_neighbour_weight]
            return strong_i if strong_i or not c else [max(c, key=lambda k: (c[k], -k))]

        def best(i: int) -> list[int]:
            c = covis(i)
            return sorted(c, key=lambda k: (-c[k], k))[: cfg.query.group_size]

        cands = self.database.detect_loop_candidates(
            bow, exclude=set(cov) | {kf.id}, min_score=min_score, neighbours=best, config=cfg.query
        )
        self.last_candidates = cands
        if not cands:
            self._groups = []
            return []
        groups = {c.kf_id: {c.kf_id} | set(connected(c.kf_id)) for c in cands}
        accepted, self._groups = consistent_candidates(groups, self._groups, cfg.consistency_threshold)
        return accepted

    def _try_close(self, kf, mp, cand_id: int, q_ms: float) -> LoopResult | None:
        cfg = self.config
        t0 = time.perf_counter()
        cand = mp.keyframes[cand_id]
        sq = np.flatnonzero(np.asarray(kf.static, bool))
        sc = np.flatnonzero(np.asarray(cand.static, bool))
        ver = verify_loop(
            kf.descriptors[sq], kf.points_c[sq], cand.descriptors[sc], cand.points_c[sc], cfg,
            angle_q=kf.angle[sq] if hasattr(kf, "angle") else None,
            angle_c=cand.angle[sc] if hasattr(cand, "angle") else None,
            rng=self._rng,
        )
        if not ver.accepted:
            return None
        T_q_c = ver.T_q_c
        # Map points of the loop group brought into the query camera and matched in 3D.
        group = [cand_id] + [k for k in mp.best_covisibles(cand_id, cfg.loop_group_size) if k != kf.id]
        pids = np.unique(np.concatenate([mp.keyframes[k].map_point_ids for k in group]))
        pids = pids[pids >= 0]
        pids = pids[mp.alive[pids]]
        T_q_w, ip, ik = refine_loop_pose(kf, mp, pids, T_q_c @ cand.T_c_w, cfg, self.camera, self.bf)
        if len(ip) < cfg.min_map_matches:
            return None
        T_q_c = T_q_w @ cand.T_w_c
        verify_ms = 1e3 * (time.perf_counter() - t0)
        t1 = time.perf_counter()
        correction, n_fused, changed = self._correct(kf, mp, cand, T_q_c, pids[ip], ik)
        return LoopResult(
            query_kf_id=int(kf.id),
            loop_kf_id=int(cand_id),
            T_query_loop=T_q_c,
            correction=correction,
            n_matches=ver.n_matches,
            n_inliers=ver.n_inliers,
            n_map_matches=int(len(ip)),
            n_fused=n_fused,
            corrected_kf_ids=changed,
            timings_ms={"query": q_ms, "verify": verify_ms, "correct": 1e3 * (time.perf_counter() - t1)},
        )

    def _correct(self, kf, mp, loop_kf, T_q_c: np.ndarray, loop_pids: np.ndarray, kp_idx: np.ndarray):
        """Correct the current side, fuse matched points, optimise the essential graph, move points."""
        cfg = self.config
        ids = sorted(mp.keyframes)
        index = {k: i for i, k in enumerate(ids)}
        T_old = np.stack([mp.keyframes[k].T_w_c for k in ids])
        # Points and their reference keyframes, before anything moves.
        pts = mp.point_ids()
        ref = mp.first_kf[pts].copy()
        missing = ~np.isin(ref, ids)
        if missing.any():
            # reference culled: use the first keyframe that still observes the point
            obs_kf, obs_pt, _ = mp.observations_of(pts[missing])
            order = np.lexsort((obs_kf, obs_pt))
            first = np.ones(len(order), bool)
            first[1:] = obs_pt[order][1:] != obs_pt[order][:-1]
            lut = dict(zip(obs_pt[order][first].tolist(), obs_kf[order][first].tolist()))
            ref[missing] = [lut.get(int(p), -1) for p in pts[missing]]
        has_ref = np.isin(ref, ids)
        pts, ref = pts[has_ref], ref[has_ref]
        ref_idx = np.searchsorted(np.asarray(ids), ref)
        X_old = mp.xyz[pts].copy()

        # 1. the current keyframe and its neighbours jump by the loop correction
        T_w_q_new = loop_kf.T_w_c @ se3_inv(T_q_c)
        C = T_w_q_new @ se3_inv(T_old[index[kf.id]])
        cov_q = mp.covisibility(kf.id)
        group = [kf.id] + [k for k in cov_q if k in index]
        T_init = T_old.copy()
        for k in group:
            T_init[index[k]] = C @ T_old[index[k]]

        # 2. essential graph edges: new loop connections (corrected poses) first, then the
        #    spanning tree, strong covisibility (before fusion) and old loops (old poses)
        W = self._covisibility_matrix(mp, ids)
        edges, Z, w = [], [], []

        def add(i, j, Ti, Tj, weight=1.0):
            edges.append((index[i], index[j]))
            Z.append(se3_inv(Ti) @ Tj)
            w.append(weight)

        seen: set[tuple[int, int]] = set()
        loop_group = [loop_kf.id] + [k for k in mp.best_covisibles(loop_kf.id, cfg.loop_group_size) if k in index]
        for q in group:
            for l in loop_group:
                if q != l and (min(q, l), max(q, l)) not in seen:
                    add(l, q, T_init[index[l]], T_init[index[q]], cfg.loop_edge_weight)
                    seen.add((min(q, l), max(q, l)))
        for k in ids:
            p = mp.keyframes[k].parent_id
            if p in index and (min(p, k), max(p, k)) not in seen:
                add(p, k, T_old[index[p]], T_old[index[k]])
                seen.add((min(p, k), max(p, k)))
        ii, jj = np.nonzero(np.triu(W >= cfg.pose_graph.min_covisibility_weight, 1))
        for a, b in zip(ii.tolist(), jj.tolist()):
            i, j = ids[a], ids[b]
            if (i, j) not in seen:
                add(i, j, T_old[a], T_old[b])
                seen.add((i, j))
        for k in ids:
            for o in mp.keyframes[k].loop_edges:
                if o in index and k < o and (k, o) not in seen:
                    add(k, o, T_old[index[k]], T_old[index[o]])
                    seen.add((k, o))
        # 3. fuse: the query keypoints matched to loop points now observe the loop points, and the
        #    loop group's points are searched (in 3D) in every corrected keyframe of the current group
        n_fused = 0
        if cfg.fuse_points:
            n_fused = self._fuse(kf, mp, loop_pids, kp_idx)
            lp = np.unique(np.concatenate([mp.keyframes[k].map_point_ids for k in loop_group]))
            lp = lp[lp >= 0]
            lp = lp[mp.alive[lp]]
            for k in group[1:]:  # the current keyframe's neighbours (a few)
                other = mp.keyframes[k]
                X_k = transform_points(se3_inv(T_init[index[k]]), mp.xyz[lp])
                pts_k = np.where(np.asarray(other.static, bool)[:, None], other.points_c, np.nan)
                ip, ik = match_points_3d(X_k, mp.descriptors[lp], pts_k, other.descriptors, cfg.inlier_abs, cfg.inlier_rel)
                alive = mp.alive[lp[ip]]
                n_fused += self._fuse(other, mp, lp[ip][alive], ik[alive])

        # 4. optimise the essential graph, the loop keyframe fixed
        res = optimize_pose_graph(
            T_init, np.asarray(edges), np.stack(Z), fixed=[index[loop_kf.id]], weights=np.asarray(w),
            config=cfg.pose_graph,
        )
        for k in ids:
            mp.keyframes[k].T_w_c = res.poses[index[k]]

        # 5. every map point moves with its reference keyframe
        X_new = correct_points(X_old, ref_idx, T_old, res.poses)
        alive = mp.alive[pts]  # fused query-side points died: leave them
        mp.xyz[pts[alive]] = X_new[alive]
        mp.update_geometry(mp.point_ids())
        kf.loop_edges.add(loop_kf.id)
        loop_kf.loop_edges.add(kf.id)
        if cfg.global_ba:
            global_bundle_adjustment(mp, loop_kf.id, self.camera, self.bf, cfg.global_ba_iterations)
        return C, n_fused, ids

    @staticmethod
    def _covisibility_matrix(mp, ids: list[int]) -> np.ndarray:
        """``(K, K)`` shared map points between keyframes ``ids`` (from the observation table)."""
        obs_kf, obs_pt, _ = mp.observations_of(mp.point_ids())
        keep = np.isin(obs_kf, ids)
        rows = np.searchsorted(np.asarray(ids), obs_kf[keep])
        A = csr_matrix((np.ones(int(keep.sum())), (rows, obs_pt[keep])), shape=(len(ids), mp.n_points_total))
        W = (A @ A.T).toarray()
        np.fill_diagonal(W, 0)
        return W

    @staticmethod
    def _fuse(kf, mp, loop_pids: np.ndarray, kp_idx: np.ndarray) -> int:
        """Make the query keypoints ``kp_idx`` observe the loop points ``loop_pids``; duplicates merge."""

        cur = kf.map_point_ids[kp_idx]
        free = cur < 0
        # keypoints without a point: observe the loop point (if the keyframe does not see it yet)
        add_kp, add_pt = kp_idx[free], loop_pids[free]
        new_obs = ~np.isin(add_pt, kf.map_point_ids)
        kf.map_point_ids[add_kp[new_obs]] = add_pt[new_obs]
        # keypoints with another point: merge it into the loop point
        old, new = cur[~free], loop_pids[~free]
        diff = (old != new) & ~np.isin(old, loop_pids)
        old, new = old[diff], new[diff]
        if len(old):
            _, first = np.unique(old, return_index=True)
            old, new = old[first], new[first]
            replace_points(mp, old, new)
        mp.invalidate()
        return int(len(old))
