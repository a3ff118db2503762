"""Geometry shared by every stage: SE(3) poses and quaternions (:mod:`.se3`), point-set
alignment and 3D RANSAC (:mod:`.align`), PnP-RANSAC (:mod:`.pnp`), the epipolar distance
(:mod:`.epipolar`), the pinhole projection's Jacobian (:mod:`.projection`) and dense depth alignment
(:mod:`.depth_alignment`)."""
from .se3 import (
    make_pose,
    se3_inv,
    transform_points,
    relative_pose,
    quat_xyzw_to_matrix,
    matrix_to_quat_xyzw,
    pose_from_tum,
    pose_to_tum,
    so3_exp,
    so3_log,
    rotation_angle_deg,
    nearest_rotation,
)

__all__ = [
    "make_pose",
    "se3_inv",
    "transform_points",
    "relative_pose",
    "quat_xyzw_to_matrix",
    "matrix_to_quat_xyzw",
    "pose_from_tum",
    "pose_to_tum",
    "so3_exp",
    "so3_log",
    "rotation_angle_deg",
    "nearest_rotation",
]
