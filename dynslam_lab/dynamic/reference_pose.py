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
3. **Refinement.** Matches within ``gate_px`` of the prediction refine it by iteratively
   reweighted Gauss-Newton on the reprojection error with a Cauchy weight whose scale shrinks
   (``scales_px``, 4 px down to 0.7 px). Because the refinement starts at the prediction, only
   admits matches already close to it and ends with a tight scale, a mover cannot pull the pose:
   its keypoints have no partner among the map points, or one far from the prediction, or (a
   mover mapped while it stood still that starts to move) one whose displacement puts it outside
   the final scale while the static majority agrees within it. Near-field movers matter most
   here: a distant background hardly constrains the camera's translation (it trades against a
   rotation), so a least-squares fit over every match would follow a close box by centimetres.
   Keypoints matched well to a map point but farther than ``moving_px`` from it under the refined
   pose saw that point move (``moved``; :mod:`.temporal` remembers it).
3b. **Surfaces that move against the rest** (ours). The refinement cannot tell a camera that
   moved from a close box that moved while the rest of the map is far: the far background
   barely resists. So every surface of the frame holding enough matches (a connected piece of
   the depth image without depth steps or creases, :func:`~dynslam_lab.dynamic.regions.surface_segments`)
   is left out in turn and the pose moved to the others' (one Gauss-Newton step from the pose of all
   matches on their normal equations less the surface's: its influence on the pose, to first order;
   ``leave_out_influence``); a surface whose matches then miss
   their map points by much more than the others do has moved (a box mapped while it stood
   still and now pushed away). With two such groups the evidence is symmetric (the box moved,
   or everything else did): a surface with less than half the matches is the mover (the static
   majority); a larger one only when leaving it out brings the pose closer to the
   constant-velocity prediction. Surfaces are joined across convex edges
   (an object stays whole) and cut at concave ones (from the floor it stands on). Its matches
   leave the final refinement and mark its keypoints.
3c. **The room's depth** (ours; :func:`depth_moved_surfaces`, :mod:`.room_depth`). Before step 3b, the
   room's large surfaces are aligned by their depth to an earlier frame's (point-to-plane): where that shows
   the features were pulled (the room's depth fits much better, the room's own map points agree) and names
   the surfaces that pulled them, those are movers and the aligned pose starts step 3b. Two movers that move
   together hold each other up when left out one at a time; the depth does not trade a shift for a turn. The
   room leaves out objects standing in it that carry more than their share of the keypoints, and the room's own
   map matches join the alignment (they fix the slide along a wall and the floor that two planes leave free).
4. **Fallbacks.** Fewer than ``min_inliers`` matches: the prediction itself when there is one
   (``source="prediction"``); no prediction either: the two-frame rough pose of the multi-view
   check (``source="two_frame"``, RANSAC, the papers' way), or none.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..features.matching import search_by_projection
from ..geometry.se3 import rotation_angle_deg, se3_inv, transform_points
from ..geometry.depth_alignment import ReprojectionTerm
from ..geometry.projection import projection_jacobian
from .room_depth import RoomDepth, align_room

__all__ = ["ReferencePoseConfig", "ReferencePose", "LeaveOneOut", "match_map_points", "refine_pose", "inconsistent_surfaces", "moving_surfaces",
           "depth_moved_surfaces", "map_reference_pose"]


@dataclass(frozen=True)
class ReferencePoseConfig:
    """Parameters of the reference pose (DynaSLAM's low-cost tracking, Bescos et al. 2018; values ours)."""

    search_radius_px: float = 8.0  # map points matched within this distance of their predicted pixel (px); ORB-SLAM2 motion model 15, ours 8 (beyond gate_px a match only reports a moved point)
    max_hamming: int = 80  # largest Hamming distance of a map match (bits); ORB-SLAM2 TH_HIGH 100, ours 80 (stricter)
    ratio: float = 0.8  # best / second-best Hamming distance among candidates of one map point; ORB-SLAM2 0.8
    gate_px: float = 6.0  # matches farther than this from the prediction stay out of the refinement (px); ours
    inlier_px: float = 2.5  # reprojection error of the final inliers (px); ours (ORB-SLAM2's chi^2 5.991 at 1 px sigma ~ 2.45)
    min_inliers: int = 25  # fewer inliers: keep the prediction unrefined (px); ours
    scales_px: tuple[float, ...] = (4.0, 2.0, 1.0, 0.7)  # Cauchy scales of the robust refinement, widest first (px); ours
    moving_px: float = 4.0  # a keypoint this far from its map point under the reference pose saw the point move (px); ours
    moving_hamming: int = 50  # ... when its descriptor matches the point this well (bits); ORB-SLAM2 TH_LOW 50
    segment_min_matches: int = 15  # surfaces with fewer map matches are not tested on their own (step 3b); ours
    segment_min_px: float = 1.5  # a surface moves when its median error without it exceeds this (sigma units) ...; ours
    segment_ratio: float = 2.5  # ... and this many times the median of the rest; ours
    segment_max_movers: int = 3  # surfaces removed at most per frame (step 3b); ours
    segment_area_ratio: float = 1.5  # > 0: a surface of step 3c's room left out is never the moving one when its area (depth cells) is this many times that of every surface holding the rest's matches together (it is the room the rest moves in; 0 = off: docs/robustness.md "A plain room is not the moving minority"); ours
    segment_joint_ratio: float = 0.0  # > 0: ... and only when, under the pose of all matches, its median error is this many times the rest's, or the rest fits its own pose dominant_gain_weak times better, or the pose without it lies closer to the prediction (0 = off, the default: it hid movers the tracker had begun to follow, docs/robustness.md "Two groups that fit one pose"); ours
    segment_joint_spread: float = 0.5  # ... the joint check clears a surface only where the rest alone fixes its pixels to this or worse (sigma units); ours
    room_test: bool = True  # test a surface holding most matches against the room (step 3b; on since the ORB budget, without held surfaces: docs/robustness.md "The room test, on by default"); ours
    dominant_share: float = 0.4  # a surface holding this share of the matches ... (step 3b); ours
    dominant_gain: float = 1.5  # ... when the room's median error under the pose with the surface is this many times that under its own pose (the surface pulled the pose) ...; ours
    dominant_gain_weak: float = 1.15  # ... or this many times while the surface misses by twice the bound; ours
    dominant_area_ratio: float = 1.5  # ... is tested against the matches on surfaces this many times larger (the room), and counts as the minority when it misses them; ours
    dominant_room_min_matches: int = 50  # ... when the room holds at least this many matches (refined alone on 15-39, a room of one or two surfaces fits itself better than any other pose: door_static); ours
    room_depth_gain: float = 1.5  # step 3c: the room's depth, aligned to an earlier frame's from the feature pose, lowers its median point-to-plane distance this many times (the features were pulled; 0 = off); ours
    room_depth_min_share: float = 0.1  # ... the room: surfaces holding at least this share of the reduced grid's depth cells; ours
    room_depth_feature_weight: float = 1.0  # ... the room's own map matches join the depth's alignment with this weight on their squared whitened errors (they fix the slide along a wall and the floor the planes leave free; 0 = depth alone); ours
    room_depth_max_front: float = 0.75  # ... less objects standing in it: in front of their neighbours along more than this share of their depth-step outline and holding a larger share of the keypoints than of the depth cells (the features' likeliest puller is no witness against them; 1 = off); ours
    room_depth_min_m: float = 0.001  # ... and the distance before the alignment is at least this (m: a pose the depth noise cannot tell from the aligned one is not pulled); ours
    room_depth_noise: float = 1.0  # the depth's noise in units of the Kinect model the step was set for (room_depth.depth_sigma): the alignment's sigma scales by it, and the gain is judged on the distances less the extra noise (room_depth_pulled); set from the noise measured (ScreeningConfig.for_depth_noise, docs/robustness.md "Another depth sensor"); ours
    room_depth_min_points: int = 200  # ... aligned on at least this many associated depth cells, else no test; ours
    room_depth_min_matches: int = 5  # ... a surface off the room whose matches (at least this many) miss the aligned pose moved; ours
    room_depth_miss: float = 3.0  # ... by more than this (sigma units; and segment_ratio times the room's own median) ...; ours
    room_depth_pull: float = 1.5  # ... and this many times more than they miss the feature pose (the surface pulled it; a surface whose map points miss both alike is no evidence); ours
    leave_out_influence: bool = True  # step 3b: a surface left out moves the pose by one Gauss-Newton step from the pose of all matches, on their normal equations less the surface's (an influence step; the normal equations built once a round); False = four reweighted Gauss-Newton steps on the rest (before 2026-12-07); ours (docs/speed.md "Leaving a surface out in one step")
    max_correction_m: float = 0.05  # a refinement moving the camera more than this from the prediction is distrusted (m); ours
    max_correction_deg: float = 3.0  # ... or turning it more than this (degrees); ours

    def __post_init__(self) -> None:
        for name in ("search_radius_px", "gate_px", "inlier_px", "max_correction_m", "max_correction_deg"):
            if not getattr(self, name) > 0:
                raise ValueError(f"ReferencePoseConfig.{name} must be > 0, got {getattr(self, name)}")
        if not 0 <= self.max_hamming <= 256:
            raise ValueError(f"ReferencePoseConfig.max_hamming must be in [0, 256] bits, got {self.max_hamming}")
        if self.dominant_room_min_matches < 6:
            raise ValueError(f"ReferencePoseConfig.dominant_room_min_matches must be >= 6 (a pose has 6 degrees of freedom), got {self.dominant_room_min_matches}")
        if not 0 < self.ratio <= 1:
            raise ValueError(f"ReferencePoseConfig.ratio must be in (0, 1], got {self.ratio}")
        if not self.scales_px or any(v <= 0 for v in self.scales_px):
            raise ValueError(f"ReferencePoseConfig.scales_px must be positive pixel scales, got {self.scales_px}")
        if self.moving_px <= self.inlier_px:
            raise ValueError(f"ReferencePoseConfig.moving_px ({self.moving_px}) must exceed inlier_px ({self.inlier_px})")
        if not self.segment_joint_spread >= 0:
            raise ValueError(f"ReferencePoseConfig.segment_joint_spread must be >= 0 sigma, got {self.segment_joint_spread}")
        if not (self.segment_area_ratio == 0 or self.segment_area_ratio >= 1):
            raise ValueError(f"ReferencePoseConfig.segment_area_ratio must be 0 (off) or >= 1 (times the rest's area), got {self.segment_area_ratio}")
        if not self.segment_joint_ratio >= 0:
            raise ValueError(f"ReferencePoseConfig.segment_joint_ratio must be >= 0 (0 = no check), got {self.segment_joint_ratio}")
        if self.segment_min_matches < 6 or self.segment_min_px <= 0 or self.segment_ratio <= 1 or self.segment_max_movers < 0:
            raise ValueError("ReferencePoseConfig: segment_min_matches >= 6, segment_min_px > 0, segment_ratio > 1 and "
                             "segment_max_movers >= 0 required")
        if (not 0 < self.dominant_share <= 1 or not self.dominant_area_ratio >= 1
                or not self.dominant_gain >= self.dominant_gain_weak >= 1):
            raise ValueError("ReferencePoseConfig: dominant_share in (0, 1], dominant_area_ratio >= 1 and dominant_gain >= "
                             f"dominant_gain_weak >= 1 required, got {self.dominant_share}, {self.dominant_area_ratio}, "
                             f"{self.dominant_gain}, {self.dominant_gain_weak}")
        if not self.room_depth_noise > 0:
            raise ValueError(f"ReferencePoseConfig.room_depth_noise must be > 0 (the Kinect model's units), got {self.room_depth_noise}")
        if not self.room_depth_gain >= 0 or not self.room_depth_min_m >= 0 or not 0 < self.room_depth_min_share <= 1 \
                or not self.room_depth_miss > 0 or not self.room_depth_pull >= 1 or self.room_depth_min_points < 6 \
                or self.room_depth_min_matches < 1:
            raise ValueError("ReferencePoseConfig: room_depth_gain >= 0 (0 = off), room_depth_min_m >= 0, room_depth_min_share in "
                             "(0, 1], room_depth_miss > 0, room_depth_pull >= 1, room_depth_min_points >= 6 and "
                             f"room_depth_min_matches >= 1 required, got {self.room_depth_gain}, {self.room_depth_min_m}, "
                             f"{self.room_depth_min_share}, {self.room_depth_miss}, {self.room_depth_pull}, "
                             f"{self.room_depth_min_points}, {self.room_depth_min_matches}")
        if not self.room_depth_feature_weight >= 0:
            raise ValueError(f"ReferencePoseConfig.room_depth_feature_weight must be >= 0 (0 = depth alone), got {self.room_depth_feature_weight}")
        if not 0 <= self.room_depth_max_front <= 1:
            raise ValueError(f"ReferencePoseConfig.room_depth_max_front must be in [0, 1] (1 = off), got {self.room_depth_max_front}")
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
    moved : ``(N,)`` bool, keypoints matched well (``moving_hamming``) but farther than ``moving_px``
        from their map point: the point may have moved since it was mapped (or the match is wrong).
    surface_moved : ``(N,)`` bool, keypoints on a surface that moves against the rest (step 3b).
    known_moving : ``(N,)`` bool, keypoints matched to a map point seen moving before.
    """

    T_c_w: np.ndarray | None
    source: str
    map_index: np.ndarray
    residual_px: np.ndarray
    inliers: np.ndarray
    moved: np.ndarray
    surface_moved: np.ndarray
    known_moving: np.ndarray
    room: bool = False  # step 3b took the room's pose: a surface holding most matches moved against it
    room_depth: bool = False  # step 3c took the pose of the room's depth: the features had been pulled

    @classmethod
    def none(cls, n: int) -> "ReferencePose":
        z = np.zeros(n, bool)
        return cls(None, "", np.full(n, -1, np.int64), np.full(n, np.nan), z, z.copy(), z.copy(), z.copy())


def _reprojection_px(T_c_w: np.ndarray, X_w: np.ndarray, uv: np.ndarray, K: np.ndarray) -> np.ndarray:
    X = transform_points(T_c_w, X_w)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * X[:, 0] / X[:, 2] + K[0, 2]
        v = K[1, 1] * X[:, 1] / X[:, 2] + K[1, 2]
    err = np.hypot(u - uv[:, 0], v - uv[:, 1])
    return np.where(X[:, 2] > 0, err, np.inf)


def refine_pose(T_c_w: np.ndarray, X_w: np.ndarray, uv: np.ndarray, K: np.ndarray, scales_px=(4.0, 2.0, 1.0),
                iterations: int = 3, sigma: np.ndarray | None = None) -> np.ndarray:
    """Robust Gauss-Newton refinement of ``T_c_w`` on the reprojection error of ``X_w (M, 3)`` at ``uv (M, 2)``.

    Iteratively reweighted least squares with the Cauchy weight ``1 / (1 + (|r| / s)^2)`` on the
    residual in units of each keypoint's ``sigma (M,)`` (px; ORB-SLAM2 uses the pyramid scale of the
    keypoint's level), the scale ``s`` shrinking through ``scales_px`` (``iterations`` Gauss-Newton
    steps each), the pose updated on the left (``T <- exp(delta) T``).
    """
    T = np.asarray(T_c_w, np.float64).copy()
    Xt = np.ascontiguousarray(np.asarray(X_w, np.float64).reshape(-1, 3).T)  # (3, M): rows x, y, z contiguous
    qt = np.asarray(uv, np.float64).reshape(-1, 2).T
    inv_sigma = np.ones(Xt.shape[1]) if sigma is None else 1.0 / np.asarray(sigma, np.float64)
    damping = 1e-9 * np.eye(6)
    for s in scales_px:
        for _ in range(int(iterations)):
            X = T[:3, :3] @ Xt
            X += T[:3, 3:]
            ok = X[2] > 1e-6
            if ok.all():  # the usual case: no copies
                H, g = _gauss_newton_step(X, qt, inv_sigma, K, s)
            elif np.count_nonzero(ok) < 6:
                return T
            else:
                H, g = _gauss_newton_step(X[:, ok], qt[:, ok], inv_sigma[ok], K, s)
            try:
                delta = np.linalg.solve(H + damping, g)
            except np.linalg.LinAlgError:
                return T
            dT = np.eye(4)
            dT[:3, :3] = cv2.Rodrigues(delta[:3])[0]  # exp of the rotation part (OpenCV: no scipy call per step)
            dT[:3, 3] = delta[3:]
            T = dT @ T
            if np.linalg.norm(delta) < 1e-8:
                break
    return T


def _gauss_newton_step(X: np.ndarray, qt: np.ndarray, inv_sigma: np.ndarray, K: np.ndarray, s: float):
    """The normal equations ``(H (6, 6), g (6,))`` of one reweighted Gauss-Newton step of :func:`refine_pose`
    at the camera points ``X (3, M)`` (in front of the camera) observed at ``qt (2, M)`` px
    (:func:`_weighted_jacobian`)."""
    J, Jw, r = _weighted_jacobian(X, qt, inv_sigma, K, s)
    return Jw @ J.T, Jw @ r


def _weighted_jacobian(X: np.ndarray, qt: np.ndarray, inv_sigma: np.ndarray, K: np.ndarray, s: float):
    """``(J, J W, r)`` at the camera points ``X (3, M)`` observed at ``qt (2, M)`` px.

    The Jacobian of ``(u, v)`` for a left perturbation ``(omega, v)`` of the camera-frame point is laid out
    as one ``(6, 2M)`` matrix (the ``u`` rows of every point, then the ``v`` rows), so that
    ``H = J W J^T`` and ``g = J W r`` are two matrix products, ``W`` holding each row's Cauchy weight
    ``sigma^-2 / (1 + |r / sigma|^2 / s^2)``; ``r (2M,)`` the residuals in px, laid out as ``J``'s columns.
    """
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    m = X.shape[1]
    J, xz, yz = projection_jacobian(X, K)
    r = np.empty(2 * m)  # residuals in px
    np.subtract(qt[0], fx * xz + cx, out=r[:m])
    np.subtract(qt[1], fy * yz + cy, out=r[m:])
    isg2 = inv_sigma * inv_sigma
    e2 = r * r
    q = e2[:m] + e2[m:]
    q *= isg2
    q *= 1.0 / (s * s)
    q += 1.0
    w = isg2 / q
    return J, J * np.concatenate([w, w]), r


class LeaveOneOut:
    """The pose of all matches ``use`` but one surface's, as one Gauss-Newton step from ``T_c_w`` (the pose of all of
    them) on the normal equations of all the matches less those of the surface: the influence of the surface on the
    pose, to first order. The Cauchy weights (scale ``s``, residuals in units of ``sigma``) are those of ``T_c_w``;
    the normal equations of all matches are built once and each surface's own are a product over its columns of
    the Jacobian (:func:`_weighted_jacobian`, as in :func:`refine_pose`)."""

    def __init__(self, T_c_w: np.ndarray, X_w: np.ndarray, uv: np.ndarray, K: np.ndarray, sigma: np.ndarray,
                 use: np.ndarray, s: float) -> None:
        self.T = T_c_w
        idx = np.flatnonzero(use)
        X = T_c_w[:3, :3] @ X_w[idx].T
        X += T_c_w[:3, 3:]
        front = X[2] > 1e-6
        idx, X = idx[front], X[:, front]
        self.m = len(idx)
        self.J, self.Jw, self.r = _weighted_jacobian(X, np.asarray(uv, np.float64)[idx].T, 1.0 / np.asarray(sigma[idx], np.float64), K, s)
        self.H, self.g = self.Jw @ self.J.T, self.Jw @ self.r
        self.column = np.full(len(X_w), -1)
        self.column[idx] = np.arange(self.m)

    def pose_without(self, on: np.ndarray) -> np.ndarray:
        c = self.column[on]
        c = c[c >= 0]
        if self.m - len(c) < 6:
            return self.T
        cols = np.concatenate([c, c + self.m])
        Jw = self.Jw[:, cols]
        try:
            delta = np.linalg.solve(self.H - Jw @ self.J[:, cols].T + 1e-9 * np.eye(6), self.g - Jw @ self.r[cols])
        except np.linalg.LinAlgError:
            return self.T
        dT = np.eye(4)
        dT[:3, :3] = cv2.Rodrigues(delta[:3])[0]
        dT[:3, 3] = delta[3:]
        return dT @ self.T


def _pixel_spread(T_c_w: np.ndarray, X_w: np.ndarray, uv: np.ndarray, K: np.ndarray, sigma: np.ndarray,
                  fixed: np.ndarray, judged: np.ndarray) -> float:
    """How well the matches ``fixed`` alone fix the pixels of the matches ``judged``: the median over ``judged``
    of the standard deviation (in units of each keypoint's ``sigma``) of its predicted pixel under ``T_c_w``
    with the covariance ``s^2 H^-1`` of the pose fitted on ``fixed`` (``H`` the Gauss-Newton information of
    those matches, ``s`` their noise level from the median residual). ``inf`` when they do not fix a pose."""
    Xf = transform_points(T_c_w, X_w[fixed]).T
    Xj = transform_points(T_c_w, X_w[judged]).T
    if Xf.shape[1] < 6 or not (Xf[2] > 1e-6).all() or not (Xj[2] > 1e-6).all():
        return float("inf")
    Jf, xz, yz = projection_jacobian(Xf, K)
    w = 1.0 / np.asarray(sigma[fixed], np.float64) ** 2
    H = (Jf * np.concatenate([w, w])) @ Jf.T
    # the residuals from the projections just computed (the points are not transformed again)
    err = np.hypot(uv[fixed, 0] - (K[0, 0] * xz + K[0, 2]), uv[fixed, 1] - (K[1, 1] * yz + K[1, 2]))
    noise = np.median(err / sigma[fixed]) / 1.1774  # Rayleigh median
    try:
        C = np.linalg.inv(H) * noise**2
    except np.linalg.LinAlgError:
        return float("inf")
    Jj, _, _ = projection_jacobian(Xj, K)
    Jj = Jj / np.tile(np.asarray(sigma[judged], np.float64), 2)
    rows = np.einsum("am,ab,bm->m", Jj, C, Jj)
    m = Xj.shape[1]
    return float(np.median(np.sqrt(np.maximum(rows[:m] + rows[m:], 0.0))))


def match_map_points(context, uv: np.ndarray, camera, config: ReferencePoseConfig):
    """Step 2: map points matched to keypoints near their predicted pixels.

    Returns ``(rows, kp, hamming)``: rows of the context's map arrays, the keypoint index and the
    descriptor distance of each match.
    """
    T = context.T_c_w_pred
    n_map = context.n_map_points
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))
    if T is None or n_map == 0 or context.descriptors is None or len(uv) == 0:
        return empty
    rows = np.arange(n_map)
    uv_hat, z = camera.project(transform_points(T, context.map_xyz[rows]))
    vis = (z > 0) & camera.in_image(uv_hat)
    rows, uv_hat = rows[vis], uv_hat[vis]
    if len(rows) == 0:
        return empty
    m = search_by_projection(uv_hat, context.map_descriptors[rows], np.full(len(rows), config.search_radius_px), None,
                             uv, context.octave, context.descriptors, max_distance=config.max_hamming, ratio=config.ratio)
    return rows[m.idx_a], m.idx_b, m.distance


def _correction_ok(T_a: np.ndarray, T_b: np.ndarray, config: ReferencePoseConfig) -> bool:
    D = T_a @ se3_inv(T_b)
    return bool(np.linalg.norm(D[:3, 3]) <= config.max_correction_m and rotation_angle_deg(D[:3, :3]) <= config.max_correction_deg)


def _pose_gap_px(T_a: np.ndarray, T_b: np.ndarray, X_w: np.ndarray, K: np.ndarray) -> float:
    """Median pixel distance between the projections of ``X_w`` under two poses."""
    ua, _ = _project(T_a, X_w, K)
    ub, _ = _project(T_b, X_w, K)
    return float(np.nanmedian(np.linalg.norm(ua - ub, axis=1)))


def _project(T: np.ndarray, X_w: np.ndarray, K: np.ndarray):
    X = transform_points(T, X_w)
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([K[0, 0] * X[:, 0] / X[:, 2] + K[0, 2], K[1, 1] * X[:, 1] / X[:, 2] + K[1, 2]], axis=1)
    return uv, X[:, 2]


def inconsistent_surfaces(T_c_w: np.ndarray, X_w: np.ndarray, uv: np.ndarray, K: np.ndarray, sigma: np.ndarray,
                          labels: np.ndarray, use: np.ndarray, config: "ReferencePoseConfig",
                          T_pred: np.ndarray | None = None, surface_cells: np.ndarray | None = None,
                          matched: np.ndarray | None = None) -> np.ndarray:
    """Step 3b: the matches on surfaces that move against the rest of the map (:func:`moving_surfaces`
    without the pose)."""
    return moving_surfaces(T_c_w, X_w, uv, K, sigma, labels, use, config, T_pred, surface_cells, matched)[0]


def moving_surfaces(T_c_w: np.ndarray, X_w: np.ndarray, uv: np.ndarray, K: np.ndarray, sigma: np.ndarray,
                    labels: np.ndarray, use: np.ndarray, config: "ReferencePoseConfig",
                    T_pred: np.ndarray | None = None, surface_cells: np.ndarray | None = None,
                    matched: np.ndarray | None = None, room_labels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, bool]:
    """Step 3b: the matches on surfaces that move against the rest of the map.

    Each surface (``labels (M,)``, 0 = none) with at least ``segment_min_matches`` matches, leaving at
    least ``segment_min_matches`` others, is left out in turn and the pose moved to the others' (from
    ``T_c_w``, on the matches ``use``: with ``leave_out_influence``, the default, one Gauss-Newton step on the
    normal equations of all of them less the surface's, :class:`LeaveOneOut`; else four reweighted steps on the
    rest). The surface is inconsistent when its median error (in units of
    ``sigma``) under that pose exceeds both ``segment_min_px`` and ``segment_ratio`` times the median of
    the others. With ``segment_joint_ratio > 0`` (off by default) the two groups must also disagree under
    ``T_c_w`` itself (the pose of all matches): the surface
    misses it ``segment_joint_ratio`` times more than the rest does, or the rest fits its own pose
    ``dominant_gain_weak`` times better than ``T_c_w`` (the surface pulled it); when both fit ``T_c_w``, the
    constant-velocity prediction ``T_pred`` decides: the surface moved if the pose without it lies closer to
    the prediction than ``T_c_w`` does; and it clears a surface only where the rest alone fixes the surface's
    pixels to ``segment_joint_spread`` sigma or worse (:func:`_pixel_spread`). Without that check a large static wall left out missed the pose of a
    few dozen matches elsewhere by 1.6-3.9 sigma while both fitted ``T_c_w`` within noise (``panel_rpy``,
    ``random_161``); without the prediction's say, movers at their onset, which fit ``T_c_w`` as well, were
    let through too; and once tracking has begun to follow a mover, ``T_c_w`` and the prediction both carry
    it and the ratios hide the mover that would have set them right, where the rest fixes the pose well
    (hence the spread; docs/robustness.md, "Two groups that fit one pose"). Two groups that disagree are symmetric
    (is the box moving, or everything but the box?): a surface holding less than half the matches is moving (the static majority); one holding
    more only when the pose without it lies closer to the constant-velocity prediction ``T_pred``
    than the pose with it. With ``segment_area_ratio > 0`` a surface of the room (``room_labels``, step 3c's: large,
    not standing in front of its neighbours) whose area (``surface_cells``) is that many times the area of all the
    surfaces holding the rest's matches is never the moving one (a plain room with a few dozen matches, the movers
    in front of it holding the rest: ``carried_xyz``). The worst such surface
    (minorities first) is removed and the search repeated (at most ``segment_max_movers`` times). Returns
    ``(M,)`` bool.

    **Dominant surfaces** (ours; with ``room_test``, on by default): a surface holding at least
    ``dominant_share`` of the matches is a mover mapped while it stood still, if anything is (a textured cart 1.3 m in front of the camera carries half
    the keypoints on 6 % of the image). When it starts slowly, ``T_c_w`` and the prediction follow it
    within a few frames, and so do the cart's other faces: left out alone, it is held by them. So it is
    tested against **the room**: the matches on surfaces at least ``dominant_area_ratio`` times larger
    (``surface_cells``: depth-grid cells per label, label 0 first; every match ``matched``, also those
    beyond the prediction's gate; at least ``dominant_room_min_matches`` of them, else no test), refined from wide Cauchy scales (``(8,) + scales_px``, five steps
    each). The room agrees with the mover's pose within a pixel or so, but refined on its own it returns
    to the static world's; under that pose the surface misses its map points and counts as the
    minority: the static world is the majority of the scene, not of its texture. Only when the surface
    pulled ``T_c_w``: the room's median error under ``T_c_w`` must be ``dominant_gain`` times that under
    its own pose, or ``dominant_gain_weak`` times while the surface misses by twice the bound (a room that
    fits ``T_c_w`` as well is no evidence, only a weaker constraint: refined alone, a room of a few dozen
    matches lets a static surface miss by up to ~1.7 times the bound). Every other surface
    smaller than the room's (``dominant_area_ratio`` times the surface's area) whose matches miss the
    room's pose as the surface does (median error beyond ``segment_min_px`` and ``segment_ratio`` times
    the room's own) goes with it: the object's other faces.
    """
    out = np.zeros(len(X_w), bool)
    use = use.copy()
    T = T_c_w
    room = False
    room_set = None if room_labels is None else {int(v) for v in np.asarray(room_labels).reshape(-1)}
    for _ in range(config.segment_max_movers):
        labs, counts = np.unique(labels[(labels > 0) & use], return_counts=True)
        total = int(use.sum())
        cand = labs[(counts >= config.segment_min_matches) & (total - counts >= config.segment_min_matches)]
        best, best_key, best_T, best_fit = None, None, None, None
        e_T = None  # errors under T, needed by the consistency checks only
        gap_with = _pose_gap_px(T, T_pred, X_w[use], K) if T_pred is not None else None
        leave_out = None  # the normal equations of all matches under T, built for the first surface that needs them
        for lab, count in zip(cand, counts[np.isin(labs, cand)]):
            on = (labels == lab) & use
            rest = use & ~on
            fit = None
            if config.room_test and surface_cells is not None and count >= config.dominant_share * total:
                # the room: the surfaces much larger than this one (an object is often several surfaces, all
                # of which moved), with every match on them, also those beyond the prediction's gate
                pool = (use if matched is None else matched) & ~out & (labels > 0)
                fit = pool & (surface_cells[labels] >= config.dominant_area_ratio * surface_cells[lab])
                if fit.sum() < max(config.segment_min_matches, config.dominant_room_min_matches):
                    fit = None
            dominant = fit is not None
            if dominant:
                T_l = refine_pose(T, X_w[fit], uv[fit], K, (8.0, *config.scales_px), iterations=5, sigma=sigma[fit])
            elif config.leave_out_influence:
                if leave_out is None:
                    leave_out = LeaveOneOut(T, X_w, uv, K, sigma, use, config.scales_px[-2])
                T_l = leave_out.pose_without(on)
            else:
                T_l = refine_pose(T, X_w[rest], uv[rest], K, config.scales_px[-2:], iterations=2, sigma=sigma[rest])
            e = _reprojection_px(T_l, X_w, uv, K) / sigma
            r_on, r_rest = np.median(e[on]), np.median(e[rest])
            bound = max(config.segment_min_px, config.segment_ratio * r_rest)
            if r_on <= bound:
                continue
            if not dominant and config.segment_area_ratio > 0 and surface_cells is not None and room_set is not None \
                    and int(lab) in room_set:
                # the static world is the majority of the scene, not of its texture: a surface of the room far
                # larger than all those holding the rest's matches is the room they move in, whatever their number
                rest_labels = np.unique(labels[rest & (labels > 0)])
                if surface_cells[lab] >= config.segment_area_ratio * surface_cells[rest_labels].sum():
                    continue
            if not dominant and config.segment_joint_ratio > 0:
                # left out, a surface misses a pose the rest alone fixes poorly (a large wall against a few
                # dozen matches elsewhere) by as much as a mover misses it; one pose that fits both groups
                # (all matches) says the surface agrees with the rest, unless the surface pulled it there
                # (the rest fits its own pose better, or that pose lies closer to the prediction)
                if e_T is None:
                    e_T = _reprojection_px(T, X_w, uv, K) / sigma
                miss = np.median(e_T[on]) / max(np.median(e_T[rest]), 1e-9)
                pulled = np.median(e_T[rest]) / max(r_rest, 1e-9)
                closer = T_pred is not None and _pose_gap_px(T_l, T_pred, X_w[use], K) < gap_with
                if miss < config.segment_joint_ratio and pulled < config.dominant_gain_weak and not closer:
                    # the ratios clear the surface only where the rest alone fixes its pixels poorly
                    if _pixel_spread(T_l, X_w, uv, K, sigma, rest, on) >= config.segment_joint_spread:
                        continue
            if dominant:  # evidence that the surface pulled T: the room fits its own pose clearly better, or
                # somewhat better while the surface misses by twice the bound (a poorly constrained room's pose
                # alone makes a static surface miss by less)
                if e_T is None:
                    e_T = _reprojection_px(T, X_w, uv, K) / sigma
                gain = np.median(e_T[fit]) / max(np.median(e[fit]), 1e-9)
                if not (gain >= config.dominant_gain or (gain >= config.dominant_gain_weak and r_on >= 2 * bound)):
                    continue
            minority = 2 * count < total or dominant
            if not minority and (T_pred is None or _pose_gap_px(T_l, T_pred, X_w[use], K) >= gap_with):
                continue  # most of the map would be moving, and the prediction does not say so
            key = (minority, r_on / bound)  # the static majority first, then the prediction
            if best_key is None or key > best_key:
                best, best_key, best_T, best_fit = lab, key, T_l, fit
        if best is None:
            break
        on = labels == best
        if best_fit is not None:  # the room's pose: every other surface that misses it moved with the object
            room = True
            e = _reprojection_px(best_T, X_w, uv, K) / sigma
            bound = max(config.segment_min_px, config.segment_ratio * np.median(e[best_fit]))
            small = surface_cells[best] * config.dominant_area_ratio  # faces of an object, not of the room
            for lab in np.unique(labels[use & ~on & ~best_fit & (labels > 0)]):
                other = use & (labels == lab)
                if surface_cells[lab] < small and np.median(e[other]) > bound:
                    on |= labels == lab
        out |= on
        use &= ~on
        T = best_T
    return out, T, room


def room_depth_pulled(d_start: float, d_end: float, config: ReferencePoseConfig) -> bool:
    """Whether aligning the room's depth lowered its median point-to-plane distance from ``d_start`` to ``d_end``
    enough to say the feature pose had been pulled (step 3c, condition a): ``d_start >= room_depth_gain d_end`` and
    ``d_start >= room_depth_min_m``.

    The distance after the alignment is the depth noise; before it, the noise and the pose's offset together, about
    ``d_start^2 = d_end^2 + d_pose^2``. On a sensor ``s = room_depth_noise`` times noisier than the Kinect model the
    same pose offset hardly raises the median (``random_183`` with ``CameraEffects(depth_noise=0.005)``, a pose 28 mm
    off: 10.8 mm against 9.4, where the Kinect gives 5.8 against 3.0), so the gain is judged on the distances with
    the extra noise taken out: ``d_start^2 - d_end^2 >= (gain^2 - 1) (d_end / s)^2``, the same test as above at
    ``s = 1``."""
    gain, s = config.room_depth_gain, config.room_depth_noise
    if not d_start >= config.room_depth_min_m:
        return False
    if s == 1.0:
        return d_start >= gain * d_end
    return d_start * d_start - d_end * d_end >= (gain * gain - 1.0) * (d_end / s) ** 2


def depth_moved_surfaces(T_c_w: np.ndarray, X_w: np.ndarray, uv: np.ndarray, K: np.ndarray, sigma: np.ndarray,
                         labels: np.ndarray, matched: np.ndarray, config: ReferencePoseConfig, room: RoomDepth | None,
                         room_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """Step 3c (ours): the room's depth says where the camera is (:mod:`.room_depth`).

    The room's depth points (``room``, on the surfaces ``room_ids``) are aligned to an earlier frame's
    depth from ``T_c_w`` (:func:`~.room_depth.align_room`). The features had been pulled when (a) the
    alignment lowers the room's median point-to-plane distance ``room_depth_gain`` times, from at least
    ``room_depth_min_m`` (a pose the features already fix leaves the distance at the depth noise, where no
    step lowers it that much) and
    (b) the room's own map matches (``labels`` in ``room_ids``, among ``matched``) agree with the aligned
    pose: their median error is at most ``segment_min_px`` sigma and at most ``room_depth_pull`` times
    their median error under ``T_c_w`` (else the map itself disagrees with the depth). Then every other surface with at
    least ``room_depth_min_matches`` matches whose median error under the aligned pose exceeds
    ``room_depth_miss`` and ``segment_ratio`` times the room's median, and ``room_depth_pull`` times its
    median error under ``T_c_w`` (the surface pulled the feature pose), moved. Without such a surface the
    step does nothing: the features' pose is the one the map points agree with, and the checks judge
    keypoints against map points (taking the depth's pose whenever it fits the depth better cut keypoint
    precision from 0.68 to 0.38 on ``random_189``: static points then missed their map points). Returns ``(moving (M,) bool, T_c_w, fired)``;
    ``T_c_w`` is the aligned pose when the step fired, else the input.
    """
    none = (np.zeros(len(X_w), bool), T_c_w, False)
    if room is None or config.room_depth_gain <= 0 or len(room_ids) == 0:
        return none
    in_room = np.isin(labels, room_ids)
    on_room = matched & in_room
    if on_room.sum() < config.segment_min_matches:
        return none
    w = config.room_depth_feature_weight
    feats = ReprojectionTerm(X_w[on_room], uv[on_room], K, sigma[on_room] / np.sqrt(w)) if w > 0 else None
    a = align_room(room, T_c_w, features=feats, sigma_scale=config.room_depth_noise)
    if a.n < config.room_depth_min_points or not room_depth_pulled(a.d_start, a.d_end, config):
        return none
    e = _reprojection_px(a.T_c_w, X_w, uv, K) / sigma
    e_feat = _reprojection_px(T_c_w, X_w, uv, K) / sigma
    r_room = float(np.median(e[on_room]))
    if r_room > min(config.segment_min_px, config.room_depth_pull * np.median(e_feat[on_room])):
        return none  # the room's own map points disagree with its depth (the map, not the features, is off)
    bound = max(config.room_depth_miss, config.segment_ratio * r_room)
    moving = np.zeros(len(X_w), bool)
    off = matched & (labels > 0) & ~in_room
    labs, counts = np.unique(labels[off], return_counts=True)
    for lab in labs[counts >= config.room_depth_min_matches]:
        on = off & (labels == lab)
        miss = np.median(e[on])
        if miss > bound and miss >= config.room_depth_pull * np.median(e_feat[on]):
            moving |= on
    if not moving.any():  # no surface pulled the features: keep their pose, which the map points agree with
        return none
    return moving, a.T_c_w, True


def map_reference_pose(context, uv: np.ndarray, camera, config: ReferencePoseConfig = ReferencePoseConfig(),
                       exclude_ids=None, surfaces: np.ndarray | None = None,
                       surface_cells: np.ndarray | None = None, room_depth: RoomDepth | None = None,
                       room_ids: np.ndarray | None = None) -> ReferencePose:
    """Steps 1-4 except the two-frame fallback (which needs the LK pairs; see :mod:`.stages`).

    Parameters
    ----------
    context : :class:`~dynslam_lab.dynamic.context.ScreeningContext` (prediction, local map, descriptors).
    uv : ``(N, 2)`` keypoint pixels (undistorted).
    camera : intrinsics.
    exclude_ids : ids of map points seen moving: matched (their keypoints are reported) but left out
        of the refinement and never inliers.
    surfaces : ``(N,)`` int surface label of each keypoint (0 = none) for step 3b, or None.
    surface_cells : ``(L,)`` depth-grid cells of each surface label (label 0 first), or None (step 3b then
        tests no dominant surface).
    room_depth, room_ids : the room's depth against an earlier frame's and the labels of its surfaces (step 3c,
        :func:`depth_moved_surfaces`), or None (no step 3c); step 3b never judges a large surface of ``room_ids``
        to be the moving one (``segment_area_ratio``).

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
    rows, kp, ham = match_map_points(context, uv, camera, config)
    if len(rows) < config.min_inliers:
        return out
    K = camera.K
    X, q = context.map_xyz[rows], uv[kp]
    sigma = context.scale_factor ** context.octave[kp].astype(np.float64)
    err = _reprojection_px(T_pred, X, q, K)
    known_moving = np.isin(context.map_ids[rows], exclude_ids) if exclude_ids is not None and len(exclude_ids) else np.zeros(len(rows), bool)
    use = (err < config.gate_px) & ~known_moving
    if use.sum() < config.min_inliers:
        return out
    T = refine_pose(T_pred, X[use], q[use], K, config.scales_px, sigma=sigma[use])
    moving = np.zeros(len(rows), bool)
    room = depth_fired = False
    if surfaces is not None:
        lab = np.asarray(surfaces)[kp]
        if room_ids is not None:
            moving, T, depth_fired = depth_moved_surfaces(T, X, q, K, sigma, lab, ~known_moving, config, room_depth,
                                                          room_ids)
        moved, T_s, room = moving_surfaces(T, X, q, K, sigma, lab, use & ~moving, config, T_pred,
                                           surface_cells, matched=~known_moving & ~moving, room_labels=room_ids)
        moving |= moved
        keep = use & ~moving
        if room:  # the room's pose: a re-refinement on the rest would let the object's unseen parts pull it back
            T = T_s
        elif moving.any() and keep.sum() >= config.min_inliers:
            T = refine_pose(T, X[keep], q[keep], K, config.scales_px[-2:], sigma=sigma[keep])
    err = _reprojection_px(T, X, q, K)
    # when the room's pose was taken, the prediction followed the mover: it is no check
    if (err < config.inlier_px).sum() < config.min_inliers or not (room or _correction_ok(T, T_pred, config)):
        return out
    out.T_c_w, out.source = T, "map"
    out.map_index[kp] = rows
    out.residual_px[kp] = err
    out.inliers[kp] = (err < config.inlier_px) & ~moving & ~known_moving
    out.moved[kp] = (err > config.moving_px) & (ham <= config.moving_hamming)
    out.surface_moved[kp] = moving
    if room or depth_fired:  # the object as a whole: every keypoint on its surfaces, matched to the map or not
        lab_all = np.asarray(surfaces)
        gone = np.unique(lab_all[kp][moving])
        out.surface_moved |= np.isin(lab_all, gone[gone > 0])
    out.known_moving[kp] = known_moving
    out.room = room
    out.room_depth = depth_fired
    return out
