"""ORB features spread evenly over the image and over a scale pyramid.

ORB-SLAM2 (Mur-Artal and Tardos, IEEE T-RO 2017, Sec. III-A, and ORB-SLAM, T-RO 2015,
Sec. III-A) extracts FAST corners on an image pyramid with ``n_levels`` levels, each
level ``s`` scaled by ``1 / scale_factor**s``. The ``n_features`` keypoints are shared
among the levels as a geometric series, so that every level gets the same number of
features per unit area::

    n_s = N (1 - 1/f) / (1 - (1/f)^L) * (1/f)^s ,   s = 0 .. L-1        (f = scale_factor)

Inside a level the features are spread over a grid of cells (ORB-SLAM2 uses 30x30 px
cells and a quadtree); in each cell the strongest corners (highest Harris response) win.
A cell with no corner at the FAST threshold ``fast_threshold`` (20) is searched again at
``min_fast_threshold`` (7). The orientation is the intensity centroid angle and the
descriptor the 256-bit rotated BRIEF (Rublee et al., ICCV 2011).

Our reading: OpenCV's ``cv2.ORB`` builds the pyramid, detects FAST corners, scores them
with the Harris measure, computes the angle and the descriptor. We ask it for more
corners than needed and then do the ORB-SLAM part ourselves, vectorised: per level a
quota by the series above, per cell of a ``grid_cols x grid_rows`` grid an equal share of
that quota, the strongest corners first, and the quota a cell cannot fill is handed to the
remaining corners of the level by response. The same ORB object then computes the
descriptors of the kept keypoints. OpenCV keeps, per level, a fixed number of corners by
response, so a textured object can take the whole list and leave weakly textured cells (a wall
of fine noise under dim light) without a candidate. With ``cell_retry`` > 0 (off by default)
those cells (fewer than ``cell_retry`` candidates, over all levels) are searched again at
``min_fast_threshold`` by one detection masked to them (:func:`retry_cells`): ORB-SLAM2's
per-cell retry. An image with fewer corners than ``n_features`` in all is detected again at
``min_fast_threshold`` as a whole. docs/robustness.md, "ORB corners at minThFAST", measures
what the per-cell retry changes for dynamic scenes.

With a dynamic ``region`` (pixels known or believed to move) the budget leaves it: the region keeps
``region_share`` of the quota its area deserves (0 = DynaSLAM's extraction outside the dynamic masks,
Bescos et al. 2018) and the pixels outside get the rest. Both sides take their candidates from one
detection with ``region_candidates`` times the usual number of corners, split by the region; a side
the other one crowded out of that list (a textured mover), or that has too few corners at the FAST
threshold, gets a detection of its own, masked to it (:func:`budget_candidates`); see
docs/robustness.md, "ORB budget", and docs/speed.md.

The keypoint pixels ``uv`` are in level-0 (full image) pixel coordinates.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, replace
from typing import NamedTuple

import cv2
import numpy as np

__all__ = [
    "OrbConfig", "Features", "Candidates", "extract_features", "refine_subpixel", "level_quotas", "region_quotas",
    "budget_candidates", "retry_cells", "scale_factors",
]


@dataclass(frozen=True)
class OrbConfig:
    """Parameters of ORB extraction (ORB-SLAM2 ``ORBextractor`` settings for TUM RGB-D)."""

    n_features: int = 1000  # number of keypoints per image; ORB-SLAM2 TUM1-3.yaml: 1000
    scale_factor: float = 1.2  # ratio between pyramid levels; ORB-SLAM2: 1.2
    n_levels: int = 8  # pyramid levels; ORB-SLAM2: 8
    fast_threshold: int = 20  # FAST intensity threshold (grey levels); ORB-SLAM2 iniThFAST: 20
    min_fast_threshold: int = 7  # retry threshold where too few corners; ORB-SLAM2 minThFAST: 7
    grid_cols: int = 20  # grid cells across the level-0 image (640/20 = 32 px, ORB-SLAM2 uses 30 px)
    grid_rows: int = 15  # grid cells down the level-0 image (480/15 = 32 px)
    edge_threshold: int = 19  # border without features (px); ORB-SLAM2 EDGE_THRESHOLD: 19
    patch_size: int = 31  # BRIEF / orientation patch (px); ORB-SLAM2 PATCH_SIZE: 31
    oversample: float = 2.5  # corners asked from OpenCV per kept keypoint (ours; bucketing needs spare)
    cell_retry: int = 0  # grid cells with fewer corners than this at fast_threshold are searched again at min_fast_threshold (ORB-SLAM2 retries a cell with no corner at minThFAST: 1); 0 = off, the default (the whole-image retry only; docs/robustness.md "ORB corners at minThFAST": 1 fixes weak-texture rooms but lets a slowly starting cart pull tracking)
    subpixel_levels: int = 0  # refine keypoints of levels < this with cv2.cornerSubPix on their level image (0 = off); ours (ORB-SLAM2 keeps integer level pixels)
    subpixel_max_shift: float = 0.75  # a refinement moving a keypoint more than this (level px) is dropped (keeps the integer position); ours
    # The keypoint budget and the dynamic region (extract_features(region=...), docs/robustness.md "ORB budget"):
    truth_region_share: float = 0.0  # quota of a region known dynamic in the frame itself (the oracle's masks), as a fraction of its area's fair share (0 = outside only, DynaSLAM, Bescos et al. 2018; 1 = off)
    prior_region_share: float = 0.25  # quota of the region a screener found dynamic on an earlier frame (fraction, as above; 1 = off; > 0 keeps keypoints on movers for the screener to judge: docs/robustness.md); ours
    prior_lag: int = 2  # the prior region of frame t is the screened region of frame t - prior_lag (frames; >= 1; 1 delays extraction until the previous frame is screened); ours
    prior_dilate_px: int = 16  # the prior region grows by this many pixels (movers move between frames); ours
    region_candidates: float = 2.0  # with a region: corners of the one detection both sides share, as a multiple of the plain extraction's (n_features x oversample); ours (docs/speed.md)

    def __post_init__(self) -> None:
        if self.n_features < 1:
            raise ValueError(f"OrbConfig.n_features must be >= 1, got {self.n_features}")
        if not self.scale_factor > 1.0:
            raise ValueError(f"OrbConfig.scale_factor must be > 1, got {self.scale_factor}")
        if self.n_levels < 1:
            raise ValueError(f"OrbConfig.n_levels must be >= 1, got {self.n_levels}")
        if self.grid_cols < 1 or self.grid_rows < 1:
            raise ValueError(f"OrbConfig grid must be at least 1x1, got {self.grid_cols}x{self.grid_rows}")
        if not 0 < self.min_fast_threshold <= self.fast_threshold:
            raise ValueError(
                f"OrbConfig needs 0 < min_fast_threshold <= fast_threshold, got "
                f"{self.min_fast_threshold} and {self.fast_threshold}"
            )
        if self.oversample < 1.0:
            raise ValueError(f"OrbConfig.oversample must be >= 1, got {self.oversample}")
        if self.edge_threshold < 0:
            raise ValueError(f"OrbConfig.edge_threshold must be >= 0 pixels, got {self.edge_threshold}")
        if self.patch_size < 3:
            raise ValueError(f"OrbConfig.patch_size must be >= 3 pixels, got {self.patch_size}")
        if not 0 <= self.subpixel_levels <= self.n_levels:
            raise ValueError(f"OrbConfig.subpixel_levels must be in [0, n_levels], got {self.subpixel_levels}")
        if not self.subpixel_max_shift > 0:
            raise ValueError(f"OrbConfig.subpixel_max_shift must be > 0 (level px), got {self.subpixel_max_shift}")
        for name in ("truth_region_share", "prior_region_share"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"OrbConfig.{name} must be in [0, 1] (fraction of the fair share), got {getattr(self, name)}")
        if self.prior_lag < 1:
            raise ValueError(f"OrbConfig.prior_lag must be >= 1 frame, got {self.prior_lag}")
        if self.prior_dilate_px < 0:
            raise ValueError(f"OrbConfig.prior_dilate_px must be >= 0 pixels, got {self.prior_dilate_px}")
        if self.cell_retry < 0:
            raise ValueError(f"OrbConfig.cell_retry must be >= 0 corners (0 = off), got {self.cell_retry}")
        if not self.region_candidates >= 1.0:
            raise ValueError(f"OrbConfig.region_candidates must be >= 1 (multiple of n_features x oversample), got {self.region_candidates}")


@dataclass
class Features:
    """ORB keypoints of one image.

    Attributes
    ----------
    uv : ``(N, 2)`` float32 pixel coordinates (level 0), x right, y down.
    octave : ``(N,)`` int pyramid level the keypoint was found on.
    angle : ``(N,)`` float orientation in degrees [0, 360).
    response : ``(N,)`` float Harris response (larger = stronger corner).
    descriptors : ``(N, 32)`` uint8 rotated-BRIEF descriptors (256 bits).
    """

    uv: np.ndarray
    octave: np.ndarray
    angle: np.ndarray
    response: np.ndarray
    descriptors: np.ndarray

    def __post_init__(self) -> None:
        self.uv = np.asarray(self.uv, dtype=np.float32).reshape(-1, 2)
        n = len(self.uv)
        self.octave = np.asarray(self.octave, dtype=np.int64).reshape(-1)
        self.angle = np.asarray(self.angle, dtype=np.float64).reshape(-1)
        self.response = np.asarray(self.response, dtype=np.float64).reshape(-1)
        self.descriptors = np.asarray(self.descriptors, dtype=np.uint8).reshape(-1, 32)
        for name in ("octave", "angle", "response", "descriptors"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"Features.{name} has {len(getattr(self, name))} rows, uv has {n}")

    def __len__(self) -> int:
        return len(self.uv)

    def select(self, keep: np.ndarray) -> "Features":
        """The features at indices / boolean mask ``keep``."""
        return Features(self.uv[keep], self.octave[keep], self.angle[keep], self.response[keep], self.descriptors[keep])

    @classmethod
    def empty(cls) -> "Features":
        return cls(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros((0, 32), np.uint8))


def scale_factors(cfg: OrbConfig) -> np.ndarray:
    """``(n_levels,)`` scale of each pyramid level: ``scale_factor ** level``."""
    return cfg.scale_factor ** np.arange(cfg.n_levels, dtype=np.float64)


def level_quotas(cfg: OrbConfig) -> np.ndarray:
    """``(n_levels,)`` int: features wanted per level, the geometric series of ORB-SLAM2.

    ``n_s = N (1 - 1/f) / (1 - (1/f)^L) (1/f)^s``, rounded, the last level takes the rest.
    """
    inv = 1.0 / cfg.scale_factor
    first = cfg.n_features * (1.0 - inv) / (1.0 - inv**cfg.n_levels)
    q = np.round(first * inv ** np.arange(cfg.n_levels)).astype(np.int64)
    q[-1] = max(cfg.n_features - int(q[:-1].sum()), 0)
    return q


# One cv2.ORB per thread and parameter set: creating it costs ~4 ms, as much as a sixth of an
# extraction (docs/speed.md); an ORB object is not shared between threads (extraction runs in the
# run loop's worker thread and in notebooks in the main one).
_ORB_OBJECTS = threading.local()


def _n_candidates(cfg: OrbConfig, widen: float = 1.0) -> int:
    """Corners asked from OpenCV: ``n_features x oversample`` (x ``widen``: the budget's shared detection)."""
    return int(np.ceil(cfg.n_features * cfg.oversample * widen))


def _orb_object(cfg: OrbConfig, fast_threshold: int, n_candidates: int | None = None) -> cv2.ORB:
    key = (_n_candidates(cfg) if n_candidates is None else int(n_candidates), float(cfg.scale_factor), int(cfg.n_levels),
           int(cfg.edge_threshold), int(cfg.patch_size), int(fast_threshold))
    cache = getattr(_ORB_OBJECTS, "by_key", None)
    if cache is None:
        cache = _ORB_OBJECTS.by_key = {}
    orb = cache.get(key)
    if orb is None:
        if len(cache) >= 8:  # a sweep over ORB parameters: keep the cache small
            cache.clear()
        orb = cache[key] = cv2.ORB_create(nfeatures=key[0], scaleFactor=key[1], nlevels=key[2],
                                          edgeThreshold=key[3], patchSize=key[4], fastThreshold=key[5])
    return orb


def _detect(gray: np.ndarray, cfg: OrbConfig, fast_threshold: int, mask: np.ndarray | None = None,
            n_candidates: int | None = None) -> tuple[cv2.ORB, list]:
    orb = _orb_object(cfg, fast_threshold, n_candidates)
    return orb, list(orb.detect(gray, mask))


def _cells(uv: np.ndarray, shape: tuple[int, int], cfg: OrbConfig) -> np.ndarray:
    """``(N,)`` grid cell (row-major, ``grid_rows x grid_cols`` over the level-0 image) of each keypoint."""
    h, w = shape
    col = np.clip((uv[:, 0] * cfg.grid_cols / w).astype(np.int64), 0, cfg.grid_cols - 1)
    row = np.clip((uv[:, 1] * cfg.grid_rows / h).astype(np.int64), 0, cfg.grid_rows - 1)
    return row * cfg.grid_cols + col


def _bucket(uv: np.ndarray, octave: np.ndarray, response: np.ndarray, shape: tuple[int, int], cfg: OrbConfig,
            quotas: np.ndarray | None = None, shares: np.ndarray | None = None) -> np.ndarray:
    """Indices of the keypoints kept by per-level quotas and per-cell shares (vectorised).

    ``quotas`` ``(n_levels,)`` (default :func:`level_quotas`) and ``shares`` ``(n_levels, n_cells)``
    first-pass shares per level and cell (default: the level's quota over the cells, at least one)."""
    quotas = level_quotas(cfg) if quotas is None else quotas
    n_cells = cfg.grid_cols * cfg.grid_rows
    lvl = np.clip(octave, 0, cfg.n_levels - 1)
    cell_xy = _cells(uv, shape, cfg)
    cell = octave * n_cells + cell_xy
    # Rank of each keypoint inside its (level, cell), strongest first.
    order = np.lexsort((-response, cell))
    sorted_cell = cell[order]
    start = np.searchsorted(sorted_cell, sorted_cell, side="left")
    rank = np.empty(len(uv), dtype=np.int64)
    rank[order] = np.arange(len(uv)) - start
    if shares is None:
        # Share of a level's quota per cell: quota / cells (at least one per cell).
        share = np.maximum(np.ceil(quotas / n_cells), 1).astype(np.int64)
        first_pass = rank < share[lvl]
    else:
        first_pass = rank < shares[lvl, cell_xy]
    # Per level: keep the first-pass winners by response up to the quota, then fill the
    # rest of the quota with the strongest remaining corners (cells with spare corners).
    priority = np.where(first_pass, 0, 1)
    order2 = np.lexsort((-response, priority, lvl))
    lvl_sorted = lvl[order2]
    pos_in_level = np.arange(len(uv)) - np.searchsorted(lvl_sorted, lvl_sorted, side="left")
    keep_sorted = pos_in_level < quotas[lvl_sorted]
    return np.sort(order2[keep_sorted])


def region_quotas(region: np.ndarray, cfg: OrbConfig, share: float) -> tuple[np.ndarray, np.ndarray]:
    """How the keypoint budget is split with a dynamic ``region`` (``(H, W)`` bool).

    A region covering the fraction ``a`` of the image would get ``a`` of each level's quota ``n_s``
    (the fair share of its area); it gets ``share`` of that, ``r_s = round(share a n_s)``, and the
    rest of the level's quota goes to the pixels outside. Returns ``(r, cover)``: ``(n_levels,)`` the
    region's quotas and ``(n_cells,)`` the fraction of each grid cell inside the region (row-major).
    """
    cover = cv2.resize(np.asarray(region, np.float32), (cfg.grid_cols, cfg.grid_rows), interpolation=cv2.INTER_AREA)
    cover = np.clip(cover.reshape(-1).astype(np.float64), 0.0, 1.0)
    r = np.round(share * float(cover.mean()) * level_quotas(cfg)).astype(np.int64)
    return r, cover


def _cell_shares(quotas: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """``(n_levels, n_cells)`` first-pass shares: each level's quota spread over the cells in
    proportion to ``weight`` (the cell's area that takes part), rounded up (0 where the weight is 0)."""
    total = float(weight.sum())
    if total <= 0:
        return np.zeros((len(quotas), len(weight)), np.int64)
    return np.ceil(quotas[:, None] * weight[None, :] / total).astype(np.int64)


def _inside(region: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``(N,)`` bool: keypoint pixel (nearest integer) inside ``region``."""
    h, w = region.shape
    ui = np.clip(np.round(uv[:, 0]).astype(int), 0, w - 1)
    vi = np.clip(np.round(uv[:, 1]).astype(int), 0, h - 1)
    return region[vi, ui]


def _keypoint_arrays(kps: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    # cv2.KeyPoint_convert: the float32 pixels as stored (k.pt, 70x faster than a list of tuples)
    uv = (cv2.KeyPoint_convert(kps) if kps else np.zeros((0, 2))).astype(np.float32).reshape(-1, 2)
    octave = np.array([k.octave for k in kps], dtype=np.int64)
    response = np.array([k.response for k in kps], dtype=np.float64)
    return uv, octave, response


class Candidates(NamedTuple):
    """Corners one side of a region chooses its keypoints from: entries ``index`` of the ``cv2.KeyPoint``
    list ``kps`` (a detection's, shared by both sides), with their arrays."""

    kps: list
    index: np.ndarray  # (N,) int64 into kps
    uv: np.ndarray  # (N, 2) float32 level-0 pixels
    octave: np.ndarray  # (N,) int64
    response: np.ndarray  # (N,) float64

    def keypoints(self, keep: np.ndarray | None = None) -> list:
        """The ``cv2.KeyPoint`` objects (of the candidates ``keep``, default all)."""
        return [self.kps[i] for i in (self.index if keep is None else self.index[keep])]


def _candidates(kps: list, keep: np.ndarray | None = None, arrays=None) -> Candidates:
    """``kps`` (or its entries ``keep``) with their arrays (computed, or ``arrays`` indexed)."""
    if keep is None:
        return Candidates(kps, np.arange(len(kps)), *(_keypoint_arrays(kps) if arrays is None else arrays))
    return Candidates(kps, keep, *(a[keep] for a in arrays))


def budget_candidates(gray: np.ndarray, cfg: OrbConfig, region: np.ndarray, quotas_in: np.ndarray,
                      mask: np.ndarray | None = None) -> tuple[cv2.ORB, Candidates, Candidates, int]:
    """The corners each side of a dynamic ``region`` chooses its keypoints from.

    One detection at ``cfg.fast_threshold`` asks OpenCV for ``cfg.region_candidates`` times the plain
    extraction's corners over the allowed pixels (``mask``), and splits them by the region (keypoint
    pixel, nearest integer). OpenCV keeps, per level, a fixed number of corners by response: a
    textured mover can take that list. So a side gets a detection of its own, masked to it, at
    ``cfg.min_fast_threshold`` (ORB-SLAM2's minThFAST) when

    * it was **crowded out**: at a level where the detection kept all it could, the side got fewer
      than ``cfg.oversample`` times its quota there, or
    * it is **short**: fewer corners than its quota at the FAST threshold (low texture; ORB-SLAM2
      retries at minThFAST there, as the plain extraction does).

    Otherwise the outside side takes its share of the list, and its cells left with fewer than
    ``cfg.cell_retry`` corners are searched again (:func:`retry_cells`, one more detection).

    The region's quotas are ``quotas_in`` (``(n_levels,)``, :func:`region_quotas`), the outside's
    the rest of :func:`level_quotas`. Returns ``(orb, inside, outside, detections)``: the ORB object
    of the shared detection, each side's :class:`Candidates` (``inside`` empty when the region's
    quota is 0) and the number of detections run (1-3). Deterministic: it depends on the image only.
    """
    allowed = None if mask is None else (mask > 0)
    n_wide = _n_candidates(cfg, cfg.region_candidates)
    orb, kps = _detect(gray, cfg, cfg.fast_threshold, None if allowed is None else allowed.astype(np.uint8) * 255, n_wide)
    arrays = _keypoint_arrays(kps)
    inside = _inside(region, arrays[0])
    lvl = np.clip(arrays[1], 0, cfg.n_levels - 1)
    caps = level_quotas(replace(cfg, n_features=n_wide))  # OpenCV's corners per level (the same series)
    full = np.bincount(lvl, minlength=cfg.n_levels) >= caps
    detections = 1
    sides = []
    for sel, quota, pixels, static in ((inside, quotas_in, region, False), (~inside, level_quotas(cfg) - quotas_in, ~region, True)):
        if quota.sum() <= 0:
            sides.append(_candidates([]))
            continue
        got = np.bincount(lvl[sel], minlength=cfg.n_levels)
        crowded = bool(np.any(full & (got < np.ceil(cfg.oversample * quota))))
        own = pixels if allowed is None else pixels & allowed
        if crowded or got.sum() < quota.sum():
            sides.append(_candidates(_detect(gray, cfg, cfg.min_fast_threshold, own.astype(np.uint8) * 255)[1]))
            detections += 1
        else:
            extra = []
            if cfg.cell_retry > 0 and static:  # the static side: its weakly textured cells again
                extra = retry_cells(gray, cfg, arrays[0][sel], own)
                detections += bool(extra)
            if extra:
                sides.append(_candidates([kps[i] for i in np.flatnonzero(sel)] + extra))
            else:
                sides.append(_candidates(kps, np.flatnonzero(sel), arrays))
    return orb, sides[0], sides[1], detections


def retry_cells(gray: np.ndarray, cfg: OrbConfig, uv: np.ndarray, allowed: np.ndarray | None = None) -> list:
    """ORB-SLAM2's per-cell retry: corners at ``cfg.min_fast_threshold`` in the grid cells where the
    detection at ``cfg.fast_threshold`` left fewer than ``cfg.cell_retry`` candidates.

    ``uv`` ``(N, 2)`` are the candidates' level-0 pixels (every level counts for the cell they fall in);
    ``allowed`` ``(H, W)`` bool limits the search (the pixels outside a dynamic region, a mask); a cell
    is searched only when at least half of it is searchable (allowed, and inside OpenCV's border of
    ``edge_threshold`` pixels). One OpenCV detection, masked to those cells, asked for their share of
    ``n_features x oversample`` corners (at least 64). Returns the new ``cv2.KeyPoint`` objects (empty when no cell is short).
    """
    n_cells = cfg.grid_cols * cfg.grid_rows
    h, w = gray.shape
    counts = np.bincount(_cells(uv, gray.shape, cfg), minlength=n_cells) if len(uv) else np.zeros(n_cells, np.int64)
    short = (counts < cfg.cell_retry).reshape(cfg.grid_rows, cfg.grid_cols)
    if not short.any():
        return []
    # only cells mostly searchable: inside the border OpenCV leaves (edge_threshold) and the allowed pixels
    # (a cell cut by a dynamic region has few corners outside it because it has few pixels there)
    e = int(cfg.edge_threshold)
    searchable = np.zeros((h, w), np.uint8)
    searchable[e : h - e, e : w - e] = 1
    if allowed is not None:
        searchable &= np.asarray(allowed, bool).astype(np.uint8)
    share = cv2.resize(searchable.astype(np.float32), (cfg.grid_cols, cfg.grid_rows), interpolation=cv2.INTER_AREA)
    short &= share >= 0.5
    if not short.any():
        return []
    m = cv2.resize(short.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) & searchable
    n = max(int(np.ceil(_n_candidates(cfg) * float(short.mean()))), 64)
    kps = _detect(gray, cfg, cfg.min_fast_threshold, m * 255, n)[1]
    if not kps:
        return []
    inside = short.reshape(-1)[_cells(cv2.KeyPoint_convert(kps).reshape(-1, 2), gray.shape, cfg)]  # the pyramid's corners near a cell edge
    return [k for k, ok in zip(kps, inside) if ok]


def _budgeted(gray: np.ndarray, cfg: OrbConfig, region: np.ndarray, share: float, mask: np.ndarray | None) -> tuple[cv2.ORB, list]:
    """The keypoints kept when the region gets ``share`` of its fair share of the budget (see
    :func:`region_quotas`) and the rest of each level's quota goes to the cells outside it, spread
    by their area outside the region; each side chooses among its own candidates
    (:func:`budget_candidates`), so a textured mover cannot take the static side's."""
    quotas = level_quotas(cfg)
    r, cover = region_quotas(region, cfg, share)
    orb, ins, outs, _ = budget_candidates(gray, cfg, region, r, mask)
    kept: list = []
    rest = quotas
    if len(ins.index):
        keep = _bucket(ins.uv, ins.octave, ins.response, gray.shape, cfg, r, _cell_shares(r, cover))
        kept = ins.keypoints(keep)
        rest = quotas - np.bincount(np.clip(ins.octave[keep], 0, cfg.n_levels - 1), minlength=cfg.n_levels)[: cfg.n_levels]
    if len(outs.index):
        keep = _bucket(outs.uv, outs.octave, outs.response, gray.shape, cfg, rest, _cell_shares(rest, 1.0 - cover))
        kept += outs.keypoints(keep)
    return orb, kept


def extract_features(gray: np.ndarray, cfg: OrbConfig = OrbConfig(), mask: np.ndarray | None = None,
                     region: np.ndarray | None = None, region_share: float = 0.0) -> Features:
    """Extract ORB features spread over the image and the scale pyramid.

    Parameters
    ----------
    gray : ``(H, W)`` uint8 grey image.
    cfg : extraction parameters.
    mask : optional ``(H, W)`` bool/uint8; features only where non-zero.
    region : optional ``(H, W)`` bool/uint8 pixels known or believed dynamic (non-zero): they get
        ``region_share`` of their area's fair share of each level's quota, the pixels outside the
        rest (:func:`region_quotas`; 0 = features outside the region only, as DynaSLAM, Bescos et
        al. 2018). None, an empty region or ``region_share`` 1: the plain extraction.

    Returns
    -------
    Features with at most ``cfg.n_features`` keypoints (fewer in low-texture images).

    Examples
    --------
    >>> import numpy as np
    >>> img = (np.random.default_rng(0).random((120, 160)) * 255).astype(np.uint8)
    >>> f = extract_features(img, OrbConfig(n_features=100))
    >>> f.descriptors.shape[1]
    32
    """
    gray = np.asarray(gray)
    if gray.ndim != 2:
        raise ValueError(f"extract_features expects an (H, W) grey image, got shape {gray.shape}")
    if gray.dtype != np.uint8:
        raise ValueError(f"extract_features expects a uint8 image, got {gray.dtype}")
    min_side = 2 * cfg.edge_threshold + 1
    if gray.shape[0] < min_side or gray.shape[1] < min_side:
        raise ValueError(f"extract_features: image {gray.shape} smaller than {min_side} px (edge_threshold)")
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != gray.shape:
            raise ValueError(f"extract_features: mask shape {mask.shape} != image shape {gray.shape}")
    if region is not None:
        region = np.asarray(region)
        if region.shape != gray.shape:
            raise ValueError(f"extract_features: region shape {region.shape} != image shape {gray.shape}")
        if not 0.0 <= float(region_share) <= 1.0:
            raise ValueError(f"extract_features: region_share must be in [0, 1], got {region_share}")
        region = region > 0
        if region_share >= 1.0 or not region.any():
            region = None
    if region is not None:
        orb, kept = _budgeted(gray, cfg, region, float(region_share), mask)
        if not kept:
            return Features.empty()
    else:
        orb, kps = _detect(gray, cfg, cfg.fast_threshold)
        if len(kps) < cfg.n_features:
            # Low texture: redo the detection with the lower FAST threshold (ORB-SLAM2 minThFAST).
            orb, kps = _detect(gray, cfg, cfg.min_fast_threshold)
        elif cfg.cell_retry > 0:  # ORB-SLAM2's retry per cell, where the image as a whole had corners enough
            kps = kps + retry_cells(gray, cfg, cv2.KeyPoint_convert(kps).reshape(-1, 2), None if mask is None else mask > 0)
        if not kps:
            return Features.empty()
        uv, octave, response = _keypoint_arrays(kps)
        idx = np.arange(len(kps))
        if mask is not None:
            idx = idx[_inside(mask > 0, uv)]
        keep = idx[_bucket(uv[idx], octave[idx], response[idx], gray.shape, cfg)]
        kept = [kps[i] for i in keep]
    kept, desc = orb.compute(gray, kept)
    if desc is None or not kept:
        return Features.empty()
    uv, octave, response = _keypoint_arrays(kept)
    if cfg.subpixel_levels > 0:
        uv = refine_subpixel(gray, uv, octave, cfg)
    return Features(
        uv=uv,
        octave=octave,
        angle=np.array([k.angle for k in kept], dtype=np.float64),
        response=response,
        descriptors=desc,
    )


def refine_subpixel(gray: np.ndarray, uv: np.ndarray, octave: np.ndarray, cfg: OrbConfig) -> np.ndarray:
    """Keypoints of the levels ``s < cfg.subpixel_levels`` moved to the sub-pixel corner position
    of ``cv2.cornerSubPix`` (5x5 window) on their level image; ``(N, 2)`` float32 level-0 pixels.

    OpenCV's ORB (as ORB-SLAM2) reports a level-``s`` keypoint at its integer level pixel times
    ``f^s``: a 0.5 px rounding at level 0 is 0.5 f^s px at level ``s``. A refinement that moves a
    point more than ``cfg.subpixel_max_shift`` level pixels is not trusted (the point keeps its
    integer position).
    """
    out = uv.copy()
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.01)
    h, w = gray.shape
    for s in range(min(cfg.subpixel_levels, cfg.n_levels)):
        sel = np.flatnonzero(octave == s)
        if not len(sel):
            continue
        scale = cfg.scale_factor ** s
        img = gray if s == 0 else cv2.resize(gray, (round(w / scale), round(h / scale)), interpolation=cv2.INTER_LINEAR)
        pts = (uv[sel] / scale).astype(np.float32).reshape(-1, 1, 2)
        ref = cv2.cornerSubPix(img, pts.copy(), (2, 2), (-1, -1), crit).reshape(-1, 2)
        ok = np.all(np.abs(ref - pts.reshape(-1, 2)) <= cfg.subpixel_max_shift, axis=1)
        out[sel[ok]] = ref[ok] * scale
    return out
