"""Tracking: the camera pose of each frame against the map
(ORB-SLAM, Mur-Artal et al., T-RO 2015, Sec. V; ORB-SLAM2, T-RO 2017, Sec. III-A/B).

For each new frame, with only the keypoints the screening stage judged static:

1. **Motion model** (Sec. V-B): predict ``T_c_w = V T_c_w^{last}`` with the constant velocity
   ``V = T_c_w^{last} (T_c_w^{before last})^{-1}`` (ours: scaled to the frame's interval, ``V^s`` with
   ``s = dt / dt_V``, ``velocity_per_second``; frames 30 and 40 ms apart are not one step each);
   project the map points matched in the last
   frame and search each within ``r = th * scale_factor**octave`` pixels (``th = 15`` for RGB-D),
   on the keypoint's pyramid level +-1, Hamming distance <= 100, orientation consistent;
   doubling the radius once if fewer than 20 matches. Ours, for repeated patterns, all off by
   default (docs/tracking.md "Repeated patterns": none helped everywhere): a ratio test against the
   second candidate on any level (``motion_ratio``), a depth-consistency gate
   (``match_depth_tolerance``), and a second search in a tight window around the pose refined from
   the first matches (``motion_refine_radius``).
   **From the screener's reference pose** (ours, ``start_from_reference``, on by default): with a
   geometric screener, the frame was already matched to the local map around the same prediction and its
   pose refined on the static matches (:mod:`dynslam_lab.dynamic.reference_pose`, DynaSLAM's "low-cost
   tracking"); tracking takes that pose and those matches and goes to step 4 (the same work not done twice).
2. **Reference keyframe** fallback: match the descriptors of the frame to those of the
   reference keyframe's map points (ratio 0.7; ORB-SLAM2 uses its bag of words here) and
   estimate the pose by **PnP-RANSAC** (``cv2.solvePnPRansac``).
3. **Pose-only refinement** (motion-only BA, eq. 2 of ORB-SLAM2, in :mod:`.optimize`) with a
   Huber loss and chi^2 outlier rejection.
4. **Track the local map** (Sec. V-D): the local keyframes are those sharing points with the
   frame plus their best covisible neighbours; their map points that fall in the frustum
   (in the image, at distance within the scale-invariance range ``[0.8 d_min, 1.2 d_max]``,
   viewing angle to the mean direction below 60 deg) are searched by projection with
   ``r = th * (2.5 or 4) * scale_factor**level`` (``th = 3`` for RGB-D), then the pose is refined
   again (ours, off by default: the same depth gate, and the ratio test against a second candidate
   on any level, ``local_ratio_any_level``). Tracking succeeds with at least 30 inliers (50 just after
   relocalisation).
5. **Keyframe decision** (Sec. V-E and ORB-SLAM2 ``NeedNewKeyFrame``): a new keyframe when the
   frame tracks fewer than 60 % of the points of the reference keyframe (ORB-SLAM2: 75 % of those
   seen by two keyframes; without triangulation between keyframes our points are seen by fewer
   keyframes, and that count made keyframes come too late on a turning camera: synthetic ``loop``
   ATE 7.6 cm, with ours 0.9 cm), or fewer than 100 close
   points are tracked while more than 70 close points could be created, with more than 15
   inliers, and at least ``kf_min_frames`` frames after the last keyframe (always after
   ``kf_max_frames``).
6. **Relocalisation** when lost (Sec. V-C): candidate keyframes from the keyframe database
   queried with the frame's bag-of-words vector (``DetectRelocalizationCandidates``; brute force
   over recent and evenly spaced keyframes when there is no database), descriptor matching,
   PnP-RANSAC, pose refinement and local-map search, accepted with 50 inliers.

**Dense depth term** (ours, ``dense``: docs/tracking.md "Dense depth term" has the
measurements; :mod:`~dynslam_lab.geometry.depth_alignment`): ``"always"`` tracks every frame with the point-to-plane error of
its depth image against the last frame's in each motion-only BA (plus a weak prior to the motion
prediction), ``"weak"`` only frames the features fail or keep few inliers, ``"auto"`` (the default) only
frames the features fail, or keep few inliers with a pose off the motion prediction (suspect), so plain
walls (few features) keep a pose; depth samples near keypoints judged dynamic are left out. ``"off"`` is
ORB-SLAM2.

**Joint refinement** (ours, method ``"joint"``). By default (``joint_every_frame``) every frame the features
tracked, while the scene is judged static, is refined by two Gauss-Newton steps over its feature inliers and
its image edges against the reference keyframe's image (the photometric term of Steinbruecker et al. 2011's
hybrid odometry): the corners' white jitter of ~2.5 mm from frame to frame falls to ~1.4 mm (docs/tracking.md
"Image edges against the corners' jitter"). An older option (``joint_position_sigma`` /
``joint_rotation_deg`` with ``joint_every_frame`` and ``joint_gn_iterations`` off): a frame whose pose the
features fix poorly (:func:`~.optimize.pose_uncertainty`: keypoints clustered on a few objects of a plain
room) is refined by motion-only BA over its features and the dense depth term together (docs/tracking.md
"Weak feature poses"). Options of the dense term, off by default
(docs/tracking.md "A depth model of recent keyframes"): the reference a model fused from the last keyframes'
depth instead of the last frame's (``dense_reference``), depth averaged before alignment
(``dense_smooth_px``), its weight (``dense_sigma_scale``).

**Far points** (ours, ``new_point_depth``, 8 m by default): a keyframe makes a map point of every
static keypoint with depth up to that, not only the close ones: ORB-SLAM2 triangulates far points between
keyframes, we do not (docs/tracking.md "Far points from depth").

**When they engage** (ours): the far points and the dense term (``"weak"``, ``"auto"``) assume a static
world. On dynamic scenes they let the tracker follow a mover the screening judged only in part, so they
engage only while the screening judged none of the last ``static_scene_frames`` (30) frames dynamic
(more than ``static_scene_max_dynamic``, 2 %, of its keypoints), and the dense term only on frames with
fewer than ``dense_max_keypoints`` (500) keypoints with depth (a plain wall, not a mover that took ORB's
budget). docs/robustness.md "Tracking options and movers" has the measurements.

Dynamic keypoints (``static == False``) are never matched, never used for pose and never turned
into map points.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from ..camera import PinholeCamera
from ..datasets.kinect import DepthNoise, nguyen_sigma
from ..features.matching import TH_HIGH, TH_LOW, Matches, match_descriptors, orientation_consistent, search_by_projection
from ..geometry.pnp import pnp_ransac
from ..geometry.se3 import nearest_rotation, rotation_angle_deg, se3_inv, so3_exp, so3_log, transform_points
from ..geometry.depth_alignment import (DenseTerm, DepthGrid, DepthSource, HybridTerm, ImageLevel, MotionPrior, align_depth, fuse_depth_model,
                                        image_level, photometric_term, smooth_depth, vertex_normal_grid)
from .frame import KeyFrame, SlamFrame
from .keyframe_database import static_bow
from .map import Map
from .optimize import Observations, optimize_pose, pose_step_mahalanobis, pose_uncertainty

__all__ = ["TrackingConfig", "Tracker", "TrackState", "frustum_candidates", "pose_distance"]


_DENSE_KF_MIN_INLIERS = 5  # feature inliers a dense-tracked keyframe needs to be tied to the map (local BA needs observations)
JOINT_MAX_STEP = (0.01, 0.5)  # m, deg: a Gauss-Newton joint refinement moving the feature pose farther is refused (the feature pose stands), unless the features' own information allows the move (TrackingConfig.joint_gate_chi2)
JOINT_KEYFRAME_LEVELS = 4  # image levels of the most recent keyframes kept for the joint refinement (joint_reference = "keyframe"; 4 x 160 x 120 x 4 float32 planes ~ 1.2 MB)


def pose_distance(T: np.ndarray) -> tuple[float, float]:
    """Size of a pose difference ``T (4, 4)``: translation (m) and rotation angle (deg)."""
    return float(np.linalg.norm(T[:3, 3])), float(rotation_angle_deg(T[:3, :3]))


@dataclass(frozen=True)
class TrackingConfig:
    """Parameters of tracking (ORB-SLAM2 ``Tracking.cc`` / TUM settings unless noted)."""

    bf: float = 400.0  # virtual stereo baseline x fx (px*m) of the u_R residual, i.e. the weight of a keypoint's depth (a depth error dz costs bf dz / z^2 px); ours, 10x ORB-SLAM2's TUM Camera.bf (40, under which a 5 cm error at 3 m costs 0.2 px and local BA slid keyframes by 14 cm): docs/tracking.md "The weight of depth"
    th_depth: float = 4.0  # close points: depth < th_depth * bf / fx (m; 3.05 m at fx 525, as ORB-SLAM2's ThDepth 40 with bf 40)
    min_depth: float = 0.1  # keypoint depths below this are missing (m); ours (sensor minimum)
    max_depth: float = 8.0  # keypoint depths above this are missing (m); ours (Kinect range)
    init_min_points: int = 500  # keypoints with depth needed to start the map; ORB-SLAM2: 500
    init_weak_min_points: int = 50  # a frame with fewer than init_min_points keypoints with depth in all (weak texture: it cannot offer more) starts the map with this many static ones (the dense term tracks the plain room); 0 = off (ORB-SLAM2: the map never starts there); ours, docs/tracking.md "Starting the map in a room of weak texture"
    velocity_per_second: bool = True  # scale the constant-velocity motion by the ratio of the frame intervals (dt / dt_last): frames 30 and 40 ms apart (the synthetic sequences, TUM's jitter) are not predicted one step each; False = ORB-SLAM2 (one step per frame); ours, docs/tracking.md "Motion model in time"
    motion_radius: float = 15.0  # motion-model search radius at level 0 (px); ORB-SLAM2 RGB-D th: 15
    motion_min_matches: int = 20  # matches needed before optimising (else radius x2); ORB-SLAM2: 20
    motion_ratio: float = 1.0  # best / second-best Hamming distance in the motion-model search, second candidate on any level (1 = off, ORB-SLAM2: no ratio test there); ours, off: docs/tracking.md "Repeated patterns"
    motion_refine_radius: float = 0.0  # px at level 0: second motion-model search around the refined pose (0 = off, ORB-SLAM2); ours, off: docs/tracking.md "Repeated patterns"
    match_depth_tolerance: float = 0.0  # largest |z_keypoint - z_predicted| / z_predicted of a candidate in the motion-model and local-map searches (0 = off, ORB-SLAM2); ours (RGB-D), off: docs/tracking.md "Repeated patterns"
    min_track_inliers: int = 10  # inliers for motion-model / reference tracking; ORB-SLAM2: 10
    ref_ratio: float = 0.7  # ratio test for reference keyframe matching; ORB-SLAM2 SearchByBoW: 0.7
    local_radius: float = 3.0  # local map search factor th (px); ORB-SLAM2 RGB-D: 3 (5 after relocalisation)
    local_ratio: float = 0.8  # ratio test in local map search; ORB-SLAM2 SearchLocalPoints: 0.8
    local_ratio_any_level: bool = False  # local-map ratio test against the second candidate on any level (True; ours, off: docs/tracking.md "Repeated patterns"); ORB-SLAM2: same level only (False)
    local_max_keyframes: int = 80  # local keyframes at most; ORB-SLAM2: 80
    local_neighbours: int = 10  # best covisible neighbours added per local keyframe; ORB-SLAM2: 10
    view_cos: float = 0.5  # minimum cos of viewing angle to a point's mean direction; ORB-SLAM2: 0.5 (60 deg)
    min_local_inliers: int = 30  # inliers after local map tracking; ORB-SLAM2: 30
    min_local_inliers_reloc: int = 50  # same, within kf_max_frames of a relocalisation; ORB-SLAM2: 50
    pnp_reproj_px: float = 4.0  # PnP-RANSAC inlier threshold (px); ours (ORB-SLAM2: chi^2 5.991 -> 2.45 sigma)
    pnp_iterations: int = 200  # PnP-RANSAC iterations; ours
    pnp_min_inliers: int = 10  # PnP-RANSAC inliers to accept a pose; ORB-SLAM2 PnPsolver: 10
    reloc_ratio: float = 0.75  # ratio test in relocalisation matching; ORB-SLAM2: 0.75
    reloc_min_matches: int = 15  # matches to try a candidate keyframe; ORB-SLAM2: 15
    bow_relocalisation: bool = True  # keep a keyframe BoW database for relocalisation even without loop closing (ours; ORB-SLAM2 always has one)
    reloc_candidates: int = 20  # keyframes tried per relocalisation at most (BoW candidates; without a database the most recent and evenly spaced); ours
    kf_min_frames: int = 0  # frames between keyframes at least; ORB-SLAM2 mMinFrames: 0
    kf_max_frames: int = 30  # a keyframe at the latest after this many frames; ORB-SLAM2 mMaxFrames: fps (30)
    kf_ref_ratio: float = 0.6  # tracked / reference keyframe points below this -> keyframe; ours, ORB-SLAM2 RGB-D: 0.75 (see kf_ref_min_obs)
    kf_ref_min_obs: int = 1  # reference points counted: seen by this many keyframes; ours, ORB-SLAM2: 3 RGB-D obs (= 2)
    kf_min_inliers: int = 15  # a keyframe needs more inliers than this; ORB-SLAM2: 15
    kf_close_tracked: int = 100  # fewer tracked close points than this ...; ORB-SLAM2: 100
    kf_close_untracked: int = 70  # ... and more untracked close points -> keyframe; ORB-SLAM2: 70
    kf_new_points_min: int = 100  # new map points per keyframe at least (closest first); ORB-SLAM2: 100
    new_point_depth: float = 8.0  # m; a keyframe makes a map point of every static keypoint with depth below this (or below the close depth th_depth * bf / fx, whichever is farther), then far ones up to kf_new_points_min, while the scene is judged static (static_scene_frames); ours: ORB-SLAM2 makes only close points from depth and triangulates far ones between keyframes, which we do not, so a room 3-5 m deep had ~100 points per keyframe and tracking ran out of points (docs/tracking.md "Far points from depth"); 0 = the close depth only (ORB-SLAM2)
    suspect_translation: float = 0.03  # m; a pose this far from the constant-velocity prediction is suspect (no keyframe on it); ours
    suspect_rotation_deg: float = 1.0  # deg; same for the rotation; ours
    suspect_trusted_inliers: int = 0  # a pose with at least this many inliers is never suspect (a tracker following a mover keeps few); 0 = off; ours, docs/tracking.md "Graceful failure"
    flood_keyframes: int = 3  # this many frames asking for a keyframe within flood_window frames make a bad stretch; ours
    flood_window: int = 6  # frames; ours
    flood_min_gap: int = 5  # frames between keyframes at least during a bad stretch (and local BA capped); ours
    depth_residual: str = "stereo"  # motion-only BA's depth row: "stereo" = ORB-SLAM2's u_R = u - bf/z, "metric" = (z_c - z) / sigma_z; ours, docs/tracking.md "Depth in motion-only BA"
    depth_sigma_0: float = 0.0012  # m, constant term of the keypoint depth noise sigma_z = s0 + s2 (z - zref)^2; Nguyen et al. 2012 (Kinect v1), Eq. 3
    depth_sigma_2: float = 0.0019  # m/m^2, quadratic term; Nguyen et al. 2012, Eq. 3
    depth_sigma_zref: float = 0.4  # m, depth of the quadratic term's minimum; Nguyen et al. 2012, Eq. 3
    depth_sigma_scale: float = 1.5  # sigma_z used = this x the sensor's (the map point carries the noise of the keyframe depth it came from, ~sqrt 2, plus its pixel rounding); ours
    dense: str = "auto"  # the dense point-to-plane depth term in motion-only BA: "off" (ORB-SLAM2), "weak" (frames whose feature tracking fails or keeps fewer than dense_below_inliers inliers are tracked again with it), "auto" (frames whose feature tracking fails, or keeps fewer than dense_below_inliers inliers with a pose the suspect thresholds reject), "always" (every frame is tracked with it); "weak" and "auto" only while the scene is judged static (static_scene_frames) and on frames with few keypoints (dense_max_keypoints); ours, docs/tracking.md "Dense depth term"
    static_scene_frames: int = 30  # frames: the far points (new_point_depth) and the dense term ("weak", "auto") engage only when none of the last this many frames had more than static_scene_max_dynamic of its keypoints judged dynamic (0 = always engaged); ours: on dynamic scenes they let the tracker follow a mover, docs/robustness.md "Tracking options and movers"
    dense_max_keypoints: int = 500  # "weak" and "auto" engage only on frames with fewer keypoints with depth than this (0 = any frame): a plain wall gives ORB 5-200 keypoints (loop_flat), a mover that takes most of ORB's budget leaves 700-850 that fail to match (random_123, no filter); ours, docs/robustness.md "Tracking options and movers"
    static_scene_max_dynamic: float = 0.02  # fraction of a frame's keypoints judged dynamic above which the frame counts as dynamic (static_scene_frames); ours
    dense_below_inliers: int = 100  # "weak": the inlier count below which a frame is tracked again with the dense term; ours
    dense_mask_radius: float = 24.0  # px: depth samples this close to a keypoint judged dynamic are left out of the dense term (the screening judges keypoints, not pixels); ours
    motion_prior_m: float = 0.0  # > 0: the motion-only BA without a depth term holds the pose to the motion model's prediction with this sigma (m) on the position ... (depth_alignment.MotionPrior); 0 = off (ORB-SLAM2); ours
    motion_prior_deg: float = 1.0  # ... and this one (deg) on the orientation
    dense_mask_region: bool = True  # depth samples inside the screened dynamic region (the oracle's masks, the region stage's region) are left out of the dense term too; ours
    dense_in_dynamic_scenes: bool = False  # the dense term ("weak", "auto") engages on scenes judged dynamic too (static_scene_frames then governs the far points only); ours
    dense_stride: int = 8  # px between the depth samples of the dense term (80 x 60 for 640 x 480); ours
    dense_max_distance: float = 0.05  # m, point-to-plane distance beyond which a depth sample has no association; ours
    dense_view_margin_px: float = -1.0  # px; >= 0: only the depth samples that the motion prediction puts at least this far inside the reference's image cost the association gate when left unassociated (a sample the reference never saw is no evidence; charged, such samples pull the pose towards no motion: loop_flat seed 8, a slide of 32 mm a frame tracked as 9); negative (the default): every sample, as before, because that pull also damps the velocity the motion prediction carries across a plain wall (16 px: loop_flat worst of 12 seeds 46.9 -> 40.4 mm, but 3 seeds over 20 mm instead of 1); ours, docs/tracking.md "Samples the last frame never saw"
    dense_photometric_sigma: float = 4.0  # grey levels; > 0: a frame tracked with the dense term starts from (and is held to) the pose that aligns its image edges and depth to the last frame's, coarse to fine (hybrid RGB-D odometry, Steinbruecker et al. 2011), not the constant-velocity prediction: a plain wall's depth leaves a slide along it free (loop_flat seed 8: 20-30 mm of error a frame along the wall -> 0.1-3 mm); the residuals are whitened with this sigma; 0 = off (the depth term alone, as before); ours, docs/tracking.md "Image edges on a plain wall"
    dense_photometric_scales: tuple[int, ...] = (4, 2)  # image reductions of the photometric alignment, coarse to fine; ours
    photometric_affine: bool = True  # both photometric terms (dense_photometric_sigma, joint_photometric_scale) fit an affine brightness transfer (gain, bias) between the frame and its reference before taking the residuals: a camera's auto-exposure changes the whole image's brightness between frames (Engel et al. 2018, DSO, model it so); False = equal brightness assumed (Steinbruecker et al. 2011); docs/tracking.md "Exposure changes"
    dense_min_fraction: float = 0.5  # a dense-tracked pose is accepted when this fraction of the frame's depth samples is associated; ours
    dense_min_inliers: int = 0  # ... and it keeps at least this many feature inliers (the planes may leave a direction free); ours
    dense_prior_translation: float = 0.02  # m, the dense-tracked pose is held to the motion prediction with this sigma (for the directions the planes leave free); ours
    dense_prior_rotation_deg: float = 1.0  # deg, same for the rotation; ours
    dense_sigma_scale: float = 1.5  # the dense term's samples are weighted with sigma = this x the sensor's axial noise (Nguyen et al. 2012, as depth_sigma); 1.5 as depth_sigma_scale before; ours, docs/tracking.md "A depth model of recent keyframes"
    dense_smooth_px: int = 1  # the depth images of the dense term (the frame's samples and the reference) are averaged over this many px square first (depth_alignment.smooth_depth: the Kinect's quantised depth biases point-to-plane alignment); 1 = raw depth; ours, docs/tracking.md "A depth model of recent keyframes"
    dense_reference: str = "frame"  # what the dense term aligns a frame's depth to: "frame" (the last frame's depth image: frame to frame, drifts), "keyframes" (a model fused from the depth of the last dense_model_keyframes keyframes at their current, optimised poses, the last frame filling only the cells they leave empty: depth_alignment.fuse_depth_model); ours, docs/tracking.md "A depth model of recent keyframes"
    dense_model_keyframes: int = 4  # "keyframes": the most recent keyframes whose depth makes the model; ours
    dense_model_stride: int = 4  # "keyframes": px between the model's samples of a keyframe's depth image (finer than dense_stride so that the samples of a few views fill the model's cells); ours
    dense_model_pose: str = "map"  # "keyframes": the pose of a keyframe's depth in the model: "map" (the keyframe's current pose), "tracked" (the pose tracking gave the frame, moved as the keyframe moved since its first local BA: loop corrections); ours
    dense_model_last_frame: bool = True  # "keyframes": the last frame's depth fills the model's cells no keyframe sample reaches (a plain wall makes few keyframes); ours
    joint_position_sigma: float = 0.0  # m; a frame the features tracked is refined with the dense term too ("joint") when its feature pose leaves the camera centre this uncertain (optimize.pose_uncertainty, 1 px noise) or more, while "weak"/"auto" engage (static scene); 0 = off (the default: it trades loop_pattern's ATE for loop_flat's); tried 0.0025; ours, docs/tracking.md "Weak feature poses: features and depth together"
    joint_rotation_deg: float = 0.0  # deg; same for the orientation; 0 = off; tried 0.05; ours
    joint_every_frame: bool = True  # every frame the features tracked is refined jointly (not only those whose pose is uncertain, joint_position_sigma), while "weak"/"auto" engage (static scene); ours, docs/tracking.md "Image edges against the corners' jitter"
    joint_gn_iterations: int = 2  # > 0: the joint refinement is this many Gauss-Newton steps from the feature pose over its inliers (no outlier rounds); 0 = a motion-only BA with its outlier rounds and the dense depth term (the joint refinement of weak feature poses, as before); ours
    joint_photometric_scale: int = 4  # > 0: the joint refinement adds the photometric term (the frame's image edges against a reference image, Steinbruecker et al. 2011) at this image reduction (4: 160 x 120 for 640 x 480); 0 = the dense depth term only; ours
    joint_photometric_sigma: float = 8.0  # grey levels: the whitening of the joint refinement's photometric residuals (Huber at 2 sigma); weaker than dense_photometric_sigma (4): here the features fix the pose on the map and the image only steadies it; ours
    joint_photometric_samples: int = 3000  # pixels of the photometric term at most (the strongest gradients); ours
    joint_reference: str = "keyframe"  # the image the photometric term aligns to: "keyframe" (the reference keyframe's, kept when it was made, at its pose as local BA keeps it: consecutive frames share one anchored reference) or "frame" (the last frame's: frame to frame, it chains the last pose's error: loop_flat's ATE +50 %); ours
    joint_depth: bool = False  # the joint refinement with the photometric term keeps the dense depth term (against the last frame's depth) too: no better on the static presets (RPE median 1.39 mm with it, sigma 16; 1.36 without, sigma 8) at ~3 ms more a frame; ours
    joint_gate_chi2: float = 12.6  # a joint refinement moving the feature pose farther than JOINT_MAX_STEP is kept when the move costs the feature inliers at most this much (d^2 = xi^T H xi under their Gauss-Newton information H, one pixel a unit: optimize.pose_step_mahalanobis; 12.6 = the chi^2 95 % quantile of 6 dof): a plain room's far corners leave centimetres free sideways; 0 = the fixed bound only (as before); ours, docs/tracking.md "How far the image may move a weak feature pose"
    joint_dense_step: int = 1  # the depth term of the joint refinement takes every this-many-th sample of the dense grid (dense_stride); ours
    start_from_reference: bool = True  # with a screener that refined the frame's pose on the local map (the reference pose, dynamic.reference_pose), track the local map from that pose and its inlier matches instead of the motion-model search and refinement (the same matching and refinement done once; DynaSLAM's "low-cost tracking" feeds its tracking the same way); ours, docs/speed.md "Tracking from the reference pose"
    overlap_detection: bool = True  # run the detector on frame t in a worker thread while ORB extracts frame t (same results; DS-SLAM / Wu et al. 2022 run semantics in their own thread); ours

    def __post_init__(self) -> None:
        positive = ("bf", "th_depth", "motion_radius", "local_radius", "pnp_reproj_px", "max_depth",
                    "suspect_translation", "suspect_rotation_deg", "depth_sigma_0", "depth_sigma_scale",
                    "dense_max_distance", "dense_prior_translation", "dense_prior_rotation_deg", "dense_sigma_scale")
        if not self.dense_photometric_sigma >= 0:
            raise ValueError(f"TrackingConfig.dense_photometric_sigma must be >= 0, got {self.dense_photometric_sigma}")
        scales = tuple(self.dense_photometric_scales)
        if not scales or not all(isinstance(k, int) and not isinstance(k, bool) and k >= 1 for k in scales):
            raise ValueError(f"TrackingConfig.dense_photometric_scales must be integers >= 1, got {self.dense_photometric_scales!r}")
        object.__setattr__(self, "dense_photometric_scales", scales)  # a list from a TOML file becomes a tuple
        if self.joint_reference not in ("frame", "keyframe"):
            raise ValueError(f"TrackingConfig.joint_reference must be 'frame' or 'keyframe', got {self.joint_reference!r}")
        for name, lo in (("joint_gn_iterations", 0), ("joint_photometric_scale", 0), ("joint_photometric_samples", 20), ("joint_dense_step", 1)):
            v = getattr(self, name)
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= lo):
                raise ValueError(f"TrackingConfig.{name} must be an integer >= {lo}, got {v!r}")
        if not self.joint_gate_chi2 >= 0:
            raise ValueError(f"TrackingConfig.joint_gate_chi2 must be >= 0, got {self.joint_gate_chi2}")
        if not self.joint_photometric_sigma > 0:
            raise ValueError(f"TrackingConfig.joint_photometric_sigma must be > 0 grey levels, got {self.joint_photometric_sigma}")
        if self.dense_reference not in ("frame", "keyframes"):
            raise ValueError(f"TrackingConfig.dense_reference must be 'frame' or 'keyframes', got {self.dense_reference!r}")
        if self.dense_model_pose not in ("map", "tracked"):
            raise ValueError(f"TrackingConfig.dense_model_pose must be 'map' or 'tracked', got {self.dense_model_pose!r}")
        if not isinstance(self.dense_model_last_frame, bool):
            raise ValueError(f"TrackingConfig.dense_model_last_frame must be a bool, got {self.dense_model_last_frame!r}")
        if self.dense not in ("off", "weak", "auto", "always"):
            raise ValueError(f"TrackingConfig.dense must be 'off', 'weak', 'auto' or 'always', got {self.dense!r}")
        if not self.dense_mask_radius >= 0:
            raise ValueError(f"TrackingConfig.dense_mask_radius must be >= 0, got {self.dense_mask_radius}")
        if not 0 < self.dense_min_fraction <= 1:
            raise ValueError(f"TrackingConfig.dense_min_fraction must be in (0, 1], got {self.dense_min_fraction}")
        if self.depth_residual not in ("stereo", "metric"):
            raise ValueError(f"TrackingConfig.depth_residual must be 'stereo' or 'metric', got {self.depth_residual!r}")
        for name in ("depth_sigma_2", "depth_sigma_zref"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"TrackingConfig.{name} must be >= 0, got {getattr(self, name)}")
        at_least_one = ("pnp_iterations", "local_max_keyframes", "reloc_candidates", "kf_max_frames", "kf_ref_min_obs",
                        "min_track_inliers", "flood_keyframes", "flood_window", "flood_min_gap", "dense_stride",
                        "dense_model_keyframes", "dense_model_stride", "dense_smooth_px")
        if not 0 <= self.static_scene_max_dynamic <= 1:
            raise ValueError(f"TrackingConfig.static_scene_max_dynamic must be in [0, 1], got {self.static_scene_max_dynamic}")
        non_negative = ("min_depth", "static_scene_frames", "init_min_points", "init_weak_min_points", "motion_min_matches", "local_neighbours", "min_local_inliers",
                        "min_local_inliers_reloc", "reloc_min_matches", "kf_min_frames", "kf_min_inliers", "suspect_trusted_inliers",
                        "kf_close_tracked", "kf_close_untracked", "kf_new_points_min", "dense_below_inliers",
                        "dense_min_inliers", "dense_max_keypoints", "joint_position_sigma", "joint_rotation_deg")
        ratios = ("ref_ratio", "local_ratio", "reloc_ratio", "kf_ref_ratio", "motion_ratio")
        for name in ("motion_refine_radius", "match_depth_tolerance", "new_point_depth"):
            if getattr(self, name) < 0:
                raise ValueError(f"TrackingConfig.{name} must be >= 0, got {getattr(self, name)}")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"TrackingConfig.{name} must be > 0, got {getattr(self, name)}")
        for name in ("overlap_detection", "local_ratio_any_level", "velocity_per_second", "start_from_reference",
                     "dense_mask_region", "dense_in_dynamic_scenes"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"TrackingConfig.{name} must be a bool, got {getattr(self, name)!r}")
        if self.motion_prior_m < 0 or not self.motion_prior_deg > 0:
            raise ValueError(f"TrackingConfig: motion_prior_m must be >= 0 and motion_prior_deg > 0, got "
                             f"{self.motion_prior_m}, {self.motion_prior_deg}")
        for name in at_least_one:
            if getattr(self, name) < 1:
                raise ValueError(f"TrackingConfig.{name} must be >= 1, got {getattr(self, name)}")
        for name in non_negative:
            if getattr(self, name) < 0:
                raise ValueError(f"TrackingConfig.{name} must be >= 0, got {getattr(self, name)}")
        for name in ratios:
            if not 0 < getattr(self, name) <= 1:
                raise ValueError(f"TrackingConfig.{name} must be in (0, 1], got {getattr(self, name)}")
        if not self.min_depth < self.max_depth:
            raise ValueError(f"TrackingConfig: min_depth ({self.min_depth}) must be below max_depth ({self.max_depth})")
        if not -1 <= self.view_cos <= 1:
            raise ValueError(f"TrackingConfig.view_cos must be in [-1, 1], got {self.view_cos}")
        if self.pnp_min_inliers < 4:
            raise ValueError(f"TrackingConfig.pnp_min_inliers must be >= 4 (a PnP pose needs 4 points), got {self.pnp_min_inliers}")
        if self.kf_min_frames > self.kf_max_frames:
            raise ValueError(
                f"TrackingConfig: kf_min_frames ({self.kf_min_frames}) must not exceed kf_max_frames ({self.kf_max_frames})"
            )

class TrackState:
    """Tracking states (strings, for files and plots)."""

    NOT_INITIALIZED = "not_initialized"
    OK = "ok"
    RELOCALIZED = "relocalized"
    LOST = "lost"


def frustum_candidates(
    mp: Map, ids: np.ndarray, T_c_w: np.ndarray, camera: PinholeCamera, view_cos: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Map points ``ids`` that the camera ``T_c_w`` can see (ORB-SLAM ``isInFrustum``, vectorised).

    Returns ``(kept ids, uv (K, 2), predicted level (K,), viewing cos (K,))``.
    """
    X = mp.xyz[ids]
    X_c = transform_points(T_c_w, X)
    uv, z = camera.project(X_c)
    ok = (z > 0) & camera.in_image(uv)
    C = se3_inv(T_c_w)[:3, 3]
    ray = X - C
    dist = np.linalg.norm(ray, axis=1)
    ok &= (dist >= 0.8 * mp.min_dist[ids]) & (dist <= 1.2 * mp.max_dist[ids])
    cos = np.einsum("ij,ij->i", ray, mp.normal[ids]) / np.maximum(dist, 1e-12)
    ok &= cos >= view_cos
    return ids[ok], uv[ok], mp.predict_level(ids[ok], dist[ok]), cos[ok]


class Tracker:
    """Tracking state of one run: last frame, velocity, reference keyframe, local map.

    The map and keyframe creation are shared with :class:`~dynslam_lab.slam.system.System`,
    which calls :meth:`track` per frame and :meth:`need_keyframe` afterwards.
    """

    def __init__(self, camera: PinholeCamera, mp: Map, cfg: TrackingConfig, scale_factor: float) -> None:
        self.camera = camera
        self.map = mp
        self.cfg = cfg
        self._depth_noise = DepthNoise(sigma_0=cfg.depth_sigma_0, sigma_2=cfg.depth_sigma_2, z_ref=cfg.depth_sigma_zref)
        self.scale_factor = float(scale_factor)
        self.state = TrackState.NOT_INITIALIZED
        self.last: SlamFrame | None = None
        self.velocity: np.ndarray | None = None  # T_c_w(last) @ T_w_c(before last)
        self.velocity_dt = 0.0  # s between the two frames of the velocity (0 = unknown)
        self.ref_kf: KeyFrame | None = None
        self.last_kf_frame = -(10**9)
        self.last_reloc_frame = -(10**9)
        self.n_inliers = 0
        self.local_kf_ids: list[int] = []
        self.method = ""
        # Place recognition for relocalisation (set by the System from the loop closer), or None.
        self.database = None  # KeyframeDatabase of the keyframes' BoW vectors
        self.vocabulary = None  # the Vocabulary those vectors come from
        self.last_reloc_candidates: list[int] = []  # keyframes tried by the last relocalisation
        # Graceful failure (ours): the constant-velocity prediction of the frame being tracked, how far
        # the tracked pose landed from it, and the recent frames that asked for a keyframe.
        self.predicted_T_c_w: np.ndarray | None = None
        self.motion_deviation = (0.0, 0.0)  # (m, deg) from the prediction; zeros without one
        self.kf_demand_frames: list[int] = []
        # Dense depth term (ours): the term of the frame being re-tracked (None otherwise), the last
        # frame's vertex/normal grid (frame index, grid), the fraction of depth samples associated.
        self._dense: DenseTerm | None = None
        self._dense_grid: tuple[int, DepthGrid] | None = None
        # dense_reference "keyframes": the depth samples of recent keyframes (id -> DepthSource in the keyframe's
        # camera; the pose is read from the map at use), and the last frame's (frame index, DepthSource)
        self._kf_depth: dict[int, DepthSource] = {}
        self._last_depth: tuple[int, DepthSource] | None = None
        self._smoothed: dict[int, np.ndarray] = {}  # frame index -> depth image smoothed for the dense term (two kept)
        self._levels: dict[tuple[int, int], ImageLevel] = {}  # (frame index, scale) -> image level of the photometric term (two frames kept)
        self._kf_levels: dict[int, ImageLevel] = {}  # keyframe id -> its image level for the joint refinement (joint_reference = "keyframe"; the most recent few)
        self.dense_model_sources = 0  # views fused into the last model (0: the last frame's grid, "frame")
        self.dense_fraction = 0.0
        # The low-texture options (far points, dense term) engage only while the screening judges the
        # scene static (ours): the index of the last frame with more than static_scene_max_dynamic of
        # its keypoints judged dynamic.
        self.last_dynamic_frame = -(10**9)
        # The screener's reference pose of the frame being tracked (set by the System before track):
        # (T_c_w, keypoint indices, map point ids of its inlier matches), or None.
        self.reference_start: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    # -------------------------------------------------------------- helpers
    def depth_sigma(self, z: np.ndarray) -> np.ndarray:
        """Standard deviation (m) of keypoint depths ``z`` in the metric depth row: ``depth_sigma_scale``
        x Nguyen et al. 2012's Kinect v1 axial noise ``s0 + s2 (z - zref)^2`` (the renderer's sensor model,
        :func:`~dynslam_lab.datasets.kinect.nguyen_sigma`, at normal incidence, with this config's terms)."""
        return self.cfg.depth_sigma_scale * nguyen_sigma(z, 0.0, self._depth_noise)

    def _obs(self, frame: SlamFrame, idx: np.ndarray) -> Observations:
        z = frame.depth[idx]
        z_sigma = None
        if self.cfg.depth_residual == "metric":
            z_sigma = np.where(np.isfinite(z), self.depth_sigma(np.nan_to_num(z, nan=1.0)), np.nan)
        return Observations.from_keypoints(frame.uv[idx], z, frame.octave[idx], self.cfg.bf, self.scale_factor, z_sigma)

    def _optimize(self, frame: SlamFrame, T_c_w: np.ndarray) -> int:
        """Motion-only BA over the frame's matches (with the dense term when one is set, else with the motion prior
        when ``motion_prior_m`` > 0 and there is a prediction); marks outliers; returns inlier count."""
        idx = np.flatnonzero(frame.map_point_ids >= 0)
        frame.outlier[:] = False
        if len(idx) < 3 and self._dense is None:
            frame.T_w_c = se3_inv(T_c_w)
            return 0
        term = self._dense
        if term is None and self.cfg.motion_prior_m > 0 and self.predicted_T_c_w is not None:
            term = MotionPrior(self.predicted_T_c_w, (self.cfg.motion_prior_m, self.cfg.motion_prior_deg))
        T, out = optimize_pose(T_c_w, self.map.xyz[frame.map_point_ids[idx]], self._obs(frame, idx), self.camera, self.cfg.bf,
                               dense=term)
        frame.T_w_c = se3_inv(T)
        frame.outlier[idx[out]] = True
        return int((~out).sum())

    def note_screening(self, frame: SlamFrame) -> None:
        """Record whether the screening judged more than ``static_scene_max_dynamic`` of ``frame``'s
        keypoints dynamic (:meth:`scene_static`)."""
        n = len(frame.static)
        if n and int(n - frame.static.sum()) > self.cfg.static_scene_max_dynamic * n:
            self.last_dynamic_frame = frame.index

    def scene_static(self, frame_index: int) -> bool:
        """The screening judged none of the last ``static_scene_frames`` frames up to ``frame_index``
        dynamic (ours): only then do the far points and the dense term ("weak", "auto") engage. They
        assume a static world: with a mover the screening judges only in part they follow it
        (docs/robustness.md "Tracking options and movers"). Without a screener every frame is static."""
        n = self.cfg.static_scene_frames
        return n == 0 or frame_index - self.last_dynamic_frame > n

    def _discard_outliers(self, frame: SlamFrame) -> None:
        frame.map_point_ids[frame.outlier] = -1
        frame.outlier[:] = False

    def _available(self, frame: SlamFrame) -> np.ndarray:
        return frame.static & (frame.map_point_ids < 0)

    def predict_pose(self, timestamp: float | None = None) -> np.ndarray | None:
        """The constant-velocity prediction ``T_c_w = V T_c_w^last`` for the next frame (``V`` the last
        frame-to-frame motion in the camera frame, ``T_c_w^last (T_c_w^before)^-1``), or None.

        With ``velocity_per_second`` and the frame's ``timestamp``, ``V`` is scaled to the frame's interval:
        ``V^s`` with ``s = (timestamp - t_last) / dt_V`` (rotation vector and translation scaled by ``s``; ours)."""
        if self.velocity is None or self.last is None or self.last.T_w_c is None:
            return None
        V = self.velocity
        if self.cfg.velocity_per_second and timestamp is not None and self.velocity_dt > 0:
            s = (float(timestamp) - self.last.timestamp) / self.velocity_dt
            if 0 < s < 10 and s != 1.0:
                V = np.eye(4)
                V[:3, :3] = so3_exp(s * so3_log(self.velocity[:3, :3]))
                V[:3, 3] = s * self.velocity[:3, 3]
        return V @ se3_inv(self.last.T_w_c)

    # --------------------------------------------------------------- stages
    def track_motion_model(self, frame: SlamFrame) -> bool:
        """Constant-velocity prediction, projection matching of the last frame's points, refinement."""
        last = self.last
        if last is None or self.velocity is None or last.T_w_c is None:
            return False
        T_pred = self.predict_pose(frame.timestamp)
        self.predicted_T_c_w = T_pred
        cfg = self.cfg
        found = self._match_last_frame(frame, T_pred, cfg.motion_min_matches)
        if found is None:
            return False
        lidx, pids = found
        n = self._optimize(frame, T_pred)
        if cfg.motion_refine_radius > 0 and n >= cfg.min_track_inliers:
            # Second pass (ours): the pose from the unambiguous matches is accurate to a pixel or
            # two, so every point of the last frame is searched again in a tight window, where the
            # neighbouring copies of a repeated pattern cannot be reached.
            T1 = se3_inv(frame.T_w_c)
            uv, z = self.camera.project(transform_points(T1, self.map.xyz[pids]))
            m2 = self._search_last(frame, last, lidx, pids, uv, z, cfg.motion_refine_radius, 1.0)
            if len(m2) >= n:
                frame.map_point_ids[:] = -1
                frame.map_point_ids[m2.idx_b] = pids[m2.idx_a]
                n = self._optimize(frame, T1)
        self._discard_outliers(frame)
        return n >= cfg.min_track_inliers

    def start_from_reference(self, frame: SlamFrame) -> bool:
        """Start the frame at the screener's reference pose (:attr:`reference_start`, ``start_from_reference``;
        ours): the screener already matched the local map's points around the constant-velocity prediction
        and refined the pose on them robustly (:func:`~dynslam_lab.dynamic.reference_pose.map_reference_pose`),
        which is what the motion model does with the last frame's points. Its inlier matches on keypoints
        judged static become the frame's matches, its pose the frame's pose; the local map search and
        motion-only BA that follow (:meth:`track_local_map`) then refine both as after the motion model.
        False (the motion model runs) without a reference pose or with fewer than ``min_track_inliers``
        such matches."""
        start, self.reference_start = self.reference_start, None
        if not self.cfg.start_from_reference or start is None:
            return False
        T_c_w, kp, ids = start
        keep = frame.static[kp] & self.map.alive[ids]
        if int(keep.sum()) < self.cfg.min_track_inliers:
            return False
        self.predicted_T_c_w = self.predict_pose(frame.timestamp)
        frame.map_point_ids[:] = -1
        frame.map_point_ids[kp[keep]] = ids[keep]
        frame.outlier[:] = False
        frame.T_w_c = se3_inv(T_c_w)
        return True

    def _match_last_frame(self, frame: SlamFrame, T_pred: np.ndarray, min_matches: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Project the last frame's matched points with ``T_pred`` and search them in ``frame`` (radius
        doubled when fewer than ``min_matches``); sets ``frame.map_point_ids``. Returns the last frame's
        keypoints and point ids searched, or None with fewer than ``min_matches`` points or matches."""
        last, cfg = self.last, self.cfg
        lidx = np.flatnonzero((last.map_point_ids >= 0) & ~last.outlier)
        pids = last.map_point_ids[lidx]
        alive = self.map.alive[pids]
        lidx, pids = lidx[alive], pids[alive]
        frame.map_point_ids[:] = -1
        if len(pids) < min_matches:
            return None
        uv, z = self.camera.project(transform_points(T_pred, self.map.xyz[pids]))
        vis = (z > 0) & self.camera.in_image(uv)
        lidx, pids, uv, z = lidx[vis], pids[vis], uv[vis], z[vis]
        for factor in (1.0, 2.0):
            m = self._search_last(frame, last, lidx, pids, uv, z, factor * cfg.motion_radius, cfg.motion_ratio)
            if len(m) >= max(min_matches, 1):
                break
        if len(m) < min_matches:
            return None
        frame.map_point_ids[m.idx_b] = pids[m.idx_a]
        return lidx, pids

    def _dense_depth(self, frame: SlamFrame) -> np.ndarray:
        """``frame``'s depth image as the dense term reads it: averaged over ``dense_smooth_px`` px
        (:func:`~dynslam_lab.geometry.depth_alignment.smooth_depth`; cached for the frame being tracked, which is the next one's
        last frame)."""
        if frame.index not in self._smoothed:
            self._smoothed = {k: v for k, v in self._smoothed.items() if k > frame.index - 2}
            self._smoothed[frame.index] = smooth_depth(frame.depth_image, self.cfg.dense_smooth_px)
        return self._smoothed[frame.index]

    def _depth_source(self, frame: SlamFrame) -> DepthSource:
        """``frame``'s depth samples every ``dense_model_stride`` px with normals (two cells apart, so over
        the same ~``2 dense_stride`` px as the frame-to-frame grid), cells near dynamic keypoints left out."""
        s = self.cfg.dense_model_stride
        grid = vertex_normal_grid(self._dense_depth(frame), self.camera, s, step=max(1, round(self.cfg.dense_stride / s)))
        grid.N[self._dynamic_cells(frame, grid.N.shape[:2], s)] = np.nan
        z = grid.V[..., 2]
        grid.N[~((z >= self.cfg.min_depth) & (z <= self.cfg.max_depth))] = np.nan
        return DepthSource.from_grid(grid, np.eye(4))

    def _note_keyframe_depth(self) -> None:
        """Keep the depth samples of the last frame when it became a keyframe (``dense_reference =
        "keyframes"``), and forget those of keyframes no longer in the map or beyond the most recent
        ``2 dense_model_keyframes``."""
        last, kf = self.last, self.ref_kf
        if (self.cfg.dense_reference != "keyframes" or self.cfg.dense == "off" or last is None or kf is None
                or last.depth_image is None or kf.frame_index != last.index or self.last_kf_frame != last.index
                or kf.id in self._kf_depth):
            return
        src = self._last_depth[1] if self._last_depth is not None and self._last_depth[0] == last.index else self._depth_source(last)
        # T_w_c: the tracked pose relative to the keyframe's pose now (after its first local BA), so that the
        # keyframe's later moves (loop corrections) carry it along (dense_model_pose = "tracked")
        self._kf_depth[kf.id] = DepthSource(src.V, src.N, se3_inv(kf.T_w_c) @ last.T_w_c)
        self._kf_depth = self._recent_keyframes(self._kf_depth, 2 * self.cfg.dense_model_keyframes)

    def _recent_keyframes(self, per_keyframe: dict, n: int) -> dict:
        """``per_keyframe`` (keyframe id -> data) cut to the ``n`` most recent keyframes still in the map."""
        keep = sorted(k for k in per_keyframe if k in self.map.keyframes)[-n:]
        return {k: per_keyframe[k] for k in keep}

    def _note_keyframe_level(self) -> None:
        """Keep the image level of the last frame when it became a keyframe (the joint refinement's reference,
        ``joint_reference = "keyframe"``), and forget those of keyframes no longer in the map or beyond the
        most recent ``JOINT_KEYFRAME_LEVELS``."""
        last, kf, cfg = self.last, self.ref_kf, self.cfg
        if (cfg.joint_reference != "keyframe" or cfg.joint_photometric_scale <= 0 or last is None or kf is None
                or last.gray_image is None or last.depth_image is None or kf.frame_index != last.index
                or kf.id in self._kf_levels):
            return
        self._kf_levels[kf.id] = self._image_level(last, cfg.joint_photometric_scale)
        self._kf_levels = self._recent_keyframes(self._kf_levels, JOINT_KEYFRAME_LEVELS)

    def _joint_reference(self) -> tuple[ImageLevel, np.ndarray]:
        """The image level the joint refinement aligns a frame's edges to, and its ``T_r_w``: the reference
        keyframe's (``joint_reference = "keyframe"``, when its level is kept: its pose is the one local BA keeps
        on the map, so consecutive frames share one anchored reference and do not chain their errors), else the
        last frame's."""
        cfg, kf = self.cfg, self.ref_kf
        if cfg.joint_reference == "keyframe" and kf is not None and kf.id in self._kf_levels and not kf.bad:
            return self._kf_levels[kf.id], se3_inv(kf.T_w_c)
        return self._image_level(self.last, cfg.joint_photometric_scale), se3_inv(self.last.T_w_c)

    def dense_reference_model(self, T_r_w: np.ndarray) -> DepthGrid | None:
        """The reference of the dense term for ``dense_reference = "keyframes"``: the depth samples of the most
        recent ``dense_model_keyframes`` keyframes (at their current poses; the keyframes local BA and loop
        closing optimise against the map, so the model does not follow the last frame's error) fused into a
        grid seen from ``T_r_w`` (:func:`~dynslam_lab.geometry.depth_alignment.fuse_depth_model`), the last frame's samples filling
        the cells none of them reaches (``dense_model_last_frame``). None without any depth."""
        cfg, last = self.cfg, self.last
        kids = [k for k in sorted(self._kf_depth, reverse=True)
                if k in self.map.keyframes and not self.map.keyframes[k].bad][: cfg.dense_model_keyframes]
        sources = []
        for k in kids:
            src = self._kf_depth[k]
            T = self.map.keyframes[k].T_w_c
            sources.append(DepthSource(src.V, src.N, T @ src.T_w_c if cfg.dense_model_pose == "tracked" else T, 0))
        if cfg.dense_model_last_frame and last is not None and last.T_w_c is not None and last.depth_image is not None \
                and not any(self.map.keyframes[k].frame_index == last.index for k in kids):
            if self._last_depth is None or self._last_depth[0] != last.index:
                self._last_depth = (last.index, self._depth_source(last))
            src = self._last_depth[1]
            sources.append(DepthSource(src.V, src.N, last.T_w_c, 1))
        self.dense_model_sources = len(sources)
        if not sources:
            return None
        return fuse_depth_model(sources, T_r_w, self.camera, cfg.dense_stride)[0]

    def _dense_term(self, frame: SlamFrame, T_ref: np.ndarray | None = None) -> DenseTerm | None:
        """The point-to-plane term of ``frame``'s depth (module :mod:`~dynslam_lab.geometry.depth_alignment`) against the last
        frame's depth image (``dense_reference = "frame"``) or the model of recent keyframes' depth
        (``"keyframes"``, :meth:`dense_reference_model`, seen from ``T_ref``, a ``T_c_w`` near the frame's pose;
        the motion prediction when None); None without depth on both sides."""
        last, cfg = self.last, self.cfg
        if frame.depth_image is None or last is None or last.depth_image is None or last.T_w_c is None:
            return None
        X = self.camera.backproject_depth(self._dense_depth(frame), cfg.dense_stride)
        X = X[~self._dynamic_cells(frame, X.shape[:2])]
        X = X[(X[:, 2] >= cfg.min_depth) & (X[:, 2] <= cfg.max_depth)]
        if len(X) < 100:
            return None
        T_pred = self.predict_pose(frame.timestamp)
        if T_pred is None:
            T_pred = se3_inv(last.T_w_c)
        if cfg.dense_reference == "keyframes":
            T_r_w = T_pred if T_ref is None else T_ref
            ref = self.dense_reference_model(T_r_w)
            if ref is None:
                return None
        else:
            if self._dense_grid is None or self._dense_grid[0] != last.index:
                grid = vertex_normal_grid(smooth_depth(last.depth_image, cfg.dense_smooth_px), self.camera, cfg.dense_stride)
                grid.N[self._dynamic_cells(last, grid.N.shape[:2])] = np.nan
                self._dense_grid = (last.index, grid)
            ref, T_r_w = self._dense_grid[1], se3_inv(last.T_w_c)
            self.dense_model_sources = 0
        sigma = cfg.dense_sigma_scale * nguyen_sigma(X[:, 2], 0.0, self._depth_noise)
        term = DenseTerm(X, sigma, ref, T_r_w, self.camera,
                         cfg.dense_max_distance, T_pred, (cfg.dense_prior_translation, cfg.dense_prior_rotation_deg))
        if cfg.dense_view_margin_px >= 0:
            term.charged = term.in_view(T_pred, cfg.dense_view_margin_px)
        return term

    def _dynamic_cells(self, frame: SlamFrame, shape: tuple[int, int], stride: int | None = None) -> np.ndarray:
        """``(h, w)`` bool over the dense grid (``stride`` px, ``dense_stride`` when None): cells whose
        sample pixel lies in the frame's screened region (``dense_mask_region``), and cells within
        ``dense_mask_radius`` px of a keypoint the screening judged dynamic (vectorised: the keypoints'
        cells, dilated by a disc)."""
        s = self.cfg.dense_stride if stride is None else stride
        out = np.zeros(shape, bool)
        dyn = frame.uv[~frame.static]
        if len(dyn) and self.cfg.dense_mask_radius > 0:
            i = np.clip(np.round(dyn[:, 1] / s).astype(np.int64), 0, shape[0] - 1)
            j = np.clip(np.round(dyn[:, 0] / s).astype(np.int64), 0, shape[1] - 1)
            out[i, j] = True
            r = int(np.ceil(self.cfg.dense_mask_radius / s))
            disc = (np.add.outer(np.arange(-r, r + 1) ** 2, np.arange(-r, r + 1) ** 2) <= r * r).astype(np.uint8)
            out = cv2.dilate(out.astype(np.uint8), disc) > 0
        if self.cfg.dense_mask_region and frame.dynamic_region is not None:
            out |= frame.dynamic_region[::s, ::s][: shape[0], : shape[1]]
        return out

    def track_dense(self, frame: SlamFrame) -> bool:
        """Track ``frame`` again with the dense depth term in every motion-only BA (ours, for frames
        with few features): the last frame's points searched around the prediction (no minimum), the
        pose from them and the depth, then the local map with the depth term too. Accepted with
        ``min_track_inliers`` feature inliers and ``dense_min_fraction`` of the depth samples associated."""
        cfg = self.cfg
        term = self._dense_term(frame)
        if term is None:
            return False
        T_pred = term.T_prior
        if self.velocity is not None:
            self.predicted_T_c_w = T_pred
        if cfg.dense_photometric_sigma > 0:
            T_pred = term.T_prior = self.photometric_prediction(frame, term)
        self._dense = term
        try:
            self._match_last_frame(frame, T_pred, 0)
            self._optimize(frame, T_pred)
            self._discard_outliers(frame)
            n = self.track_local_map(frame)
        finally:
            self._dense = None
        T = se3_inv(frame.T_w_c)
        self.dense_fraction = term.associated_fraction(T)
        self.n_inliers = n
        return n >= cfg.dense_min_inliers and self.dense_fraction >= cfg.dense_min_fraction

    def _image_level(self, frame: SlamFrame, scale: int) -> ImageLevel:
        """``frame``'s :class:`~dynslam_lab.geometry.depth_alignment.ImageLevel` at ``scale`` (cached for the frame
        being tracked, which is the next one's last frame), its ``invalid`` pixels those the screening judged
        dynamic (:meth:`_dynamic_cells`): left out of the frame's own samples, and as the reference of a later
        frame no evidence."""
        key = (frame.index, scale)
        if key not in self._levels:
            self._levels = {k: v for k, v in self._levels.items() if k[0] > frame.index - 2}
            level = image_level(frame.gray_image, frame.depth_image, self.camera, scale)
            invalid = self._dynamic_cells(frame, level.I.shape, stride=scale)
            if invalid.any():
                level = replace(level, invalid=invalid)
            self._levels[key] = level
        return self._levels[key]

    def photometric_prediction(self, frame: SlamFrame, term: DenseTerm) -> np.ndarray:
        """The pose ``T_c_w`` that aligns ``frame``'s image edges and depth to the last frame's (ours; the hybrid
        term of Steinbruecker et al. 2011: :class:`~dynslam_lab.geometry.depth_alignment.PhotometricTerm` with
        ``term``'s point-to-plane residuals and its prior), coarse to fine over ``dense_photometric_scales``, from
        ``term``'s prior (the constant-velocity prediction). The prior itself when either frame has no image, or
        no level has 20 pixels with an edge and depth."""
        cfg, last = self.cfg, self.last
        T = term.T_prior
        if T is None or frame.gray_image is None or last is None or last.gray_image is None or last.T_w_c is None:
            return T
        T_r_w = se3_inv(last.T_w_c)
        for scale in cfg.dense_photometric_scales:
            lf, lr = self._image_level(frame, scale), self._image_level(last, scale)
            photo = photometric_term(lf, lr, T_r_w, cfg.dense_photometric_sigma, exclude=lf.invalid,
                                     affine=cfg.photometric_affine)
            if photo is not None:
                T = align_depth(term, T, iterations=10, photometric=photo).T_c_w
        return T

    def _search_last(self, frame: SlamFrame, last: SlamFrame, lidx: np.ndarray, pids: np.ndarray, uv: np.ndarray,
                     z: np.ndarray, radius: float, ratio: float) -> Matches:
        """Projection search of the last frame's points ``pids`` (keypoints ``lidx`` of ``last``),
        predicted at pixels ``uv`` and depths ``z``, within ``radius * f**octave`` px, ratio tested
        on any level, depth-consistent, orientation-consistent."""
        oct_last = last.octave[lidx]
        ok = self.camera.in_image(uv) & (z > 0)
        m = search_by_projection(
            uv[ok], self.map.descriptors[pids[ok]], radius * self.scale_factor**oct_last[ok], oct_last[ok],
            frame.uv, frame.octave, frame.descriptors, kp_available=frame.static, max_distance=TH_HIGH,
            ratio=ratio, ratio_any_level=True, pred_depth=z[ok], kp_depth=frame.depth,
            depth_tolerance=self.cfg.match_depth_tolerance,
        )
        sel = np.flatnonzero(ok)
        m = Matches(sel[m.idx_a], m.idx_b, m.distance)
        if len(m):
            m = m.select(orientation_consistent(last.angle[lidx[m.idx_a]], frame.angle[m.idx_b]))
        return m

    def track_reference_keyframe(self, frame: SlamFrame) -> bool:
        """Descriptor matching against the reference keyframe's map points, PnP-RANSAC, refinement."""
        kf = self.ref_kf
        if kf is None:
            return False
        return self._track_against_keyframe(frame, kf, self.cfg.ref_ratio, self.cfg.min_track_inliers)

    def _track_against_keyframe(self, frame: SlamFrame, kf: KeyFrame, ratio: float, min_inliers: int) -> bool:
        kidx = np.flatnonzero(kf.map_point_ids >= 0)
        kidx = kidx[self.map.alive[kf.map_point_ids[kidx]]]
        fidx = np.flatnonzero(frame.static)
        if len(kidx) < self.cfg.reloc_min_matches or len(fidx) < self.cfg.reloc_min_matches:
            return False
        m = match_descriptors(
            kf.descriptors[kidx], frame.descriptors[fidx], ratio=ratio, max_distance=TH_LOW,
            angle_a=kf.angle[kidx], angle_b=frame.angle[fidx],
        )
        if len(m) < self.cfg.reloc_min_matches:
            return False
        pids = kf.map_point_ids[kidx[m.idx_a]]
        fi = fidx[m.idx_b]
        T, inl = pnp_ransac(self.map.xyz[pids], frame.uv[fi], self.camera.K, self.cfg.pnp_reproj_px, self.cfg.pnp_iterations,
                            seed=frame.index)
        if T is None or inl.sum() < self.cfg.pnp_min_inliers:
            return False
        frame.map_point_ids[:] = -1
        frame.map_point_ids[fi[inl]] = pids[inl]
        n = self._optimize(frame, T)
        self._discard_outliers(frame)
        return n >= min_inliers

    def update_local_map(self, frame: SlamFrame) -> np.ndarray:
        """Local keyframes (sharing points with the frame, plus neighbours) and their points."""
        mp = self.map
        ids = frame.map_point_ids[frame.map_point_ids >= 0]
        counts = mp.keyframes_observing(ids) if len(ids) else {}
        local = sorted(counts, key=lambda k: (-counts[k], k))[: self.cfg.local_max_keyframes]
        if not local and self.ref_kf is not None and self.ref_kf.id in mp.keyframes:
            local = [self.ref_kf.id]
        chosen = list(local)
        seen = set(chosen)
        for k in local:
            if len(chosen) >= self.cfg.local_max_keyframes:
                break
            for nb in mp.best_covisibles(k, self.cfg.local_neighbours):
                if nb not in seen:
                    seen.add(nb)
                    chosen.append(nb)
                    break
        if counts:
            best = local[0]
            self.ref_kf = mp.keyframes[best]
        self.local_kf_ids = chosen
        return mp.points_of(chosen)

    def track_local_map(self, frame: SlamFrame) -> int:
        """Project the local map into the frame, search, refine; returns the inlier count."""
        mp = self.map
        local_pts = self.update_local_map(frame)
        matched = frame.map_point_ids[frame.map_point_ids >= 0]
        mp.n_visible[matched] += 1
        cand = np.setdiff1d(local_pts, matched, assume_unique=False)
        T_c_w = se3_inv(frame.T_w_c)
        ids, uv, lvl, cos = frustum_candidates(mp, cand, T_c_w, self.camera, self.cfg.view_cos)
        mp.n_visible[ids] += 1
        th = self.cfg.local_radius + (2.0 if frame.index - self.last_reloc_frame < 2 else 0.0)
        radius = th * np.where(cos > 0.998, 2.5, 4.0) * self.scale_factor**lvl
        z = transform_points(T_c_w, mp.xyz[ids])[:, 2]
        m = search_by_projection(
            uv, mp.descriptors[ids], radius, lvl, frame.uv, frame.octave, frame.descriptors,
            kp_available=self._available(frame), max_distance=TH_HIGH, ratio=self.cfg.local_ratio,
            ratio_any_level=self.cfg.local_ratio_any_level, pred_depth=z, kp_depth=frame.depth,
            depth_tolerance=self.cfg.match_depth_tolerance,
        )
        frame.map_point_ids[m.idx_b] = ids[m.idx_a]
        n = self._optimize(frame, T_c_w)
        inl = frame.matched()
        mp.n_found[frame.map_point_ids[inl]] += 1
        self._discard_outliers(frame)
        return n

    def relocalisation_candidates(self, frame: SlamFrame) -> list[int]:
        """Keyframe ids to try for a lost frame, most promising first.

        With a keyframe database and a vocabulary (:attr:`database`, :attr:`vocabulary`, shared
        with the loop closer) the frame's BoW vector from its static keypoints is queried
        (ORB-SLAM2 ``DetectRelocalizationCandidates``: keyframes sharing words, scored, grouped
        with their 10 best covisible keyframes, groups above 0.75 x the best kept), at most
        ``reloc_candidates`` of them. Without a database, brute force: the ``reloc_candidates / 2``
        most recent keyframes, then evenly spaced ones.
        """
        mp = self.map
        kfs = sorted(mp.keyframes)
        if not kfs:
            return []
        n = self.cfg.reloc_candidates
        if self.database is not None and self.vocabulary is not None and len(self.database):
            bow = static_bow(self.vocabulary, frame)
            if len(bow) == 0:
                return []
            memo: dict[int, list[int]] = {}

            def best(i: int) -> list[int]:
                if i not in memo:
                    memo[i] = mp.best_covisibles(i, 10) if i in mp.keyframes else []
                return memo[i]

            culled = [k for k in self.database.ids() if k not in mp.keyframes]
            cands = self.database.detect_relocalisation_candidates(bow, neighbours=best, exclude=culled)
            return [c.kf_id for c in cands][:n]
        recent = kfs[-(n // 2) :]
        spread = [kfs[i] for i in np.linspace(0, len(kfs) - 1, n - len(recent)).astype(int)] if len(kfs) > len(recent) else []
        return list(dict.fromkeys(recent[::-1] + spread))

    def relocalize(self, frame: SlamFrame) -> bool:
        """Match the frame to candidate keyframes (:meth:`relocalisation_candidates`), PnP-RANSAC,
        motion-only BA and the local map; the first candidate reaching ``min_local_inliers_reloc``
        inliers wins."""
        cands = self.relocalisation_candidates(frame)
        self.last_reloc_candidates = cands
        for kid in cands:
            if self._track_against_keyframe(frame, self.map.keyframes[kid], self.cfg.reloc_ratio, self.cfg.pnp_min_inliers):
                self.ref_kf = self.map.keyframes[kid]
                if self.track_local_map(frame) >= self.cfg.min_local_inliers_reloc:
                    self.last_reloc_frame = frame.index
                    return True
            frame.map_point_ids[:] = -1
            frame.T_w_c = None
        return False

    # ------------------------------------------------------------------ main
    def track(self, frame: SlamFrame) -> str:
        """Estimate ``frame.T_w_c`` (None when lost); returns the new state."""
        cfg = self.cfg
        ok = False
        self.method = ""
        self.note_screening(frame)
        self._note_keyframe_depth()
        self._note_keyframe_level()
        self.predicted_T_c_w = None
        self.motion_deviation = (0.0, 0.0)
        if self.state in (TrackState.OK, TrackState.RELOCALIZED):
            if cfg.dense == "always" and self.track_dense(frame):
                ok, self.method = True, "dense"
            else:
                ok = self._track_features(frame)
                if self._needs_dense(frame, ok):
                    kept = (frame.T_w_c, frame.map_point_ids.copy(), frame.outlier.copy(), self.n_inliers, self.ref_kf,
                            self.method)
                    frame.outlier[:] = False
                    if self.track_dense(frame):
                        ok, self.method = True, "dense"
                    elif ok:  # the feature-only pose stands
                        frame.T_w_c, frame.map_point_ids, frame.outlier, self.n_inliers, self.ref_kf, self.method = kept
                    else:
                        self.method = ""
                elif ok and self._needs_joint(frame):
                    self.refine_joint(frame)
            state = TrackState.OK if ok else TrackState.LOST
        else:
            ok = self.relocalize(frame)
            self.method = "relocalization" if ok else ""
            self.n_inliers = int(frame.matched().sum()) if ok else 0
            state = TrackState.RELOCALIZED if ok else TrackState.LOST
        if ok:
            if self.predicted_T_c_w is not None:
                self.motion_deviation = pose_distance(self.predicted_T_c_w @ frame.T_w_c)
            if self.last is not None and self.last.T_w_c is not None and frame.index - self.last.index == 1:
                V = se3_inv(frame.T_w_c) @ self.last.T_w_c
                V[:3, :3] = nearest_rotation(V[:3, :3])
                self.velocity = V
                self.velocity_dt = frame.timestamp - self.last.timestamp
            else:
                self.velocity = None
            self.last = frame
        else:
            frame.T_w_c = None
            frame.map_point_ids[:] = -1
            self.velocity = None
        self.state = state
        return state

    def _needs_dense(self, frame: SlamFrame, ok: bool) -> bool:
        """Whether a frame the features tracked (``ok``) or failed is tracked again with the dense term:
        ``"weak"``: failed or fewer than ``dense_below_inliers`` inliers; ``"auto"``: failed, or fewer
        inliers *and* a pose the graceful-failure guard calls suspect (farther than ``suspect_translation``
        / ``suspect_rotation_deg`` from the constant-velocity prediction: a few features on a plain wall or
        a repeated pattern that jumped). Neither while the scene is not judged static (:meth:`scene_static`) nor
        on a frame with ``dense_max_keypoints`` keypoints with depth or more. Ours, docs/tracking.md "Dense
        depth term, automatic"."""
        cfg = self.cfg
        if cfg.dense in ("off", "always") or not (cfg.dense_in_dynamic_scenes or self.scene_static(frame.index)):
            return False
        if cfg.dense_max_keypoints and int(np.isfinite(frame.depth).sum()) >= cfg.dense_max_keypoints:
            return False  # texture enough: the features failed for another reason (a mover took them)
        if not ok:
            return True
        if self.n_inliers >= cfg.dense_below_inliers:
            return False
        if cfg.dense == "weak":
            return True
        if self.predicted_T_c_w is None or frame.T_w_c is None:
            return False
        return self._off_prediction(*pose_distance(self.predicted_T_c_w @ frame.T_w_c))

    def feature_pose_uncertainty(self, frame: SlamFrame) -> tuple[float, float]:
        """``(m, deg)``: how uncertain ``frame``'s pose is from its matched points alone
        (:func:`~.optimize.pose_uncertainty`: the largest standard deviation of the camera centre and
        orientation of motion-only BA at one pixel of noise)."""
        idx = np.flatnonzero(frame.map_point_ids >= 0)
        if frame.T_w_c is None or len(idx) < 3:
            return float("inf"), float("inf")
        return pose_uncertainty(se3_inv(frame.T_w_c), self.map.xyz[frame.map_point_ids[idx]], self._obs(frame, idx),
                                self.camera, self.cfg.bf)

    def _needs_joint(self, frame: SlamFrame) -> bool:
        """Whether a frame the features tracked is refined with the dense term as well (:meth:`refine_joint`):
        ``"weak"`` or ``"auto"``, the scene judged static (:meth:`scene_static`), and ``joint_every_frame`` or a
        feature pose whose uncertainty (:meth:`feature_pose_uncertainty`) reaches ``joint_position_sigma`` or
        ``joint_rotation_deg``: matches clustered on a few objects of a plain room. Ours, docs/tracking.md
        "Weak feature poses: features and depth together" and "Image edges against the corners' jitter"."""
        cfg = self.cfg
        if cfg.dense not in ("weak", "auto") or not self.scene_static(frame.index):
            return False
        if cfg.joint_every_frame:
            return True
        if cfg.joint_position_sigma <= 0 and cfg.joint_rotation_deg <= 0:
            return False
        s_c, s_r = self.feature_pose_uncertainty(frame)
        return (0 < cfg.joint_position_sigma <= s_c) or (0 < cfg.joint_rotation_deg <= s_r)

    def refine_joint(self, frame: SlamFrame) -> bool:
        """``frame``'s pose from its feature matches together with the dense depth term (its depth image against
        the last frame's, :mod:`~dynslam_lab.geometry.depth_alignment`; with the photometric term only when
        ``joint_depth``) and, with ``joint_photometric_scale``, the photometric term (its image edges against the
        reference image of :meth:`_joint_reference`: :class:`~dynslam_lab.geometry.depth_alignment.HybridTerm`),
        from the feature pose. ``joint_gn_iterations`` > 0: that many Gauss-Newton steps over the feature inliers as
        they are; 0: a motion-only BA with its outlier rounds (always with the depth term), kept when
        ``min_track_inliers`` matches stay inliers. Kept (method ``"joint"``) when ``dense_min_fraction`` of the
        depth samples are associated (when there is a depth term); otherwise the feature pose stands."""
        cfg = self.cfg
        term = depth = None
        if cfg.joint_depth or cfg.joint_photometric_scale <= 0 or cfg.joint_gn_iterations <= 0:
            term = depth = self._dense_term(frame, se3_inv(frame.T_w_c))
            if term is None:
                return False
            term = depth = term.every(cfg.joint_dense_step)
        if cfg.joint_photometric_scale > 0 and frame.gray_image is not None and self.last.gray_image is not None:
            k = cfg.joint_photometric_scale
            lf = self._image_level(frame, k)
            lr, T_r_w = self._joint_reference()
            photo = photometric_term(lf, lr, T_r_w, cfg.joint_photometric_sigma,
                                     exclude=lf.invalid,
                                     max_samples=cfg.joint_photometric_samples, affine=cfg.photometric_affine)
            if photo is not None:
                term = HybridTerm(depth, photo)
        if term is None:
            return False
        if cfg.joint_gn_iterations > 0:
            idx = np.flatnonzero(frame.map_point_ids >= 0)  # the feature pose's inliers (outliers were discarded)
            if len(idx) < cfg.min_track_inliers:
                return False
            T, _ = optimize_pose(se3_inv(frame.T_w_c), self.map.xyz[frame.map_point_ids[idx]], self._obs(frame, idx),
                                 self.camera, cfg.bf, rounds=1, max_iterations=cfg.joint_gn_iterations, dense=term,
                                 damped=False)
            fraction = depth.associated_fraction(T) if depth is not None else 1.0
            if fraction < cfg.dense_min_fraction or not self._joint_move_allowed(frame, idx, T):
                return False  # a refinement is a nudge: a jump says the image disagrees with the features
            frame.T_w_c = se3_inv(T)
            self.dense_fraction, self.method = fraction, "joint"
            return True
        kept = (frame.T_w_c, frame.map_point_ids.copy(), frame.outlier.copy(), self.n_inliers)
        self._dense = term
        try:
            n = self._optimize(frame, se3_inv(frame.T_w_c))
        finally:
            self._dense = None
        T = se3_inv(frame.T_w_c)
        fraction = depth.associated_fraction(T)
        if n < cfg.min_track_inliers or fraction < cfg.dense_min_fraction:
            # rolled back: the feature pose, its matches and their outlier flags as they were (the joint BA's
            # outlier marks must not survive to drop matches of the feature pose)
            frame.T_w_c, frame.map_point_ids, frame.outlier, self.n_inliers = kept
            return False
        self._discard_outliers(frame)
        self.dense_fraction, self.n_inliers, self.method = fraction, n, "joint"
        return True

    def _joint_move_allowed(self, frame: SlamFrame, idx: np.ndarray, T_c_w: np.ndarray) -> bool:
        """Whether the joint refinement may move ``frame``'s feature pose to ``T_c_w``: within ``JOINT_MAX_STEP``, or
        (``joint_gate_chi2`` > 0) by a step whose squared Mahalanobis length under the Gauss-Newton information of
        the feature inliers ``idx`` (:func:`~.optimize.pose_step_mahalanobis`) is at most ``joint_gate_chi2``: to
        second order, what the move adds to the features' cost. Features spread over the image pin the pose (a centimetre
        is far outside what they allow); a few far corners in a band of a plain room leave centimetres free along
        some directions, and there the image may move the pose (ours)."""
        moved_m, moved_deg = pose_distance(T_c_w @ frame.T_w_c)
        if moved_m <= JOINT_MAX_STEP[0] and moved_deg <= JOINT_MAX_STEP[1]:
            return True
        if self.cfg.joint_gate_chi2 <= 0:
            return False
        d2 = pose_step_mahalanobis(se3_inv(frame.T_w_c), T_c_w, self.map.xyz[frame.map_point_ids[idx]],
                                   self._obs(frame, idx), self.camera, self.cfg.bf)
        return d2 <= self.cfg.joint_gate_chi2

    def _track_features(self, frame: SlamFrame) -> bool:
        """ORB-SLAM2's tracking of a frame: motion model (else reference keyframe), then the local map;
        the screener's reference pose in place of the motion model when there is one (:meth:`start_from_reference`)."""
        cfg = self.cfg
        if self.velocity is not None and self.start_from_reference(frame):
            ok, self.method = True, "reference_pose"
        elif self.velocity is not None and self.track_motion_model(frame):
            ok, self.method = True, "motion_model"
        else:
            frame.map_point_ids[:] = -1
            ok = self.track_reference_keyframe(frame)
            self.method = "reference_keyframe" if ok else ""
        if ok:
            n = self.track_local_map(frame)
            need = cfg.min_local_inliers_reloc if frame.index - self.last_reloc_frame < cfg.kf_max_frames else cfg.min_local_inliers
            ok = n >= need
            self.n_inliers = n
        return ok

    @property
    def suspect(self) -> bool:
        """The last tracked pose landed implausibly far from the constant-velocity prediction (a camera
        does not accelerate by centimetres or degrees within a frame; tracking that latched onto a
        moving object does). Ours, for graceful failure (issue: failure is expensive)."""
        if 0 < self.cfg.suspect_trusted_inliers <= self.n_inliers:
            return False
        return self._off_prediction(*self.motion_deviation)

    def _off_prediction(self, dt: float, dr: float) -> bool:
        """A deviation ``(m, deg)`` from the constant-velocity prediction beyond the suspect thresholds."""
        return dt > self.cfg.suspect_translation or dr > self.cfg.suspect_rotation_deg

    def in_bad_stretch(self, frame_index: int) -> bool:
        """At least ``flood_keyframes`` of the last ``flood_window`` frames asked for a keyframe: the
        keyframe flood of a tracker following a mover (each new keyframe's points move away at once).
        Ours, for graceful failure."""
        return sum(frame_index - f < self.cfg.flood_window for f in self.kf_demand_frames) >= self.cfg.flood_keyframes

    def need_keyframe(self, frame: SlamFrame) -> bool:
        """ORB-SLAM2 ``NeedNewKeyFrame`` for RGB-D with local mapping always idle, with our guards for
        graceful failure: no keyframe on a :attr:`suspect` pose, and during a bad stretch
        (:meth:`in_bad_stretch`) at least ``flood_min_gap`` frames between keyframes, unless the frame was
        tracked by depth alone with almost no map point (fewer than 5, the keyframe asked for by its many new
        close keypoints: a plain wall giving way to an unmapped part of the room; a mover is tracked by its
        features, not there): without that keyframe the next frame has no map to track. Ours."""
        need = self._need_keyframe(frame)
        if need:
            self.kf_demand_frames = [f for f in self.kf_demand_frames if frame.index - f < self.cfg.flood_window]
            self.kf_demand_frames.append(frame.index)
            if self.suspect:
                return False
            mapless = self.method == "dense" and self.n_inliers < _DENSE_KF_MIN_INLIERS
            if (self.in_bad_stretch(frame.index) and frame.index - self.last_kf_frame < self.cfg.flood_min_gap
                    and not mapless):
                return False
        return need

    def _need_keyframe(self, frame: SlamFrame) -> bool:
        cfg = self.cfg
        if frame.T_w_c is None or self.ref_kf is None:
            return False
        mp = self.map
        n_kfs = len(mp.keyframes)
        since = frame.index - self.last_kf_frame
        if frame.index - self.last_reloc_frame < cfg.kf_max_frames and n_kfs > cfg.kf_max_frames:
            return False
        # ORB-SLAM2 counts an RGB-D observation twice (nMinObs 2 / 3 -> keyframes 1 / 2).
        min_obs = 1 if n_kfs <= 2 else cfg.kf_ref_min_obs
        ref_ids = self.ref_kf.map_point_ids[self.ref_kf.map_point_ids >= 0]
        ref_ids = ref_ids[mp.alive[ref_ids]]
        n_ref = int((mp.n_obs(ref_ids) >= min_obs).sum()) if len(ref_ids) else 0
        close = frame.static & (frame.depth < cfg.th_depth * cfg.bf / self.camera.fx)
        tracked_close = int((close & (frame.map_point_ids >= 0)).sum())
        untracked_close = int((close & (frame.map_point_ids < 0)).sum())
        need_close = tracked_close < cfg.kf_close_tracked and untracked_close > cfg.kf_close_untracked
        ratio = 0.4 if n_kfs < 2 else cfg.kf_ref_ratio
        n = self.n_inliers
        c1 = since >= cfg.kf_max_frames or since >= cfg.kf_min_frames
        c1c = n < 0.25 * n_ref or need_close
        # a dense-tracked frame (few features, ours) may make a keyframe with fewer inliers (a few, to tie it
        # to the map), or none when it sees many new close points (the map starts again from the pose the
        # depth gave): else the map cannot grow over a stretch of plain walls
        enough = n > cfg.kf_min_inliers or (self.method == "dense" and (n >= _DENSE_KF_MIN_INLIERS or need_close))
        c2 = (n < ratio * n_ref or need_close) and enough
        return bool((c1 or c1c) and c2)
