"""The people and other movers of the synthetic office.

A person is articulated from capsules (neck, limbs), ellipsoids (pelvis, torso, head, hands)
and boxes (shoes) by :func:`person_parts`, given joint angles: :func:`walking_joints` (a gait:
thighs swing +-24 deg, knees bend up to 35 deg, arms swing against the legs, the pelvis bobs)
or :func:`sitting_joints` (a seated person leaning, turning the head and gesturing). Movers
give their parts at time ``t`` (s):

* :class:`Walker`: round a closed path (:func:`path_pose`) at constant speed;
* :class:`Sitter`: seated on a chair, talking;
* :class:`SlidingObject`: a rigid object pushed out and back now and then (a book).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .shapes import Shape, pose, rot_x, rot_y, rot_z

__all__ = ["PersonLook", "person_parts", "walking_joints", "sitting_joints", "path_pose", "heading_rotation",
           "Walker", "Sitter", "SlidingObject"]


@dataclass(frozen=True)
class PersonLook:
    """Textures (indices into the bank) and proportions of one person."""

    shirt: int
    trousers: int
    head: int
    skin: int
    shoes: int
    height: float = 1.0  # scale of a 1.72 m tall body
    shirt_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)


def _capsule_between(p0: np.ndarray, R: np.ndarray, length: float) -> np.ndarray:
    """Pose of a capsule hanging from joint ``p0`` along ``-R z`` over ``length`` m."""
    return pose(R, p0 + R @ np.array([0.0, 0.0, -0.5 * length]))


def person_parts(look: PersonLook, instance: int, T_w_root: np.ndarray, joints: dict) -> list[tuple[Shape, np.ndarray]]:
    """Articulated person: ellipsoids (pelvis, torso, head, hands) and capsules (limbs, neck).

    ``T_w_root`` places the body frame (origin on the floor between the feet, x right,
    y forward, z up). ``joints`` (radians unless noted): ``pelvis`` height of the hip joints (m,
    before scaling), ``lean`` (forward, about x), ``twist`` (about z), ``head_yaw``,
    ``head_pitch``, and per side (index 0 = left, 1 = right) ``thigh`` (forward swing),
    ``knee`` (bend), ``shoulder`` (forward swing), ``abduct`` (sideways), ``elbow`` (bend).
    """
    k = look.height
    shirt = dict(textures=(look.shirt,), instance=instance, density=400.0, turn=float(256), tint=look.shirt_tint)
    trous = dict(textures=(look.trousers,), instance=instance, density=400.0, turn=float(256))
    skin = dict(textures=(look.skin,), instance=instance, density=400.0, turn=float(128))
    parts: list[tuple[Shape, np.ndarray]] = []

    def add(shape: Shape, T_root_p: np.ndarray) -> None:
        parts.append((shape, T_w_root @ T_root_p))

    hip_h = joints["pelvis"] * k
    pelvis_c = np.array([0.0, 0.0, hip_h + 0.03 * k])
    add(Shape("ellipsoid", (0.17 * k, 0.11 * k, 0.11 * k), **trous), pose(rot_z(joints["twist"] * 0.3), pelvis_c))
    # upper body leans about the hip line and twists
    R_up = rot_z(joints["twist"]) @ rot_x(-joints["lean"])
    T_up = pose(R_up, pelvis_c)
    add(Shape("ellipsoid", (0.22 * k, 0.14 * k, 0.29 * k), **shirt), T_up @ pose(None, (0, 0, 0.29 * k)))
    add(Shape("capsule", (0.05 * k, 0.05 * k, 0.04 * k), **skin), T_up @ pose(None, (0, 0, 0.56 * k)))
    head_size = np.array([0.085, 0.1, 0.115]) * k
    W, H = 512, 256
    head = Shape("ellipsoid", tuple(head_size), textures=(look.head,), instance=instance, density=H / (2 * head_size[2]),
                 turn=float(W), offset=(0.0, H / 2))
    add(head, T_up @ pose(rot_z(joints["head_yaw"]) @ rot_x(joints["head_pitch"]), (0, 0.01 * k, 0.7 * k)))
    for side, sx in ((0, -1.0), (1, 1.0)):
        # leg: thigh and shin capsules, a shoe box
        hip = np.array([sx * 0.09 * k, 0.0, hip_h])
        R_th = rot_x(joints["thigh"][side])
        lt, ls = 0.43 * k, 0.43 * k
        add(Shape("capsule", (0.072 * k, 0.072 * k, 0.5 * lt), **trous), _capsule_between(hip, R_th, lt))
        knee = hip + R_th @ np.array([0, 0, -lt])
        R_sh = R_th @ rot_x(-joints["knee"][side])
        add(Shape("capsule", (0.055 * k, 0.055 * k, 0.5 * ls), **trous), _capsule_between(knee, R_sh, ls))
        ankle = knee + R_sh @ np.array([0, 0, -ls])
        R_ft = R_sh @ rot_x(joints["knee"][side] - joints["thigh"][side])  # feet stay roughly level
        add(Shape("box", (0.045 * k, 0.11 * k, 0.035 * k), textures=(look.shoes,), instance=instance, density=400.0),
            pose(R_ft, ankle + R_ft @ np.array([0, 0.05 * k, -0.025 * k])))
        # arm: upper arm (shirt), forearm (skin), hand
        sh = np.array([sx * 0.235 * k, 0.0, 0.49 * k])
        R_ua = rot_y(sx * joints["abduct"][side]) @ rot_x(joints["shoulder"][side])
        lu, lf = 0.29 * k, 0.26 * k
        add(Shape("capsule", (0.052 * k, 0.052 * k, 0.5 * lu), **shirt), T_up @ _capsule_between(sh, R_ua, lu))
        elbow = sh + R_ua @ np.array([0, 0, -lu])
        R_fa = R_ua @ rot_x(joints["elbow"][side])
        add(Shape("capsule", (0.042 * k, 0.042 * k, 0.5 * lf), **skin), T_up @ _capsule_between(elbow, R_fa, lf))
        wrist = elbow + R_fa @ np.array([0, 0, -lf])
        add(Shape("ellipsoid", (0.025 * k, 0.045 * k, 0.075 * k), **skin), T_up @ pose(R_fa, wrist + R_fa @ np.array([0, 0, -0.06 * k])))
    return parts


def walking_joints(phase: float) -> dict:
    """Joint angles of a walking gait at ``phase`` (radians, one stride per 2*pi)."""
    sw = np.radians(24.0) * np.sin(phase)
    knee_l = np.radians(35.0) * max(0.0, np.sin(phase + 1.9))
    knee_r = np.radians(35.0) * max(0.0, np.sin(phase + 1.9 + np.pi))
    return dict(
        pelvis=0.9 + 0.015 * np.cos(2 * phase),
        lean=np.radians(4.0),
        twist=np.radians(5.0) * np.sin(phase),
        head_yaw=0.0,
        head_pitch=0.0,
        thigh=(sw, -sw),
        knee=(knee_l, knee_r),
        shoulder=(-0.8 * sw, 0.8 * sw),
        abduct=(np.radians(8.0), np.radians(8.0)),
        elbow=(np.radians(15.0) - 0.3 * sw, np.radians(15.0) + 0.3 * sw),
    )


def sitting_joints(t: float, seed_phase: float) -> dict:
    """Joint angles of a person seated and talking at time ``t`` (s): slow lean, head turns, gestures."""
    p = seed_phase
    g = np.sin(2 * np.pi * 0.3 * t + p)
    return dict(
        pelvis=0.52,
        lean=np.radians(8.0 + 6.0 * np.sin(2 * np.pi * 0.13 * t + p)),
        twist=np.radians(8.0) * np.sin(2 * np.pi * 0.11 * t + 2 * p),
        head_yaw=np.radians(25.0) * np.sin(2 * np.pi * 0.21 * t + p),
        head_pitch=np.radians(10.0) * np.sin(2 * np.pi * 0.17 * t + 3 * p),
        thigh=(np.radians(88.0), np.radians(92.0)),
        knee=(np.radians(88.0), np.radians(95.0)),
        shoulder=(np.radians(35.0 + 15.0 * g), np.radians(30.0 + 12.0 * np.sin(2 * np.pi * 0.2 * t + 2 * p))),
        abduct=(np.radians(12.0), np.radians(12.0)),
        elbow=(np.radians(70.0 + 15.0 * np.sin(2 * np.pi * 0.4 * t + p)), np.radians(60.0)),
    )


def path_pose(path: np.ndarray, s: float, blend: float = 0.45) -> tuple[np.ndarray, float]:
    """Position ``(2,)`` and heading (rad) at arc length ``s`` along a closed polygon ``(K, 2)``.

    The heading turns smoothly over ``blend`` metres on either side of each corner.
    """
    P = np.asarray(path, float)
    seg = np.roll(P, -1, axis=0) - P
    L = np.linalg.norm(seg, axis=1)
    total = L.sum()
    s = s % total
    i = int(np.searchsorted(np.cumsum(L), s, side="right"))
    i = min(i, len(P) - 1)
    s0 = s - (np.cumsum(L)[i] - L[i])
    xy = P[i] + seg[i] * (s0 / L[i])
    yaw = np.arctan2(seg[:, 1], seg[:, 0])

    def wrap(a):
        return (a + np.pi) % (2 * np.pi) - np.pi

    h = yaw[i]
    if L[i] - s0 < blend:
        h = yaw[i] + 0.5 * (1 - (L[i] - s0) / blend) * wrap(yaw[(i + 1) % len(P)] - yaw[i])
    elif s0 < blend:
        h = yaw[i - 1] + (0.5 + 0.5 * s0 / blend) * wrap(yaw[i] - yaw[i - 1])
    return xy, float(h)


def heading_rotation(yaw: float) -> np.ndarray:
    """Rotation taking the body's forward axis (+y) to the world heading ``yaw`` (about z)."""
    return rot_z(yaw - np.pi / 2)


@dataclass
class Walker:
    """A person walking round a closed path at constant speed."""

    instance: int
    look: PersonLook
    path: np.ndarray
    speed: float = 0.9  # m/s
    start: float = 0.0  # arc length at t = 0, m
    stride: float = 1.35  # m per gait cycle

    motion = "walking"

    def parts(self, t: float) -> list[tuple[Shape, np.ndarray]]:
        s = self.start + self.speed * t
        xy, yaw = path_pose(self.path, s)
        T = pose(heading_rotation(yaw), (xy[0], xy[1], 0.0))
        return person_parts(self.look, self.instance, T, walking_joints(2 * np.pi * s / self.stride))


@dataclass
class Sitter:
    """A person seated on a chair, talking and gesturing."""

    instance: int
    look: PersonLook
    T_w_seat: np.ndarray  # body frame on the floor under the seat, facing +y
    phase: float = 0.0

    motion = "sitting"

    def parts(self, t: float) -> list[tuple[Shape, np.ndarray]]:
        return person_parts(self.look, self.instance, self.T_w_seat @ pose(None, (0, -0.04, 0)), sitting_joints(t, self.phase))


@dataclass
class SlidingObject:
    """A rigid object pushed back and forth now and then (a book moved on the desk)."""

    instance: int
    shapes: list[tuple[Shape, np.ndarray]]  # shapes with poses relative to the object frame
    T_w_o: np.ndarray
    shift: tuple[float, float, float] = (0.18, -0.08, 0.0)  # m, displacement when moved
    period: float = 8.0  # s
    motion = "moved"

    def offset(self, t: float) -> np.ndarray:
        """Displacement (m) at time ``t``: out over [1.5, 2.7] s and back over [5, 6.2] s of each period."""
        u = t % self.period

        def smooth(a, b):
            x = np.clip((u - a) / (b - a), 0.0, 1.0)
            return x * x * (3 - 2 * x)

        return np.asarray(self.shift) * (smooth(1.5, 2.7) - smooth(5.0, 6.2))

    def parts(self, t: float) -> list[tuple[Shape, np.ndarray]]:
        T = self.T_w_o.copy()
        T[:3, 3] += self.offset(t)
        return [(s, T @ P) for s, P in self.shapes]
