"""Octree occupancy map (OctoMap) built from the static points of the keyframes.

Chang et al. 2021 (YOLACT-based SLAM, IEEE TIM), Section III-D and Fig. 9: "the point cloud
map has been converted into the octree map, which facilitates further navigation and path
planning". The octree map is OctoMap (Hornung, Wurm, Bennewitz, Stachniss, Burgard,
"OctoMap: an efficient probabilistic 3D mapping framework based on octrees", Autonomous
Robots 2013). Its pieces, as implemented here:

* **Occupancy in log-odds** (Hornung et al., eqs. 2-3). Each leaf ``n`` stores
  ``L(n) = log(P / (1 - P))``; a measurement ``z_t`` adds ``L(n | z_t)``::

      L(n | z_1:t) = max(min(L(n | z_1:t-1) + L(n | z_t), l_max), l_min)

  with ``L(n | z_t) = logit(p_hit) = logit(0.7)`` for the voxel holding a ray's end point,
  ``logit(p_miss) = logit(0.4)`` for the voxels the ray crosses before it, and clamping at
  ``P = 0.12`` and ``0.97`` (the OctoMap defaults). A node is occupied when ``P > 0.5``.
* **Octree addressing.** A leaf of side ``r`` (the resolution) has integer key
  ``k = floor(X / r) + 2^15`` per axis (16 levels, as OctoMap). Interleaving the bits of
  the three keys gives the leaf's Morton code; dropping the last ``3 l`` bits gives the code
  of its ancestor ``l`` levels up, a node of side ``r 2^l``. The tree is stored *linearly*:
  the sorted Morton codes of the leaves and their log-odds, which is the set of leaves of a
  pointer octree without the pointers.
* **Inner nodes** take the maximum log-odds of their children (OctoMap's default
  ``updateInnerOccupancy``), so a coarse node is occupied when any voxel below it is.
* **Ray casting.** OctoMap walks every ray with 3D-DDA (Amanatides and Woo 1987); we sample
  each ray every ``r / 2`` (vectorised over all rays), which visits the same voxels except
  where a ray only grazes a corner.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["OctreeConfig", "OctreeMap", "morton_encode", "morton_decode", "logit"]

_TREE_DEPTH = 16  # levels, as OctoMap: keys 0 .. 2^16 - 1 per axis
_KEY_OFFSET = 1 << (_TREE_DEPTH - 1)


@dataclass(frozen=True)
class OctreeConfig:
    """Parameters of the occupancy octree (defaults: OctoMap, Hornung et al. 2013)."""

    resolution: float = 0.05  # leaf side in metres; Chang et al. Fig. 9 shows a few-cm octree (OctoMap: user choice)
    prob_hit: float = 0.7  # P(occupied | ray ends in voxel); OctoMap default 0.7
    prob_miss: float = 0.4  # P(occupied | ray crosses voxel); OctoMap default 0.4
    clamp_min: float = 0.1192  # lower clamping probability; OctoMap default 0.1192
    clamp_max: float = 0.971  # upper clamping probability; OctoMap default 0.971
    occupancy_threshold: float = 0.5  # P above which a node is occupied; OctoMap default 0.5
    max_range: float = 5.0  # metres; end points farther than this update free space only up to it (OctoMap maxrange, -1 = off there)

    def __post_init__(self) -> None:
        if not np.isfinite(self.resolution) or self.resolution <= 0:
            raise ValueError(f"OctreeConfig.resolution must be > 0 metres, got {self.resolution}")
        for name in ("prob_hit", "prob_miss", "clamp_min", "clamp_max", "occupancy_threshold"):
            p = getattr(self, name)
            if not 0.0 < p < 1.0:
                raise ValueError(f"OctreeConfig.{name} must be a probability in (0, 1), got {p}")
        if not self.prob_miss < 0.5 < self.prob_hit:
            raise ValueError(
                f"OctreeConfig: need prob_miss < 0.5 < prob_hit, got prob_miss={self.prob_miss}, prob_hit={self.prob_hit}"
            )
        if not self.clamp_min < self.clamp_max:
            raise ValueError(f"OctreeConfig: clamp_min {self.clamp_min} must be below clamp_max {self.clamp_max}")
        if self.max_range <= 0:
            raise ValueError(f"OctreeConfig.max_range must be > 0 metres, got {self.max_range}")


def logit(p: float | np.ndarray) -> float | np.ndarray:
    """Log-odds ``log(p / (1 - p))``."""
    p = np.asarray(p, dtype=np.float64)
    return np.log(p / (1.0 - p))


def _spread_bits(x: np.ndarray) -> np.ndarray:
    """Insert two zero bits after each of the low 21 bits of ``x`` (int64)."""
    x = x.astype(np.int64) & 0x1FFFFF
    x = (x | (x << 32)) & 0x1F00000000FFFF
    x = (x | (x << 16)) & 0x1F0000FF0000FF
    x = (x | (x << 8)) & 0x100F00F00F00F00F
    x = (x | (x << 4)) & 0x10C30C30C30C30C3
    x = (x | (x << 2)) & 0x1249249249249249
    return x


def _compact_bits(x: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_spread_bits`."""
    x = x.astype(np.int64) & 0x1249249249249249
    x = (x | (x >> 2)) & 0x10C30C30C30C30C3
    x = (x | (x >> 4)) & 0x100F00F00F00F00F
    x = (x | (x >> 8)) & 0x1F0000FF0000FF
    x = (x | (x >> 16)) & 0x1F00000000FFFF
    x = (x | (x >> 32)) & 0x1FFFFF
    return x


def morton_encode(keys: np.ndarray) -> np.ndarray:
    """Morton (Z-order) codes of integer voxel keys ``(N, 3)`` in ``[0, 2^21)``: bits ``..z y x``."""
    keys = np.asarray(keys, dtype=np.int64)
    if keys.ndim != 2 or keys.shape[1] != 3:
        raise ValueError(f"morton_encode: keys must be (N, 3), got {keys.shape}")
    return _spread_bits(keys[:, 0]) | (_spread_bits(keys[:, 1]) << 1) | (_spread_bits(keys[:, 2]) << 2)


def morton_decode(codes: np.ndarray) -> np.ndarray:
    """Integer keys ``(N, 3)`` of Morton codes ``(N,)`` (inverse of :func:`morton_encode`)."""
    c = np.asarray(codes, dtype=np.int64)
    return np.stack([_compact_bits(c), _compact_bits(c >> 1), _compact_bits(c >> 2)], axis=1)


class OctreeMap:
    """A probabilistic occupancy octree, updated scan by scan.

    Parameters
    ----------
    config : :class:`OctreeConfig` (resolution, sensor model, clamping).

    Attributes
    ----------
    codes : ``(L,)`` int64 sorted Morton codes of the known leaves.
    log_odds : ``(L,)`` float32 log-odds of those leaves.
    """

    def __init__(self, config: OctreeConfig | None = None) -> None:
        self.config = config or OctreeConfig()
        c = self.config
        self.l_hit = float(logit(c.prob_hit))
        self.l_miss = float(logit(c.prob_miss))
        self.l_min = float(logit(c.clamp_min))
        self.l_max = float(logit(c.clamp_max))
        self.l_occ = float(logit(c.occupancy_threshold))
        self.codes = np.zeros(0, dtype=np.int64)
        self.log_odds = np.zeros(0, dtype=np.float32)

    def __len__(self) -> int:
        return len(self.codes)

    @property
    def resolution(self) -> float:
        return self.config.resolution

    # ------------------------------------------------------------- addressing
    def keys_of(self, xyz: np.ndarray) -> np.ndarray:
        """Leaf keys ``(N, 3)`` int64 of world points ``(N, 3)`` (metres)."""
        k = np.floor(np.asarray(xyz, dtype=np.float64) / self.resolution).astype(np.int64) + _KEY_OFFSET
        if len(k) and ((k < 0).any() or (k >= 2 * _KEY_OFFSET).any()):
            raise ValueError(
                f"OctreeMap: points beyond +-{_KEY_OFFSET * self.resolution:g} m are outside the "
                f"{_TREE_DEPTH}-level tree at resolution {self.resolution} m"
            )
        return k

    def codes_of(self, xyz: np.ndarray) -> np.ndarray:
        """Leaf Morton codes ``(N,)`` of world points ``(N, 3)``."""
        return morton_encode(self.keys_of(xyz))

    def centres_of(self, codes: np.ndarray, level: int = 0) -> np.ndarray:
        """World centres ``(N, 3)`` of nodes ``level`` levels above the leaves (side ``r 2^level``)."""
        keys = morton_decode(np.asarray(codes, dtype=np.int64)) << level
        return (keys - _KEY_OFFSET + 0.5 * (1 << level)) * self.resolution

    # ---------------------------------------------------------------- updates
    def insert_scan(self, points_w: np.ndarray, origin: np.ndarray) -> None:
        """Integrate one scan: rays from the sensor ``origin`` to each end point.

        Parameters
        ----------
        points_w : ``(N, 3)`` end points in the world frame (metres), e.g. a keyframe's static
            back-projected (and voxel-downsampled) pixels.
        origin : ``(3,)`` sensor position in the world frame (the camera centre ``t_w_c``).

        Voxels crossed by a ray get ``logit(prob_miss)``, the end voxel ``logit(prob_hit)``;
        a voxel both crossed and hit in one scan counts as hit (OctoMap's ``insertPointCloud``).
        End points beyond ``max_range`` clear the ray up to ``max_range`` and add no hit.
        """
        P = np.asarray(points_w, dtype=np.float64)
        o = np.asarray(origin, dtype=np.float64).reshape(-1)
        if P.ndim != 2 or P.shape[1] != 3:
            raise ValueError(f"OctreeMap.insert_scan: points_w must be (N, 3), got {P.shape}")
        if o.shape != (3,) or not np.isfinite(o).all():
            raise ValueError(f"OctreeMap.insert_scan: origin must be a finite (3,) position, got {origin!r}")
        P = P[np.isfinite(P).all(axis=1)]
        if len(P) == 0:
            return
        ray = P - o
        length = np.linalg.norm(ray, axis=1)
        in_range = length <= self.config.max_range
        end = np.where(in_range, length, self.config.max_range)
        direction = ray / np.maximum(length, 1e-12)[:, None]
        hit_codes = np.unique(self.codes_of(P[in_range]))

        # Free space: samples every r/2 along each ray, up to one voxel short of the end point.
        step = 0.5 * self.resolution
        n_samples = np.maximum(np.floor((end - self.resolution) / step).astype(np.int64), 0)
        free_parts = []
        chunk = 2_000_000  # samples per batch, bounds memory
        starts = np.concatenate([[0], np.cumsum(n_samples)])
        ray_ids = np.arange(len(P))
        lo = 0
        while lo < len(P):
            hi = int(np.searchsorted(starts, starts[lo] + chunk, side="right")) - 1
            hi = max(hi, lo + 1)
            counts = n_samples[lo:hi]
            rid = np.repeat(ray_ids[lo:hi], counts)
            if len(rid):
                t = (np.arange(len(rid)) - np.repeat(starts[lo:hi] - starts[lo], counts)) * step
                free_parts.append(np.unique(self.codes_of(o + direction[rid] * t[:, None])))
            lo = hi
        free_codes = np.unique(np.concatenate(free_parts)) if free_parts else np.zeros(0, np.int64)
        free_codes = np.setdiff1d(free_codes, hit_codes, assume_unique=True)
        self._update(free_codes, self.l_miss)
        self._update(hit_codes, self.l_hit)

    def _update(self, codes: np.ndarray, delta: float) -> None:
        """Add ``delta`` to the log-odds of the leaves ``codes`` (unique), creating unknown ones at 0."""
        if len(codes) == 0:
            return
        pos = np.searchsorted(self.codes, codes)
        known = pos < len(self.codes)
        known[known] = self.codes[pos[known]] == codes[known]
        self.log_odds[pos[known]] = np.clip(self.log_odds[pos[known]] + delta, self.l_min, self.l_max)
        new = codes[~known]
        if len(new):
            codes_all = np.concatenate([self.codes, new])
            values = np.concatenate([self.log_odds, np.full(len(new), np.clip(delta, self.l_min, self.l_max), np.float32)])
            order = np.argsort(codes_all, kind="stable")
            self.codes, self.log_odds = codes_all[order], values[order].astype(np.float32)

    # ---------------------------------------------------------------- queries
    def nodes(self, level: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Known nodes ``level`` levels above the leaves and their log-odds (max over children).

        Returns ``(codes (M,), log_odds (M,))``; node centres via :meth:`centres_of`.
        """
        if not 0 <= level <= _TREE_DEPTH:
            raise ValueError(f"OctreeMap.nodes: level must be in 0..{_TREE_DEPTH}, got {level}")
        if level == 0 or len(self.codes) == 0:
            return self.codes.copy(), self.log_odds.copy()
        parents = self.codes >> (3 * level)  # sorted, since the leaf codes are sorted
        starts = np.flatnonzero(np.r_[True, parents[1:] != parents[:-1]])
        return parents[starts], np.maximum.reduceat(self.log_odds, starts)

    def occupied(self, level: int = 0) -> tuple[np.ndarray, float]:
        """Centres ``(M, 3)`` (metres) of the occupied nodes at ``level``, and their side in metres."""
        codes, lo = self.nodes(level)
        occ = lo > self.l_occ
        return self.centres_of(codes[occ], level), self.resolution * (1 << level)

    def occupancy(self, xyz: np.ndarray) -> np.ndarray:
        """Occupancy probability ``(N,)`` of the leaves holding ``xyz``; nan where unknown."""
        codes = self.codes_of(np.asarray(xyz, dtype=np.float64).reshape(-1, 3))
        out = np.full(len(codes), np.nan)
        if len(self.codes) == 0:
            return out
        pos = np.minimum(np.searchsorted(self.codes, codes), len(self.codes) - 1)
        hit = self.codes[pos] == codes
        out[hit] = 1.0 / (1.0 + np.exp(-self.log_odds[pos[hit]].astype(np.float64)))
        return out

    def stats(self) -> dict:
        """Counts of known, occupied and free leaves."""
        occ = int((self.log_odds > self.l_occ).sum())
        return {"leaves": len(self), "occupied": occ, "free": len(self) - occ, "resolution_m": self.resolution}
