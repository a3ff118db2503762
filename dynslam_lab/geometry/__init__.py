"""Rigid-body geometry: SE(3) helpers, quaternions, alignment."""
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
]
