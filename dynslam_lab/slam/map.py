"""The map: keyframes, map points, observations and the covisibility graph
(ORB-SLAM, Mur-Artal et al., T-RO 2015, Sec. III-B/C; ORB-SLAM2, T-RO 2017).

* A **map point** ``p`` has a world position ``xyz`` (metres), a representative ORB descriptor,
  a mean viewing direction ``normal`` and the distance range ``[min_dist, max_dist]`` in which
  ORB's scale pyramid can see it: observed at distance ``d`` on level ``s``,
  ``max_dist = d * f**s`` and ``min_dist = max_dist / f**(L-1)`` (ORB-SLAM Sec. III-C).
  Its predicted level at distance ``d`` is ``ceil(log(max_dist / d) / log(f))``.
* An **observation** is a (keyframe, keypoint) pair seeing a point. The single source of truth
  is each keyframe's ``map_point_ids``; the map keeps a flat observation table
  (``obs_kf, obs_pt, obs_kp``) rebuilt from them on demand, so every query is vectorised.
* The **covisibility graph** weights an edge between two keyframes by the number of map points
  both observe (ORB-SLAM Sec. III-D). The **spanning tree** links each keyframe to the
  keyframe it shares most points with when created.

Map points live in growing numpy arrays indexed by point id (never reused): ``xyz``,
``descriptors``, ``normal``, ``min_dist``, ``max_dist``, ``alive``, ``n_visible``, ``n_found``
(tracking statistics for culling), ``first_kf`` and ``rgb``. Loop closing may overwrite
``map.xyz[ids]`` and keyframe poses in place and then call :meth:`Map.update_geometry`.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from ..features.matching import hamming_pairs
from .frame import KeyFrame

__all__ = ["Map"]


class Map:
    """Keyframes and map points of one run.

    Parameters
    ----------
    scale_factor, n_levels : ORB pyramid (for the scale-invariance distances).
    """

    INDEX_AFTER_SCANS = 8  # observation queries answered by a table scan before the point index is built

    def __init__(self, scale_factor: float = 1.2, n_levels: int = 8) -> None:
        self.scale_factor = float(scale_factor)
        self.n_levels = int(n_levels)
        self.keyframes: dict[int, KeyFrame] = {}
        self._n = 0
        cap = 1024
        self.xyz = np.zeros((cap, 3))
        self.descriptors = np.zeros((cap, 32), np.uint8)
        self.normal = np.zeros((cap, 3))
        self.min_dist = np.zeros(cap)
        self.max_dist = np.zeros(cap)
        self.alive = np.zeros(cap, bool)
        self.n_visible = np.zeros(cap, np.int64)
        self.n_found = np.zeros(cap, np.int64)
        self.first_kf = np.zeros(cap, np.int64)
        self.rgb = np.zeros((cap, 3), np.uint8)
        self._obs: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        # Index of the table by point id, CSR style (rows of point p: by_pt[start[p]:start[p + 1]]),
        # and the covisibility dictionaries computed since the table was built; both go with it.
        # The index is one tuple so that a reader never sees half of an old and half of a new one.
        self._pt_index: tuple[np.ndarray, np.ndarray] | None = None
        self._scans = 0  # queries answered by a scan since the table was built
        self._covis: dict[int, dict[int, int]] = {}
        self._next_kf_id = 0
        # Culled keyframes: id -> (parent id, T_parent_kf), so frames anchored to them keep a pose.
        self.removed_anchor: dict[int, tuple[int, np.ndarray]] = {}

    # ---------------------------------------------------------------- points
    @property
    def n_points_total(self) -> int:
        """Number of point ids ever created (alive or not)."""
        return self._n

    def point_ids(self) -> np.ndarray:
        """Ids ``(M,)`` of the alive map points."""
        return np.flatnonzero(self.alive[: self._n])

    def _grow(self, need: int) -> None:
        cap = len(self.xyz)
        if need <= cap:
            return
        new = max(need, 2 * cap)
        for name in ("xyz", "descriptors", "normal", "min_dist", "max_dist", "alive", "n_visible", "n_found", "first_kf", "rgb"):
            old = getattr(self, name)
            arr = np.zeros((new,) + old.shape[1:], old.dtype)
            arr[:cap] = old
            setattr(self, name, arr)

    def add_points(
        self,
        xyz: np.ndarray,
        descriptors: np.ndarray,
        kf: KeyFrame,
        kp_idx: np.ndarray,
        rgb: np.ndarray | None = None,
    ) -> np.ndarray:
        """Create map points at world positions ``xyz (K, 3)`` seen by keypoints ``kp_idx (K,)`` of
        keyframe ``kf`` (which must be in the map); the keyframe's ``map_point_ids`` are set.
        Returns the new ids ``(K,)``."""
        xyz = np.asarray(xyz, float).reshape(-1, 3)
        kp_idx = np.asarray(kp_idx, np.int64).reshape(-1)
        k = len(xyz)
        if len(kp_idx) != k or len(descriptors) != k:
            raise ValueError(f"add_points: {k} points, {len(descriptors)} descriptors, {len(kp_idx)} keypoints")
        if kf.id not in self.keyframes:
            raise ValueError(f"add_points: keyframe {kf.id} is not in the map")
        ids = np.arange(self._n, self._n + k)
        self._grow(self._n + k)
        self._n += k
        self.xyz[ids] = xyz
        self.descriptors[ids] = descriptors
        self.alive[ids] = True
        self.n_visible[ids] = 1
        self.n_found[ids] = 1
        self.first_kf[ids] = kf.id
        self.rgb[ids] = 0 if rgb is None else rgb
        kf.map_point_ids[kp_idx] = ids
        self.invalidate()
        self.update_geometry(ids)
        return ids

    def remove_points(self, ids: np.ndarray) -> None:
        """Mark points bad and drop their observations from all keyframes."""
        ids = np.asarray(ids, np.int64).reshape(-1)
        if len(ids) == 0:
            return
        self.alive[ids] = False
        kf_ids, _, kp = self.observations_of(ids)
        for kid in np.unique(kf_ids):  # loop over keyframes, not keypoints
            sel = kf_ids == kid
            self.keyframes[int(kid)].map_point_ids[kp[sel]] = -1
        self.invalidate()

    # ------------------------------------------------------------ keyframes
    def new_keyframe_id(self) -> int:
        kid = self._next_kf_id
        self._next_kf_id += 1
        return kid

    def add_keyframe(self, kf: KeyFrame) -> None:
        """Insert a keyframe; its parent in the spanning tree is its strongest covisible keyframe."""
        if kf.id in self.keyframes:
            raise ValueError(f"keyframe id {kf.id} already in the map")
        self.keyframes[kf.id] = kf
        self.invalidate()
        if kf.parent_id < 0 and len(self.keyframes) > 1:
            cov = self.covisibility(kf.id)
            if cov:
                kf.parent_id = max(cov, key=lambda k: (cov[k], k))
            else:
                kf.parent_id = max(k for k in self.keyframes if k != kf.id)
        if kf.parent_id in self.keyframes:
            self.keyframes[kf.parent_id].children.add(kf.id)

    def remove_keyframe(self, kf_id: int) -> None:
        """Cull a keyframe: its observations go, its children are re-parented to its parent
        (or to their strongest covisible keyframe when it has none)."""
        kf = self.keyframes.get(kf_id)
        if kf is None:
            return
        if kf.parent_id < 0:
            raise ValueError("the first keyframe (the origin of the map) cannot be removed")
        kf.bad = True
        parent_now = self.keyframes.get(kf.parent_id)
        if parent_now is not None:
            self.removed_anchor[kf_id] = (kf.parent_id, parent_now.T_c_w @ kf.T_w_c)
        del self.keyframes[kf_id]
        self.invalidate()
        parent = self.keyframes.get(kf.parent_id)
        if parent is not None:
            parent.children.discard(kf_id)
        for c in kf.children:
            child = self.keyframes.get(c)
            if child is None:
                continue
            child.parent_id = kf.parent_id if parent is not None else -1
            if parent is not None:
                parent.children.add(c)
        for other in kf.loop_edges:
            if other in self.keyframes:
                self.keyframes[other].loop_edges.discard(kf_id)
        # Points left with no observation die.
        ids = kf.map_point_ids[kf.map_point_ids >= 0]
        if len(ids):
            n = self.n_obs(ids)
            self.alive[ids[n == 0]] = False

    # --------------------------------------------------------- observations
    def _table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Flat observation table ``(kf_id, point_id, keypoint_index, octave)``, cached."""
        if self._obs is None:
            kfs = list(self.keyframes.values())
            if not kfs:
                z = np.zeros(0, np.int64)
                self._obs = (z, z, z, z)
            else:
                has = [k.map_point_ids >= 0 for k in kfs]
                self._obs = (
                    np.concatenate([np.full(int(h.sum()), k.id, np.int64) for k, h in zip(kfs, has)]),
                    np.concatenate([k.map_point_ids[h] for k, h in zip(kfs, has)]),
                    np.concatenate([np.flatnonzero(h) for h in has]),
                    np.concatenate([k.octave[h] for k, h in zip(kfs, has)]),
                )
        return self._obs

    def invalidate(self) -> None:
        """Call after changing any keyframe's ``map_point_ids`` directly."""
        self._obs = None
        self._pt_index = None
        self._scans = 0
        self._covis = {}

    def _point_index(self) -> tuple[np.ndarray, np.ndarray]:
        """Rows of the observation table sorted by point id ``(n_obs,)``, and the first of them of
        each point ``(n_points_total + 1,)``: a point's observations are one slice. Built once per
        table, so ``observations_of`` costs O(its rows), not a scan of the table. The grouping is
        a counting sort, O(observations + points): the table as a one-row sparse matrix (column =
        point id, value = row) converted from CSR to CSC (4x faster than ``np.argsort`` at 1000
        keyframes, benchmarks/covisibility_speed.py)."""
        index = self._pt_index
        if index is None:
            pt = self._table()[1]
            rows = sparse.csr_matrix((np.arange(len(pt)), pt, np.array([0, len(pt)])), shape=(1, max(self._n, 1))).tocsc()
            index = (rows.data.astype(np.int64), rows.indptr.astype(np.int64))
            self._pt_index = index
        return index

    def _rows_of(self, ids: np.ndarray) -> np.ndarray:
        """Observation-table rows of the points ``ids``, in table order. The first
        ``INDEX_AFTER_SCANS`` queries after a change scan the table (``np.isin``); later ones use the
        point index (built once, about as costly as 10 scans: a ski-rental rule, never much worse
        than always scanning or always indexing; benchmarks/covisibility_speed.py)."""
        ids = np.asarray(ids, np.int64).reshape(-1)
        if self._pt_index is None and self._scans < self.INDEX_AFTER_SCANS:
            self._scans += 1
            return np.flatnonzero(np.isin(self._table()[1], ids))
        by_pt, start = self._point_index()
        ids = ids[(ids >= 0) & (ids < len(start) - 1)]
        if len(ids) == 0:
            return np.zeros(0, np.int64)
        ids = np.unique(ids)
        lo, hi = start[ids], start[ids + 1]
        n = hi - lo
        total = int(n.sum())
        if total == 0:
            return np.zeros(0, np.int64)
        offs = np.repeat(lo - (np.cumsum(n) - n), n) + np.arange(total)
        return np.sort(by_pt[offs])

    def observations_of(self, ids: np.ndarray, with_octave: bool = False) -> tuple[np.ndarray, ...]:
        """Observation rows ``(kf_id, point_id, keypoint_index[, octave])`` of the points ``ids``."""
        kf, pt, kp, octave = self._table()
        sel = self._rows_of(ids)
        if with_octave:
            return kf[sel], pt[sel], kp[sel], octave[sel]
        return kf[sel], pt[sel], kp[sel]

    def observations(self, point_id: int) -> dict[int, int]:
        """``{keyframe id: keypoint index}`` of one map point."""
        kf, _, kp = self.observations_of(np.array([point_id]))
        return {int(a): int(b) for a, b in zip(kf, kp)}

    def n_obs(self, ids: np.ndarray) -> np.ndarray:
        """Number of keyframes observing each point ``(K,)``."""
        pt = self._table()[1]
        counts = np.bincount(pt, minlength=self._n) if len(pt) else np.zeros(self._n, np.int64)
        return counts[np.asarray(ids, np.int64)]

    def keyframes_observing(self, ids: np.ndarray) -> dict[int, int]:
        """``{keyframe id: number of the points ids it observes}``."""
        kf, _, _ = self.observations_of(ids)
        u, c = np.unique(kf, return_counts=True)
        return {int(a): int(b) for a, b in zip(u, c)}

    def covisibility(self, kf_id: int) -> dict[int, int]:
        """``{other keyframe id: number of shared map points}`` for keyframe ``kf_id``."""
        cached = self._covis.get(kf_id)
        if cached is None:
            kf = self.keyframes[kf_id]
            ids = kf.map_point_ids[kf.map_point_ids >= 0]
            cached = self.keyframes_observing(ids)
            cached.pop(kf_id, None)
            self._covis[kf_id] = cached
        return dict(cached)

    def best_covisibles(self, kf_id: int, n: int | None = None, min_weight: int = 1) -> list[int]:
        """Covisible keyframe ids by decreasing weight (at most ``n``; weight ``>= min_weight``)."""
        cov = self.covisibility(kf_id)
        ids = sorted((k for k, w in cov.items() if w >= min_weight), key=lambda k: (-cov[k], k))
        return ids if n is None else ids[:n]

    # ------------------------------------------------------------- geometry
    def update_geometry(self, ids: np.ndarray) -> None:
        """Recompute mean viewing direction and scale-invariance distances of points ``ids``
        from their observations (vectorised over observations)."""
        ids = np.asarray(ids, np.int64).reshape(-1)
        if len(ids) == 0:
            return
        kf, pt, kp, octave = self.observations_of(ids, with_octave=True)
        if len(kf) == 0:
            return
        kf_list = np.unique(kf)
        centers = np.array([self.keyframes[int(k)].center for k in kf_list])
        rays = self.xyz[pt] - centers[np.searchsorted(kf_list, kf)]
        dist = np.linalg.norm(rays, axis=1)
        unit = rays / np.maximum(dist, 1e-12)[:, None]
        acc = np.zeros((self._n, 3))
        np.add.at(acc, pt, unit)
        nrm = np.linalg.norm(acc[ids], axis=1)
        has = nrm > 0
        self.normal[ids[has]] = acc[ids[has]] / nrm[has, None]
        # Scale range from the observation in the point's first keyframe (else any one).
        is_ref = kf == self.first_kf[pt]
        pick = np.lexsort((~is_ref, pt))
        first = np.ones(len(pick), bool)
        first[1:] = pt[pick][1:] != pt[pick][:-1]
        sel = pick[first]
        f = self.scale_factor
        maxd = dist[sel] * f ** octave[sel]
        self.max_dist[pt[sel]] = maxd
        self.min_dist[pt[sel]] = maxd / f ** (self.n_levels - 1)

    def update_descriptors(self, ids: np.ndarray) -> None:
        """Give each point ``ids`` its most central observed descriptor: the one with the least
        median Hamming distance to the point's other observations (ORB-SLAM Sec. III-C,
        ``ComputeDistinctiveDescriptors``). Vectorised over all pairs of a point's observations."""
        ids = np.asarray(ids, np.int64).reshape(-1)
        kf, pt, kp = self.observations_of(ids)
        if len(pt) == 0:
            return
        desc = np.empty((len(pt), 32), np.uint8)
        for k in np.unique(kf):  # gather per keyframe
            sel = kf == k
            desc[sel] = self.keyframes[int(k)].descriptors[kp[sel]]
        order = np.argsort(pt, kind="stable")
        pt, desc = pt[order], desc[order]
        start = np.searchsorted(pt, pt, side="left")  # first row of each row's point
        count = np.searchsorted(pt, pt, side="right") - start
        # all (i, j) pairs of rows of the same point
        ii = np.repeat(np.arange(len(pt)), count)
        jj = start[ii] + (np.arange(len(ii)) - np.repeat(np.cumsum(count) - count, count))
        d = hamming_pairs(desc[ii], desc[jj])
        o = np.lexsort((d, ii))
        block = np.cumsum(count) - count  # start of row i's block in the sorted pair list
        median = d[o][block + (count - 1) // 2]
        best = np.lexsort((median, pt))
        first = np.ones(len(best), bool)
        first[1:] = pt[best][1:] != pt[best][:-1]
        self.descriptors[pt[best[first]]] = desc[best[first]]

    def predict_level(self, ids: np.ndarray, dist: np.ndarray) -> np.ndarray:
        """Predicted pyramid level ``(K,)`` of points ``ids`` seen from ``dist`` metres."""
        ratio = self.max_dist[ids] / np.maximum(dist, 1e-9)
        lvl = np.ceil(np.log(np.maximum(ratio, 1e-9)) / np.log(self.scale_factor) - 1e-9)
        return np.clip(lvl, 0, self.n_levels - 1).astype(np.int64)

    def keyframe_pose(self, kf_id: int) -> np.ndarray:
        """``T_w_c`` of a keyframe, also of a culled one (through its parent chain)."""
        T = np.eye(4)
        k = kf_id
        for _ in range(100000):
            if k in self.keyframes:
                return self.keyframes[k].T_w_c @ T
            if k not in self.removed_anchor:
                break
            parent, T_p_k = self.removed_anchor[k]
            T = T_p_k @ T
            k = parent
        raise KeyError(f"keyframe {kf_id} has no pose (removed without a parent)")

    # --------------------------------------------------------------- export
    def keyframe_ids(self) -> list[int]:
        return sorted(self.keyframes)

    def __repr__(self) -> str:
        return f"Map(keyframes={len(self.keyframes)}, points={int(self.alive[: self._n].sum())})"
