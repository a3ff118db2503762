"""Loop correction: essential-graph optimisation and global BA, computed off the frame loop.

ORB-SLAM2 (Mur-Artal and Tardos 2017, Sec. V-B/C; ORB-SLAM, T-RO 2015, Sec. VII-C/D) corrects an
accepted loop in its loop-closing thread while tracking goes on, and runs the global bundle
adjustment in yet another thread; when the BA finishes, the map is locked, the optimised poses are
written back and the keyframes made since are moved along the spanning tree. Ours follows that:

1. **Snapshot** (frame loop, a few ms): keyframe poses, parents and loop edges, the observation
   table, point positions and reference keyframes are copied (:func:`take_snapshot`); keyframe
   objects are shared read-only (their keypoints, depths and descriptors never change).
2. **Compute** (worker thread, :class:`LoopCorrector`): the current keyframe ``K_i`` and its
   covisible keyframes jump by the loop correction ``C = T_w_i^new (T_w_i)^-1``; the loop group's
   points are searched in those keyframes (3D, as :func:`.verification.match_points_3d`); the
   essential graph (new loop links, spanning tree, covisibility edges with ``>= 100`` shared points,
   earlier loops) is optimised in SE(3) with the loop keyframe fixed
   (:func:`~dynslam_lab.slam.pose_graph.optimize_pose_graph`; :func:`essential_graph`), each edge
   weighted by the information of the map points its keyframes share (:func:`edge_information`, the
   default ``pose_graph.information = "points"``; ORB-SLAM2's identity with ``"identity"``), and each
   odometry edge measured again by aligning its keyframes' reduced depth (:func:`depth_edges`, ours).
3. **Apply** (frame loop, between two frames, :func:`apply_correction`): each keyframe of the
   snapshot gets its correction ``D_k = T_k^new (T_k^old)^-1`` applied to its *current* pose (what
   local BA did since is kept); keyframes made since the snapshot take the correction of their
   nearest ancestor in the spanning tree (ORB-SLAM2 does this after its global BA); every map point
   moves with its reference keyframe; the matched points of the two sides are fused.
4. **Global BA** (worker again, on a fresh snapshot, :func:`run_global_ba`): every keyframe and
   point, the loop keyframe and the map origin fixed; applied the same way (points in the BA take
   its positions, points made since move with their reference keyframe).

With ``config.background = False`` the same jobs run at once inside ``on_keyframe`` (deterministic
results for tests and notebooks; the frame that closes the loop then waits for them).
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from ...camera import PinholeCamera
from ...geometry.depth_alignment import DenseTerm, align_depth, depth_sigma, reduced_depth_points, vertex_normal_grid
from ...geometry.se3 import make_pose, nearest_rotation, se3_inv, transform_points
from ..local_mapping import gather_observations, replace_points
from ..optimize import Observations, local_bundle_adjustment, pose_information
from ..pose_graph import optimize_pose_graph
from .config import LoopClosingConfig
from .verification import match_points_3d

__all__ = ["Snapshot", "Correction", "take_snapshot", "essential_graph", "depth_edges", "run_loop_correction", "run_global_ba",
           "apply_correction", "fuse_points", "fuse_group", "LoopCorrector"]


@dataclass
class Snapshot:
    """The map as the correction sees it (copies; keyframe objects shared read-only).

    ``ids (K,)`` sorted keyframe ids, ``T_w_c (K, 4, 4)``, ``parent (K,)`` ids, ``loop_edges`` pairs,
    ``obs_kf, obs_pt, obs_kp`` the observation table, ``points`` alive point ids, ``xyz (P, 3)`` and
    ``ref (P,)`` (reference keyframe id, -1 for none) of those points, ``keyframes`` by id.
    """

    ids: np.ndarray
    T_w_c: np.ndarray
    parent: np.ndarray
    loop_edges: list[tuple[int, int]]
    obs_kf: np.ndarray
    obs_pt: np.ndarray
    obs_kp: np.ndarray
    points: np.ndarray
    xyz: np.ndarray
    ref: np.ndarray
    descriptors: np.ndarray
    keyframes: dict
    scale_factor: float

    def index(self) -> dict[int, int]:
        return {int(k): i for i, k in enumerate(self.ids)}


def _reference_keyframes(mp, pts: np.ndarray, obs_kf: np.ndarray, obs_pt: np.ndarray) -> np.ndarray:
    """Reference keyframe of each point (its first keyframe; if culled, the first keyframe still
    observing it; -1 when none)."""
    ref = mp.first_kf[pts].copy()
    missing = ~np.isin(ref, np.fromiter(mp.keyframes, np.int64))
    if missing.any():
        sel = np.isin(obs_pt, pts[missing])
        o_kf, o_pt = obs_kf[sel], obs_pt[sel]
        order = np.lexsort((o_kf, o_pt))
        first = np.ones(len(order), bool)
        first[1:] = o_pt[order][1:] != o_pt[order][:-1]
        lut = dict(zip(o_pt[order][first].tolist(), o_kf[order][first].tolist()))
        ref[missing] = [lut.get(int(p), -1) for p in pts[missing]]
    return ref


def take_snapshot(mp) -> Snapshot:
    """Copy what the correction needs from the live map (frame loop)."""
    ids = np.array(sorted(mp.keyframes), np.int64)
    pts = mp.point_ids()
    obs_kf, obs_pt, obs_kp = (a.copy() for a in mp.observations_of(pts))
    loops = sorted({(min(k, o), max(k, o)) for k in ids.tolist() for o in mp.keyframes[k].loop_edges})
    return Snapshot(
        ids=ids,
        T_w_c=np.stack([mp.keyframes[k].T_w_c for k in ids.tolist()]),
        parent=np.array([mp.keyframes[k].parent_id for k in ids.tolist()], np.int64),
        loop_edges=loops,
        obs_kf=obs_kf, obs_pt=obs_pt, obs_kp=obs_kp,
        points=pts, xyz=mp.xyz[pts].copy(), ref=_reference_keyframes(mp, pts, obs_kf, obs_pt),
        descriptors=mp.descriptors[pts].copy(),
        keyframes={int(k): mp.keyframes[int(k)] for k in ids},
        scale_factor=float(mp.scale_factor),
    )


@dataclass
class Correction:
    """A computed correction, ready to apply: ``ids``, their poses before (``T_old``, the snapshot's)
    and after (``T_new``); optionally points set outright (``point_ids``, ``xyz``), outlier
    observations ``(kf, kp, pt)`` to drop, fusion triples ``(kf, kp, loop point)`` and the loop edge."""

    ids: np.ndarray
    T_old: np.ndarray
    T_new: np.ndarray
    point_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    outliers: tuple = ()
    fuse: list = field(default_factory=list)
    loop_edge: tuple[int, int] | None = None
    kind: str = "pose_graph"
    stats: dict = field(default_factory=dict)


def _covisibility_pairs(snap: Snapshot, min_weight: int) -> np.ndarray:
    """``(E, 2)`` index pairs (into ``snap.ids``) of keyframes sharing at least ``min_weight`` points."""
    if len(snap.obs_kf) == 0:
        return np.zeros((0, 2), np.int64)
    rows = np.searchsorted(snap.ids, snap.obs_kf)
    cols = np.searchsorted(snap.points, snap.obs_pt)
    A = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(snap.ids), len(snap.points)))
    W = (A @ A.T).tocoo()
    keep = (W.row < W.col) & (W.data >= min_weight)
    return np.column_stack([W.row[keep], W.col[keep]]).astype(np.int64)


def essential_graph(snap: Snapshot, T_init: np.ndarray, current_group: list[int], loop_group: list[int],
                    config: LoopClosingConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edges ``(E, 2)`` (indices into ``snap.ids``), measurements ``(E, 4, 4)`` and weights ``(E,)``:
    new loop links current group x loop group measured with ``T_init`` (the corrected poses), then
    the spanning tree, strong covisibility and earlier loops measured with the old poses."""
    index = snap.index()
    T_old = snap.T_w_c
    edges, Z, w = [], [], []
    seen: set[tuple[int, int]] = set()

    def add(a: int, b: int, T: np.ndarray, weight: float) -> None:
        key = (min(a, b), max(a, b))
        if a != b and key not in seen:
            seen.add(key)
            edges.append((a, b))
            Z.append(se3_inv(T[a]) @ T[b])
            w.append(weight)

    for q in current_group:
        for l in loop_group:
            if q in index and l in index:
                add(index[l], index[q], T_init, config.loop_edge_weight)
    for i, p in enumerate(snap.parent.tolist()):
        if p in index:
            add(index[p], i, T_old, 1.0)
    for a, b in _covisibility_pairs(snap, config.pose_graph.min_covisibility_weight).tolist():
        add(a, b, T_old, 1.0)
    for a, b in snap.loop_edges:
        if a in index and b in index:
            add(index[a], index[b], T_old, 1.0)
    if not edges:
        return np.zeros((0, 2), np.int64), np.zeros((0, 4, 4)), np.zeros(0)
    return np.asarray(edges, np.int64), np.stack(Z), np.asarray(w, float)


def edge_information(snap: Snapshot, edges: np.ndarray, loop_edge: int | None, loop_obs: tuple | None,
                     T_init: np.ndarray, camera: PinholeCamera, bf: float, config: LoopClosingConfig) -> np.ndarray:
    """``(E, 6, 6)`` information of each essential-graph edge ``(i, j)`` (ours; ORB-SLAM2 uses the identity).

    An odometry edge (spanning tree, covisibility, an earlier loop) is measured from the map points its two
    keyframes share: their observations in the keyframe ``j`` with the points held where they are
    (:func:`~dynslam_lab.slam.optimize.pose_information` at the identity with the points in ``j``'s
    frame, which is where the edge's residual lives). The new
    loop edge (index ``loop_edge``, query last) is measured by the loop's map matches in the query,
    ``loop_obs = (query keyframe, keypoint indices, point rows)``, at the corrected pose. Each gets
    ``pose_graph.floor_*`` added (a prior of a degree and two centimetres: what a keyframe tracked by
    depth alone, with no point shared, is still worth; tracking's dense prior).

    The information knows which directions the points determine: matches at one depth (a far wall)
    leave the sideways-shift-and-turn direction weak, and the graph then takes it from the odometry.
    """
    pg = config.pose_graph
    floor = np.diag([np.radians(pg.floor_rotation_deg) ** -2] * 3 + [pg.floor_translation ** -2] * 3)
    out = np.tile(floor, (len(edges), 1, 1))

    def info(kf_rows: np.ndarray, kfs: list, kp: np.ndarray, rows_xyz: np.ndarray, T_w_c: np.ndarray) -> np.ndarray:
        """``(K, 6, 6)``: each observation's information, keypoint ``kp`` of keyframe ``kfs[kf_rows]`` at
        pose ``T_w_c[kf_rows]``, its point (row ``rows_xyz``) held in that keyframe's frame."""
        T_c_w = se3_inv(T_w_c)
        X = np.einsum("kij,kj->ki", T_c_w[kf_rows, :3, :3], snap.xyz[rows_xyz]) + T_c_w[kf_rows, :3, 3]
        uv, z, octave = np.zeros((len(kp), 2)), np.zeros(len(kp)), np.zeros(len(kp), np.int64)
        for r in np.unique(kf_rows).tolist():
            sel = kf_rows == r
            kf = kfs[r]
            uv[sel], z[sel], octave[sel] = kf.uv[kp[sel]], kf.points_c[kp[sel], 2], np.asarray(kf.octave)[kp[sel]]
        obs = Observations.from_keypoints(uv, z, octave, bf, snap.scale_factor)
        return pose_information(np.eye(4), X, obs, camera, bf, per_observation=True)

    # every observation's share once (in its own keyframe's frame), by keyframe row then point
    alive = np.isin(snap.obs_kf, snap.ids)
    o_row = np.searchsorted(snap.ids, snap.obs_kf[alive])
    o_pt, o_kp = snap.obs_pt[alive], snap.obs_kp[alive]
    order = np.lexsort((o_pt, o_row))
    o_row, o_pt, o_kp = o_row[order], o_pt[order], o_kp[order]
    kfs = [snap.keyframes[int(k)] for k in snap.ids.tolist()]
    M = info(o_row, kfs, o_kp, np.searchsorted(snap.points, o_pt), snap.T_w_c)
    starts = np.searchsorted(o_row, np.arange(len(snap.ids)))
    ends = np.searchsorted(o_row, np.arange(len(snap.ids)), side="right")

    for e, (i, j) in enumerate(np.asarray(edges).tolist()):
        if e == loop_edge:
            if loop_obs is not None:
                kf, kp, prow = loop_obs
                out[e] += info(np.zeros(len(kp), np.int64), [kf], np.asarray(kp, np.int64), prow, T_init[j][None]).sum(0)
            continue
        # the points keyframes i and j share, observed in j
        shared = np.isin(o_pt[starts[j]:ends[j]], o_pt[starts[i]:ends[i]], assume_unique=True)
        out[e] += M[starts[j]:ends[j]][shared].sum(0)
    return out


def depth_edges(snap: Snapshot, edges: np.ndarray, Z: np.ndarray, info: np.ndarray, loop_edge: int | None,
                camera: PinholeCamera, pg) -> int:
    """Odometry edges measured by depth too (ours; in place; returns how many). For each edge ``(i, j)``
    other than ``loop_edge`` (at most ``pg.dense_max_edges``, the weakest by ``info`` first) whose keyframes
    kept a reduced depth (``LoopClosingConfig.dense_factor``),
    ``j``'s depth (every other cell) is aligned point-to-plane to ``i``'s
    (:func:`~dynslam_lab.geometry.depth_alignment.align_depth`), starting at the edge's measurement ``Z[e]``
    and held to it with the floor sigmas (``pg.floor_translation``, ``pg.floor_rotation_deg``). When a third
    of the points associate and their median distance does not grow, the aligned relative pose becomes the
    measurement and ``pg.dense_scale`` times the alignment's Gauss-Newton information (in ``j``'s frame at
    the identity, the step of :func:`~dynslam_lab.slam.optimize.pose_information`) is added to ``info[e]``.

    Why: an edge's measurement is tracking's relative pose. Across a plain wall tracked by depth frame to
    frame it carries the drift of every frame; one alignment keyframe to keyframe carries one, and its
    information says which directions the depth fixes (a wall: the shift along its normal and two turns)
    and which it leaves to the features and the floor. The information alone, with tracking's
    measurements, made ``loop_flat`` worse at every scale (docs/loop_closing.md, "Odometry edges measured
    by depth")."""
    kfs = [snap.keyframes[int(k)] for k in snap.ids.tolist()]
    views: dict = {}  # keyframe id -> (grid camera, vertex/normal grid, points every other cell)
    done = 0
    edges = np.asarray(edges)
    # the weakest edges first: smallest eigenvalue of the information in units of the floor (1 = the floor alone)
    f = np.array([np.radians(pg.floor_rotation_deg)] * 3 + [pg.floor_translation] * 3)
    weakest = np.linalg.eigvalsh(info * f[:, None] * f[None, :])[:, 0] if len(edges) else np.zeros(0)
    for e in np.argsort(weakest, kind="stable")[: pg.dense_max_edges].tolist():
        i, j = edges[e].tolist()
        a, b = kfs[i], kfs[j]
        if e == loop_edge or a.depth_small is None or b.depth_small is None or a.depth_small.shape != b.depth_small.shape:
            continue
        for kf in (a, b):
            if kf.id not in views:
                cam, X = reduced_depth_points(kf.depth_small, camera, 2)
                views[kf.id] = (cam, vertex_normal_grid(kf.depth_small, cam, 1), X)
        cam, X = views[b.id][0], views[b.id][2]
        if len(X) < 100:
            continue
        T_j_i = se3_inv(Z[e])
        term = DenseTerm(X, depth_sigma(X[:, 2]), views[a.id][1], np.eye(4), cam, max_distance=0.05, T_prior=T_j_i,
                         prior_sigma=(pg.floor_translation, pg.floor_rotation_deg))
        res = align_depth(term, T_j_i)
        if not (res.n >= len(X) / 3 and res.d_end <= res.d_start):
            continue
        Z[e] = se3_inv(res.T_c_w)
        _, J, _ = DenseTerm(X, term.sigma, views[a.id][1], Z[e], cam, max_distance=0.05).residuals(np.eye(3), np.zeros(3))
        info[e] += pg.dense_scale * (J.T @ J)
        done += 1
    return done


def run_loop_correction(snap: Snapshot, query_id: int, loop_id: int, C: np.ndarray, current_group: list[int],
                        loop_group: list[int], loop_pids: np.ndarray, query_kp: np.ndarray,
                        config: LoopClosingConfig, camera: PinholeCamera | None = None,
                        bf: float | None = None) -> Correction:
    """Steps 2 of the module docstring (worker thread): corrected guesses, fusion search, pose graph."""
    index = snap.index()
    T_init = snap.T_w_c.copy()
    group = [k for k in current_group if k in index]
    for k in group:
        T_init[index[k]] = C @ snap.T_w_c[index[k]]
    fuse = [(int(query_id), np.asarray(query_kp, np.int64), np.asarray(loop_pids, np.int64))]
    if config.fuse_points:
        # the loop group's points searched (in 3D) in every corrected keyframe of the current group
        in_group = np.isin(snap.obs_kf, loop_group)
        lp = np.unique(snap.obs_pt[in_group])
        li = np.searchsorted(snap.points, lp)
        for k in group:  # the current keyframe's neighbours (a few)
            if k == query_id:
                continue
            kf = snap.keyframes[k]
            X_k = transform_points(se3_inv(T_init[index[k]]), snap.xyz[li])
            pts_k = np.where(np.asarray(kf.static, bool)[:, None], kf.points_c, np.nan)
            ip, ik = match_points_3d(X_k, snap.descriptors[li], pts_k, kf.descriptors, config.inlier_abs, config.inlier_rel)
            fuse.append((int(k), ik, lp[ip]))
    info = None
    n_depth = 0
    if config.pose_graph.information == "points":
        if camera is None or bf is None:
            raise ValueError("run_loop_correction: pose_graph.information = 'points' needs the camera and bf")
        # one loop edge (query - loop keyframe) with the loop's own information; the other pairs of the two
        # groups would repeat the same measurement
        edges, Z, w = essential_graph(snap, T_init, [query_id], [loop_id], config)
        loop_kp = np.asarray(query_kp, np.int64)
        prow = np.searchsorted(snap.points, np.asarray(loop_pids, np.int64))
        ok = (prow < len(snap.points)) & (snap.points[np.minimum(prow, len(snap.points) - 1)] == loop_pids)
        q = snap.keyframes[int(query_id)]
        loop_edge = 0 if len(edges) and query_id in index and loop_id in index else None
        info = edge_information(snap, edges, loop_edge, (q, loop_kp[ok], prow[ok]), T_init, camera, bf, config)
        if config.pose_graph.dense_scale > 0:
            n_depth = depth_edges(snap, edges, Z, info, loop_edge, camera, config.pose_graph)
    else:
        edges, Z, w = essential_graph(snap, T_init, group, loop_group, config)
    if len(edges) == 0:
        T_new = T_init
    else:
        T_new = optimize_pose_graph(T_init, edges, Z, fixed=[index[loop_id]], weights=w, config=config.pose_graph,
                                    information=info).poses
    return Correction(snap.ids, snap.T_w_c, T_new, fuse=fuse, loop_edge=(int(loop_id), int(query_id)),
                      stats={"edges": int(len(edges)), "depth_edges": int(n_depth), "keyframes": int(len(snap.ids))})


def run_global_ba(snap: Snapshot, fixed_ids: set[int], camera: PinholeCamera, bf: float, iterations: int,
                  min_observations: int = 0, part_weight: int = 0) -> Correction:
    """Bundle adjustment of every keyframe and point of the snapshot (ORB-SLAM2
    ``RunGlobalBundleAdjustment``), the keyframes ``fixed_ids`` (and the map origin) held, and (ours)
    every keyframe observing fewer than ``min_observations`` points: its pose is not determined by them
    (a keyframe on a plain wall, tracked by depth, with a handful of points) and stays where the pose
    graph put it. With ``part_weight`` > 0 (ours) the keyframes joined by at least that many shared points form the map's rigid
    parts; every part without a held keyframe is moved back, as one rigid body with its points, onto the poses the
    snapshot (the pose graph) gave its keyframes (:func:`_anchor_parts`)."""
    alive_obs = np.isin(snap.obs_kf, snap.ids)
    o_kf, o_pt, o_kp = snap.obs_kf[alive_obs], snap.obs_pt[alive_obs], snap.obs_kp[alive_obs]
    if len(o_kf) == 0:
        return Correction(snap.ids, snap.T_w_c, snap.T_w_c.copy(), kind="global_ba")
    ks, counts = np.unique(o_kf, return_counts=True)
    kfs = {int(k): snap.keyframes[int(k)] for k in ks}
    weak = {int(k) for k, c in zip(ks.tolist(), counts.tolist()) if c < min_observations}
    anchors = ({int(f) for f in fixed_ids} | {int(snap.ids[0])}) & set(kfs)  # the loop keyframe, the map's origin
    fixed = anchors | weak
    if not fixed:
        fixed = {min(kfs)}
    index = snap.index()
    upts = np.unique(o_pt)
    obs = gather_observations(kfs, o_kf, o_kp, bf, snap.scale_factor)
    res = local_bundle_adjustment({k: se3_inv(snap.T_w_c[index[k]]) for k in kfs}, fixed,
                                  snap.xyz[np.searchsorted(snap.points, upts)], o_kf, np.searchsorted(upts, o_pt), obs,
                                  camera, bf, iterations)
    T_new = snap.T_w_c.copy()
    for k in kfs:
        if k not in fixed:
            T_new[index[k]] = se3_inv(res.T_c_w[k])
    out = res.outlier
    xyz = res.points
    n_parts = 0
    if part_weight > 0:
        n_parts = _anchor_parts(snap, T_new, upts, xyz, anchors or fixed, fixed, part_weight)
    return Correction(snap.ids, snap.T_w_c, T_new, point_ids=upts, xyz=xyz,
                      outliers=(o_kf[out], o_kp[out], o_pt[out]), kind="global_ba",
                      stats={"gba_points": int(len(upts)), "gba_keyframes": len(kfs), "gba_outliers": int(out.sum()),
                             "gba_held_weak": len(weak), "gba_parts_anchored": n_parts,
                             "gba_cost_before": res.cost_before, "gba_cost_after": res.cost_after})


def _anchor_parts(snap: Snapshot, T_new: np.ndarray, upts: np.ndarray, xyz: np.ndarray, anchors: set[int],
                  fixed: set[int], part_weight: int) -> int:
    """Move each rigid part of the global BA's result without an anchor keyframe (the loop keyframe, the map's
    origin) back onto the snapshot's poses (in place: ``T_new (K, 4, 4)`` keyframe poses T_w_c, ``xyz`` the
    positions of the points ``upts``). A part is a connected component of the keyframes sharing at least
    ``part_weight`` points. Its transform ``A`` (world to world) is the least-squares one over its keyframes
    the BA moved (not in ``fixed``), ``A T_new ~ T_snap``: the rotation nearest to ``sum R_snap R_new^T`` and
    the translation that matches their mean camera centres; they and the part's points (by reference keyframe)
    move with it. Returns how many parts were moved."""
    pairs = _covisibility_pairs(snap, part_weight)
    K = len(snap.ids)
    graph = csr_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(K, K))
    _, label = connected_components(graph, directed=False)
    index = snap.index()
    held = {label[index[k]] for k in anchors if k in index}
    free = np.array([int(k) not in fixed for k in snap.ids])
    ref = snap.ref[np.searchsorted(snap.points, upts)]
    ref_label = np.full(len(upts), -1)
    known = np.isin(ref, snap.ids)
    ref_label[known] = label[np.searchsorted(snap.ids, ref[known])]
    moved = 0
    for c in np.unique(label):
        if c in held:
            continue
        members = np.flatnonzero((label == c) & free)
        if len(members) == 0:
            continue
        Rs = snap.T_w_c[members, :3, :3] @ np.swapaxes(T_new[members, :3, :3], 1, 2)
        R_A = nearest_rotation(Rs.sum(axis=0))
        t_A = (snap.T_w_c[members, :3, 3] - T_new[members, :3, 3] @ R_A.T).mean(axis=0)
        A = make_pose(R_A, t_A)
        T_new[members] = A @ T_new[members]
        sel = ref_label == c
        xyz[sel] = xyz[sel] @ R_A.T + t_A
        moved += 1
    return moved


def _fusion_pairs(kf, mp, loop_pids: np.ndarray, kp_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Make the free keypoints ``kp_idx`` of ``kf`` observe the loop points ``loop_pids``; return the
    merges ``(old, new)`` their taken keypoints call for (another point there than the loop's)."""
    keep = mp.alive[loop_pids]
    loop_pids, kp_idx = loop_pids[keep], kp_idx[keep]
    cur = kf.map_point_ids[kp_idx]
    free = cur < 0
    add_kp, add_pt = kp_idx[free], loop_pids[free]
    new_obs = ~np.isin(add_pt, kf.map_point_ids)
    kf.map_point_ids[add_kp[new_obs]] = add_pt[new_obs]
    old, new = cur[~free], loop_pids[~free]
    diff = (old != new) & ~np.isin(old, loop_pids) & mp.alive[np.maximum(old, 0)]
    return old[diff], new[diff]


def _merge(mp, old: np.ndarray, new: np.ndarray) -> int:
    """Merge the points ``old`` into ``new`` (each old point once, its first pair; no chains: a point
    that is merged away is never a target). Returns the number merged."""
    if len(old):
        _, first = np.unique(old, return_index=True)
        old, new = old[first], new[first]
        keep = ~np.isin(new, old)
        old, new = old[keep], new[keep]
        replace_points(mp, old, new)
    mp.invalidate()
    return int(len(old))


def fuse_points(kf, mp, loop_pids: np.ndarray, kp_idx: np.ndarray) -> int:
    """Make keypoints ``kp_idx`` of ``kf`` observe the loop points ``loop_pids``; duplicates merge
    (ORB-SLAM2 ``SearchAndFuse``). Returns the number of merged points."""
    return _merge(mp, *_fusion_pairs(kf, mp, np.asarray(loop_pids, np.int64), np.asarray(kp_idx, np.int64)))


def fuse_group(mp, fuse: list) -> int:
    """:func:`fuse_points` for every ``(keyframe id, keypoint indices, loop points)`` of a correction,
    the merges of all the keyframes done at once (one pass over the observations instead of one per
    keyframe: the frame loop waits for this). Returns the number of merged points."""
    olds, news = [], []
    for k, kp, lp in fuse:
        kf = mp.keyframes.get(int(k))
        if kf is not None and len(kp):
            o, n = _fusion_pairs(kf, mp, np.asarray(lp, np.int64), np.asarray(kp, np.int64))
            olds.append(o)
            news.append(n)
    if not olds:
        return 0
    return _merge(mp, np.concatenate(olds), np.concatenate(news))


def _keyframe_deltas(mp, corr: Correction) -> dict[int, np.ndarray]:
    """Correction ``D_k`` of every keyframe of the map: its own for snapshot keyframes, its nearest
    snapshot ancestor's (spanning tree) for keyframes made since, identity without one."""
    own = {int(k): corr.T_new[i] @ se3_inv(corr.T_old[i]) for i, k in enumerate(corr.ids.tolist())}
    out: dict[int, np.ndarray] = {}
    for k in sorted(mp.keyframes):  # parents have smaller ids: one pass
        if k in own:
            out[k] = own[k]
        else:
            p = mp.keyframes[k].parent_id
            out[k] = out.get(p, own.get(p, np.eye(4)))
    return out


def apply_correction(mp, corr: Correction) -> list[int]:
    """Step 3 of the module docstring (frame loop). Returns the ids of the keyframes moved."""
    D = _keyframe_deltas(mp, corr)
    pts = mp.point_ids()
    obs_kf, obs_pt, _ = mp.observations_of(pts)
    ref = _reference_keyframes(mp, pts, obs_kf, obs_pt)
    for k, Dk in D.items():
        kf = mp.keyframes[k]
        kf.T_w_c = Dk @ kf.T_w_c
    # points move rigidly with their reference keyframe (grouped by reference: one transform each);
    # their viewing direction turns with it and their distance to it is kept, so the scale range
    # (min/max distance) stays valid without re-gathering every observation (ORB-SLAM2 recomputes
    # them; local mapping does it here for the points it touches next)
    kid = np.fromiter(D, np.int64, len(D))  # sorted
    if len(kid) and len(pts):
        Ds = np.stack([D[k] for k in kid.tolist()])
        at = np.minimum(np.searchsorted(kid, ref), len(kid) - 1)
        moved = kid[at] == ref  # points whose reference keyframe is in the map (-1: none)
        P, R = pts[moved], Ds[at[moved], :3, :3]
        mp.xyz[P] = np.einsum("pij,pj->pi", R, mp.xyz[P]) + Ds[at[moved], :3, 3]
        mp.normal[P] = np.einsum("pij,pj->pi", R, mp.normal[P])
    if len(corr.point_ids):  # global BA: its points take its positions (the alive ones)
        ok = mp.alive[corr.point_ids]
        mp.xyz[corr.point_ids[ok]] = corr.xyz[ok]
    if corr.outliers:
        o_kf, o_kp, o_pt = corr.outliers
        for k in np.unique(o_kf):  # loop over keyframes
            kf = mp.keyframes.get(int(k))
            if kf is None:
                continue
            sel = o_kf == k
            same = kf.map_point_ids[o_kp[sel]] == o_pt[sel]
            kf.map_point_ids[o_kp[sel][same]] = -1
    n_fused = fuse_group(mp, corr.fuse)
    if corr.loop_edge is not None:
        a, b = corr.loop_edge
        if a in mp.keyframes and b in mp.keyframes:
            mp.keyframes[a].loop_edges.add(b)
            mp.keyframes[b].loop_edges.add(a)
    mp.invalidate()  # (global BA moves points by millimetres: their viewing geometry is kept)
    corr.stats["fused"] = n_fused
    return sorted(D)


class LoopCorrector:
    """Runs the loop closer's jobs one at a time, in a worker thread (``background``) or at once.

    :meth:`submit` takes a function computing from copies only (a :class:`Correction`, or a
    verification on a frozen map view); :meth:`poll` (frame loop) returns the finished ones in
    submission order, and the loop closer applies them.
    """

    def __init__(self, background: bool) -> None:
        self.background = bool(background)
        self._pool: ThreadPoolExecutor | None = None
        self._pending: list[tuple[Future, object]] = []
        self._kinds: dict[object, int] = {}  # pending jobs per kind (a tag's first item)

    @property
    def busy(self) -> bool:
        return bool(self._pending)

    def tags(self) -> list:
        """Tags of the pending jobs, in submission order."""
        return [tag for _, tag in self._pending]

    @staticmethod
    def _kind(tag) -> object:
        return tag[0] if isinstance(tag, tuple) and tag else None

    def pending(self, kind) -> int:
        """Pending jobs whose tag is a tuple starting with ``kind`` (O(1): counted on submit and poll)."""
        return self._kinds.get(kind, 0)

    def submit(self, fn, tag) -> None:
        """Start ``fn() -> Correction``; ``tag`` comes back with the result."""
        k = self._kind(tag)
        self._kinds[k] = self._kinds.get(k, 0) + 1
        if self.background:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="loop-correction")
            self._pending.append((self._pool.submit(fn), tag))
        else:
            f: Future = Future()
            try:
                f.set_result(fn())
            except Exception as exc:  # reported by poll, as the worker's would be
                f.set_exception(exc)
            self._pending.append((f, tag))

    def poll(self, wait: bool = False) -> list[tuple[Correction, object]]:
        """Finished jobs ``(correction, tag)`` in submission order (all of them when ``wait``); a job
        that raised re-raises here (the caller reports it)."""
        done = []
        while self._pending and (wait or self._pending[0][0].done()):
            fut, tag = self._pending.pop(0)
            self._kinds[self._kind(tag)] -= 1
            done.append((fut.result(), tag))
        return done

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
