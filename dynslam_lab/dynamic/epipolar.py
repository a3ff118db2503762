"""Epipolar check of keypoint matches (Zhang et al. 2023 eqs. 15-17, Chang et al. 2021 eq. 1, Ge et al. 2024 Sec. 2.3).

A static scene point seen in two frames satisfies the epipolar constraint
``p2^T F p1 = 0`` (Ge et al. 2024 eq. 1, Zhang et al. 2023 eq. 15): its pixel ``p2`` in the current frame
lies on the epipolar line of its pixel ``p1`` in the previous frame::

    l2 = (a, b, c)^T = F p1                                              (16)
    d  = |p2^T l2| / sqrt(a^2 + b^2)                                     (17)

A point on an object that moved between the two frames leaves its line; ``d > mu`` marks it
dynamic. ASG-SLAM (Ge et al. 2024, Sec. 2.3) spells the procedure out, and we follow it:

1. match keypoints between the frames with pyramidal Lucas-Kanade optical flow (we track
   the current keypoints back into the previous image and keep a pair only when tracking
   forward again returns within ``fb_max_px``);
2. leave out pairs inside potentially moving objects (the semantic prior) and near the image
   border;
3. estimate F from the remaining pairs with RANSAC;
4. compute ``d`` for every matched keypoint and compare with ``mu`` (``threshold_px``).

None of the papers gives ``mu``; the default 1 px is DS-SLAM's value (Yu et al. 2018), and the
notebook ``05_epipolar_and_flow`` shows what moving it does. A point moving *along* its
epipolar line stays undetected: the limitation the multi-view test (:mod:`.multiview`) removes.
With a camera at rest F is undefined (no baseline); then :func:`estimate_fundamental` returns
None when the matched pixels barely move and the stage flags nothing.
"""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry.epipolar import epipolar_distance
from ..geometry.se3 import skew
from .table import check_uv

__all__ = [
    "LkConfig",
    "EpipolarConfig",
    "EpipolarResult",
    "track_lk",
    "track_lk_async",
    "run_beside",
    "estimate_fundamental",
    "epipolar_check",
    "pair_inputs",
    "fundamental_from_pose",
]


@dataclass(frozen=True)
class LkConfig:
    """Pyramidal Lucas-Kanade matching of keypoints between frames (ASG-SLAM, Ge et al. 2024, Sec. 2.3)."""

    win_size: int = 11  # search window side (px); OpenCV default 21, ours 11 (1.5x faster than 15, same P/R on synthetic)
    max_level: int = 2  # pyramid levels above the image (reach ~ win * 2^level px); OpenCV default 3, ours 2
    fb_max_px: float = 1.0  # forward-backward error above which a pair is dropped (px); ours, 1.0
    max_iterations: int = 30  # LK iterations per level; OpenCV default 30
    epsilon: float = 0.01  # LK convergence (px); OpenCV default 0.01

    def __post_init__(self) -> None:
        if self.win_size < 3 or self.max_level < 0 or self.fb_max_px <= 0:
            raise ValueError("LkConfig: win_size must be >= 3, max_level >= 0, fb_max_px > 0")
        if self.max_iterations < 1 or not self.epsilon > 0:
            raise ValueError(f"LkConfig: max_iterations must be >= 1 and epsilon > 0, got {self.max_iterations}, {self.epsilon}")


@dataclass(frozen=True)
class EpipolarConfig:
    """Parameters of the epipolar check (Zhang et al. 2023, Chang et al. 2021 and Ge et al. 2024)."""

    threshold_px: float = 1.0  # mu of Zhang et al. 2023 eq. 17 (px); not given in the papers, DS-SLAM uses 1.0
    border_px: float = 20.0  # pairs this close to the image edge are left out of F (px); Ge et al. 2024, value ours
    ransac_threshold_px: float = 1.0  # RANSAC inlier distance for F (px); ours, 1.0
    ransac_confidence: float = 0.999  # RANSAC confidence for F; ours, 0.999
    min_pairs: int = 15  # fewer pairs for F: the check is skipped; ours, 15 (8-point needs 8)
    min_parallax_px: float = 0.5  # median pixel motion below which F is undefined (camera at rest); ours, 0.5
    seed: int = 0  # OpenCV RNG seed for RANSAC; ours, 0

    def __post_init__(self) -> None:
        if self.threshold_px <= 0 or self.ransac_threshold_px <= 0:
            raise ValueError("EpipolarConfig: threshold_px and ransac_threshold_px must be > 0 (pixels)")
        if self.min_pairs < 8:
            raise ValueError(f"EpipolarConfig.min_pairs must be >= 8 (eight-point algorithm), got {self.min_pairs}")
        if self.border_px < 0 or self.min_parallax_px < 0:
            raise ValueError(f"EpipolarConfig: border_px and min_parallax_px must be >= 0, got {self.border_px}, {self.min_parallax_px}")
        if not 0 < self.ransac_confidence < 1:
            raise ValueError(f"EpipolarConfig.ransac_confidence must be in (0, 1), got {self.ransac_confidence}")


@dataclass
class EpipolarResult:
    """Epipolar check of one frame.

    Attributes
    ----------
    F : ``(3, 3)`` fundamental matrix with ``p_cur^T F p_prev = 0``, or None when skipped.
    distance : ``(N,)`` px distance of each keypoint to its epipolar line (eq. 17), ``nan`` unmatched.
    dynamic : ``(N,)`` bool, ``distance > threshold_px``.
    used : ``(N,)`` bool, pairs that entered the RANSAC estimate of F.
    """

    F: np.ndarray | None
    distance: np.ndarray
    dynamic: np.ndarray
    used: np.ndarray


def track_lk(prev_gray: np.ndarray, gray: np.ndarray, uv: np.ndarray, config: LkConfig = LkConfig(),
             guess: np.ndarray | None = None):
    """Match current keypoints into the previous image with pyramidal LK.

    Parameters
    ----------
    prev_gray, gray : ``(H, W)`` uint8 previous and current images.
    uv : ``(N, 2)`` current keypoint pixels.
    guess : ``(N, 2)`` where to start the search in the previous image (``OPTFLOW_USE_INITIAL_FLOW``; the
        multi-frame 2-D test starts at the static prediction), or None (at ``uv``).

    Returns
    -------
    uv_prev : ``(N, 2)`` float64 matched pixels in the previous image (``nan`` where lost).
    ok : ``(N,)`` bool, tracked and forward-backward consistent.
    """
    uv = check_uv(uv)
    if prev_gray.shape != gray.shape or gray.ndim != 2:
        raise ValueError(f"track_lk: images must be equal (H, W) grey, got {prev_gray.shape} and {gray.shape}")
    n = len(uv)
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0, bool)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, config.max_iterations, config.epsilon)
    win = (config.win_size, config.win_size)
    p0 = uv.astype(np.float32).reshape(-1, 1, 2)
    if guess is None:
        p1, st1, _ = cv2.calcOpticalFlowPyrLK(gray, prev_gray, p0, None, winSize=win, maxLevel=config.max_level, criteria=crit)
        p0b, st2, _ = cv2.calcOpticalFlowPyrLK(prev_gray, gray, p1, None, winSize=win, maxLevel=config.max_level, criteria=crit)
    else:
        start = np.asarray(guess, np.float32).reshape(-1, 1, 2).copy()
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
        p1, st1, _ = cv2.calcOpticalFlowPyrLK(gray, prev_gray, p0, start, winSize=win, maxLevel=config.max_level,
                                              criteria=crit, flags=flags)
        p0b, st2, _ = cv2.calcOpticalFlowPyrLK(prev_gray, gray, p1, p0.copy(), winSize=win, maxLevel=config.max_level,
                                               criteria=crit, flags=flags)
    fb = np.linalg.norm(p0b.reshape(-1, 2) - uv, axis=1)
    h, w = gray.shape
    q = p1.reshape(-1, 2).astype(np.float64)
    ok = (st1.reshape(-1) == 1) & (st2.reshape(-1) == 1) & (fb < config.fb_max_px)
    ok &= (q[:, 0] >= 0) & (q[:, 0] <= w - 1) & (q[:, 1] >= 0) & (q[:, 1] <= h - 1)
    q[~ok] = np.nan
    return q, ok


_POOL: tuple[int, ThreadPoolExecutor] | None = None
_POOL_LOCK = threading.Lock()


def run_beside(fn, *args) -> Future:
    """``fn(*args)`` in the screener's worker thread (one per process, made again in a forked child, where the
    parent's thread does not exist); jobs run one after the other, in the order given. For OpenCV calls, which
    release the interpreter lock: the caller's Python and numpy work runs beside them on a second core."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None or _POOL[0] != os.getpid():
            _POOL = (os.getpid(), ThreadPoolExecutor(max_workers=1, thread_name_prefix="dynslam-screen"))
        return _POOL[1].submit(fn, *args)


def _timed_ms(fn, *args):
    t0 = time.perf_counter()
    out = fn(*args)
    return out, (time.perf_counter() - t0) * 1e3


def track_lk_async(prev_gray: np.ndarray, gray: np.ndarray, uv: np.ndarray, config: LkConfig = LkConfig(),
                   guess: np.ndarray | None = None) -> Future:
    """:func:`track_lk` started in the worker thread (:func:`run_beside`); the future gives ``((uv_prev, ok), ms)``
    (``ms``: the pass's own duration): the screener's reference pose is computed while LK matches the previous frame,
    the multi-frame grid tests while it matches an older one."""
    guess = None if guess is None else np.array(guess, np.float64)  # copies: the caller may change its arrays
    return run_beside(_timed_ms, track_lk, prev_gray, gray, check_uv(uv).copy(), config, guess)


def pair_inputs(where: str, uv, uv_prev, matched, exclude, **per_keypoint) -> tuple[np.ndarray, ...]:
    """The per-keypoint inputs of a two-frame check, as arrays of one length ``N``.

    Parameters
    ----------
    where : the calling function, for the error message.
    uv, uv_prev : ``(N, 2)`` current keypoints and their matches in the previous frame.
    matched : ``(N,)`` valid pairs (from :func:`track_lk`).
    exclude : ``(N,)`` pairs on potentially moving objects, or None (none excluded).
    per_keypoint : further ``(N,)`` float inputs by name (e.g. depths).

    Returns
    -------
    ``(uv, uv_prev, matched, exclude, *per_keypoint)``: float64 ``(N, 2)``, float64 ``(N, 2)``,
    bool ``(N,)``, bool ``(N,)``, then float64 ``(N,)`` in the order given.
    """
    uv = check_uv(uv)
    uv_prev = check_uv(uv_prev, "uv_prev")
    n = len(uv)
    arrays = {
        "uv_prev": uv_prev,
        "matched": np.asarray(matched, bool).reshape(-1),
        "exclude": np.zeros(n, bool) if exclude is None else np.asarray(exclude, bool).reshape(-1),
    }
    arrays.update({k: np.asarray(v, np.float64).reshape(-1) for k, v in per_keypoint.items()})
    wrong = [f"{k} {len(v)}" for k, v in arrays.items() if len(v) != n]
    if wrong:
        raise ValueError(f"{where}: per-keypoint inputs must have the same length as uv ({n}), got {', '.join(wrong)}")
    return (uv, *arrays.values())


def estimate_fundamental(p_prev: np.ndarray, p_cur: np.ndarray, config: EpipolarConfig = EpipolarConfig()):
    """RANSAC fundamental matrix from matched pixels ``(M, 2)``; ``(F, inliers)`` or ``(None, None)``
    with too few pairs or too little parallax (a camera at rest)."""
    p1 = check_uv(p_prev, "p_prev")
    p2 = check_uv(p_cur, "p_cur")
    if len(p1) < config.min_pairs:
        return None, None
    if np.median(np.linalg.norm(p2 - p1, axis=1)) < config.min_parallax_px:
        return None, None
    cv2.setRNGSeed(config.seed)
    F, mask = cv2.findFundamentalMat(p1, p2, cv2.FM_RANSAC, config.ransac_threshold_px, config.ransac_confidence)
    if F is None or F.shape != (3, 3):
        return None, None
    return F, mask.reshape(-1).astype(bool)


def fundamental_from_pose(T_c_p: np.ndarray, K: np.ndarray) -> np.ndarray | None:
    """``F = K^-T [t]_x R K^-1`` of a known motion ``T_c_p`` (previous camera -> current camera),
    with ``p_cur^T F p_prev = 0`` (Zhang et al. 2023 eq. 15); None when ``t`` is (nearly) zero: a
    pure rotation has no epipolar geometry."""
    R, t = np.asarray(T_c_p[:3, :3], float), np.asarray(T_c_p[:3, 3], float)
    if np.linalg.norm(t) < 1e-4:
        return None
    Kinv = np.linalg.inv(np.asarray(K, float))
    return Kinv.T @ skew(t) @ R @ Kinv


def epipolar_check(
    uv: np.ndarray,
    uv_prev: np.ndarray,
    matched: np.ndarray,
    exclude: np.ndarray | None,
    image_size: tuple[int, int],
    config: EpipolarConfig = EpipolarConfig(),
    F: np.ndarray | None = None,
) -> EpipolarResult:
    """Steps 2-4: F from the pairs outside ``exclude`` and the border, then eq. 17 for all pairs.

    Parameters
    ----------
    uv : ``(N, 2)`` current keypoints; ``uv_prev`` ``(N, 2)`` their matches in the previous image.
    matched : ``(N,)`` bool valid pairs (from :func:`track_lk`).
    exclude : ``(N,)`` bool pairs on potentially moving objects (left out of F), or None.
    image_size : ``(H, W)``.
    F : a fundamental matrix known from the camera motion (:func:`fundamental_from_pose` of the
        reference pose); None estimates it from the pairs by RANSAC (the papers' way).
    """
    uv, uv_prev, matched, exclude = pair_inputs("epipolar_check", uv, uv_prev, matched, exclude)
    n = len(uv)
    h, w = image_size
    b = config.border_px
    away = (uv[:, 0] >= b) & (uv[:, 0] <= w - 1 - b) & (uv[:, 1] >= b) & (uv[:, 1] <= h - 1 - b)
    used = matched & ~exclude & away
    distance = np.full(n, np.nan)
    if F is None:
        F, _ = estimate_fundamental(uv_prev[used], uv[used], config)
    else:
        used = np.zeros(n, bool)  # no pair was needed to estimate F
    if F is None:
        return EpipolarResult(None, distance, np.zeros(n, bool), used)
    distance[matched] = epipolar_distance(F, uv_prev[matched], uv[matched])
    dynamic = matched & (distance > config.threshold_px)
    return EpipolarResult(F, distance, dynamic, used)
