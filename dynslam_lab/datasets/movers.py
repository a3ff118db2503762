"""Movers of the stress scenes: stop-and-go motion plans and the objects that follow them.

A mover goes back and forth along a straight segment on the floor (or, for a door, swings about
its hinge). How far along it is at time ``t`` is a :class:`MotionPlan`: a list of *legs*, each
either a wait or a move from arc length ``s0`` to ``s1`` with a trapezoidal speed profile
(accelerate at ``a`` to the cruise speed ``v``, cruise, brake at ``a``; a short move that cannot
reach ``v`` is a triangle, peak ``sqrt(a D)``). Plans are drawn by :func:`make_plan` from a seeded
generator in three patterns:

* ``pace``: end to end and back, pausing only to turn;
* ``stop_go``: to random intermediate stops, each held 0.4-2.5 s (a mover that is static for a
  while, then moves again);
* ``enter``: the segment starts outside the camera's view; the mover waits there (``delay``), walks
  in, and then paces, leaving and re-entering the view.

The movers (:class:`PersonMover`, :class:`RigidMover`, :class:`AttachedMover` for a box carried or
a cart pushed by a person, :class:`HingedMover` for a door) give their parts at time ``t`` like the
office's movers (:mod:`dynslam_lab.datasets.people`), plus ``reference(t)``: one point of the
mover (its body origin, or a door's free edge) whose speed is the plan's speed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .people import PersonLook, heading_rotation, person_parts, walking_joints
from .shapes import Shape, pose, rot_z

__all__ = ["PATTERNS", "MotionPlan", "make_plan", "Segment", "gait_joints", "PersonMover", "RigidMover",
           "AttachedMover", "HingedMover", "CARRY_ARMS", "PUSH_ARMS"]

#: Motion patterns of :func:`make_plan`.
PATTERNS = ("pace", "stop_go", "enter")
#: Plans are drawn this far ahead (s); after that the mover stays where it is.
PLAN_HORIZON = 1200.0


def _smooth(u: float) -> float:
    u = min(max(u, 0.0), 1.0)
    return u * u * (3.0 - 2.0 * u)


def _wrap(a: float) -> float:
    return (a + np.pi) % (2 * np.pi) - np.pi


class MotionPlan:
    """Arc length ``s(t)`` (m) along a path: waits and trapezoidal-profile moves (see the module docstring).

    Parameters
    ----------
    legs : ``[(t0, s0, s1, v, a), ...]`` in time order; a leg starts at ``t0`` (s) and lasts until the
        next leg's ``t0``; a move when ``s1 != s0`` (cruise speed ``v`` m/s, acceleration ``a`` m/s^2),
        else a wait. A move must fit into its leg.
    turn : seconds a body takes to turn round at a reversal, at the end of the wait before it
        (:meth:`direction`).
    """

    def __init__(self, legs: list[tuple[float, float, float, float, float]], turn: float = 0.0) -> None:
        if not legs:
            raise ValueError("MotionPlan needs at least one leg")
        if turn < 0:
            raise ValueError(f"MotionPlan.turn must be >= 0 s, got {turn}")
        self.turn = float(turn)
        arr = np.array(legs, float)
        self.t0, self.s0, self.s1, self.v, self.a = arr.T
        if np.any(np.diff(self.t0) < 0):
            raise ValueError("MotionPlan: legs must be in time order")
        D = np.abs(self.s1 - self.s0)
        moving = D > 0
        if np.any(moving & ((self.v <= 0) | (self.a <= 0))):
            raise ValueError("MotionPlan: a move needs a positive speed and acceleration")
        # trapezoid (or triangle) per move: peak speed, time to reach it, cruise time, duration
        with np.errstate(divide="ignore", invalid="ignore"):
            self.peak = np.where(moving, np.minimum(self.v, np.sqrt(D * self.a)), 0.0)
            self.t_acc = np.where(moving, self.peak / self.a, 0.0)
            self.t_cruise = np.where(moving, (D - self.peak * self.t_acc) / np.where(moving, self.peak, 1.0), 0.0)
        self.duration = 2 * self.t_acc + self.t_cruise
        ends = self.t0 + self.duration
        if np.any(ends[:-1] > self.t0[1:] + 1e-9):
            raise ValueError("MotionPlan: a move does not fit into its leg")
        self.sign = np.sign(self.s1 - self.s0)
        # distance walked before each leg (for the gait phase)
        self.walked = np.concatenate([[0.0], np.cumsum(D)[:-1]])

    def _leg(self, t: float) -> int:
        return max(int(np.searchsorted(self.t0, t, side="right")) - 1, 0)

    def _along(self, k: int, tau: float) -> tuple[float, float]:
        """Distance covered (m) and speed (m/s) ``tau`` s into leg ``k``."""
        a, p, ta, tc, T = self.a[k], self.peak[k], self.t_acc[k], self.t_cruise[k], self.duration[k]
        if p == 0.0 or tau <= 0.0:
            return 0.0, 0.0
        if tau >= T:
            return abs(self.s1[k] - self.s0[k]), 0.0
        if tau < ta:
            return 0.5 * a * tau * tau, a * tau
        if tau < ta + tc:
            return 0.5 * p * ta + p * (tau - ta), p
        r = T - tau
        return abs(self.s1[k] - self.s0[k]) - 0.5 * a * r * r, a * r

    def s(self, t: float) -> float:
        """Arc length at time ``t`` (s)."""
        k = self._leg(t)
        d, _ = self._along(k, t - self.t0[k])
        return float(self.s0[k] + self.sign[k] * d)

    def velocity(self, t: float) -> float:
        """Signed speed ``ds/dt`` (m/s) at time ``t``."""
        k = self._leg(t)
        _, v = self._along(k, t - self.t0[k])
        return float(self.sign[k] * v)

    def walked_at(self, t: float) -> float:
        """Total distance travelled (m) up to time ``t`` (for the gait phase)."""
        k = self._leg(t)
        d, _ = self._along(k, t - self.t0[k])
        return float(self.walked[k] + d)

    def direction(self, t: float) -> tuple[float, float]:
        """``(sign, u)``: the direction of the current or next move (+1 towards the far end, -1 back), and
        during the last :attr:`turn` seconds of a wait before a reversal the progress ``u`` (0..1, smoothed)
        of turning round from the previous direction; ``u = 1`` otherwise."""
        k = self._leg(t)
        if self.sign[k] != 0:
            return float(self.sign[k]), 1.0
        nxt = next((j for j in range(k + 1, len(self.sign)) if self.sign[j] != 0), None)
        prv = next((j for j in range(k - 1, -1, -1) if self.sign[j] != 0), None)
        if nxt is None:
            return (float(self.sign[prv]) if prv is not None else 1.0), 1.0
        if prv is None or self.sign[prv] == self.sign[nxt]:
            return float(self.sign[nxt]), 1.0
        t_end = self.t0[nxt]
        u = _smooth(1.0 - (t_end - t) / max(min(self.turn, t_end - self.t0[k]), 1e-9))
        return float(self.sign[nxt]), u


def make_plan(pattern: str, length: float, speed: float, accel: float, rng: np.random.Generator,
              delay: float = 0.0, turn: float = 0.0, horizon: float = PLAN_HORIZON) -> MotionPlan:
    """Draw a plan along a segment of ``length`` m starting at its ``s = 0`` end.

    ``pattern`` is one of :data:`PATTERNS`; ``speed`` the cruise speed (m/s), ``accel`` the
    acceleration (m/s^2); ``delay`` s of waiting before the first move; ``turn`` s of waiting at
    every reversal (a person turning round). Stops of ``stop_go`` are at least ``1.2 v^2 / a`` apart
    (when the segment allows), so the cruise speed is reached between them.
    """
    if pattern not in PATTERNS:
        raise ValueError(f"motion pattern must be one of {PATTERNS}, got {pattern!r}")
    if length <= 0 or speed <= 0 or accel <= 0:
        raise ValueError(f"make_plan: length, speed and accel must be > 0, got {length}, {speed}, {accel}")
    legs: list[tuple[float, float, float, float, float]] = []
    t, s, direction = 0.0, 0.0, 1.0

    def move(s1: float) -> None:
        nonlocal t, s
        D = abs(s1 - s)
        p = min(speed, np.sqrt(D * accel))
        legs.append((t, s, s1, speed, accel))
        t += 2 * p / accel + (D - p * p / accel) / p
        s = s1

    def wait(T: float) -> None:
        nonlocal t
        if T > 0:
            legs.append((t, s, s, 0.0, 0.0))
            t += T

    wait(delay)
    min_step = min(length, 1.2 * speed * speed / accel)
    while t < horizon:
        end = length if direction > 0 else 0.0
        remaining = abs(end - s)
        if pattern == "stop_go" and remaining > 2 * min_step and rng.random() < 0.65:
            move(s + direction * float(rng.uniform(min_step, remaining - min_step)))
            wait(float(rng.uniform(0.4, 2.5)))
            continue
        move(end)
        pause = float(rng.uniform(0.4, 2.5)) if pattern == "stop_go" else float(rng.uniform(0.0, 0.3))
        wait(turn + pause)
        direction = -direction
    wait(1.0)  # a last wait, so the final position holds
    return MotionPlan(legs, turn)


@dataclass(frozen=True)
class Segment:
    """A straight path on the floor from ``p0`` to ``p1`` (world ``(x, y)``, m)."""

    p0: tuple[float, float]
    p1: tuple[float, float]

    @property
    def length(self) -> float:
        return float(np.hypot(self.p1[0] - self.p0[0], self.p1[1] - self.p0[1]))

    @property
    def yaw(self) -> float:
        """Heading (rad, about z from +x) of the direction ``p0 -> p1``."""
        return float(np.arctan2(self.p1[1] - self.p0[1], self.p1[0] - self.p0[0]))

    def at(self, s: float) -> np.ndarray:
        """World ``(x, y)`` at arc length ``s``."""
        p0, p1 = np.asarray(self.p0, float), np.asarray(self.p1, float)
        return p0 + (p1 - p0) * (s / self.length)


def gait_joints(phase: float, amplitude: float) -> dict:
    """:func:`~dynslam_lab.datasets.people.walking_joints` with the swing scaled by ``amplitude``
    (0 = standing still, 1 = the full gait), so that a mover slowing to a stop stops stepping."""
    j = walking_joints(phase)
    a = float(np.clip(amplitude, 0.0, 1.0))
    j["pelvis"] = 0.9 + (j["pelvis"] - 0.9) * a
    j["twist"] *= a
    for k in ("thigh", "knee", "shoulder"):
        j[k] = tuple(v * a for v in j[k])
    j["elbow"] = tuple(np.radians(15.0) + (v - np.radians(15.0)) * a for v in j["elbow"])
    return j


#: Arm poses (radians) of a person carrying a box in front of the chest and of one pushing a cart:
#: shoulders swung forward, elbows bent; the hands end ~0.4 m in front at ~1.15 m (scale 1).
CARRY_ARMS = {"shoulder": (np.radians(30.0),) * 2, "elbow": (np.radians(60.0),) * 2, "abduct": (np.radians(14.0),) * 2}
PUSH_ARMS = {"shoulder": (np.radians(45.0),) * 2, "elbow": (np.radians(30.0),) * 2, "abduct": (np.radians(8.0),) * 2}


@dataclass
class PersonMover:
    """A person walking a :class:`MotionPlan` along a :class:`Segment`.

    ``arms`` (e.g. :data:`CARRY_ARMS`) fixes the arm joints; ``face_path``: the body always faces
    ``p0 -> p1`` (walking backwards on the way back, as when pulling a cart) instead of turning
    round at the ends.
    """

    instance: int
    look: PersonLook
    path: Segment
    plan: MotionPlan
    stride: float = 1.35  # m per gait cycle (scale 1)
    arms: dict | None = None
    face_path: bool = False
    lean: float = 0.0  # extra forward lean (rad)
    motion: str = "walking"

    def root(self, t: float) -> np.ndarray:
        """Body frame ``T_w_root`` (origin on the floor between the feet, y forward) at time ``t``."""
        xy = self.path.at(self.plan.s(t))
        yaw = self.path.yaw
        if not self.face_path:
            sign, u = self.plan.direction(t)
            if sign < 0:
                yaw = yaw + np.pi
            yaw = yaw - (1.0 - u) * np.pi  # turning round (always to the left) before a reversal
        return pose(heading_rotation(yaw), (xy[0], xy[1], 0.0))

    def reference(self, t: float) -> np.ndarray:
        return self.root(t)[:3, 3]

    def parts(self, t: float) -> list[tuple[Shape, np.ndarray]]:
        v = abs(self.plan.velocity(t))
        walked = self.plan.s(t) if self.face_path else self.plan.walked_at(t)
        j = gait_joints(2 * np.pi * walked / (self.stride * self.look.height), v / 0.6)
        if self.arms:
            j.update(self.arms)
        j["lean"] += self.lean
        return person_parts(self.look, self.instance, self.root(t), j)


@dataclass
class RigidMover:
    """A rigid object (box stack, cart, panel) sliding along a :class:`Segment` with a fixed heading."""

    instance: int
    shapes: list[tuple[Shape, np.ndarray]]  # shapes with poses in the object frame (origin on the floor)
    path: Segment
    plan: MotionPlan
    yaw: float = 0.0  # heading of the object frame (rad about z)
    motion: str = "sliding"

    def root(self, t: float) -> np.ndarray:
        xy = self.path.at(self.plan.s(t))
        return pose(rot_z(self.yaw), (xy[0], xy[1], 0.0))

    def reference(self, t: float) -> np.ndarray:
        return self.root(t)[:3, 3]

    def parts(self, t: float) -> list[tuple[Shape, np.ndarray]]:
        T = self.root(t)
        return [(s, T @ P) for s, P in self.shapes]


@dataclass
class AttachedMover:
    """An object moved by a person: its frame is ``carrier.root(t) @ T_root_o`` (a box carried in
    front of the chest, a cart pushed ahead)."""

    instance: int
    shapes: list[tuple[Shape, np.ndarray]]
    carrier: PersonMover
    T_root_o: np.ndarray = field(default_factory=lambda: np.eye(4))
    motion: str = "carried"

    def reference(self, t: float) -> np.ndarray:
        return (self.carrier.root(t) @ self.T_root_o)[:3, 3]

    def parts(self, t: float) -> list[tuple[Shape, np.ndarray]]:
        T = self.carrier.root(t) @ self.T_root_o
        return [(s, T @ P) for s, P in self.shapes]


@dataclass
class HingedMover:
    """A door: shapes in the door frame (hinge axis = local z through the origin, the slab along +x,
    ``width`` m wide), swung by ``angle = sign * s(t) / width`` about the hinge; the plan's arc length
    is that of the free edge, so the plan's speed is the edge's speed."""

    instance: int
    shapes: list[tuple[Shape, np.ndarray]]
    T_w_hinge: np.ndarray
    plan: MotionPlan
    width: float
    sign: float = 1.0  # +1 opens anticlockwise (seen from above)
    motion: str = "swinging"

    def frame(self, t: float) -> np.ndarray:
        return self.T_w_hinge @ pose(rot_z(self.sign * self.plan.s(t) / self.width))

    def reference(self, t: float) -> np.ndarray:
        return (self.frame(t) @ np.array([self.width, 0.0, 1.0, 1.0]))[:3]

    def parts(self, t: float) -> list[tuple[Shape, np.ndarray]]:
        T = self.frame(t)
        return [(s, T @ P) for s, P in self.shapes]
