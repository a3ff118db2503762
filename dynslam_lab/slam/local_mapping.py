"""Local mapping: new map points, fusion, culling and local bundle adjustment
(ORB-SLAM, Mur-Artal et al., T-RO 2015, Sec. VI; ORB-SLAM2, T-RO 2017, Sec. III).

For each new keyframe ``K_i`` (run synchronously, right after tracking inserts it):

1. **New map points from depth** (ORB-SLAM2 ``CreateNewKeyFrame`` for RGB-D): every static
   keypoint with a depth reading and no map point becomes a point, ``X_w = T_w_c pi^-1(u, v, z)``;
   close points (``z < th_depth * bf / fx``) always, far ones only until ``kf_new_points_min``
   points are made (closest first).
2. **Fusion** (Sec. VI-D, ``SearchInNeighbors``): the points of ``K_i`` are projected into its
   best covisible keyframes and the neighbours' points into ``K_i``; a match to a keypoint without
   a point adds an observation, a match to another point merges the two (the one with more
   observations survives).
3. **Recent map point culling** (Sec. VI-B): a point made in the last keyframes dies if it was
   found in fewer than 25 % of the frames that should have seen it
   (``n_found / n_visible < 0.25``), or if two keyframes later it is seen by fewer than
   ``cull_min_obs`` keyframes (3 for RGB-D).
4. **Local BA** (Sec. VI-D, ORB-SLAM2 eq. 3-4): ``K_i`` and its covisible keyframes (a bounded
   window of ``ba_window``) and all their points; keyframes outside that see the points are
   fixed (at most ``ba_max_fixed``). Observations that are outliers afterwards are removed.
5. **Keyframe culling** (Sec. VI-E): a local keyframe whose close points are seen, at the same or
   a finer scale, by at least 3 other keyframes for 90 % of them is redundant and removed.

After fusion, the points of ``K_i`` take their most central descriptor (least median Hamming
distance to their other observations, ORB-SLAM Sec. III-C). Our simplification: no
triangulation between keyframes (RGB-D depth makes every point at creation).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..camera import PinholeCamera
from ..features.matching import TH_LOW, search_by_projection
from ..geometry.se3 import se3_inv, transform_points
from .frame import KeyFrame
from .map import Map
from .optimize import Observations, local_bundle_adjustment
from .tracking import frustum_candidates

__all__ = [
    "LocalMappingConfig",
    "LocalMapper",
    "create_points_from_depth",
    "replace_points",
    "fuse_with_neighbours",
    "cull_recent_points",
    "run_local_ba",
    "local_ba_window",
    "LocalBAWindow",
    "bundle_adjust_map",
    "apply_ba_result",
    "cull_keyframes",
]


@dataclass(frozen=True)
class LocalMappingConfig:
    """Parameters of local mapping (ORB-SLAM2 ``LocalMapping.cc`` unless noted)."""

    fuse_neighbours: int = 10  # covisible keyframes searched for fusion; ORB-SLAM2: 10 (RGB-D)
    fuse_radius: float = 3.0  # fusion search radius at level 0 (px); ORB-SLAM2 Fuse th: 3
    cull_found_ratio: float = 0.25  # min n_found / n_visible of a recent point; ORB-SLAM2: 0.25
    cull_min_obs: int = 2  # min observing keyframes two keyframes after creation; ORB-SLAM2 RGB-D: cnThObs 3 stereo observations (= 2 keyframes)
    cull_age: int = 2  # keyframes after creation when cull_min_obs applies; ORB-SLAM2: 2
    recent_age: int = 3  # keyframes a point stays "recent"; ORB-SLAM2: 3
    ba_window: int = 7  # keyframes optimised by local BA (current + best covisible); ours (ORB-SLAM2: all covisible)
    ba_max_fixed: int = 10  # fixed keyframes at most in local BA; ours (ORB-SLAM2: all)
    ba_hold_min_obs: int = 30  # window keyframes observing fewer of the window's points than this keep their pose in local BA (a keyframe tracked by depth on a plain wall, with a handful of points, swings: loop_flat seed 6, 88 mm / 2.0 deg as tracked -> 219 mm / 5.6 deg after local BA); 30 as global_ba_min_observations; 0 = none held (ORB-SLAM2); ours, docs/tracking.md "Image edges on a plain wall"
    ba_iterations: int = 5  # Levenberg-Marquardt iterations per local BA round at most (2 rounds); ORB-SLAM2: 5 + 10
    ba_every: int = 1  # run local BA every this many keyframes; ours (1 = every keyframe)
    capped_ba_window: int = 3  # local BA window during a bad stretch of tracking (keyframe flood); ours
    capped_ba_iterations: int = 2  # local BA iterations per round during a bad stretch; ours
    kf_cull: bool = True  # remove redundant keyframes; ORB-SLAM2: on
    kf_cull_redundant: float = 0.9  # fraction of points seen elsewhere that makes a keyframe redundant; ORB-SLAM2: 0.9
    kf_cull_min_obs: int = 3  # other keyframes that must see a point; ORB-SLAM2: 3

    def __post_init__(self) -> None:
        for name in ("ba_window", "ba_iterations", "ba_every", "capped_ba_window", "capped_ba_iterations",
                     "fuse_neighbours", "recent_age", "kf_cull_min_obs"):
            if getattr(self, name) < 1:
                raise ValueError(f"LocalMappingConfig.{name} must be >= 1, got {getattr(self, name)}")
        for name in ("ba_max_fixed", "cull_min_obs", "cull_age", "ba_hold_min_obs"):
            if getattr(self, name) < 0:
                raise ValueError(f"LocalMappingConfig.{name} must be >= 0, got {getattr(self, name)}")
        if not self.fuse_radius > 0:
            raise ValueError(f"LocalMappingConfig.fuse_radius must be > 0 pixels, got {self.fuse_radius}")
        for name in ("cull_found_ratio", "kf_cull_redundant"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"LocalMappingConfig.{name} must be in [0, 1], got {getattr(self, name)}")


def create_points_from_depth(
    mp: Map, kf: KeyFrame, close_depth: float, min_new: int, rgb: np.ndarray | None = None
) -> np.ndarray:
    """New map points for the static keypoints of ``kf`` with depth and no point yet.

    All with depth below ``close_depth`` metres; farther ones (closest first) only until
    ``min_new`` points are made. ``rgb`` ``(H, W, 3)`` gives the points their colour.
    Returns the new point ids.
    """
    z = kf.points_c[:, 2]
    cand = np.flatnonzero(kf.static & np.isfinite(z) & (z > 0) & (kf.map_point_ids < 0))
    if len(cand) == 0:
        return np.zeros(0, np.int64)
    cand = cand[np.argsort(z[cand], kind="stable")]
    n_close = int((z[cand] < close_depth).sum())
    cand = cand[: max(n_close, min(min_new, len(cand)))]
    X_w = transform_points(kf.T_w_c, kf.points_c[cand])
    col = None
    if rgb is not None:
        h, w = rgb.shape[:2]
        ui = np.clip(np.round(kf.uv[cand, 0]).astype(int), 0, w - 1)
        vi = np.clip(np.round(kf.uv[cand, 1]).astype(int), 0, h - 1)
        col = rgb[vi, ui]
    return mp.add_points(X_w, kf.descriptors[cand], kf, cand, rgb=col)


def replace_points(mp: Map, old: np.ndarray, new: np.ndarray) -> None:
    """Merge map points: every observation of ``old[k]`` becomes one of ``new[k]`` (a keyframe
    that already sees ``new[k]`` drops the duplicate); ``old`` points die."""
    old = np.asarray(old, np.int64)
    new = np.asarray(new, np.int64)
    if len(old) == 0:
        return
    lut = np.arange(mp.n_points_total)
    lut[old] = new
    kf_ids, _, _ = mp.observations_of(old)
    for kid in np.unique(kf_ids):  # loop over keyframes
        kf = mp.keyframes[int(kid)]
        ids = kf.map_point_ids
        has = np.flatnonzero(ids >= 0)
        mapped = lut[ids[has]]
        _, first = np.unique(mapped, return_index=True)
        dup = np.ones(len(has), bool)
        dup[first] = False
        ids[has] = np.where(dup, -1, mapped)
    mp.n_visible[new] += mp.n_visible[old]
    mp.n_found[new] += mp.n_found[old]
    mp.alive[old] = False
    mp.invalidate(kf_ids)


def _fuse_into(mp: Map, kf: KeyFrame, pids: np.ndarray, camera: PinholeCamera, radius: float, scale_factor: float,
               view_cos: float) -> tuple[np.ndarray, np.ndarray]:
    """Project points ``pids`` into keyframe ``kf``; add observations, return merge pairs (old, new)."""
    pids = pids[mp.alive[pids] & ~np.isin(pids, kf.map_point_ids)]
    ids, uv, lvl, _ = frustum_candidates(mp, pids, kf.T_c_w, camera, view_cos)
    if len(ids) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    m = search_by_projection(uv, mp.descriptors[ids], radius * scale_factor**lvl, lvl, kf.uv, kf.octave,
                             kf.descriptors, kp_available=kf.static, max_distance=TH_LOW, ratio=1.0)
    # Reject matches whose depth disagrees with the keyframe's measured point (3 sigma of
    # the virtual-stereo residual, ORB-SLAM2 Fuse chi^2 7.8).
    X_c = transform_points(kf.T_c_w, mp.xyz[ids[m.idx_a]])
    z_meas = kf.points_c[m.idx_b, 2]
    ok = ~np.isfinite(z_meas) | (np.abs(X_c[:, 2] - z_meas) < 0.1 * np.maximum(z_meas, 1.0))
    m = m.select(ok)
    kp, p = m.idx_b, ids[m.idx_a]
    existing = kf.map_point_ids[kp]
    empty = existing < 0
    kf.map_point_ids[kp[empty]] = p[empty]
    q, pp = existing[~empty], p[~empty]
    live = mp.alive[q] & (q != pp)
    return q[live], pp[live]


def fuse_with_neighbours(mp: Map, kf: KeyFrame, camera: PinholeCamera, cfg: LocalMappingConfig,
                         scale_factor: float, view_cos: float = 0.5) -> int:
    """Fusion of ``kf`` with its best covisible keyframes (``SearchInNeighbors``); returns merges."""
    nbs = mp.best_covisibles(kf.id, cfg.fuse_neighbours)
    own = kf.map_point_ids[kf.map_point_ids >= 0]
    pairs_old, pairs_new = [], []
    for nb in nbs:  # loop over keyframes
        o, n = _fuse_into(mp, mp.keyframes[nb], own, camera, cfg.fuse_radius, scale_factor, view_cos)
        pairs_old.append(o)
        pairs_new.append(n)
    if nbs:
        nb_pts = np.concatenate([mp.keyframes[k].map_point_ids for k in nbs])
        nb_pts = np.unique(nb_pts[nb_pts >= 0])
        o, n = _fuse_into(mp, kf, nb_pts, camera, cfg.fuse_radius, scale_factor, view_cos)
        pairs_old.append(o)
        pairs_new.append(n)
    mp.invalidate([kf.id, *nbs])
    if not pairs_old:
        return 0
    a = np.concatenate(pairs_old)
    b = np.concatenate(pairs_new)
    if len(a) == 0:
        return 0
    # Keep the point with more observations (the older one on a tie); each point merged once, no chains.
    na, nb_ = mp.n_obs(a), mp.n_obs(b)
    a_survives = (na > nb_) | ((na == nb_) & (a < b))
    old = np.where(a_survives, b, a)
    new = np.where(a_survives, a, b)
    _, first = np.unique(old, return_index=True)
    old, new = old[first], new[first]
    keep = ~np.isin(new, old)
    replace_points(mp, old[keep], new[keep])
    return int(keep.sum())


def cull_recent_points(mp: Map, recent: np.ndarray, current_kf_id: int, cfg: LocalMappingConfig) -> np.ndarray:
    """ORB-SLAM ``MapPointCulling`` on the recently created points; returns those still recent."""
    recent = recent[mp.alive[recent]]
    if len(recent) == 0:
        return recent
    found_ratio = mp.n_found[recent] / np.maximum(mp.n_visible[recent], 1)
    age = current_kf_id - mp.first_kf[recent]
    n_obs = mp.n_obs(recent)
    bad = (found_ratio < cfg.cull_found_ratio) | ((age >= cfg.cull_age) & (n_obs < cfg.cull_min_obs))
    mp.remove_points(recent[bad])
    return recent[~bad & (age < cfg.recent_age)]


def gather_observations(kfs: dict[int, KeyFrame], o_kf: np.ndarray, o_kp: np.ndarray, bf: float,
                        scale_factor: float) -> Observations:
    """The bundle-adjustment observations of ``(keyframe id, keypoint index)`` pairs ``o_kf, o_kp`` (M,):
    each keypoint's pixel, depth (metres) and pyramid level, gathered keyframe by keyframe."""
    uv = np.empty((len(o_kf), 2))
    depth = np.empty(len(o_kf))
    octave = np.empty(len(o_kf), np.int64)
    for k, f in kfs.items():  # one vectorised gather per keyframe
        sel = o_kf == k
        uv[sel] = f.uv[o_kp[sel]]
        depth[sel] = f.points_c[o_kp[sel], 2]
        octave[sel] = f.octave[o_kp[sel]]
    return Observations.from_keypoints(uv, depth, octave, bf, scale_factor)


def bundle_adjust_map(mp: Map, kfs: dict[int, KeyFrame], fixed: set[int], pts: np.ndarray, o_kf: np.ndarray,
                      o_pt: np.ndarray, o_kp: np.ndarray, camera: PinholeCamera, bf: float, scale_factor: float,
                      iterations: int):
    """Bundle adjustment of keyframes ``kfs`` and map points ``pts`` (sorted ids) over the observations
    ``(o_kf, o_pt, o_kp)``, written back into the map; shared by local BA and the global BA after a loop.

    The keyframes in ``fixed`` keep their pose; the others get the optimised one, the points their
    optimised position; observations that are outliers afterwards are removed from their keyframes
    and the points' geometry (viewing direction, distance range) is recomputed.
    Returns the :func:`~dynslam_lab.slam.optimize.local_bundle_adjustment` result.
    """
    obs = gather_observations(kfs, o_kf, o_kp, bf, scale_factor)
    res = local_bundle_adjustment({k: f.T_c_w for k, f in kfs.items()}, fixed, mp.xyz[pts], o_kf,
                                  np.searchsorted(pts, o_pt), obs, camera, bf, max_iterations=iterations)
    apply_ba_result(mp, kfs, fixed, pts, o_kf, o_kp, res)
    return res


def apply_ba_result(mp: Map, kfs: dict[int, KeyFrame], fixed: set[int], pts: np.ndarray, o_kf: np.ndarray,
                    o_kp: np.ndarray, res) -> None:
    """Write a bundle adjustment back: poses of the free keyframes, point positions, outlier
    observations removed from their keyframes, point geometry recomputed."""
    for k, f in kfs.items():
        if k not in fixed:
            f.set_pose(se3_inv(res.T_c_w[k]))
    mp.xyz[pts] = res.points
    for k in np.unique(o_kf[res.outlier]):  # loop over keyframes
        sel = res.outlier & (o_kf == k)
        mp.keyframes[int(k)].map_point_ids[o_kp[sel]] = -1
    mp.invalidate(np.unique(o_kf[res.outlier]))
    mp.update_geometry(pts)


@dataclass
class LocalBAWindow:
    """What local BA optimises around a keyframe: the ``local`` keyframes (moved), the ``fixed`` ones
    (seeing the points from outside the window; the map origin too when it is local), the points
    ``pts`` (sorted ids) and their observations ``(o_kf, o_pt, o_kp)`` by those keyframes."""

    local: list[int]
    fixed: set[int]
    pts: np.ndarray
    o_kf: np.ndarray
    o_pt: np.ndarray
    o_kp: np.ndarray


def local_ba_window(mp: Map, kf: KeyFrame, window: int, max_fixed: int, hold_min_obs: int = 0) -> LocalBAWindow | None:
    """``kf`` and its ``window - 1`` best covisible keyframes, all their points, and at most ``max_fixed``
    other keyframes (those observing most of the points) held fixed; the window's keyframes observing fewer
    than ``hold_min_obs`` of the points held too; None without points."""
    local = [kf.id] + mp.best_covisibles(kf.id, window - 1)
    pts = mp.points_of(local)
    if len(pts) == 0:
        return None
    o_kf, o_pt, o_kp = mp.observations_of(pts)
    in_local = np.isin(o_kf, local)
    outside, counts = np.unique(o_kf[~in_local], return_counts=True)
    order = np.lexsort((outside, -counts))
    fixed = [int(k) for k in outside[order][:max_fixed]]
    origin = min(mp.keyframes)
    fixed_set = set(fixed) | ({origin} if origin in local else set())
    if hold_min_obs > 0:
        n_obs = dict(zip(*np.unique(o_kf[in_local], return_counts=True)))
        fixed_set |= {k for k in local if n_obs.get(k, 0) < hold_min_obs}
    if not fixed_set:
        fixed_set = {min(local)}
    use = np.isin(o_kf, local + fixed)
    return LocalBAWindow(local, fixed_set, pts, o_kf[use], o_pt[use], o_kp[use])


def run_local_ba(mp: Map, kf: KeyFrame, camera: PinholeCamera, cfg: LocalMappingConfig, bf: float,
                 scale_factor: float, capped: bool = False) -> dict:
    """Local BA around ``kf`` (:func:`local_ba_window`, :func:`bundle_adjust_map`); writes poses and
    points back, removes outlier observations. ``capped`` (a bad stretch of tracking): the smaller
    window ``capped_ba_window`` and ``capped_ba_iterations``."""
    window = cfg.capped_ba_window if capped else cfg.ba_window
    iterations = cfg.capped_ba_iterations if capped else cfg.ba_iterations
    win = local_ba_window(mp, kf, window, cfg.ba_max_fixed, cfg.ba_hold_min_obs)
    if win is None or not set(win.local) - win.fixed:  # no points, or a keyframe sharing none (nothing free)
        return {"ba_points": 0}
    kfs = {k: mp.keyframes[k] for k in set(win.local) | win.fixed}
    res = bundle_adjust_map(mp, kfs, win.fixed, win.pts, win.o_kf, win.o_pt, win.o_kp, camera, bf, scale_factor,
                            iterations)
    return {"ba_points": int(len(win.pts)), "ba_keyframes": len(win.local), "ba_fixed": len(win.fixed),
            "ba_outliers": int(res.outlier.sum()), "ba_cost_before": res.cost_before, "ba_cost_after": res.cost_after,
            "ba_iterations": res.iterations, "ba_capped": bool(capped)}


def cull_keyframes(mp: Map, kf: KeyFrame, cfg: LocalMappingConfig, close_depth: float) -> list[int]:
    """Remove redundant covisible keyframes of ``kf`` (ORB-SLAM ``KeyFrameCulling``); returns their ids."""
    removed = []
    origin = min(mp.keyframes)
    for kid in mp.best_covisibles(kf.id):  # loop over keyframes
        if kid == origin or kid == kf.id or kid not in mp.keyframes:
            continue
        k = mp.keyframes[kid]
        z = k.points_c[:, 2]
        idx = np.flatnonzero((k.map_point_ids >= 0) & np.isfinite(z) & (z < close_depth))
        idx = idx[mp.alive[k.map_point_ids[idx]]]
        if len(idx) == 0:
            continue
        pids = k.map_point_ids[idx]
        o_kf, o_pt, _, o_oct = mp.observations_of(pids, with_octave=True)
        own_oct = np.zeros(mp.n_points_total, np.int64)
        own_oct[pids] = k.octave[idx]
        good = (o_kf != kid) & (o_oct <= own_oct[o_pt] + 1)
        count = np.bincount(o_pt[good], minlength=mp.n_points_total)[pids]
        if (count >= cfg.kf_cull_min_obs).sum() > cfg.kf_cull_redundant * len(idx):
            mp.remove_keyframe(kid)
            removed.append(kid)
    return removed


@dataclass
class LocalMapper:
    """Local mapping state: the recently created points, and a keyframe counter for ``ba_every``."""

    map: Map
    camera: PinholeCamera
    cfg: LocalMappingConfig
    bf: float
    close_depth: float
    scale_factor: float
    recent: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    n_processed: int = 0

    def process(self, kf: KeyFrame, new_points: np.ndarray, capped: bool = False) -> dict:
        """Run local mapping for a keyframe just inserted (with its new point ids); ``capped``: tracking is
        in a bad stretch, local BA runs with its capped window and iterations."""
        mp = self.map
        stats: dict = {}
        mp.update_geometry(kf.map_point_ids[kf.map_point_ids >= 0])
        self.recent = np.concatenate([self.recent, np.asarray(new_points, np.int64)])
        self.recent = cull_recent_points(mp, self.recent, kf.id, self.cfg)
        stats["fused"] = fuse_with_neighbours(mp, kf, self.camera, self.cfg, self.scale_factor)
        mp.update_descriptors(kf.map_point_ids[kf.map_point_ids >= 0])
        self.n_processed += 1
        if len(mp.keyframes) > 1 and self.n_processed % max(self.cfg.ba_every, 1) == 0:
            stats.update(run_local_ba(mp, kf, self.camera, self.cfg, self.bf, self.scale_factor, capped))
        if self.cfg.kf_cull:
            stats["culled_keyframes"] = cull_keyframes(mp, kf, self.cfg, self.close_depth)
        return stats
