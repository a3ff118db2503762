"""Multi-view RGB-D check (Chang et al., IEEE TIM 2021, Chang et al. 2021, Sec. III-B, eq. 2, Sec. IV-A).

With depth, a keypoint seen in the previous frame at ``x`` with depth ``s1`` predicts where it
must appear in the current frame if it is static::

    s2 x_hat = s1 R x + t                                                  (2)

(``x``, ``x_hat`` normalised coordinates, ``R, t`` the camera motion from the previous to the
current frame). The keypoint is dynamic when its observed pixel ``x'`` is far from the
prediction or its measured depth disagrees with ``s2``: "when the Euclidean distance of a pixel
exceeds 4 or the depth difference exceeds 0.1 m, the feature point will be removed" (Sec. III-B).
Our one change: the depth threshold grows with the square of the depth, ``max(0.1, 0.01 z^2)`` m,
because a Kinect's depth error does (Khoshelham & Elberink, Sensors 2012): beyond ~3 m a fixed
0.1 m is below two disparity steps and flags static background (``depth_quadratic=0`` restores 0.1 m).

``R, t`` come from "slightly tracking" (Sec. IV-A): a rough pose from the feature points outside
the segmentation mask, by PnP in the RGB-D case. We solve PnP with RANSAC (OpenCV
``solvePnPRansac``) from the previous frame's 3-D points (back-projected matched pixels) to the
current keypoints; the keypoint matches are those of :func:`dynslam_lab.dynamic.epipolar.track_lk`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.pnp import pnp_ransac
from ..geometry.se3 import transform_points
from .epipolar import pair_inputs
from .table import check_uv

__all__ = ["MultiViewConfig", "MultiViewResult", "rough_pose", "multiview_check"]


@dataclass(frozen=True)
class MultiViewConfig:
    """Parameters of the multi-view RGB-D check (Chang et al. 2021, Sec. III-B)."""

    reprojection_px: float = 4.0  # pixel distance |x' - x_hat| above which a keypoint is dynamic (px); Chang et al. 2021: 4
    depth_m: float = 0.1  # depth difference |s2 - depth| above which a keypoint is dynamic (m); Chang et al. 2021: 0.1
    # The depth threshold grows as max(depth_m, depth_quadratic * z^2) with the measured depth z (m): a Kinect's
    # depth error grows with z^2 (Khoshelham & Elberink 2012); 0.01 /m keeps 0.1 m up to 3.2 m and allows 0.25 m
    # at 5 m (about three disparity steps). Ours; 0 = the paper's fixed 0.1 m.
    depth_quadratic: float = 0.01
    pnp_reprojection_px: float = 2.0  # RANSAC inlier threshold of the rough PnP pose (px); ours, 2.0
    pnp_iterations: int = 100  # RANSAC iterations of the rough pose; ours, 100
    pnp_confidence: float = 0.99  # RANSAC confidence of the rough pose; ours, 0.99
    min_pairs: int = 12  # fewer 3-D/2-D pairs: no rough pose, the check is skipped; ours, 12
    min_inliers: int = 10  # fewer PnP inliers: the rough pose is rejected; ours, 10
    seed: int = 0  # OpenCV RNG seed for RANSAC; ours, 0

    def __post_init__(self) -> None:
        if self.depth_quadratic < 0:
            raise ValueError(f"MultiViewConfig.depth_quadratic must be >= 0 (1/m), got {self.depth_quadratic}")
        if self.reprojection_px <= 0 or self.depth_m <= 0 or self.pnp_reprojection_px <= 0:
            raise ValueError("MultiViewConfig: reprojection_px, depth_m and pnp_reprojection_px must be > 0")
        if self.min_pairs < 4 or self.min_inliers < 4:
            raise ValueError("MultiViewConfig: PnP needs min_pairs >= 4 and min_inliers >= 4")
        if self.pnp_iterations < 1 or not 0 < self.pnp_confidence < 1:
            raise ValueError(f"MultiViewConfig: pnp_iterations must be >= 1 and pnp_confidence in (0, 1), got "
                             f"{self.pnp_iterations}, {self.pnp_confidence}")


@dataclass
class MultiViewResult:
    """Multi-view check of one frame.

    Attributes
    ----------
    T_c_p : ``(4, 4)`` rough pose, previous camera -> current camera, or None when skipped.
    reprojection_px : ``(N,)`` ``|x' - x_hat|`` in pixels, ``nan`` where not measured.
    depth_error_m : ``(N,)`` ``|s2 - depth|`` in metres, ``nan`` where not measured.
    dynamic : ``(N,)`` bool, either error above its threshold.
    inliers : ``(N,)`` bool, keypoints that were PnP inliers of the rough pose.
    """

    T_c_p: np.ndarray | None
    reprojection_px: np.ndarray
    depth_error_m: np.ndarray
    dynamic: np.ndarray
    inliers: np.ndarray


def rough_pose(points_prev: np.ndarray, uv: np.ndarray, K: np.ndarray, config: MultiViewConfig = MultiViewConfig()):
    """The "slightly tracking" pose (Chang et al. 2021, Sec. IV-A) by PnP-RANSAC.

    Parameters
    ----------
    points_prev : ``(M, 3)`` metres, points in the previous camera frame.
    uv : ``(M, 2)`` their pixels in the current frame.
    K : ``(3, 3)`` intrinsics.

    Returns
    -------
    ``(T_c_p, inliers)``: ``(4, 4)`` pose and ``(M,)`` bool, or ``(None, None)``.
    """
    P = np.asarray(points_prev, np.float64)
    uv = check_uv(uv)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) != len(uv):
        raise ValueError(f"rough_pose: points_prev must be (M, 3) matching uv (M, 2), got {P.shape} and {uv.shape}")
    if len(P) < config.min_pairs:
        return None, None
    T, inl = pnp_ransac(P, uv, K, config.pnp_reprojection_px, config.pnp_iterations, config.pnp_confidence,
                        seed=config.seed, min_inliers=config.min_inliers, refine=True)
    if T is None:
        return None, None
    return T, inl


def multiview_check(
    uv: np.ndarray,
    depth_cur: np.ndarray,
    uv_prev: np.ndarray,
    depth_prev: np.ndarray,
    matched: np.ndarray,
    exclude: np.ndarray | None,
    camera,
    config: MultiViewConfig = MultiViewConfig(),
    T_c_p: np.ndarray | None = None,
) -> MultiViewResult:
    """Eq. 2 for every matched keypoint, with the rough pose from the pairs outside ``exclude``.

    Parameters
    ----------
    uv : ``(N, 2)`` current keypoints; ``depth_cur`` ``(N,)`` metres at them (``nan`` = none).
    uv_prev : ``(N, 2)`` matched pixels in the previous frame; ``depth_prev`` ``(N,)`` metres there.
    matched : ``(N,)`` bool valid pairs.
    exclude : ``(N,)`` bool pairs on potentially moving objects, left out of the rough pose.
    camera : :class:`~dynslam_lab.camera.PinholeCamera`.
    T_c_p : the camera motion previous -> current when it is known (from the reference pose of
        :mod:`.reference_pose`); None estimates the rough pose by PnP-RANSAC (the paper's way).
    """
    uv, uv_prev, matched, exclude, depth_cur, depth_prev = pair_inputs(
        "multiview_check", uv, uv_prev, matched, exclude, depth_cur=depth_cur, depth_prev=depth_prev
    )
    n = len(uv)
    reproj = np.full(n, np.nan)
    derr = np.full(n, np.nan)
    inliers = np.zeros(n, bool)
    valid = matched & np.isfinite(depth_prev) & (depth_prev > 0)
    use = valid & ~exclude
    P = np.full((n, 3), np.nan)
    P[valid] = camera.backproject(uv_prev[valid], depth_prev[valid])
    if T_c_p is None:
        T_c_p, inl = rough_pose(P[use], uv[use], camera.K, config)
        if T_c_p is None:
            return MultiViewResult(None, reproj, derr, np.zeros(n, bool), inliers)
        inliers[np.flatnonzero(use)[inl]] = True
    X = transform_points(T_c_p, P[valid])
    uv_hat, s2 = camera.project(X)
    reproj[valid] = np.linalg.norm(uv[valid] - uv_hat, axis=1)
    derr[valid] = np.abs(s2 - depth_cur[valid])  # nan where the current frame has no depth
    depth_thr = np.maximum(config.depth_m, config.depth_quadratic * np.nan_to_num(depth_cur) ** 2)
    with np.errstate(invalid="ignore"):
        dynamic = valid & ((reproj > config.reprojection_px) | (derr > depth_thr))
    return MultiViewResult(T_c_p, reproj, derr, dynamic, inliers)
