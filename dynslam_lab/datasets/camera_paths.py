"""Camera paths of the synthetic presets and the times of their frames.

The motions mirror the TUM fr3 sequences (``static``, ``xyz``, ``rpy``, ``halfsphere``) plus a
closed ``loop`` round the room; :func:`camera_pose` gives the camera pose ``T_w_c`` at any time,
so the 100 Hz ground truth and the 30 Hz colour frames come from the same smooth function.
Where the motions happen is a :class:`CameraRig`: the office's by default, the stress rooms
(:mod:`~dynslam_lab.datasets.stress`) place their own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.se3 import so3_exp
from .office import VIEW_EYE, VIEW_TARGET
from .shapes import look_at, pose, rot_x, rot_y, rot_z

__all__ = ["frame_times", "camera_pose", "CameraRig", "OFFICE_RIG", "MOTIONS"]

#: The camera motions of :func:`camera_pose`.
MOTIONS = ("static", "xyz", "rpy", "halfsphere", "loop")


@dataclass(frozen=True)
class CameraRig:
    """Where the camera motions of :func:`camera_pose` happen (world frame, z up, metres).

    Attributes
    ----------
    eye, target : the base view of the fixed-view motions (``static``, ``xyz``, ``rpy``,
        ``halfsphere``): the camera at ``eye`` looking at ``target``.
    loop_centre : centre of the ``loop`` circle (its height is the camera height).
    loop_radius : radius of the ``loop`` circle (m).
    loop_tilt : the loop camera looks outwards and down by ``atan(loop_tilt)``.
    """

    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    loop_centre: tuple[float, float, float] = (0.0, 0.1, 1.4)
    loop_radius: float = 0.85
    loop_tilt: float = 0.22

    def __post_init__(self) -> None:
        if np.linalg.norm(np.subtract(self.target, self.eye)[:2]) < 1e-6:
            raise ValueError(f"CameraRig: target {self.target} must not lie straight above or below eye {self.eye}")
        if self.loop_radius <= 0:
            raise ValueError(f"CameraRig.loop_radius must be > 0 m, got {self.loop_radius}")


#: The office's rig: the desk seen from ``VIEW_EYE``; a loop of 0.85 m round the room centre.
OFFICE_RIG = CameraRig(tuple(float(v) for v in VIEW_EYE), tuple(float(v) for v in VIEW_TARGET))


# ---------------------------------------------------------------------------- time
def frame_times(n_frames: int) -> np.ndarray:
    """Times (s from the start) of ``n_frames`` colour frames at 30 Hz on the 100 Hz ground-truth grid.

    Frame ``i`` is taken at ``round(i * 100 / 30) / 100`` s (intervals of 30, 40, 30 ms), so every
    colour frame has an exact ground-truth pose in the 100 Hz ``groundtruth.txt``.
    """
    return np.round(np.arange(n_frames) * 100.0 / 30.0) / 100.0


# -------------------------------------------------------------------- camera paths
def camera_pose(motion: str, t: float, duration: float, rig: CameraRig = OFFICE_RIG) -> np.ndarray:
    """Camera pose ``T_w_c (4, 4)`` of a motion preset at time ``t`` (s) of a ``duration`` s sequence.

    * ``static``: the fixed view with a hand-held tremor of ~2 mm and ~0.1 deg;
    * ``xyz``: translations along the camera axes, amplitudes 0.4 / 0.25 / 0.3 m (x / y / z);
    * ``rpy``: rotations about the camera axes: pitch 12 deg, yaw 20 deg, roll 15 deg;
    * ``halfsphere``: on a sphere of radius 0.5 m, azimuth +-60 deg, elevation 0..40 deg, looking at
      the target;
    * ``loop``: round a circle (radius 0.85 m in the office's room centre), looking outwards, once in
      ``duration`` with zero speed at both ends: the last pose equals the first.

    The fixed-view motions start at the rig's base view (``rig.eye`` looking at ``rig.target``);
    ``rig`` defaults to the office's.
    """
    w = 2 * np.pi
    eye0, target0 = np.array(rig.eye, float), np.array(rig.target, float)
    R0 = look_at(eye0, target0)[:3, :3]
    if motion == "static":
        dt = 0.002 * np.array([np.sin(w * 0.7 * t), np.sin(w * 0.45 * t + 1), np.sin(w * 0.3 * t + 2)])
        dr = np.radians(0.1) * np.array([np.sin(w * 0.5 * t + 3), np.sin(w * 0.35 * t), np.sin(w * 0.6 * t + 1)])
        return pose(R0 @ so3_exp(dr), eye0 + R0 @ dt)
    if motion == "xyz":
        dt = np.array([0.4 * np.sin(w * t / 10.0), 0.25 * np.sin(w * t / 8.0 + 0.5), 0.3 * np.sin(w * t / 12.0 + 1.0)])
        dt -= np.array([0.0, 0.25 * np.sin(0.5), 0.3 * np.sin(1.0)])  # start at the base view
        dr = np.radians(2.0) * np.array([np.sin(w * t / 7.0), np.sin(w * t / 9.0), 0.0])
        return pose(R0 @ so3_exp(dr), eye0 + R0 @ dt)
    if motion == "rpy":
        ang = np.radians([12.0 * np.sin(w * t / 7.0), 20.0 * np.sin(w * t / 9.0), 15.0 * np.sin(w * t / 11.0)])
        dt = 0.02 * np.array([np.sin(w * t / 5.0), np.sin(w * t / 6.0), np.sin(w * t / 4.0)])
        R = R0 @ rot_x(ang[0]) @ rot_y(ang[1]) @ rot_z(ang[2])
        return pose(R, eye0 + dt)
    if motion == "halfsphere":
        phi = np.radians(60.0) * np.sin(w * t / 12.0)
        theta = np.radians(20.0) * (1.0 - np.cos(w * t / 9.0))
        fwd = target0 - eye0
        fwd[2] = 0.0
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        centre = eye0 + 0.5 * fwd
        eye = centre + 0.5 * (np.cos(theta) * (np.sin(phi) * right - np.cos(phi) * fwd) + np.sin(theta) * np.array([0, 0, 1.0]))
        return look_at(eye, target0)
    if motion == "loop":
        tau = np.clip(t / max(duration, 1e-9), 0.0, 1.0)
        alpha = np.pi / 2 + 2 * np.pi * (tau - np.sin(2 * np.pi * tau) / (2 * np.pi))
        centre = np.array(rig.loop_centre, float)
        eye = centre + rig.loop_radius * np.array([np.cos(alpha), np.sin(alpha), 0.0])
        target = eye + np.array([np.cos(alpha), np.sin(alpha), -rig.loop_tilt])
        return look_at(eye, target)
    raise ValueError(f"unknown camera motion {motion!r}")
