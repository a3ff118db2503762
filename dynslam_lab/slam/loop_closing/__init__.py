"""Loop closing (ORB-SLAM2, Mur-Artal and Tardos 2017, Sec. V): detection, verification, correction.

* :mod:`.detection`: keyframe-database candidates and temporal consistency (``DetectLoop``);
* :mod:`.verification`: RANSAC, map matches, refinement and the checks that keep false loops out;
* :mod:`.correction`: snapshot, essential graph, global BA, applied between frames (worker thread);
* :mod:`.closer`: :class:`LoopCloser`, the stage the system calls for each new keyframe;
* :mod:`.place_recognition`: precision/recall of loop candidates against the truth (DBoW2's measure).

See ``docs/loop_closing.md``.
"""

from .closer import LoopCloser, LoopResult
from .config import LoopClosingConfig
from .correction import apply_correction, essential_graph, run_global_ba, run_loop_correction, take_snapshot
from .detection import LoopDetector, consistent_candidates
from .verification import (
    CandidateCheck,
    LoopVerification,
    correction_size,
    depth_spread,
    image_spread,
    match_points_3d,
    neighbour_agreement,
    path_length,
    refine_loop_pose,
    verify_candidate,
    verify_loop,
)

__all__ = [
    "LoopCloser",
    "LoopResult",
    "LoopClosingConfig",
    "LoopDetector",
    "consistent_candidates",
    "LoopVerification",
    "CandidateCheck",
    "verify_loop",
    "verify_candidate",
    "match_points_3d",
    "refine_loop_pose",
    "image_spread",
    "depth_spread",
    "path_length",
    "correction_size",
    "neighbour_agreement",
    "take_snapshot",
    "essential_graph",
    "run_loop_correction",
    "run_global_ba",
    "apply_correction",
]
