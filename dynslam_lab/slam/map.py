"""The map: keyframes, map points, observations and the covisibility graph
(ORB-SLAM, Mur-Artal et al., T-RO 2015, Sec. III-B/C; ORB-SLAM2, T-RO 2017).

* A **map point** ``p`` has a world position ``xyz`` (metres), a representative ORB descriptor,
  a mean viewing direction ``normal`` and the distance range ``[min_dist, max_dist]`` in which
  ORB's scale pyramid can see it: observed at distance ``d`` on level ``s``,
  ``max_dist = d * f**s`` and ``min_dist = max_dist / f**(L-1)`` (ORB-SLAM Sec. III-C).
  Its predicted level at distance ``d`` is ``ceil(log(max_dist / d) / log(f))``.
* An **observation** is a (keyframe, keypoint) pair seeing a point. The single source of truth
  is each keyframe's ``map_point_ids``; the map keeps a flat observation table
  (``kf, point, keypoint, octave`` rows) indexed by point, so every query is vectorised. The
  table is kept up to date incrementally (an append-only table with dead rows, compacted now and
  then): a change costs O(the observations changed), not O(all observations), see
  :meth:`Map.invalidate` and docs/speed.md.
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

    # Compaction of the observation table (rebuild of its point index) once the rows added since the
    # last one, or the dead rows, exceed this fraction of the indexed rows (amortised O(1) per row).
    COMPACT_FRACTION = 0.25
    COMPACT_MIN_ROWS = 4096

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
        # The observation table: rows [0, _rows) of kf, pt, kp, octave; a row dies (``_live`` False)
        # when its observation goes. Rows [0, _n_base) are indexed by point CSR style (rows of point
        # p: _by_pt[_start[p]:_start[p + 1]]); later rows are chained per point (``_head[p]`` the
        # newest, ``_next[row]`` the one before). ``_row_of[kf id][keypoint]``: the row of each
        # keypoint's observation (or -1), which is also what the table last saw of ``map_point_ids``.
        cap = 4096
        self._t = np.zeros((4, cap), np.int64)  # kf, pt, kp, octave
        self._live = np.zeros(cap, bool)
        self._next = np.full(cap, -1, np.int64)
        self._rows = 0
        self._n_dead = 0
        self._n_base = 0
        self._by_pt = np.zeros(0, np.int64)
        self._start = np.zeros(1, np.int64)
        self._head = np.full(1024, -1, np.int64)
        self._count = np.zeros(1024, np.int64)  # live observations per point
        self._row_of: dict[int, np.ndarray] = {}
        self._dirty: set[int] = set()  # keyframes whose map_point_ids may have changed
        self._all_dirty = False
        # Covisibility computed so far, per keyframe: {other: weight}, and the others by decreasing
        # weight (ties: lower id first) with their weights; a change drops those of the keyframes it touches.
        self._covis: dict[int, tuple[dict[int, int], list[int], np.ndarray]] = {}
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

    def points_of(self, kf_ids) -> np.ndarray:
        """Ids ``(M,)`` of the alive map points observed by the keyframes ``kf_ids``, sorted and unique
        (``np.unique`` of their ``map_point_ids``; a mark per point id instead of a sort: the local map of
        tracking, of the screener's context and of local BA asks this every frame, ~15 k ids)."""
        keyframes = [self.keyframes[k].map_point_ids for k in kf_ids]
        if not keyframes:
            return np.zeros(0, np.int64)
        mark = np.zeros(self._n, bool)
        for ids in keyframes:
            mark[ids[ids >= 0]] = True
        mark &= self.alive[: self._n]
        return np.flatnonzero(mark)

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
        self.invalidate([kf.id])
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
        self.invalidate(np.unique(kf_ids))

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
        self.invalidate([kf.id])
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
        self.invalidate([kf_id])
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
    def invalidate(self, kf_ids=None) -> None:
        """Call after changing keyframes' ``map_point_ids`` directly: ``kf_ids`` those keyframes
        (None: any keyframe may have changed; every keyframe is then compared with the table,
        O(keyframes x keypoints) numpy compares). The table catches up at the next query."""
        if kf_ids is None:
            self._all_dirty = True
        else:
            self._dirty.update(int(k) for k in np.asarray(kf_ids, np.int64).reshape(-1).tolist())

    def _ensure_rows(self, need: int) -> None:
        cap = len(self._live)
        if need <= cap:
            return
        new = max(need, 2 * cap)
        t = np.zeros((4, new), np.int64)
        t[:, :cap] = self._t
        self._t = t
        self._live = np.concatenate([self._live, np.zeros(new - cap, bool)])
        self._next = np.concatenate([self._next, np.full(new - cap, -1, np.int64)])

    def _ensure_points(self) -> None:
        cap = len(self._head)
        if self._n <= cap:
            return
        new = max(self._n, 2 * cap)
        self._head = np.concatenate([self._head, np.full(new - cap, -1, np.int64)])
        self._count = np.concatenate([self._count, np.zeros(new - cap, np.int64)])

    def _sync(self) -> None:
        """Bring the observation table up to date with the dirty keyframes' ``map_point_ids``:
        kill the rows of observations that went, append rows for new ones, drop the covisibility
        of every keyframe sharing a point whose observers changed."""
        if not self._dirty and not self._all_dirty:
            return
        kids = set(self._row_of) | set(self.keyframes) if self._all_dirty else self._dirty
        self._all_dirty = False
        self._dirty = set()
        self._ensure_points()
        pt_col = self._t[1]
        kill, add_kf, add_kp, add_pt, add_oct, add_slot, touched_kf = [], [], [], [], [], [], []
        for k in sorted(kids):  # loop over keyframes
            kf = self.keyframes.get(k)
            rows = self._row_of.get(k)
            if kf is None:
                if rows is not None:
                    kill.append(rows[rows >= 0])
                    del self._row_of[k]
                    touched_kf.append(k)
                continue
            cur = kf.map_point_ids
            if rows is None or len(rows) != len(cur):
                rows = np.full(len(cur), -1, np.int64)
                self._row_of[k] = rows
            old = np.where(rows >= 0, pt_col[np.maximum(rows, 0)], -1)
            changed = np.flatnonzero(old != cur)
            if len(changed) == 0:
                continue
            touched_kf.append(k)
            r = rows[changed]
            kill.append(r[r >= 0])
            rows[changed] = -1
            new = changed[cur[changed] >= 0]
            add_kf.append(np.full(len(new), k, np.int64))
            add_kp.append(new)
            add_pt.append(cur[new])
            add_oct.append(kf.octave[new])
            add_slot.append((rows, new))
        if not touched_kf:
            return
        touched_pt = []
        if kill:
            dead = np.concatenate(kill)
            self._live[dead] = False
            self._n_dead += len(dead)
            np.subtract.at(self._count, pt_col[dead], 1)
            touched_pt.append(pt_col[dead])
        n_add = sum(len(x) for x in add_pt)
        if n_add:
            r0 = self._rows
            self._ensure_rows(r0 + n_add)
            rows_new = np.arange(r0, r0 + n_add)
            pts = np.concatenate(add_pt)
            self._t[:, r0:r0 + n_add] = [np.concatenate(add_kf), pts, np.concatenate(add_kp), np.concatenate(add_oct)]
            self._live[rows_new] = True
            self._rows += n_add
            np.add.at(self._count, pts, 1)
            touched_pt.append(pts)
            at = r0
            for rows, new in add_slot:  # loop over keyframes
                rows[new] = np.arange(at, at + len(new))
                at += len(new)
            # chain the new rows per point (a point may appear twice in one batch)
            o = np.argsort(pts, kind="stable")
            ps, rs = pts[o], rows_new[o]
            first = np.ones(len(ps), bool)
            first[1:] = ps[1:] != ps[:-1]
            nxt = np.empty(len(ps), np.int64)
            nxt[first] = self._head[ps[first]]
            nxt[~first] = rs[np.flatnonzero(~first) - 1]
            self._next[rs] = nxt
            last = np.ones(len(ps), bool)
            last[:-1] = ps[1:] != ps[:-1]
            self._head[ps[last]] = rs[last]
        if self._covis:
            for k in touched_kf:
                self._covis.pop(k, None)
            if touched_pt:
                for k in np.unique(self._t[0][self._rows_of(np.concatenate(touched_pt))]).tolist():
                    self._covis.pop(k, None)
        lim = self.COMPACT_FRACTION * self._n_base + self.COMPACT_MIN_ROWS
        if self._rows - self._n_base > lim or self._n_dead > lim:
            self._compact()

    def _compact(self) -> None:
        """Drop the dead rows and index all rows by point: a counting sort, O(rows + points), the
        table as a one-row sparse matrix (column = point id, value = row) converted from CSR to CSC
        (4x faster than ``np.argsort`` at 1000 keyframes, benchmarks/covisibility_speed.py)."""
        keep = np.flatnonzero(self._live[: self._rows])
        remap = np.full(self._rows + 1, -1, np.int64)  # remap[-1] == -1
        remap[keep] = np.arange(len(keep))
        n = len(keep)
        self._t[:, :n] = self._t[:, keep]
        self._live[:n] = True
        self._live[n:] = False
        self._next[:] = -1
        self._head[:] = -1
        self._rows = self._n_base = n
        self._n_dead = 0
        for k, rows in self._row_of.items():  # loop over keyframes
            self._row_of[k] = remap[rows]
        pt = self._t[1, :n]
        m = sparse.csr_matrix((np.arange(n), pt, np.array([0, n])), shape=(1, max(self._n, 1))).tocsc()
        self._by_pt = m.data.astype(np.int64)
        self._start = m.indptr.astype(np.int64)

    def _rows_of(self, ids: np.ndarray) -> np.ndarray:
        """Live table rows of the points ``ids`` (unordered): their slices of the point index, then
        their chains of newer rows. O(their rows), never a scan of the table."""
        ids = np.asarray(ids, np.int64).reshape(-1)
        ids = np.unique(ids[(ids >= 0) & (ids < self._n)])
        if len(ids) == 0:
            return np.zeros(0, np.int64)
        parts = []
        base = ids[ids < len(self._start) - 1]
        if len(base):
            lo, hi = self._start[base], self._start[base + 1]
            n = hi - lo
            total = int(n.sum())
            if total:
                parts.append(self._by_pt[np.repeat(lo - (np.cumsum(n) - n), n) + np.arange(total)])
        cur = self._head[ids]
        cur = cur[cur >= 0]
        while len(cur):  # one step per newer observation of the most observed point
            parts.append(cur)
            cur = self._next[cur]
            cur = cur[cur >= 0]
        if not parts:
            return np.zeros(0, np.int64)
        rows = np.concatenate(parts)
        return rows[self._live[rows]]

    @staticmethod
    def _order(kf: np.ndarray, kp: np.ndarray) -> np.ndarray:
        """Order of rows by keyframe id then keypoint index. Rows are appended keyframe by keyframe,
        keypoints ascending, so the keys come in long sorted runs: a stable (merge) sort is ~O(n)."""
        return np.argsort(kf * (1 << 24) + kp, kind="stable")

    def _table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """All live observations ``(kf_id, point_id, keypoint_index, octave)``, by keyframe then keypoint."""
        self._sync()
        rows = np.flatnonzero(self._live[: self._rows])
        t = self._t[:, rows]
        o = self._order(t[0], t[2])
        return t[0, o], t[1, o], t[2, o], t[3, o]

    def observations_of(self, ids: np.ndarray, with_octave: bool = False) -> tuple[np.ndarray, ...]:
        """Observation rows ``(kf_id, point_id, keypoint_index[, octave])`` of the points ``ids``,
        by keyframe id then keypoint index."""
        self._sync()
        rows = self._rows_of(ids)
        kf, pt, kp, octave = self._t[:, rows]
        sel = self._order(kf, kp)
        if with_octave:
            return kf[sel], pt[sel], kp[sel], octave[sel]
        return kf[sel], pt[sel], kp[sel]

    def observations(self, point_id: int) -> dict[int, int]:
        """``{keyframe id: keypoint index}`` of one map point."""
        kf, _, kp = self.observations_of(np.array([point_id]))
        return {int(a): int(b) for a, b in zip(kf, kp)}

    def n_obs(self, ids: np.ndarray) -> np.ndarray:
        """Number of keyframes observing each point ``(K,)``."""
        self._sync()
        self._ensure_points()
        return self._count[np.asarray(ids, np.int64)]

    def keyframes_observing(self, ids: np.ndarray) -> dict[int, int]:
        """``{keyframe id: number of the points ids it observes}``."""
        kf, _, _ = self.observations_of(ids)
        u, c = np.unique(kf, return_counts=True)
        return {int(a): int(b) for a, b in zip(u, c)}

    def _covisibility_entry(self, kf_id: int) -> tuple[dict[int, int], list[int], np.ndarray]:
        """The cached covisibility of ``kf_id`` (computed when missing): ``{other: weight}``, the others
        by decreasing weight then increasing id, and those weights."""
        self._sync()
        cached = self._covis.get(kf_id)
        if cached is None:
            kf = self.keyframes[kf_id]
            # the observer column of the live rows of the keyframe's points, counted by keyframe id
            # (ids are small integers): no sort of the rows, no per-keyframe Python loop
            observers = self._t[0, self._rows_of(kf.map_point_ids[kf.map_point_ids >= 0])]
            counts = np.bincount(observers, minlength=kf_id + 1) if len(observers) else np.zeros(kf_id + 1, np.int64)
            counts[kf_id] = 0
            others = np.flatnonzero(counts)
            weights = counts[others]
            order = np.lexsort((others, -weights))
            cached = (dict(zip(others.tolist(), weights.tolist())), others[order].tolist(), weights[order])
            self._covis[kf_id] = cached
        return cached

    def covisibility(self, kf_id: int) -> dict[int, int]:
        """``{other keyframe id: number of shared map points}`` for keyframe ``kf_id``."""
        return dict(self._covisibility_entry(kf_id)[0])

    def best_covisibles(self, kf_id: int, n: int | None = None, min_weight: int = 1) -> list[int]:
        """Covisible keyframe ids by decreasing weight, ties by increasing id (at most ``n``; weight
        ``>= min_weight``). The order is cached with the covisibility."""
        _, order, weights = self._covisibility_entry(kf_id)
        m = len(order) if min_weight <= 1 else int(np.count_nonzero(weights >= min_weight))
        return order[: m if n is None else min(m, max(int(n), 0))]

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
