"""Parameters of loop closing (one frozen dataclass for detection, verification and correction)."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..keyframe_database import CandidateQueryConfig
from ..pose_graph import PoseGraphConfig

__all__ = ["LoopClosingConfig"]


@dataclass(frozen=True)
class LoopClosingConfig:
    """Parameters of loop closing (ORB-SLAM2 ``LoopClosing.cc`` unless noted)."""

    enabled: bool = True  # run loop closing at all (``--no-loop`` turns it off)
    # --- detection (ORB-SLAM2 DetectLoop)
    min_keyframes_between: int = 10  # no loop search in the first / after a loop for this many keyframes; ORB-SLAM2: 10
    max_verified: int = 3  # verify only this many consistent candidates per keyframe, best accumulated score first; 0 = all (ORB-SLAM2: all; ORB-SLAM3 DetectNBestCandidates: 3). 3: the same loops and trajectories as 0 on loop_noise/photo/pattern/flat seeds 0-2 (at most 2 consistent candidates a keyframe there), zero loops without a revisit, the loop stage at 1000 keyframes of the hard case bounded (docs/loop_closing.md "Speed of the loop stage")
    consistency_threshold: int = 2  # consecutive consistent detections; ORB-SLAM2 mnCovisibilityConsistencyTh: 3, ours 2: measured with the low-texture tracking options (tracking.new_point_depth = 8, dense = "auto"; the defaults, engaged while the screening judges the scene static), whose far points make fewer keyframes on the way back, 3 missed the revisit at the end of a loop by one keyframe (docs/loop_closing.md "Unseen scenes: the loop found")
    min_neighbour_weight: int = 15  # covisibility weight of the neighbours giving s_min; ORB-SLAM2 connection threshold: 15
    exclude: str = "covisible"  # keyframes never candidates: "covisible" (any shared point; ours) or "connected" (weight >= 15; ORB-SLAM2)
    # --- verification (ORB-SLAM2 ComputeSim3, SE(3) for RGB-D)
    match_ratio: float = 0.75  # best/second Hamming ratio of the loop matches; ORB-SLAM2 ComputeSim3: 0.75
    min_matches: int = 20  # descriptor matches needed before RANSAC; ORB-SLAM2: 20
    min_inliers: int = 20  # RANSAC inliers of the relative pose; ORB-SLAM2 Sim3Solver minInliers: 20
    ransac_iterations: int = 1000  # RANSAC hypotheses; ORB-SLAM2 Sim3Solver: 300, ours 1000: with 36 true inliers of 197 matches (a repeated pattern) 300 samples miss an all-inlier triple 17 % of the time, and a copy of the pattern one period away (20 inliers, 44 cm off) won (docs/loop_closing.md "Unseen scenes: the loop found")
    inlier_abs: float = 0.02  # 3D inlier tolerance at zero depth (m); ours (ORB-SLAM2 tests pixels, chi2 9.21)
    inlier_rel: float = 0.02  # 3D inlier tolerance growing with depth (m per m); ours, RGB-D depth noise
    min_map_matches: int = 40  # matches of the loop group's map points after the pose; ORB-SLAM2: 40
    refine_rounds: int = 2  # motion-only BA of the query pose on the loop group's points, then re-matching; ours (ORB-SLAM2: OptimizeSim3 once)
    loop_group_size: int = 10  # covisible neighbours of the loop keyframe whose points are matched; ORB-SLAM2: 10
    # --- verification on static evidence spread over the scene (ours; docs/loop_closing.md, "No false loops")
    spread_grid: int = 4  # the image is cut into spread_grid x spread_grid cells for the spread test (ours)
    min_spread: float = 0.35  # map matches must cover this share of the cells holding the query's static keypoints with depth (ours)
    min_depth_spread: float = 0.3  # map matches' depths: 10-90 % range at least this (m): not one flat object (ours)
    neighbour_checks: int = 2  # best covisible neighbours of the query that must agree with the loop pose too (ours)
    min_neighbour_matches: int = 30  # loop-group map points each of those neighbours must match under the corrected pose (ours)
    max_loop_sigma: float = 0.010  # m: a loop pose must fix the query camera's centre within this standard deviation (its map matches, one pixel of noise: optimize.pose_uncertainty), else it waits for a better-conditioned one; 0 = no test; ours, docs/loop_closing.md "A loop pose the matches determine"
    defer_keyframes: int = 3  # keyframes a loop that failed only max_loop_sigma waits for a better-conditioned one before it is closed as it is; ours
    dense_factor: int = 8  # an accepted loop pose is refined on its map matches and the query's depth together: depth reduced this many times per side, point-to-plane against the loop keyframe's (each keyframe keeps its reduced depth, movers left out: 19 kB at 640x480); 0 = off (features only); ours, docs/loop_closing.md "The loop pose refined with depth"
    drift_abs: float = 0.05  # correction translation allowed without travel (m); ours
    drift_rel: float = 0.1  # ... plus this per metre of odometry path between the two keyframes (ORB-SLAM-class drift: ~1 %); ours
    drift_rot_abs: float = 3.0  # correction rotation allowed without travel (deg); ours
    drift_rot_rel: float = 3.0  # ... plus this per metre of odometry path (deg per m); ours
    # --- correction (ORB-SLAM2 CorrectLoop, OptimizeEssentialGraph, RunGlobalBundleAdjustment)
    loop_edge_weight: float = 1.0  # weight of loop edges relative to odometry edges (ours; ORB-SLAM2: 1)
    fuse_points: bool = True  # fuse the matched map points of the two sides; ORB-SLAM2: always
    global_ba: bool = False  # full bundle adjustment after the pose graph; ORB-SLAM2: yes (in a thread); ours: off, measured on the unseen loop rooms (with the photometric tracking of plain walls the pose graph alone places every loop_flat seed within 20 mm, while the BA bent the plain room's map by up to 3 deg, and it gains 3-4 mm on loop_pattern), docs/loop_closing.md "Keyframes the global BA cannot place"
    global_ba_iterations: int = 10  # solver iterations of the global BA; ours (ORB-SLAM2: 10 g2o iterations)
    global_ba_part_weight: int = 0  # shared points that join two keyframes into one rigid part of the map; > 0: after the global BA, each part without a held keyframe is moved rigidly back onto the pose graph's poses of its keyframes (the BA refines inside the parts that share points, the pose graph, with its depth-measured edges, places the parts: on a plain room's far wall the BA turned a part by 3 deg across the wall's weak links); 0 = off (ORB-SLAM2); ours, docs/loop_closing.md "Keyframes the global BA cannot place"
    global_ba_min_observations: int = 30  # keyframes observing fewer points (tracking.min_local_inliers: 30) are held in the global BA (their pose stays the pose graph's); ours (ORB-SLAM2 moves every keyframe): a depth-tracked keyframe on a plain wall with ~5 points swung 42 cm / 12 deg (docs/loop_closing.md "Unseen scenes: the loop found"); 0 = none held
    background: bool = True  # pose graph and global BA in a worker thread, applied between frames; ORB-SLAM2: its own threads
    seed: int = 0  # RANSAC random generator seed (ours)
    query: CandidateQueryConfig = field(default_factory=CandidateQueryConfig)
    pose_graph: PoseGraphConfig = field(default_factory=PoseGraphConfig)

    def __post_init__(self) -> None:
        if self.exclude not in ("covisible", "connected"):
            raise ValueError(f"LoopClosingConfig.exclude must be 'covisible' or 'connected', got {self.exclude!r}")
        if not 0 < self.match_ratio <= 1:
            raise ValueError(f"LoopClosingConfig.match_ratio must be in (0, 1], got {self.match_ratio}")
        for name in ("min_matches", "min_inliers", "ransac_iterations", "min_map_matches", "consistency_threshold",
                     "spread_grid"):
            if getattr(self, name) < 1:
                raise ValueError(f"LoopClosingConfig.{name} must be >= 1, got {getattr(self, name)}")
        if self.min_inliers < 3:
            raise ValueError(f"LoopClosingConfig.min_inliers must be >= 3 (a rigid pose needs 3 points), got {self.min_inliers}")
        if self.inlier_abs < 0 or self.inlier_rel < 0 or self.inlier_abs + self.inlier_rel <= 0:
            raise ValueError(
                f"LoopClosingConfig inlier tolerance must be positive, got inlier_abs={self.inlier_abs}, "
                f"inlier_rel={self.inlier_rel}"
            )
        for name in ("refine_rounds", "min_keyframes_between", "loop_group_size", "neighbour_checks",
                     "min_neighbour_matches", "global_ba_iterations", "global_ba_min_observations", "global_ba_part_weight", "max_verified",
                     "defer_keyframes", "dense_factor"):
            if getattr(self, name) < 0:
                raise ValueError(f"LoopClosingConfig.{name} must be >= 0, got {getattr(self, name)}")
        if not 0 <= self.min_spread <= 1:
            raise ValueError(f"LoopClosingConfig.min_spread must be in [0, 1], got {self.min_spread}")
        for name in ("min_depth_spread", "drift_abs", "drift_rel", "drift_rot_abs", "drift_rot_rel"):
            if getattr(self, name) < 0:
                raise ValueError(f"LoopClosingConfig.{name} must be >= 0, got {getattr(self, name)}")
        if not self.max_loop_sigma >= 0:
            raise ValueError(f"LoopClosingConfig.max_loop_sigma must be >= 0 (m; 0 = no test), got {self.max_loop_sigma}")
        if self.loop_edge_weight <= 0:
            raise ValueError(f"LoopClosingConfig.loop_edge_weight must be > 0, got {self.loop_edge_weight}")
