"""Camera pose from 3D-2D correspondences: PnP inside RANSAC.

Given world points ``X_w (K, 3)`` and their pixels ``uv (K, 2)`` in a pinhole camera ``K``,
find ``T_c_w`` minimising the reprojection error ``|| uv - pi(K, T_c_w X_w) ||``. Each RANSAC
hypothesis solves a minimal set with EPnP (Lepetit, Moreno-Noguer and Fua, IJCV 2009); the
hypothesis with most inliers (reprojection error below ``reproj_px``) wins, and can be refined
by Levenberg-Marquardt on its inliers. OpenCV's ``solvePnPRansac`` does the sampling; the
seed makes it repeatable.

Used by tracking (reference keyframe and relocalisation, Mur-Artal and Tardos 2017) and by the
multi-view check's rough pose (Chang et al. 2021, Sec. IV-A).
"""

from __future__ import annotations

import cv2
import numpy as np

from .se3 import make_pose

__all__ = ["pnp_ransac"]


def pnp_ransac(
    X: np.ndarray,
    uv: np.ndarray,
    K: np.ndarray,
    reproj_px: float,
    iterations: int,
    confidence: float = 0.99,
    seed: int = 0,
    min_inliers: int = 0,
    refine: bool = False,
) -> tuple[np.ndarray | None, np.ndarray]:
    """Pose ``T_c_x (4, 4)`` of the camera seeing points ``X (K, 3)`` (frame x) at pixels ``uv (K, 2)``.

    Parameters
    ----------
    X : ``(K, 3)`` points (metres) in any frame ``x``.
    uv : ``(K, 2)`` their pixels.
    K : ``(3, 3)`` camera intrinsics (no distortion).
    reproj_px : RANSAC inlier threshold on the reprojection error (pixels).
    iterations : RANSAC iterations.
    confidence : RANSAC confidence.
    seed : OpenCV's random seed (repeatable runs).
    min_inliers : fewer inliers than this -> no pose.
    refine : refine the pose by Levenberg-Marquardt on the inliers.

    Returns
    -------
    ``(T_c_x or None, inliers (K,) bool)``. Fewer than 6 correspondences give no pose.
    """
    X = np.asarray(X, np.float64).reshape(-1, 3)
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    if len(X) != len(uv):
        raise ValueError(f"pnp_ransac: {len(X)} points and {len(uv)} pixels")
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"pnp_ransac: K must be (3, 3), got {K.shape}")
    inl = np.zeros(len(X), bool)
    if len(X) < 6:
        return None, inl
    cv2.setRNGSeed(int(seed))
    ok, rvec, tvec, idx = cv2.solvePnPRansac(
        X, uv, K, None, iterationsCount=int(iterations), reprojectionError=float(reproj_px),
        confidence=float(confidence), flags=cv2.SOLVEPNP_EPNP,
    )
    if not ok or idx is None or len(idx) < max(int(min_inliers), 1):
        return None, inl
    inl[idx.reshape(-1)] = True
    if refine:
        rvec, tvec = cv2.solvePnPRefineLM(X[inl], uv[inl], K, None, rvec, tvec)
    R, _ = cv2.Rodrigues(rvec)
    return make_pose(R, tvec.reshape(3)), inl
