"""The reference pose every geometric check judges a frame against: the static world's, not the movers'.

The two-frame checks of Chang et al. 2021 (Sec. IV-A, "slightly tracking") and Ge et al. 2024
(Sec. 2.3) estimate the camera motion from the keypoint pairs of the frame itself, by RANSAC
(PnP or a fundamental matrix). RANSAC returns the largest consistent set; when movers cover
much of the image (a person close to the camera, two boxes carried across it) that set can be
the movers, and every static keypoint is then judged moving. DynaSLAM (Bescos et al. 2018,
Sec. III-C) avoids it with a "low-cost tracking" of the frame against the map before the
multi-view test: the map holds points of earlier frames that were screened, so only static
keypoints find partners in it.

What we do (the matching follows ORB-SLAM2's motion model, Mur-Artal & Tardos 2017; the gating
and the fallbacks are ours):

1. **Prediction.** The SLAM system's constant-velocity prediction ``T_c_w_pred`` of the frame
   (``ScreeningContext``), when there is one.
2. **Map matches.** The local map points are projected with the prediction and each is matched
   to the keypoints within ``search_radius_px`` of its projection by ORB descriptor (Hamming
   distance <= ``max_hamming``, best / second best <= ``ratio``;
   :func:`dynslam_lab.features.matching.search_by_projection`). Map points the screener has seen
   moving (temporal consistency, :mod:`.temporal`) are left out.
3. **Refinement.** Matches within ``gate_px`` of the prediction are refined by Levenberg-Marquardt
   on the reprojection error (``cv2.solvePnPRefineLM``), then once more on those within
   ``inlier_px`` of the refined pose. Because the refinement starts at the prediction and only
   admits matches already close to it, a mover that covers most of the image cannot pull the
   pose: its keypoints have no partner among the map points, or one far from the prediction.
4. **Fallbacks.** Fewer than ``min_inliers`` matches: the prediction itself when there is one
   (``source="prediction"``); no prediction either: the two-frame rough pose of the multi-view
   check (``source="two_frame"``, RANSAC, the papers' way), or none.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..features.matching import search_by_projection
from ..geometry.se3 import make_pose, se3_inv, transform_points

__all__ = ["ReferencePoseConfig", "ReferencePose", "match_map_points", "refine_pose", "map_reference_pose"]


@dataclass(frozen=True)
class ReferencePoseConfig:
    """Parameters of the reference pose (DynaSLAM's low-cost tracking, Bescos et al. 2018; values ours)."""

    search_radius_px: float = 12.0  # map points matched within this distance of their predicted pixel (px); ORB-SLAM2 motion model 15, ours 12
    max_hamming: int = 80  # largest Hamming distance of a map match (bits); ORB-SLAM2 TH_HIGH 100, ours 80 (stricter)
    ratio: float = 0.8  # best / second-best Hamming distance among candidates of one map point; ORB-SLAM2 0.8
    gate_px: float = 6.0  # matches farther than this from the prediction stay out of the refinement (px); ours
    inlier_px: float = 2.5  # reprojection error of the final inliers (px); ours (ORB-SLAM2's chi^2 5.991 at 1 px sigma ~ 2.45)
    min_inliers: int = 25  # fewer inliers: keep the prediction unrefined (px); ours
    max_correction_m: float = 0.05  # a refinement moving the camera more than this from the prediction is distrusted (m); ours
    max_correction_deg: float = 3.0  # ... or turning it more than this (degrees); ours

    def __post_init__(self) -> None:
        for name in ("search_radius_px", "gate_px", "inlier_px", "max_correction_m", "max_correction_deg"):
            if not getattr(self, name) > 0:
                raise ValueError(f"ReferencePoseConfig.{name} must be > 0, got {getattr(self, name)}")
        if not 0 <= self.max_hamming <= 256:
            raise ValueError(f"ReferencePoseConfig.max_hamming must be in [0, 256] bits, got {self.max_hamming}")
        if not 0 < self.ratio <= 1:
            raise ValueError(f"ReferencePoseConfig.ratio must be in (0, 1], got {self.ratio}")
        if self.min_inliers < 6:
            raise ValueError(f"ReferencePoseConfig.min_inliers must be >= 6 (a pose has 6 unknowns), got {self.min_inliers}")


@dataclass
class ReferencePose:
    """The pose a frame is judged against.

    Attributes
    ----------
    T_c_w : ``(4, 4)`` world -> camera pose, or None (no reference: the checks fall back to the
        previous frame's rough pose or are skipped).
    source : ``"map"`` (refined on map points), ``"prediction"`` (the system's prediction as is),
        ``"two_frame"`` (RANSAC rough pose from the previous frame) or ``""``.
    map_index : ``(N,)`` int64 row of the context's map point matched to each keypoint, -1 for none.
    residual_px : ``(N,)`` reprojection error of each matched keypoint under ``T_c_w`` (nan unmatched).
    inliers : ``(N,)`` bool, matched keypoints within ``inlier_px`` of their map point.
    """

    T_c_w: np.ndarray | None
    source: str
    map_index: np.ndarray
    residual_px: np.ndarray
    inliers: np.ndarray

    @classmethod
    def none(cls, n: int) -> "ReferencePose":
        return cls(None, "", np.full(n, -1, np.int64), np.full(n, np.nan), np.zeros(n, bool))


def _reprojection_px(T_c_w: np.ndarray, X_w: np.ndarray, uv: np.ndarray, K: np.ndarray) -> np.ndarray:
    X = transform_points(T_c_w, X_w)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * X[:, 0] / X[:, 2] + K[0, 2]
        v = K[1, 1] * X[:, 1] / X[:, 2] + K[1, 2]
    err = np.hypot(u - uv[:, 0], v - uv[:, 1])
    return np.where(X[:, 2] > 0, err, np.inf)


def refine_pose(T_c_w: np.ndarray, X_w: np.ndarray, uv: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Levenberg-Marquardt refinement of ``T_c_w`` on the reprojection error of ``X_w (M, 3)`` at
    ``uv (M, 2)`` (``cv2.solvePnPRefineLM``, started at ``T_c_w``)."""
    rvec, _ = cv2.Rodrigues(np.asarray(T_c_w[:3, :3], np.float64))
    tvec = np.asarray(T_c_w[:3, 3], np.float64).reshape(3, 1)
    rvec, tvec = cv2.solvePnPRefineLM(np.asarray(X_w, np.float64), np.asarray(uv, np.float64), np.asarray(K, np.float64),
                                      None, rvec, tvec)
    R, _ = cv2.Rodrigues(rvec)
    return make_pose(R, tvec.reshape(3))


def match_map_points(context, uv: np.ndarray, camera, config: ReferencePoseConfig, exclude_ids=None):
    """Step 2: map points matched to keypoints near their predicted pixels.

    Returns ``(rows, kp)``: rows of the context's map arrays and the keypoint index of each match.
    """
    T = context.T_c_w_pred
    n_map = context.n_map_points
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64))
    if T is None or n_map == 0 or context.descriptors is None or len(uv) == 0:
        return empty
    rows = np.arange(n_map)
    if exclude_ids is not None and len(exclude_ids):
        rows = rows[~np.isin(context.map_ids, exclude_ids)]
    uv_hat, z = camera.project(transform_points(T, context.map_xyz[rows]))
    vis = (z > 0) & camera.in_image(uv_hat)
    rows, uv_hat = rows[vis], uv_hat[vis]
    if len(rows) == 0:
        return empty
    m = search_by_projection(uv_hat, context.map_descriptors[rows], np.full(len(rows), config.search_radius_px), None,
                             uv, context.octave, context.descriptors, max_distance=config.max_hamming, ratio=config.ratio)
    return rows[m.idx_a], m.idx_b


def _correction_ok(T_a: np.ndarray, T_b: np.ndarray, config: ReferencePoseConfig) -> bool:
    D = T_a @ se3_inv(T_b)
    ang = np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1.0, 1.0)))
    return bool(np.linalg.norm(D[:3, 3]) <= config.max_correction_m and ang <= config.max_correction_deg)


def map_reference_pose(context, uv: np.ndarray, camera, config: ReferencePoseConfig = ReferencePoseConfig(),
                       exclude_ids=None) -> ReferencePose:
    """Steps 1-4 except the two-frame fallback (which needs the LK pairs; see :mod:`.stages`).

    Parameters
    ----------
    context : :class:`~dynslam_lab.dynamic.context.ScreeningContext` (prediction, local map, descriptors).
    uv : ``(N, 2)`` keypoint pixels (undistorted).
    camera : intrinsics.
    exclude_ids : map point ids left out (seen moving).

    Returns
    -------
    :class:`ReferencePose`; ``T_c_w`` None when the context has no prediction.
    """
    n = len(uv)
    out = ReferencePose.none(n)
    if context is None or context.T_c_w_pred is None:
        return out
    T_pred = context.T_c_w_pred
    out.T_c_w, out.source = T_pred, "prediction"
    rows, kp = match_map_points(context, uv, camera, config, exclude_ids)
    if len(rows) < config.min_inliers:
        return out
    K = camera.K
    X, q = context.map_xyz[rows], uv[kp]
    err = _reprojection_px(T_pred, X, q, K)
    use = err < config.gate_px
    if use.sum() < config.min_inliers:
        return out
    T = refine_pose(T_pred, X[use], q[use], K)
    err = _reprojection_px(T, X, q, K)
    use = err < config.inlier_px
    if use.sum() < config.min_inliers:
        return out
    T = refine_pose(T, X[use], q[use], K)
    if not _correction_ok(T, T_pred, config):
        return out
    err = _reprojection_px(T, X, q, K)
    out.T_c_w, out.source = T, "map"
    out.map_index[kp] = rows
    out.residual_px[kp] = err
    out.inliers[kp] = err < config.inlier_px
    return out
