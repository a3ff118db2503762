"""Camera paths of the synthetic presets and the times of their frames.

The motions mirror the TUM fr3 sequences (``static``, ``xyz``, ``rpy``, ``halfsphere``) plus a
closed ``loop`` round the room; :func:`camera_pose` gives the camera pose ``T_w_c`` at any time,
so the 100 Hz ground truth and the 30 Hz colour frames come from the same smooth function.
"""

from __future__ import annotations

import numpy as np

from ..geometry.se3 import so3_exp
from .office import VIEW_EYE, VIEW_TARGET
from .shapes import look_at, pose, rot_x, rot_y, rot_z

__all__ = ["frame_times", "camera_pose"]


# ---------------------------------------------------------------------------- time
def frame_times(n_frames: int) -> np.ndarray:
    """Times (s from the start) of ``n_frames`` colour frames at 30 Hz on the 100 Hz ground-truth grid.

    Frame ``i`` is taken at ``round(i * 100 / 30) / 100`` s (intervals of 30, 40, 30 ms), so every
    colour frame has an exact ground-truth pose in the 100 Hz ``groundtruth.txt``.
    """
    return np.round(np.arange(n_frames) * 100.0 / 30.0) / 100.0


# -------------------------------------------------------------------- camera paths
def _base_rotation() -> np.ndarray:
    return look_at(VIEW_EYE, VIEW_TARGET)[:3, :3]


def camera_pose(motion: str, t: float, duration: float) -> np.ndarray:
    """Camera pose ``T_w_c (4, 4)`` of a motion preset at time ``t`` (s) of a ``duration`` s sequence.

    * ``static``: the fixed view with a hand-held tremor of ~2 mm and ~0.1 deg;
    * ``xyz``: translations along the camera axes, amplitudes 0.4 / 0.25 / 0.3 m (x / y / z);
    * ``rpy``: rotations about the camera axes: pitch 12 deg, yaw 20 deg, roll 15 deg;
    * ``halfsphere``: on a sphere of radius 0.5 m, azimuth +-60 deg, elevation 0..40 deg, looking at the desk;
    * ``loop``: round a circle of radius 0.85 m in the room centre, looking outwards, once in ``duration``
      with zero speed at both ends: the last pose equals the first.
    """
    w = 2 * np.pi
    R0 = _base_rotation()
    if motion == "static":
        dt = 0.002 * np.array([np.sin(w * 0.7 * t), np.sin(w * 0.45 * t + 1), np.sin(w * 0.3 * t + 2)])
        dr = np.radians(0.1) * np.array([np.sin(w * 0.5 * t + 3), np.sin(w * 0.35 * t), np.sin(w * 0.6 * t + 1)])
        return pose(R0 @ so3_exp(dr), VIEW_EYE + R0 @ dt)
    if motion == "xyz":
        dt = np.array([0.4 * np.sin(w * t / 10.0), 0.25 * np.sin(w * t / 8.0 + 0.5), 0.3 * np.sin(w * t / 12.0 + 1.0)])
        dt -= np.array([0.0, 0.25 * np.sin(0.5), 0.3 * np.sin(1.0)])  # start at the base view
        dr = np.radians(2.0) * np.array([np.sin(w * t / 7.0), np.sin(w * t / 9.0), 0.0])
        return pose(R0 @ so3_exp(dr), VIEW_EYE + R0 @ dt)
    if motion == "rpy":
        ang = np.radians([12.0 * np.sin(w * t / 7.0), 20.0 * np.sin(w * t / 9.0), 15.0 * np.sin(w * t / 11.0)])
        dt = 0.02 * np.array([np.sin(w * t / 5.0), np.sin(w * t / 6.0), np.sin(w * t / 4.0)])
        R = R0 @ rot_x(ang[0]) @ rot_y(ang[1]) @ rot_z(ang[2])
        return pose(R, VIEW_EYE + dt)
    if motion == "halfsphere":
        phi = np.radians(60.0) * np.sin(w * t / 12.0)
        theta = np.radians(20.0) * (1.0 - np.cos(w * t / 9.0))
        fwd = VIEW_TARGET - VIEW_EYE
        fwd[2] = 0.0
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        centre = VIEW_EYE + 0.5 * fwd
        eye = centre + 0.5 * (np.cos(theta) * (np.sin(phi) * right - np.cos(phi) * fwd) + np.sin(theta) * np.array([0, 0, 1.0]))
        return look_at(eye, VIEW_TARGET)
    if motion == "loop":
        tau = np.clip(t / max(duration, 1e-9), 0.0, 1.0)
        alpha = np.pi / 2 + 2 * np.pi * (tau - np.sin(2 * np.pi * tau) / (2 * np.pi))
        centre = np.array([0.0, 0.1, 1.4])
        eye = centre + 0.85 * np.array([np.cos(alpha), np.sin(alpha), 0.0])
        target = eye + np.array([np.cos(alpha), np.sin(alpha), -0.22])
        return look_at(eye, target)
    raise ValueError(f"unknown camera motion {motion!r}")
