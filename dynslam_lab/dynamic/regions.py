"""From dynamic keypoints to dynamic regions: a moving object is removed as a whole.

Every geometric test judges points: a keypoint (epipolar, multi-view), a pixel (the free-space
test of :mod:`.multiframe`). A moving object also has parts no test can judge: low-texture
patches without keypoints, surfaces that moved within themselves (a flat box face sliding
sideways keeps its depth), parts hidden in the earlier frames. DynaSLAM (Bescos et al. 2018,
Sec. III-C) grows its dynamic keypoints into regions "in the depth image" around them; Chang et
al. 2021 (Sec. III-C) join the flow regions that touch a person mask. We grow regions from the
evidence over the depth image on the reduced grid of the dense tests (our construction):

* **seeds**: cells with fresh evidence (a free-space violation in any earlier frame, a dynamic
  keypoint of a geometric test);
* **growth**: up to ``steps`` cells (4-neighbour steps), only between neighbours whose depths differ
  by less than ``continuity_rel`` of the depth (a depth edge stops it), and never into a cell
  that the multi-frame test confirms static (no earlier frame saw through it or lost it, at least
  ``static_min_agree`` agree, and no more saw it hidden than agree), unless the cell carries the
  temporal prior (the previous frame's region, :mod:`.temporal`) and lies on a surface
  (:func:`surface_segments`) that holds fresh evidence in this frame: a slow mover whose cells look
  static in this frame stays dynamic while some fresh evidence on it remains, and a region that
  spilled onto the wall or floor beside a mover does not keep itself alive there through the prior;
* **support**: a part of the grown region, joined across continuous depth only, is kept when it
  holds at least ``min_fresh_cells`` cells of fresh evidence, so a lone noisy cell grows nothing and
  the prior fades as soon as the fresh evidence does (a mover that stopped).

The result is an ``(h, w)`` bool grid of dynamic cells; keypoints inside it are dynamic.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["RegionConfig", "depth_continuity", "crease_continuity", "surface_segments", "grow_regions", "continuity_components", "supported_regions", "prior_on_fresh_surfaces", "cells_at", "on_region", "splat"]


@dataclass(frozen=True)
class RegionConfig:
    """Parameters of region growing on the reduced grid (ours, after DynaSLAM's region growing, Bescos et al. 2018)."""

    steps: int = 64  # growth steps from the seeds (cells; 64 x 4 px = 256 px at factor 4: a close mover as a whole); ours (docs/robustness.md: 8 vs 64)
    continuity_rel: float = 0.04  # neighbours join when |z_a - z_b| < continuity_rel * min(z_a, z_b); ours
    static_min_agree: int = 2  # a cell is confirmed static when this many earlier frames (and all tested) agree; ours
    min_fresh_cells: int = 3  # a region needs this many cells of fresh evidence; ours
    seed_keypoints: bool = True  # dynamic keypoints of the other geometric tests seed regions; ours
    prior_on_fresh_surfaces: bool = True  # the prior reopens confirmed-static cells only on surfaces holding min_fresh_cells of fresh evidence; ours
    crease_deg: float = 35.0  # surfaces (reference pose, step 3b) split where normals turn more than this (deg); ours
    edge_cells: int = 0  # a keypoint whose own cell straddles a depth edge (a mover's silhouette: no reduced depth) takes the region's verdict from a cell up to this many cells away on its own depth (on_region); 0 = its own cell only (the default: measured, docs/robustness.md "Keypoints on a mover's silhouette"); ours
    silhouette_px: float = 0.0  # > 0: a keypoint without depth within this distance of the grown region (a corner on a mover's silhouette, where the sensor gives no depth) is judged by its flow with the previous frame: dynamic when it follows the flow of the dynamic keypoints around it rather than the camera's (follows_the_mover); 0 = off; ours
    silhouette_reach_px: float = 24.0  # ... the flow of the dynamic keypoints with depth within this distance (px; at least 3 of them); ours
    silhouette_min_px: float = 1.0  # ... when the keypoint's flow misses the static prediction by at least this (px) ...; ours
    silhouette_ratio: float = 0.5  # ... and the movers' flow by at most this share of that; ours
    surface_share: float = 0.0  # > 0: a surface (depth segment of step 3b, split at creases) with at least this share of its cells in the region joins it whole, keypoints and cells (the region misses a mover's parts the earlier frames saw at the same depth, where the ORB budget puts its keypoints); 0 = off; ours

    def __post_init__(self) -> None:
        if self.steps < 0 or self.min_fresh_cells < 1 or self.static_min_agree < 1:
            raise ValueError("RegionConfig: steps >= 0, min_fresh_cells >= 1 and static_min_agree >= 1 required")
        if not 0 < self.crease_deg < 180:
            raise ValueError(f"RegionConfig.crease_deg must be in (0, 180) degrees, got {self.crease_deg}")
        if not 0 <= self.edge_cells <= 3:
            raise ValueError(f"RegionConfig.edge_cells must be in 0..3, got {self.edge_cells}")
        if self.silhouette_px < 0 or not self.silhouette_reach_px > 0 or not self.silhouette_min_px > 0:
            raise ValueError("RegionConfig: silhouette_px >= 0, silhouette_reach_px > 0 and silhouette_min_px > 0 required")
        if not 0 < self.silhouette_ratio < 1:
            raise ValueError(f"RegionConfig.silhouette_ratio must be in (0, 1), got {self.silhouette_ratio}")
        if not 0 <= self.surface_share <= 1:
            raise ValueError(f"RegionConfig.surface_share must be in [0, 1], got {self.surface_share}")
        if not 0 < self.continuity_rel < 1:
            raise ValueError(f"RegionConfig.continuity_rel must be in (0, 1), got {self.continuity_rel}")


def depth_continuity(depth: np.ndarray, rel: float) -> tuple[np.ndarray, np.ndarray]:
    """``(h, w - 1)`` and ``(h - 1, w)`` bool: horizontal and vertical neighbours on one surface
    (both with depth, ``|z_a - z_b| < rel * min(z_a, z_b)``)."""
    z = np.asarray(depth, np.float32)
    a, b = z[:, 1:], z[:, :-1]
    horiz = (a > 0) & (b > 0) & (np.abs(a - b) < rel * np.minimum(a, b))
    a, b = z[1:], z[:-1]
    vert = (a > 0) & (b > 0) & (np.abs(a - b) < rel * np.minimum(a, b))
    return horiz, vert


def crease_continuity(depth: np.ndarray, camera, max_angle_deg: float, join_convex: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """``(h, w - 1)`` and ``(h - 1, w)`` bool: neighbours not separated by a concave crease of the surface.

    Normals come from central differences of the back-projected grid (``camera`` of the grid),
    turned towards the camera; the edge between cells ``x`` and ``x + 1`` is a crease when the normals
    at ``x - 1`` and ``x + 2`` (either side, beyond the cells a corner blurs) differ by more than
    ``max_angle_deg``. With ``join_convex`` a convex crease (the edge of a box, the normals turning away
    from each other: ``(n_a - n_b) . (p_a - p_b) > 0``) still joins, so an object stays whole while it
    is cut from the floor it stands on and the wall it leans against (concave creases), the local
    convexity criterion of Stein et al. (CVPR 2014, LCCP). Cells without depth join nothing.
    """
    z = np.asarray(depth, np.float32)
    h, w = z.shape
    X = ((np.arange(w, dtype=np.float32) - np.float32(camera.cx)) / np.float32(camera.fx))[None, :] * z
    Y = ((np.arange(h, dtype=np.float32) - np.float32(camera.cy)) / np.float32(camera.fy))[:, None] * z
    P = (X, Y, z)  # one (h, w) plane per coordinate: the vector arithmetic below stays on contiguous planes
    dx = [np.gradient(a, axis=1) for a in P]  # central differences, one-sided at the border
    dy = [np.gradient(a, axis=0) for a in P]
    n = [dx[1] * dy[2] - dx[2] * dy[1], dx[2] * dy[0] - dx[0] * dy[2], dx[0] * dy[1] - dx[1] * dy[0]]
    flip = np.where(n[0] * X + n[1] * Y + n[2] * z > 0, np.float32(-1), np.float32(1))  # towards the camera
    norm = np.sqrt(n[0] ** 2 + n[1] ** 2 + n[2] ** 2)
    scale = np.where(norm > 0, flip / np.maximum(norm, np.float32(1e-12)), np.float32(0))  # 0 where undefined
    n = [a * scale for a in n]
    defined = norm > 0
    c = np.float32(np.cos(np.radians(max_angle_deg)))

    def joined(sa, sb) -> np.ndarray:
        na, nb = [a[sa] for a in n], [a[sb] for a in n]
        ok = (na[0] * nb[0] + na[1] * nb[1] + na[2] * nb[2]) >= c
        ok |= ~(defined[sa] & defined[sb])  # never a crease where a normal is undefined
        if join_convex:
            ok |= sum((na[k] - nb[k]) * (P[k][sa] - P[k][sb]) for k in range(3)) > 0
        return ok

    horiz = np.ones((h, w - 1), bool)
    horiz[:, 1:-1] = joined((slice(None), slice(0, w - 3)), (slice(None), slice(3, w)))
    vert = np.ones((h - 1, w), bool)
    vert[1:-1] = joined((slice(0, h - 3), slice(None)), (slice(3, h), slice(None)))
    return horiz, vert


def surface_segments(depth: np.ndarray, camera, continuity_rel: float, crease_deg: float) -> tuple[int, np.ndarray]:
    """Surfaces of a depth grid: cells joined across continuous depth and no crease
    (:func:`depth_continuity`, :func:`crease_continuity`). Returns ``(n labels, (h, w) int32)``, 0 = no depth."""
    ch, cv = depth_continuity(depth, continuity_rel)
    kh, kv = crease_continuity(depth, camera, crease_deg)
    return continuity_components(np.asarray(depth) > 0, (ch & kh, cv & kv))


def grow_regions(seeds: np.ndarray, allowed: np.ndarray, continuity: tuple[np.ndarray, np.ndarray], steps: int) -> np.ndarray:
    """Geodesic growth of ``seeds (h, w)`` through ``allowed`` cells over continuous neighbours, ``steps`` times."""
    horiz, vert = continuity
    grown = np.asarray(seeds, bool).copy()
    allowed = np.asarray(allowed, bool)
    for _ in range(int(steps)):
        new = np.zeros_like(grown)
        new[:, 1:] |= grown[:, :-1] & horiz
        new[:, :-1] |= grown[:, 1:] & horiz
        new[1:] |= grown[:-1] & vert
        new[:-1] |= grown[1:] & vert
        new &= allowed & ~grown
        if not new.any():
            break
        grown |= new
    return grown


def continuity_components(mask: np.ndarray, continuity: tuple[np.ndarray, np.ndarray]) -> tuple[int, np.ndarray]:
    """Connected parts of ``mask (h, w)`` whose neighbours join only across continuous depth.

    The cells and the joining edges are laid on a grid twice as fine (cell ``(i, j)`` at ``(2i, 2j)``,
    the edge to its right at ``(2i, 2j + 1)``, the one below at ``(2i + 1, 2j)``), so that one
    ``cv2.connectedComponents`` call (4-connected) labels them. Returns ``(n labels, (h, w) int32)``,
    0 outside ``mask``.
    """
    horiz, vert = continuity
    m = np.asarray(mask, bool)
    h, w = m.shape
    fine = np.zeros((2 * h - 1, 2 * w - 1), np.uint8)
    fine[::2, ::2] = m
    fine[::2, 1::2] = m[:, 1:] & m[:, :-1] & horiz
    fine[1::2, ::2] = m[1:] & m[:-1] & vert
    n, labels = cv2.connectedComponents(fine, connectivity=4)
    return n, labels[::2, ::2]


def supported_regions(region: np.ndarray, fresh: np.ndarray, min_fresh: int,
                      continuity: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The parts of ``region`` (joined across continuous depth only) that hold at least ``min_fresh``
    cells of ``fresh``."""
    region = np.asarray(region, bool)
    if not region.any():
        return region
    n, labels = continuity_components(region, continuity)
    support = np.bincount(labels[np.asarray(fresh, bool) & region], minlength=n)
    keep = support >= min_fresh
    keep[0] = False
    return keep[labels]


def prior_on_fresh_surfaces(prior: np.ndarray, fresh: np.ndarray, labels: np.ndarray, min_fresh: int) -> np.ndarray:
    """The cells of ``prior (h, w)`` on a surface (``labels``, :func:`surface_segments`; 0 = none) that holds
    at least ``min_fresh`` cells of ``fresh`` evidence in this frame (ours).

    The temporal prior may reopen cells the multi-frame test confirms static (a slow mover's body looks
    static: the earlier frames saw the mover there too); only on such surfaces, so that a region that
    grew past a mover's outline onto the floor or wall beside it (continuous depth through the contact)
    is not carried from frame to frame by its own prior.
    """
    prior = np.asarray(prior, bool)
    labels = np.asarray(labels)
    if not prior.any():
        return prior
    held = np.bincount(labels[np.asarray(fresh, bool)], minlength=int(labels.max()) + 1) >= min_fresh
    held[0] = False
    return prior & held[labels]


def cells_at(uv: np.ndarray, factor: int, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cell ``(row, col)`` of the reduced grid of shape ``(h, w)`` holding each pixel ``uv (N, 2)``,
    and ``inside (N,)``."""
    h, w = shape
    uv = np.asarray(uv, np.float64)
    finite = np.isfinite(uv).all(axis=1)
    safe = np.where(finite[:, None], uv, -1.0)
    c = np.floor((safe[:, 0] + 0.5) / factor).astype(np.int64)
    r = np.floor((safe[:, 1] + 0.5) / factor).astype(np.int64)
    inside = finite & (c >= 0) & (c < w) & (r >= 0) & (r < h)
    return np.clip(r, 0, h - 1), np.clip(c, 0, w - 1), inside


def on_region(region: np.ndarray, small: np.ndarray, r: np.ndarray, c: np.ndarray, z: np.ndarray, rel: float,
              reach: int = 0) -> np.ndarray:
    """``(N,)`` bool: the keypoints in cells ``(r, c)`` (:func:`cells_at`) at depth ``z (N,)`` that lie on the region.

    A keypoint takes its cell's verdict when it lies on the cell's surface: the cell's reduced depth (``small``,
    :func:`~.history.reduce_depth`) within ``2 rel`` of ``z`` (a keypoint on the wall beside a person shares a cell
    with the person's edge but not its depth). A cell that straddles a depth edge has no reduced depth, so a
    keypoint on a mover's silhouette gets no verdict from it; with ``reach`` > 0 such a keypoint takes it from a
    region cell up to ``reach`` cells away whose depth is its own (ours, ``RegionConfig.edge_cells``).
    """
    h, w = small.shape
    zc = small[r, c]
    with np.errstate(invalid="ignore"):
        out = region[r, c] & (zc > 0) & ~(np.abs(z - zc) > 2 * rel * zc)
    edge = zc <= 0  # the keypoint's cell straddles a depth edge (reduce_depth gave it no reading)
    if reach <= 0 or not edge.any():
        return out
    for dr in range(-reach, reach + 1):
        for dc in range(-reach, reach + 1):
            if dr == 0 and dc == 0:
                continue
            rr, cc = np.clip(r + dr, 0, h - 1), np.clip(c + dc, 0, w - 1)
            zn = small[rr, cc]
            with np.errstate(invalid="ignore"):
                out |= edge & region[rr, cc] & (zn > 0) & ~(np.abs(z - zn) > 2 * rel * zn)
    return out


def follows_the_mover(uv: np.ndarray, uv_prev: np.ndarray, static_prev: np.ndarray, candidates: np.ndarray,
                      dynamic: np.ndarray, reach_px: float, min_px: float, ratio: float,
                      min_neighbours: int = 3) -> np.ndarray:
    """``(N,)`` bool: the ``candidates`` whose flow follows the movers around them rather than the camera (ours).

    A corner on a mover's silhouette has no depth (the sensor loses it at depth edges), so no depth test judges
    it, and the region's cells beside it may be the mover's or the wall's. Its flow tells: two hypotheses for
    where it was in the previous frame, ``static_prev`` (the camera's motion alone) and its own position moved by
    the median flow ``uv_prev - uv`` of the keypoints judged ``dynamic`` within ``reach_px`` (at least
    ``min_neighbours`` of them with a flow). It follows the mover when its matched ``uv_prev`` misses the static
    prediction by at least ``min_px`` and the movers' by at most ``ratio`` times that. ``uv_prev`` is nan where
    the keypoint was not matched; such keypoints, and those with too few moving neighbours, stay as they are.
    """
    uv = np.asarray(uv, np.float64)
    flow = np.asarray(uv_prev, np.float64) - uv
    has_flow = np.isfinite(flow).all(axis=1)
    out = np.zeros(len(uv), bool)
    cand = np.flatnonzero(candidates & has_flow & np.isfinite(static_prev).all(axis=1))
    movers = np.flatnonzero(dynamic & has_flow)
    if len(cand) == 0 or len(movers) < min_neighbours:
        return out
    d2 = ((uv[cand, None, :] - uv[None, movers, :]) ** 2).sum(axis=2)  # (C, M)
    near = d2 <= reach_px * reach_px
    enough = near.sum(axis=1) >= min_neighbours
    if not enough.any():
        return out
    cand, near = cand[enough], near[enough]
    fm = np.where(near[:, :, None], flow[movers][None, :, :], np.nan)  # (C, M, 2)
    mover_flow = np.nanmedian(fm, axis=1)  # (C, 2)
    off_static = np.linalg.norm(uv_prev[cand] - static_prev[cand], axis=1)
    off_mover = np.linalg.norm(flow[cand] - mover_flow, axis=1)
    out[cand] = (off_static >= min_px) & (off_mover <= ratio * off_static)
    return out


def splat(uv: np.ndarray, flags: np.ndarray, factor: int, shape: tuple[int, int]) -> np.ndarray:
    """``(h, w)`` bool: the cells holding at least one keypoint ``uv`` with ``flags`` set."""
    out = np.zeros(shape, bool)
    flags = np.asarray(flags, bool)
    if flags.any():
        r, c, inside = cells_at(np.asarray(uv)[flags], factor, shape)
        out[r[inside], c[inside]] = True
    return out


def whole_surfaces(region: np.ndarray, labels: np.ndarray, cells: np.ndarray, share: float) -> np.ndarray:
    """``region (h, w)`` bool with every surface that lies at least ``share`` inside it added whole (ours).

    ``labels (h, w)`` int surface of each cell (0 = none), ``cells`` the cell count of each label (label 0
    first). A mover the earlier frames saw at the same depth where it is now (a panel sliding along its own
    plane) is confirmed static there and the region stops short of it; its keypoints crowd into those parts
    (the ORB budget keeps them off the previous region). A surface mostly in the region is taken for the
    mover, which a door in its wall is not (docs/robustness.md, "Whole surfaces into the region": off by default).
    """
    inside = np.bincount(labels[region], minlength=len(cells))[: len(cells)]
    whole = inside >= share * np.maximum(cells, 1)
    whole[0] = False
    return region | whole[labels]
