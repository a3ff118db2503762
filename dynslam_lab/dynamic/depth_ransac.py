"""Depth-RANSAC inside person boxes (YOLO-SLAM, Wu et al. 2022, Sec. 3.3, Algorithm 1, eqs. 5-8).

A detection box around a person also holds the wall, desk and screen behind the person.
YOLO-SLAM keeps those background keypoints: it assumes that (1) the person fills most of
the box, (2) keypoints on a person have nearly the same depth, (3) the person stands out in
depth from what surrounds it. So, per box, RANSAC looks for the largest set of keypoints of
consistent depth and calls that set the person (dynamic); the rest of the box stays static.

Model (Algorithm 1, lines 5-8): draw two keypoints of the box, then for every keypoint of
the box compute the variance of the three depths ``{z1, z2, z}`` (eq. 5 with N = 3)::

    s^2 = sum_i (x_i - mean(x))^2 / N                                    (5)

and count the keypoint as an inlier when ``s^2 < nThre``. The hypothesis with the most
inliers wins. The number of iterations adapts (eqs. 6-8): with inlier ratio
``w = n_in / (n_in + n_out)`` (6) and a sample of N = 2 points, ``k`` iterations find an
all-inlier sample with probability ``P`` when ``1 - P = (1 - w^N)^k`` (7), so::

    k = log(1 - P) / log(1 - w^N)                                        (8)

``k`` starts at infinity (capped by ``max_iterations``) and is recomputed each time the
best hypothesis improves.

Our reading of ``nThre = 0.43``. The paper gives no unit. In metres squared it would accept
a keypoint 1.4 m behind the person (the variance of ``{a, a, a + d}`` is ``2 d^2 / 9``),
which merges person and wall on TUM. In raw 16-bit units it would accept nothing. The reading
that works is the raw TUM PNG value divided by 1000 (the millimetre convention of other
Kinect datasets): TUM stores 5000 units per metre, so one such unit is 0.2 m and
``nThre = 0.43 * 0.2^2 = 0.0172 m^2``, a tolerance of about 0.28 m between a keypoint and two
samples of equal depth. On the real fr3/walking_xyz frame the person spans about 0.4 m of depth
(5th-95th percentile) and the background of the box lies 0.5-2 m behind: this reading splits
them (see ``tests/dynamic/test_depth_ransac.py``). Both numbers are exposed:
``var_threshold`` (paper units squared) and ``depth_unit_m``.

Vectorisation: hypotheses are drawn in batches; one batch scores ``(B, M)`` variances in
one numpy expression. The only Python loops run over batches and over boxes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .table import check_uv

__all__ = [
    "DepthRansacConfig",
    "DepthRansacResult",
    "adaptive_iterations",
    "three_point_variance",
    "depth_ransac",
    "screen_boxes",
    "inlier_test",
]


@dataclass(frozen=True)
class DepthRansacConfig:
    """Parameters of depth-RANSAC (YOLO-SLAM, Wu et al. 2022, Sec. 3.3)."""

    var_threshold: float = 0.43  # nThre, variance threshold in paper depth units squared; YOLO-SLAM eq. 5: 0.43
    depth_unit_m: float = 0.2  # metres per paper depth unit (our reading: raw TUM PNG / 1000 = 5 x metres); default 0.2
    confidence: float = 0.99  # P of eq. 8, probability of drawing one all-inlier sample; ours (not given), 0.99
    max_iterations: int = 200  # cap on k, which starts at infinity (Algorithm 1); ours, 200
    batch: int = 16  # hypotheses scored per vectorised batch; ours, 16
    min_keypoints: int = 3  # boxes with fewer keypoints with depth mark all of them dynamic; ours, 3
    select: str = "largest"  # "largest" (paper: most inliers) or "front" (nearest set with >= front_min_fraction); paper
    front_min_fraction: float = 0.25  # support a "front" set needs, fraction of the box's keypoints; ours, 0.25
    model_from: str = "pixels"  # fit on "pixels" (a grid of the box's depth pixels) or "keypoints" (paper); ours
    pixel_samples: int = 400  # depth pixels sampled on a grid per box with model_from="pixels"; ours, 400
    missing_depth: str = "nearest"  # keypoints without depth: "nearest" (label of nearest keypoint in box), "dynamic", "static"; ours
    seed: int = 0  # seed of the sampling Generator; ours, 0

    def __post_init__(self) -> None:
        if not self.var_threshold > 0:
            raise ValueError(f"DepthRansacConfig.var_threshold must be > 0, got {self.var_threshold}")
        if not self.depth_unit_m > 0:
            raise ValueError(f"DepthRansacConfig.depth_unit_m must be > 0 (metres), got {self.depth_unit_m}")
        if not 0 < self.confidence < 1:
            raise ValueError(f"DepthRansacConfig.confidence must be in (0, 1), got {self.confidence}")
        if self.max_iterations < 1 or self.batch < 1:
            raise ValueError("DepthRansacConfig.max_iterations and .batch must be >= 1")
        if self.select not in ("largest", "front"):
            raise ValueError(f"DepthRansacConfig.select must be 'largest' or 'front', got {self.select!r}")
        if self.missing_depth not in ("nearest", "dynamic", "static"):
            raise ValueError(f"DepthRansacConfig.missing_depth must be 'nearest', 'dynamic' or 'static', got {self.missing_depth!r}")
        if self.model_from not in ("pixels", "keypoints"):
            raise ValueError(f"DepthRansacConfig.model_from must be 'pixels' or 'keypoints', got {self.model_from!r}")
        if self.pixel_samples < 3:
            raise ValueError(f"DepthRansacConfig.pixel_samples must be >= 3, got {self.pixel_samples}")
        if not 0 < self.front_min_fraction <= 1:
            raise ValueError(f"DepthRansacConfig.front_min_fraction must be in (0, 1], got {self.front_min_fraction}")
        if self.min_keypoints < 0:
            raise ValueError(f"DepthRansacConfig.min_keypoints must be >= 0, got {self.min_keypoints}")

    @property
    def var_threshold_m2(self) -> float:
        """``nThre`` in square metres: ``var_threshold * depth_unit_m**2``."""
        return self.var_threshold * self.depth_unit_m**2


@dataclass
class DepthRansacResult:
    """Depth-RANSAC in one box.

    Attributes
    ----------
    inliers : ``(M,)`` bool, the consensus set (the person) among the box's depths.
    iterations : hypotheses drawn.
    k : the adaptive iteration count of eq. 8 at the end.
    depth_range : ``(min, max)`` metres of the consensus depths, or None.
    model : ``(z1, z2)`` the depths of the winning sample pair (classify more depths with
        :func:`inlier_test`), or None.
    """

    inliers: np.ndarray
    iterations: int
    k: float
    depth_range: tuple[float, float] | None
    model: tuple[float, float] | None = None


def inlier_test(z: np.ndarray, model: tuple[float, float], config: "DepthRansacConfig") -> np.ndarray:
    """``(M,)`` bool: depths ``z`` (m) within ``nThre`` of the sample pair ``model`` (eq. 5, N = 3)."""
    z = np.asarray(z, np.float64)
    with np.errstate(invalid="ignore"):
        return three_point_variance(model[0], model[1], z) < config.var_threshold_m2


def adaptive_iterations(inlier_ratio: float, sample_size: int = 2, confidence: float = 0.99) -> float:
    """Eq. 8: ``k = log(1 - P) / log(1 - w^N)``; ``inf`` for ``w = 0`` and 0 for ``w = 1``."""
    w = float(inlier_ratio)
    if not 0 <= w <= 1:
        raise ValueError(f"inlier_ratio must be in [0, 1], got {inlier_ratio}")
    p_good = w**sample_size
    if p_good <= 0:
        return math.inf
    if p_good >= 1:
        return 0.0
    return math.log(1 - confidence) / math.log(1 - p_good)


def three_point_variance(z1: np.ndarray, z2: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Eq. 5 with N = 3: the population variance of ``{z1, z2, z}`` (broadcasting)."""
    m = (z1 + z2 + z) / 3.0
    return ((z1 - m) ** 2 + (z2 - m) ** 2 + (z - m) ** 2) / 3.0


def depth_ransac(
    depths: np.ndarray, config: DepthRansacConfig = DepthRansacConfig(), rng: np.random.Generator | int | None = None
) -> DepthRansacResult:
    """Algorithm 1 on the depths of the keypoints of one box.

    Parameters
    ----------
    depths : ``(M,)`` metres, all finite and positive (drop keypoints without depth first).
    config : thresholds.
    rng : Generator or seed (default ``config.seed``).

    Returns
    -------
    DepthRansacResult with the largest consistent-depth set.
    """
    z = np.asarray(depths, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(z) & (z > 0)):
        raise ValueError("depth_ransac: depths must be finite and > 0 (metres); drop keypoints without depth")
    rng = np.random.default_rng(config.seed if rng is None else rng)
    m = len(z)
    if m < 2:
        inl = np.ones(m, bool)
        return DepthRansacResult(inl, 0, 0.0, (float(z.min()), float(z.max())) if m else None)
    thr = config.var_threshold_m2
    best = np.zeros(m, bool)  # largest set (paper)
    best_n = 0
    best_model = None
    front = np.zeros(m, bool)  # nearest set with enough support (our option)
    front_model = None
    front_depth = math.inf
    need = config.front_min_fraction * m
    k = math.inf
    it = 0
    while it < min(k, config.max_iterations):
        b = int(min(config.batch, config.max_iterations - it))
        i = rng.integers(0, m, size=b)
        j = (i + rng.integers(1, m, size=b)) % m  # a second, different keypoint
        var = three_point_variance(z[i, None], z[j, None], z[None, :])  # (b, M)
        inl = var < thr
        counts = inl.sum(axis=1)
        top = int(np.argmax(counts))
        if counts[top] > best_n:
            best_n = int(counts[top])
            best = inl[top]
            best_model = (float(z[i[top]]), float(z[j[top]]))
            k = adaptive_iterations(best_n / m, 2, config.confidence)  # eq. 8 with the new ratio (eq. 6)
        if config.select == "front":
            ok = counts >= need
            if ok.any():
                mean_z = (inl * z[None, :]).sum(axis=1) / np.maximum(counts, 1)
                mean_z[~ok] = np.inf
                f = int(np.argmin(mean_z))
                if mean_z[f] < front_depth:
                    front_depth = float(mean_z[f])
                    front = inl[f]
                    front_model = (float(z[i[f]]), float(z[j[f]]))
        it += b
    use_front = config.select == "front" and front.any()
    chosen = front if use_front else best
    model = front_model if use_front else best_model
    rng_z = (float(z[chosen].min()), float(z[chosen].max())) if chosen.any() else None
    return DepthRansacResult(chosen, it, k, rng_z, model)


def _grid_depths(depth_image: np.ndarray, box: np.ndarray, n: int) -> np.ndarray:
    """Valid depths (m) on a regular grid of about ``n`` pixels inside ``box``."""
    h, w = depth_image.shape
    x1, y1 = max(int(np.floor(box[0])), 0), max(int(np.floor(box[1])), 0)
    x2, y2 = min(int(np.ceil(box[2])), w - 1), min(int(np.ceil(box[3])), h - 1)
    if x2 < x1 or y2 < y1:
        return np.zeros(0)
    bw, bh = x2 - x1 + 1, y2 - y1 + 1
    step = max(int(np.sqrt(bw * bh / n)), 1)
    z = depth_image[y1 : y2 + 1 : step, x1 : x2 + 1 : step].astype(np.float64).ravel()
    return z[np.isfinite(z) & (z > 0)]


def screen_boxes(
    uv: np.ndarray,
    depth: np.ndarray,
    boxes: np.ndarray,
    config: DepthRansacConfig = DepthRansacConfig(),
    rng: np.random.Generator | int | None = None,
    depth_image: np.ndarray | None = None,
) -> tuple[np.ndarray, list[DepthRansacResult | None]]:
    """Depth-RANSAC in every box: the keypoints of each box's consensus set are dynamic.

    Parameters
    ----------
    uv : ``(N, 2)`` keypoint pixels.
    depth : ``(N,)`` metres at the keypoints, ``nan`` where none.
    boxes : ``(B, 4)`` ``x1, y1, x2, y2`` pixels (person boxes).
    config, rng : see :func:`depth_ransac`.
    depth_image : ``(H, W)`` metres; with ``config.model_from == "pixels"`` the model is fitted on a
        grid of the box's depth pixels and the keypoints are classified with it (our variant: the
        person fills most of the box in *area* even when it has few corners).

    Returns
    -------
    dynamic : ``(N,)`` bool, in the consensus set of at least one box; a keypoint inside a box
        but without depth follows ``config.missing_depth`` (``dynamic``, ``static``, or the
        verdict of the nearest keypoint of the box that has a depth: ``nearest``).
    results : per box, its :class:`DepthRansacResult` (None for a box without keypoints).
    """
    uv = check_uv(uv)
    depth = np.asarray(depth, np.float64).reshape(-1)
    if depth.shape != (len(uv),):
        raise ValueError(f"screen_boxes: depth must have shape ({len(uv)},), got {depth.shape}")
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    rng = np.random.default_rng(config.seed if rng is None else rng)
    inside = (
        (uv[None, :, 0] >= boxes[:, None, 0]) & (uv[None, :, 0] <= boxes[:, None, 2])
        & (uv[None, :, 1] >= boxes[:, None, 1]) & (uv[None, :, 1] <= boxes[:, None, 3])
    )  # (B, N)
    has_z = np.isfinite(depth) & (depth > 0)
    dynamic = np.zeros(len(uv), bool)
    results: list[DepthRansacResult | None] = []
    for b in range(len(boxes)):
        members = np.flatnonzero(inside[b] & has_z)
        no_z = np.flatnonzero(inside[b] & ~has_z)
        if len(members) < config.min_keypoints:
            dynamic[members] = True
            dynamic[no_z] = config.missing_depth != "static" or dynamic[no_z]
            results.append(None if len(members) == 0 else DepthRansacResult(
                np.ones(len(members), bool), 0, 0.0, (float(depth[members].min()), float(depth[members].max()))))
            continue
        if config.model_from == "pixels" and depth_image is not None:
            samples = _grid_depths(depth_image, boxes[b], config.pixel_samples)
            if len(samples) >= config.min_keypoints:
                fit = depth_ransac(samples, config, rng)
                inl = inlier_test(depth[members], fit.model, config) if fit.model else np.zeros(len(members), bool)
                zr = (float(depth[members][inl].min()), float(depth[members][inl].max())) if inl.any() else fit.depth_range
                res = DepthRansacResult(inl, fit.iterations, fit.k, zr, fit.model)
            else:
                res = depth_ransac(depth[members], config, rng)
        else:
            res = depth_ransac(depth[members], config, rng)
        dynamic[members[res.inliers]] = True
        if len(no_z) and config.missing_depth == "dynamic":
            dynamic[no_z] = True
        elif len(no_z) and config.missing_depth == "nearest":
            # the verdict of the nearest keypoint of the same box that has a depth
            _, nn = cKDTree(uv[members]).query(uv[no_z])
            dynamic[no_z] |= res.inliers[nn]
        results.append(res)
    return dynamic, results
