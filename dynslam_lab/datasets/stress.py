"""Stress scenes: a seeded random scene generator and named presets unlike the office.

The office presets show one kind of dynamic scene: two people about 1 m away covering ~20 % of
the image, in one well-textured room. A stress scene changes everything the dynamic-feature
filters could have been tuned on:

* **movers** (1-4) of seven kinds: ``person`` (COCO class ``person``), ``box`` (a stack of boxes),
  ``cart`` (a trolley with a load), ``panel`` (a large board), ``door`` (a slab swinging on its
  hinge), ``carried`` (a person carrying a box) and ``pushed`` (a person pushing a cart): the moved
  objects of Chang et al. 2021 (YOLACT-based, with multi-view geometry and optical flow). Every
  object but a person has a non-COCO class (``box``, ``cart``, ``panel``, ``door``), so no detector
  (and no oracle detector) ever names it. Movers go back and forth along straight paths
  0.8-3 m in front of the camera at up to 2 m/s, pacing, stopping and starting, or entering from
  outside the view (:mod:`~dynslam_lab.datasets.movers`);
* **rooms** of any size (3.5-10 m wide) with partitions and clutter, in four surface styles (fine
  noise, flat, repeated patterns, photographs) and five lighting families
  (:mod:`~dynslam_lab.datasets.rooms`);
* **the camera** moves as in the office presets (``static``, ``xyz``, ``rpy``, ``halfsphere``), or
  circles the room once (``loop``, back to its start pose).

A :class:`StressPreset` holds every parameter of a scene (the room, the base view, each
:class:`MoverSpec`), so it can be stored in ``synthetic.json`` and rebuilt; its ``seed`` draws the
textures, the clutter and the movers' stop-and-go plans. :func:`random_scene_preset` draws a
preset from a seed (any parameter can be fixed); :data:`STRESS_PRESETS` names a few,
:data:`STRESS_SUITE` and :data:`STRESS_LOOPS` are the lists other benchmarks run. With
``with_movers=False`` (:meth:`StressPreset.without_movers`) the same room and camera path are
rendered without movers, bit-identical wherever no mover is seen. See ``docs/synthetic.md``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace

import cv2
import numpy as np

from ..camera import CAMERA_PRESETS
from . import textures as tx
from .camera_paths import MOTIONS, CameraRig
from .kinect import DepthNoise
from .movers import (
    CARRY_ARMS,
    PATTERNS,
    PUSH_ARMS,
    AttachedMover,
    HingedMover,
    PersonMover,
    RigidMover,
    Segment,
    make_plan,
)
from .office import PERSON, OfficeScene, TextureBank, person_look
from .rooms import LIGHTINGS, ROOM_STYLES, Footprint, build_room
from .shapes import _FACE_OFFSET, Shape, pose, rot_y, rot_z

__all__ = [
    "MOVER_KINDS",
    "MOVER_CLASSES",
    "MoverSpec",
    "StressPreset",
    "random_scene_preset",
    "build_stress_scene",
    "STRESS_PRESETS",
    "STRESS_SUITE",
    "STRESS_LOOPS",
    "stress_suite",
    "describe",
]

MOVER_KINDS = ("person", "box", "cart", "panel", "door", "carried", "pushed")
#: Class names written to ``instances.json``: only people have a COCO class.
MOVER_CLASSES = {"person": PERSON, "box": "box", "cart": "cart", "panel": "panel", "door": "door"}
#: Highest cruise speed the generator draws per kind (m/s; a door: its free edge).
MAX_SPEED = {"person": 2.0, "box": 2.0, "cart": 2.0, "panel": 1.5, "door": 1.5, "carried": 1.4, "pushed": 1.5}
_KIND_WEIGHTS = (0.24, 0.16, 0.1, 0.12, 0.08, 0.15, 0.15)
# How far the camera comes forward of the base view (m), added to the nearest mover distance the
# generator draws so the camera never runs into a mover: halfsphere up to 0.31 m, xyz 0.05 m.
_FORWARD_EXCURSION = {"static": 0.0, "xyz": 0.05, "rpy": 0.02, "halfsphere": 0.31, "loop": 0.0}
# How far the camera moves sideways (m): a mover that enters starts this much further out.
_SIDE_EXCURSION = {"static": 0.0, "xyz": 0.4, "rpy": 0.02, "halfsphere": 0.44, "loop": 0.0}


@dataclass(frozen=True)
class MoverSpec:
    """One mover of a stress scene.

    Positions are in the *view frame* of the scene's base view: ``x`` to the right and ``z``
    forward along the horizontal viewing direction, metres from the base camera position (on the
    floor plane). The mover's reference point (its body origin on the floor; for a door the free
    edge) moves from ``start`` towards ``end`` and back.

    Attributes
    ----------
    kind : one of :data:`MOVER_KINDS`.
    start, end : ``(x, z)`` m, the ends of the path (a door: the hinge and the free edge when closed).
    speed : cruise speed, m/s (a door: of its free edge).
    pattern : ``pace``, ``stop_go`` or ``enter`` (:data:`~dynslam_lab.datasets.movers.PATTERNS`; a door
        does not ``enter``).
    size : ``(width, depth, height)`` m: a box stack's or panel's extent, a cart's width, length and
        handle height, a door's width, thickness and height; a person's height is ``size[2]``.
    delay : s the mover waits at ``start`` before moving.
    swing : a door's opening angle (deg).
    """

    kind: str
    start: tuple[float, float]
    end: tuple[float, float]
    speed: float
    pattern: str = "pace"
    size: tuple[float, float, float] = (0.5, 0.4, 1.0)
    delay: float = 0.0
    swing: float = 90.0

    def __post_init__(self) -> None:
        if self.kind not in MOVER_KINDS:
            raise ValueError(f"MoverSpec.kind must be one of {MOVER_KINDS}, got {self.kind!r}")
        if self.pattern not in PATTERNS or (self.kind == "door" and self.pattern == "enter"):
            raise ValueError(f"MoverSpec.pattern must be one of {PATTERNS} (a door cannot 'enter'), got {self.pattern!r}")
        if not 0 < self.speed <= 2.5:
            raise ValueError(f"MoverSpec.speed must be in (0, 2.5] m/s, got {self.speed}")
        if len(self.size) != 3 or min(self.size) <= 0:
            raise ValueError(f"MoverSpec.size must be 3 positive lengths (m), got {self.size!r}")
        if np.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1]) < 0.2:
            raise ValueError(f"MoverSpec: start {self.start} and end {self.end} must be at least 0.2 m apart")
        if self.delay < 0:
            raise ValueError(f"MoverSpec.delay must be >= 0 s, got {self.delay}")
        if not 10 <= self.swing <= 120:
            raise ValueError(f"MoverSpec.swing must be in [10, 120] deg, got {self.swing}")

    @property
    def classes(self) -> tuple[str, ...]:
        """Class names of the instances this mover adds (a carried box and a pushed cart add two)."""
        return {"carried": (PERSON, "box"), "pushed": (PERSON, "cart")}.get(self.kind, (MOVER_CLASSES.get(self.kind, ""),))

    @property
    def path_length(self) -> float:
        """Length of the path (m); a door's is the arc of its free edge."""
        if self.kind == "door":
            return float(np.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1]) * np.radians(self.swing))
        return float(np.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1]))

    @property
    def depth_range(self) -> tuple[float, float]:
        """Nearest and farthest distance (view-frame ``z``, m) of the reference point."""
        if self.kind == "door":
            w = np.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1])
            return float(self.start[1]), float(self.start[1] + w * np.sin(np.radians(self.swing)))
        return float(min(self.start[1], self.end[1])), float(max(self.start[1], self.end[1]))

    @property
    def accel(self) -> float:
        """Acceleration (m/s^2): high enough to reach the cruise speed within 60 % of the path, 1.2-4."""
        return float(np.clip(max(1.2, self.speed**2 / (0.6 * self.path_length)), 1.2, 4.0))

    def footprint(self) -> Footprint:
        """The floor region (view frame) the mover sweeps, with a 5 cm margin."""
        p0, p1 = np.asarray(self.start, float), np.asarray(self.end, float)
        w, d, h = self.size
        if self.kind == "door":
            L = float(np.linalg.norm(p1 - p0))
            a = np.radians(self.swing)
            side = np.sign(p1[0] - p0[0])
            x = sorted([p0[0] + side * min(0.0, L * np.cos(a)), p1[0]])  # past the hinge when it opens beyond 90 deg
            return Footprint.box(0.5 * (x[0] + x[1]), p0[1] + 0.5 * L * np.sin(a), 0.5 * (x[1] - x[0]) + 0.1,
                                 0.5 * L * np.sin(a) + 0.1)
        u = (p1 - p0) / np.linalg.norm(p1 - p0)
        along, across = _extent(self.kind, self.size, float(np.arctan2(u[1], u[0])))
        if self.kind == "pushed":  # the cart goes ahead of the person (along start -> end)
            shift = 0.5 * (0.45 + d - 0.3) * u
            return Footprint.of_segment(p0 + shift, p1 + shift, across, along)
        return Footprint.of_segment(p0, p1, across, along)


def _extent(kind: str, size, alpha: float) -> tuple[float, float]:
    """Half-extents ``(along, across)`` (m, with a 5 cm margin) of a mover's body relative to its path,
    ``alpha`` the path's angle to the view's x axis (panels and box stacks face the camera, carts and
    people turn with the path)."""
    w, d, _ = size
    ca, sa = abs(np.cos(alpha)), abs(np.sin(alpha))
    if kind == "pushed":  # a person 0.3 m behind the handle, the cart 0.45 + d ahead of the person's origin
        return 0.5 * (0.75 + d) + 0.05, max(0.32, w / 2) + 0.05
    if kind == "cart":
        return 0.5 * d + 0.1, 0.5 * w + 0.05
    if kind == "panel":  # w along the view's x, 0.36 m of feet along its z
        return 0.5 * (w * ca + 0.36 * sa) + 0.05, 0.5 * (w * sa + 0.36 * ca) + 0.05
    if kind == "door":
        return w + 0.1, w + 0.1
    r = {"person": 0.28, "carried": 0.55, "box": 0.5 * np.hypot(w, d)}[kind] + 0.05
    return r, r


def _free_uniform(rng: np.random.Generator, lo: float, hi: float, blocked: list[tuple[float, float]]) -> float:
    """A uniform draw from ``[lo, hi]`` minus the ``blocked`` intervals (from all of ``[lo, hi]`` if nothing is
    free); always one draw from ``rng``."""
    u = float(rng.random())
    free, x = [], lo
    for a, b in sorted(blocked):
        if a > x:
            free.append((x, min(a, hi)))
        x = max(x, b)
        if x >= hi:
            break
    if x < hi:
        free.append((x, hi))
    free = [(a, b) for a, b in free if b > a]
    total = sum(b - a for a, b in free)
    if total <= 0:
        return lo + u * (hi - lo)
    t = u * total
    for a, b in free:
        if t <= b - a:
            return a + t
        t -= b - a
    return free[-1][1]


@dataclass(frozen=True)
class StressPreset:
    """One stress scene: room, base view, camera motion, movers and sensor (see the module docstring).

    Attributes
    ----------
    name : preset name.
    seed : draws the room's textures, clutter and lights and the movers' textures and stop-and-go plans.
    motion : camera motion (``static``, ``xyz``, ``rpy``, ``halfsphere``, ``loop``).
    style : room surfaces (:data:`~dynslam_lab.datasets.rooms.ROOM_STYLES`).
    lighting : lighting family (:data:`~dynslam_lab.datasets.rooms.LIGHTINGS`).
    room : ``(W, D, H)`` m, the room ``[0, W] x [0, D] x [0, H]``.
    eye : base camera position (m, world).
    yaw : heading of the base view (deg, anticlockwise from +y; 0 for a loop, which starts looking along +y).
    pitch : the base view looks down by this angle (deg).
    loop_radius : radius of the ``loop`` circle (m), centred ``loop_radius`` behind the eye.
    partitions, clutter : numbers of wall stubs and clutter pieces (:func:`~dynslam_lab.datasets.rooms.build_room`).
    movers : the :class:`MoverSpec` of each mover.
    with_movers : False renders the same scene without any mover.
    n_frames, camera, image_noise, blur, depth : as in :class:`~dynslam_lab.datasets.synthetic.ScenePreset`.
    """

    name: str
    seed: int
    motion: str
    style: str
    lighting: str
    room: tuple[float, float, float]
    eye: tuple[float, float, float]
    yaw: float = 0.0
    pitch: float = 10.0
    loop_radius: float = 0.8
    partitions: int = 0
    clutter: int = 6
    movers: tuple[MoverSpec, ...] = ()
    with_movers: bool = True
    n_frames: int = 300
    camera: str = "default"
    image_noise: float = 2.0  # 8-bit levels, as the office presets
    blur: float = 0.5  # px, as the office presets
    depth: DepthNoise = field(default_factory=DepthNoise)

    def __post_init__(self) -> None:
        if self.motion not in MOTIONS:
            raise ValueError(f"StressPreset.motion must be one of {MOTIONS}, got {self.motion!r}")
        if self.style not in ROOM_STYLES:
            raise ValueError(f"StressPreset.style must be one of {ROOM_STYLES}, got {self.style!r}")
        if self.lighting not in LIGHTINGS:
            raise ValueError(f"StressPreset.lighting must be one of {LIGHTINGS}, got {self.lighting!r}")
        if len(self.room) != 3 or min(self.room[:2]) < 2.0 or self.room[2] < 2.0:
            raise ValueError(f"StressPreset.room must be (W, D, H) of at least 2 m each, got {self.room!r}")
        if not all(0 < e < r for e, r in zip(self.eye, self.room)):
            raise ValueError(f"StressPreset.eye {self.eye} must lie inside the room {self.room}")
        if self.motion == "loop" and self.yaw != 0.0:
            raise ValueError(f"StressPreset.yaw must be 0 for a loop (it starts looking along +y), got {self.yaw}")
        if not 0 <= self.pitch < 45:
            raise ValueError(f"StressPreset.pitch must be in [0, 45) deg, got {self.pitch}")
        if self.n_frames < 1:
            raise ValueError(f"StressPreset.n_frames must be >= 1, got {self.n_frames}")
        if self.partitions < 0 or self.clutter < 0:
            raise ValueError(f"StressPreset.partitions and clutter must be >= 0, got {self.partitions}, {self.clutter}")
        if not isinstance(self.movers, tuple) or not all(isinstance(m, MoverSpec) for m in self.movers):
            raise ValueError("StressPreset.movers must be a tuple of MoverSpec")
        if self.camera not in CAMERA_PRESETS or CAMERA_PRESETS[self.camera].has_distortion:
            raise ValueError(f"StressPreset.camera {self.camera!r} must be an undistorted preset of {sorted(CAMERA_PRESETS)}")

    # ------------------------------------------------------------------ geometry
    @property
    def forward(self) -> np.ndarray:
        """Horizontal viewing direction ``(2,)`` of the base view (world)."""
        a = np.radians(self.yaw)
        return np.array([-np.sin(a), np.cos(a)])

    @property
    def right(self) -> np.ndarray:
        a = np.radians(self.yaw)
        return np.array([np.cos(a), np.sin(a)])

    def to_world(self, xz) -> np.ndarray:
        """World ``(x, y)`` of view-frame points ``(..., 2)`` (``x`` right, ``z`` forward)."""
        xz = np.asarray(xz, float)
        return np.asarray(self.eye[:2]) + xz[..., :1] * self.right + xz[..., 1:2] * self.forward

    def footprint_to_world(self, fp: Footprint) -> Footprint:
        c = self.to_world((fp.cx, fp.cy))
        u = fp.ux * self.right + fp.uy * self.forward
        return Footprint(float(c[0]), float(c[1]), float(u[0]), float(u[1]), fp.a, fp.b)

    @property
    def rig(self) -> CameraRig:
        """The camera rig: the base view, and the loop circle behind the eye."""
        f, tilt = self.forward, np.tan(np.radians(self.pitch))
        eye = np.asarray(self.eye, float)
        target = eye + 3.0 * np.array([f[0], f[1], -tilt])
        centre = eye - self.loop_radius * np.array([f[0], f[1], 0.0])
        return CameraRig(tuple(float(v) for v in eye), tuple(float(v) for v in target), tuple(float(v) for v in centre),
                         float(self.loop_radius), float(tilt))

    def keep_out(self) -> list[Footprint]:
        """World footprints no clutter or partition may enter: the movers' paths, the camera's region
        (1.2 m behind to 0.6 m ahead of the eye, 0.9 m either side) and for a loop a square 1 m wider than
        its circle (nothing right in front of the lens)."""
        out = [self.footprint_to_world(m.footprint()) for m in self.movers]
        out.append(self.footprint_to_world(Footprint.box(0.0, -0.3, 0.9, 0.9)))
        if self.motion == "loop":
            c = self.rig.loop_centre
            out.append(Footprint.box(c[0], c[1], self.loop_radius + 1.0, self.loop_radius + 1.0))
        return out

    def without_movers(self) -> "StressPreset":
        """The same room, camera path and sensor without movers (named ``NAME_nomovers``)."""
        return replace(self, name=f"{self.name}_nomovers" if self.with_movers else self.name, with_movers=False)

    # ------------------------------------------------------------ serialisation
    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "StressPreset":
        """Inverse of :meth:`to_dict` (as read back from ``synthetic.json``)."""
        d = dict(d)
        d["movers"] = tuple(MoverSpec(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in m.items()}) for m in d["movers"])
        d["depth"] = DepthNoise(**d["depth"])
        for k in ("room", "eye"):
            d[k] = tuple(d[k])
        names = {f.name for f in fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"StressPreset: unknown fields {sorted(unknown)}")
        return cls(**d)


# ---------------------------------------------------------------- the generator
def _coverage_estimate(spec: MoverSpec, camera, eye_h: float, pitch_deg: float) -> float:
    """Rough largest image fraction a mover covers (at its nearest distance, seen whole): the
    generator keeps the sum over the movers below ``max_coverage``."""
    w, d, h = spec.size
    z = max(spec.depth_range[0] - {"carried": 0.5, "pushed": 0.3, "door": 0.0}.get(spec.kind, 0.5 * d), 0.35)
    seen_w = {"person": 0.5 * h / 1.72, "carried": 0.55, "pushed": 0.6 + d, "cart": max(w, d),
              "box": 0.9 * np.hypot(w, d), "panel": w, "door": w}[spec.kind]
    top = h if spec.kind in ("box", "panel", "door", "person") else (1.05 if spec.kind == "cart" else 1.8)
    fx, W, H = camera.fx, camera.width, camera.height
    half_v = np.arctan(0.5 * H / camera.fy)
    p = np.radians(pitch_deg)
    lo, hi = eye_h - z * np.tan(p + half_v), eye_h + z * np.tan(half_v - p)
    h_frac = max(0.0, min(hi, top) - max(lo, 0.0)) / (hi - lo)
    return float(min(1.0, seen_w * fx / z / W) * h_frac)


def _draw_size(kind: str, rng: np.random.Generator) -> tuple[float, float, float]:
    if kind in ("person", "carried"):
        return (0.5, 0.35, float(rng.uniform(1.55, 1.9)))
    if kind == "pushed":
        return (float(rng.uniform(0.5, 0.7)), float(rng.uniform(0.8, 1.1)), float(rng.uniform(1.55, 1.9)))
    if kind == "box":
        return (float(rng.uniform(0.4, 0.8)), float(rng.uniform(0.35, 0.6)), float(rng.uniform(0.9, 1.7)))
    if kind == "cart":
        return (float(rng.uniform(0.5, 0.7)), float(rng.uniform(0.8, 1.1)), 1.05)
    if kind == "panel":
        return (float(rng.uniform(0.9, 1.6)), 0.04, float(rng.uniform(1.3, 1.9)))
    return (float(rng.uniform(0.8, 1.0)), 0.04, float(rng.uniform(1.95, 2.1)))  # door


def _draw_mover(kind: str, pattern: str | None, rng: np.random.Generator, dist: tuple[float, float], speed: tuple[float, float],
                tan_h: float, excursion: tuple[float, float], shrink: float = 0.0, taken: tuple = ()) -> MoverSpec:
    """One :class:`MoverSpec` of ``kind`` drawn from ``rng`` (see :func:`random_scene_preset` for the ranges);
    ``shrink`` (0..1) lowers the longest path drawn towards the shortest and turns paths towards the image
    plane (to fit a crowded scene); the
    distance is drawn away from the regions ``taken`` ``(x0, x1, z0, z1)`` by movers already placed, where there
    is room, and else beside them."""
    v = float(rng.uniform(min(speed[0], MAX_SPEED[kind]), min(speed[1], MAX_SPEED[kind])))
    size = _draw_size(kind, rng)
    if pattern is None:
        pattern = str(rng.choice(PATTERNS, p=(0.4, 0.35, 0.25)))
    if kind == "door" and pattern == "enter":
        pattern = "stop_go"
    lo = min(dist[0] + excursion[0], dist[1])
    hi = dist[1]
    if kind == "door":
        w, swing = size[0], float(rng.uniform(70.0, 100.0))
        reach = w * np.sin(np.radians(swing))
        z = float(rng.uniform(lo, max(lo, hi - reach)))
        x = float(rng.uniform(-0.7, 0.3) * tan_h * z)
        side = 1.0 if rng.random() < 0.5 else -1.0
        delay = float(rng.uniform(0.0, 1.5))
        return MoverSpec(kind, (x, z), (x + side * w, z), v, pattern, size, delay, swing)
    length_min = max(0.8, 1.1 * v * v / 2.4)  # long enough to reach v at an acceleration <= 4 m/s^2
    approach = pattern != "enter" and rng.random() < 0.25 * (1.0 - shrink)  # towards / away from the camera, else across
    if approach:
        alpha = np.radians(rng.uniform(55.0, 90.0)) * (1.0 if rng.random() < 0.5 else -1.0)
        if length_min * abs(np.sin(alpha)) > hi - lo:
            alpha = np.radians(rng.uniform(-25.0, 25.0))
    else:
        alpha = np.radians(rng.uniform(-25.0, 25.0) if pattern != "enter" else rng.uniform(-12.0, 12.0)) * (1.0 - shrink)
    if pattern == "enter":
        side = 1.0 if rng.random() < 0.5 else -1.0
        along, r = _extent(kind, size, float(alpha))
        z0 = _free_uniform(rng, lo, hi, [(a - r, b + r) for _, _, a, b in taken])
        reach = 2 * along if kind == "pushed" else along  # how far the body reaches ahead of its origin
        x0 = side * (tan_h * z0 + reach + 0.25 + excursion[1])  # just outside the view
        x1 = -side * float(rng.uniform(-0.3, 0.6)) * tan_h * z0
        length = max(abs(x1 - x0) / np.cos(alpha), length_min)
        direction = np.array([-side * np.cos(alpha), np.sin(alpha)])
        end = np.array([x0, z0]) + length * direction
        if not lo <= end[1] <= hi:  # keep the far end in the distance range: walk straight across
            end = np.array([x0 - side * length, z0])
        delay = float(rng.uniform(0.5, 3.0))
        return MoverSpec(kind, (x0, z0), (float(end[0]), float(end[1])), v, pattern, size, delay)
    length = float(rng.uniform(length_min, max(length_min, length_min + (3.2 - length_min) * (1.0 - shrink))))
    if abs(np.sin(alpha)) * length > hi - lo:
        if approach:
            length = max(length_min, (hi - lo) / abs(np.sin(alpha)))
        if abs(np.sin(alpha)) * length > hi - lo:
            alpha = np.sign(alpha) * np.arcsin(min(1.0, (hi - lo) / length))
    half_dz = 0.5 * abs(np.sin(alpha)) * length
    along, across = _extent(kind, size, float(alpha))
    r = across + half_dz
    zc = _free_uniform(rng, lo + half_dz, max(lo + half_dz, hi - half_dz), [(a - r, b + r) for _, _, a, b in taken])
    half_dx = 0.5 * abs(np.cos(alpha)) * length + along
    beside = [(a - half_dx - 0.05, b + half_dx + 0.05) for a, b, z0, z1 in taken if z0 - r < zc < z1 + r]
    xc = _free_uniform(rng, -0.9 * tan_h * zc - 0.3, 0.9 * tan_h * zc + 0.3, beside)
    d = 0.5 * length * np.array([np.cos(alpha), np.sin(alpha)])
    a, b = np.array([xc, zc]) - d, np.array([xc, zc]) + d
    if rng.random() < 0.5:
        a, b = b, a
    delay = float(rng.uniform(0.0, 1.0))
    return MoverSpec(kind, (float(a[0]), float(a[1])), (float(b[0]), float(b[1])), v, pattern, size, delay)


def _check(arg: str, value, allowed) -> None:
    if value is not None and value not in allowed:
        raise ValueError(f"random_scene_preset: {arg} must be one of {allowed}, got {value!r}")


def random_scene_preset(
    seed: int,
    *,
    name: str | None = None,
    motion: str | None = None,
    n_movers: int | None = None,
    kinds: tuple[str, ...] | None = None,
    patterns: tuple[str, ...] | None = None,
    style: str | None = None,
    lighting: str | None = None,
    distance: tuple[float, float] = (0.8, 3.0),
    speed: tuple[float, float] = (0.4, 2.0),
    max_coverage: float = 0.6,
    n_frames: int = 300,
    with_movers: bool = True,
) -> StressPreset:
    """Draw a stress scene from ``seed``; any argument given overrides the draw.

    Drawn (uniformly unless stated): camera ``motion`` among static/xyz/rpy/halfsphere (``loop`` only
    on request); room ``style`` and ``lighting``; ``n_movers`` in 1..4; each mover's kind (person
    24 %, box 16 %, cart 10 %, panel 12 %, door 8 %, carried 15 %, pushed 15 %; at most one door),
    pattern (pace 40 %, stop_go 35 %, enter 25 %), size, cruise speed in ``speed`` (capped per kind:
    2 m/s for people, boxes and carts, 1.5 for panels, doors and pushed carts, 1.4 for carried boxes),
    path (0.8-3.2 m, at least 1.1 v^2 / 2.4 m, within 25 deg of the image plane, its distance in ``distance`` m from the base
    camera; the nearest distance grows by how far the camera comes forward: 0.31 m for halfsphere);
    camera height 1.2-1.6 m, looking down 6-14 deg, heading +-15 deg; room height 2.5-3.4 m, width
    and depth those the paths need plus 0.2-1.5 m a side (at least 3.5 m); 0-2 partitions and 4-10
    pieces of clutter; a loop radius of 0.6-1.0 m.

    Movers' paths never overlap, and the summed rough estimate of the image fraction each mover
    covers at its nearest (:func:`_coverage_estimate`) stays below ``max_coverage``: the draw of the
    movers is repeated (up to 200 times) until both hold, else a ``ValueError`` says why. The
    coverage actually rendered is measured per frame (``coverage.csv``).

    The scene-level draws and each mover's draws come from separate streams of ``seed``, so fixing
    one argument leaves the others as they were (as far as the movers still fit).
    """
    seed = int(seed)
    _check("motion", motion, MOTIONS)
    _check("style", style, ROOM_STYLES)
    _check("lighting", lighting, LIGHTINGS)
    if kinds is not None:
        kinds = tuple(kinds)
        for k in kinds:
            _check("each of kinds", k, MOVER_KINDS)
        if n_movers is not None and n_movers != len(kinds):
            raise ValueError(f"random_scene_preset: n_movers={n_movers} but {len(kinds)} kinds given")
        if kinds.count("door") > 1:
            raise ValueError("random_scene_preset: at most one door")
    if patterns is not None:
        patterns = tuple(patterns)
        for p in patterns:
            _check("each of patterns", p, PATTERNS)
    if n_movers is not None and not 0 <= n_movers <= 4:
        raise ValueError(f"random_scene_preset: n_movers must be in 0..4, got {n_movers}")
    lo, hi = (float(v) for v in distance)
    if not 0.6 <= lo < hi <= 4.5:
        raise ValueError(f"random_scene_preset: distance must be (lo, hi) with 0.6 <= lo < hi <= 4.5 m, got {distance}")
    vlo, vhi = (float(v) for v in speed)
    if not 0 < vlo <= vhi <= 2.0:
        raise ValueError(f"random_scene_preset: speed must be (lo, hi) with 0 < lo <= hi <= 2 m/s, got {speed}")
    if not 0 < max_coverage <= 1:
        raise ValueError(f"random_scene_preset: max_coverage must be in (0, 1], got {max_coverage}")
    if n_frames < 1:
        raise ValueError(f"random_scene_preset: n_frames must be >= 1, got {n_frames}")

    rs = np.random.default_rng([seed, 7001])  # scene-level draws, always all of them, in this order
    draw = dict(motion=str(rs.choice(MOTIONS[:4])), style=str(rs.choice(ROOM_STYLES)), lighting=str(rs.choice(LIGHTINGS)),
                n_movers=int(rs.integers(1, 5)))
    eye_h, pitch, yaw = float(rs.uniform(1.2, 1.6)), float(rs.uniform(6.0, 14.0)), float(rs.uniform(-15.0, 15.0))
    height = float(rs.uniform(2.5, 3.4))
    partitions, clutter = int(rs.integers(0, 3)), int(rs.integers(4, 11))
    loop_radius = float(rs.uniform(0.6, 1.0))
    margins = rs.uniform(0.2, 1.5, 4)
    motion = motion or draw["motion"]
    style = style or draw["style"]
    lighting = lighting or draw["lighting"]
    n = len(kinds) if kinds is not None else (draw["n_movers"] if n_movers is None else n_movers)
    if patterns is not None and len(patterns) not in (1, n):
        raise ValueError(f"random_scene_preset: give one pattern or one per mover ({n}), got {len(patterns)}")
    if motion == "loop":
        yaw = 0.0
    camera = CAMERA_PRESETS["default"]
    tan_h = 0.5 * camera.width / camera.fx
    excursion = (_FORWARD_EXCURSION[motion], _SIDE_EXCURSION[motion])
    loop_centre = np.array([0.0, -loop_radius])  # view frame

    movers: tuple[MoverSpec, ...] | None = () if n == 0 else None
    why, specs = "", []

    def misfit(spec: MoverSpec, placed: list[Footprint]) -> str:
        fp = spec.footprint()
        if any(fp.overlaps(q, 0.05) for q in placed):
            return "their paths overlap"
        if fp.corners()[:, 1].min() < 0.3 + excursion[0]:
            return "a path comes closer than 0.3 m to the camera"
        if motion == "loop" and fp.distance_to(loop_centre) < loop_radius + 0.45:
            return "a path comes within 0.45 m of the loop"
        return ""

    n_fixed = kinds is not None or n_movers is not None
    while movers is None:
        for attempt in range(100 if n else 0):  # draw the movers one by one, each until it fits; all again if one never does
            specs = []
            for i in range(n):
                rm = np.random.default_rng([seed, 7002, i, attempt])
                kind = kinds[i] if kinds is not None else str(rm.choice(MOVER_KINDS, p=_KIND_WEIGHTS))
                if kinds is None and kind == "door" and any(q.kind == "door" for q in specs):
                    kind = "box"
                pattern = None if patterns is None else patterns[i if len(patterns) > 1 else 0]
                placed = [q.footprint() for q in specs]
                taken = tuple((float(c[:, 0].min()), float(c[:, 0].max()), float(c[:, 1].min()), float(c[:, 1].max()))
                              for c in (fp.corners() for fp in placed))
                for k in range(40):
                    spec = _draw_mover(kind, pattern, rm, (lo, hi), (vlo, vhi), tan_h, excursion, shrink=k / 40, taken=taken)
                    why = misfit(spec, placed)
                    if not why:
                        specs.append(spec)
                        break
                else:
                    break
            if len(specs) < n:
                continue
            ests = sorted(_coverage_estimate(q, camera, eye_h, pitch) for q in specs)
            est = ests[-1] + 0.5 * sum(ests[:-1])  # rarely all at their nearest at once, and they hide each other
            if est > max_coverage:
                why = f"the coverage estimate {est:.2f} exceeds max_coverage {max_coverage}"
                continue
            movers = tuple(specs)
            break
        if movers is None and not n_fixed and n > 1:
            n -= 1  # a drawn number of movers that does not fit: one fewer
        else:
            break
    if movers is None:
        raise ValueError(f"random_scene_preset(seed={seed}): cannot place {n} movers ({', '.join(kinds or ['random'])}) "
                         f"in {distance} m: {why}; try fewer movers, a wider distance range or a larger max_coverage")

    # the room: everything the camera and the movers need, plus margins; the eye then in world coordinates
    probe = StressPreset("probe", seed, motion, style, lighting, (99.0, 99.0, height), (1.0, 1.0, eye_h), yaw, pitch,
                         loop_radius, movers=movers)
    pts = [fp.corners() for fp in probe.keep_out()]
    far = max([3.6] + [m.depth_range[1] + 1.0 for m in movers])
    pts.append(probe.to_world(np.array([[-1.0, far], [1.0, far], [0.0, -1.3]])))
    if motion == "loop":
        c = probe.rig.loop_centre
        reach = loop_radius + 1.5
        pts.append(np.array([[c[0] - reach, c[1] - reach], [c[0] + reach, c[1] + reach]]))
    P = np.concatenate(pts)
    lo_xy = P.min(axis=0) - margins[:2]
    hi_xy = P.max(axis=0) + margins[2:]
    size = np.maximum(hi_xy - lo_xy, 3.5)
    eye_xy = np.asarray(probe.eye[:2]) - lo_xy
    tallest = max([m.size[2] for m in movers if m.kind in ("door", "panel", "box")] + [0.0])
    room = (round(float(size[0]), 3), round(float(size[1]), 3), round(max(height, eye_h + 0.7, tallest + 0.3), 3))
    return StressPreset(
        name=name or f"random_s{seed}", seed=seed, motion=motion, style=style, lighting=lighting, room=room,
        eye=(float(eye_xy[0]), float(eye_xy[1]), eye_h), yaw=yaw, pitch=pitch, loop_radius=loop_radius,
        partitions=partitions, clutter=clutter, movers=movers, with_movers=with_movers, n_frames=int(n_frames),
    )


# ------------------------------------------------------------------ the scene
def _box_stack(bank: TextureBank, rng: np.random.Generator, inst: int, w: float, d: float, h: float) -> list:
    """A stack of 1-3 boxes (cardboard, plain plastic or striped) of total height ``h``, origin on the floor."""
    n = 1 if h < 0.7 else int(rng.integers(2, 4))
    heights = rng.uniform(0.7, 1.3, n)
    heights *= h / heights.sum()
    parts, z = [], 0.0
    for hz in heights:
        pick = rng.random()
        if pick < 0.6:
            tex = bank.add(tx.cardboard_texture(256, 256, rng))
        elif pick < 0.8:
            tex = bank.add(tx.paint_texture(128, 128, rng, tuple(rng.uniform(0.2, 0.8, 3)), amplitude=0.04))
        else:
            tex = bank.add(tx.stripes_texture(256, 256, rng))
        half = (0.5 * w * rng.uniform(0.85, 1.0), 0.5 * d * rng.uniform(0.85, 1.0), 0.5 * hz)
        parts.append((Shape("box", tuple(float(v) for v in half), textures=(tex,), instance=inst, density=400.0,
                            offset=(float(rng.uniform(0, 256)), float(rng.uniform(0, 256)))),
                      pose(rot_z(float(rng.uniform(-0.12, 0.12))), (0.0, 0.0, z + 0.5 * hz))))
        z += hz
    return parts


def _cart(bank: TextureBank, rng: np.random.Generator, inst: int, w: float, length: float) -> list:
    """A trolley ``w`` wide and ``length`` long, frame origin on the floor at the middle of its handle
    end, +y forward: platform, four wheels, a handle 1.06 m high, a load of 1-2 boxes."""
    metal = bank.add(tx.metal_texture(128, 256, rng, color=tuple(rng.uniform(0.3, 0.7, 3))))
    dark = bank.add(tx.metal_texture(64, 128, rng, color=(0.08, 0.08, 0.09)))

    def shape(kind, size, tex, density=400.0):
        return Shape(kind, tuple(float(v) for v in size), textures=(tex,), instance=inst, density=density, turn=256.0)

    parts = [(shape("box", (w / 2, length / 2, 0.02), metal), pose(None, (0.0, length / 2, 0.22)))]
    for sx in (-1, 1):
        for y in (0.1, length - 0.1):
            parts.append((shape("cylinder", (0.07, 0.07, 0.025), dark), pose(rot_y(np.pi / 2), (sx * (w / 2 - 0.06), y, 0.07))))
        parts.append((shape("box", (0.013, 0.013, 0.42), metal), pose(None, (sx * (w / 2 - 0.03), 0.03, 0.66))))
    parts.append((shape("cylinder", (0.016, 0.016, w / 2), metal), pose(rot_y(np.pi / 2), (0.0, 0.03, 1.06))))
    y = 0.1
    for _ in range(int(rng.integers(1, 3))):
        bl = float(rng.uniform(0.3, 0.45))
        if y + bl > length - 0.05:
            break
        half = w / 2 - 0.02  # the load's half-width: inside the platform (a 0.5 m cart leaves 0.23 m)
        bw, bh = float(rng.uniform(min(0.25, half), half)), float(rng.uniform(0.15, 0.35))
        tex = bank.add(tx.cardboard_texture(256, 256, rng))
        parts.append((Shape("box", (bw, bl / 2, bh), textures=(tex,), instance=inst, density=400.0), pose(None, (0.0, y + bl / 2, 0.24 + bh))))
        y += bl + 0.03
    return parts


# texture offset that puts texel (0, 0) at the top-left corner of a box's -y face (see shapes._FACE_OFFSET)
_FRONT_ALIGNED = (-float(_FACE_OFFSET[2, 0]), -float(_FACE_OFFSET[2, 1]))


def _panel(bank: TextureBank, rng: np.random.Generator, inst: int, w: float, h: float) -> list:
    """A free-standing board ``w x h`` m (facing +-y) on two feet; striped, a poster, plain or fine noise."""
    pick = rng.random()
    H, W = tx.aligned(h * 200), tx.aligned(w * 200)
    if pick < 0.3:
        img = tx.stripes_texture(H, W, rng, period=int(rng.integers(16, 48)))
    elif pick < 0.55:
        img = tx.poster(H, W, rng)
    elif pick < 0.8:
        img = tx.paint_texture(H, W, rng, tuple(rng.uniform(0.3, 0.9, 3)), amplitude=0.04)
    else:
        img = tx.granite_texture(H, W, rng, tuple(rng.uniform(0.0, 0.3, 3)), tuple(rng.uniform(0.6, 1.0, 3)))
    face = bank.add(img)
    edge = bank.add(tx.metal_texture(64, 128, rng, color=(0.3, 0.3, 0.32)))
    board = Shape("box", (w / 2, 0.02, (h - 0.08) / 2), textures=(edge, edge, face, face, edge, edge), instance=inst, density=200.0,
                  offset=_FRONT_ALIGNED)
    parts = [(board, pose(None, (0.0, 0.0, 0.08 + (h - 0.08) / 2)))]
    for sx in (-1, 1):
        parts.append((Shape("box", (0.03, 0.18, 0.04), textures=(edge,), instance=inst), pose(None, (sx * (w / 2 - 0.12), 0.0, 0.04))))
    return parts


def _door(bank: TextureBank, rng: np.random.Generator, inst: int, w: float, h: float) -> tuple[list, list]:
    """A door slab in its hinge frame (hinge = local z axis, slab along +x) and its static frame (two posts, a lintel)."""
    W, H = tx.aligned(w * 200), tx.aligned(h * 200)
    img = tx.wood_texture(H, W, rng, color=tuple(rng.uniform(0.4, 0.7, 3) * (1.0, 0.75, 0.5)))
    for y0, y1 in ((0.08, 0.46), (0.54, 0.92)):  # two recessed panels
        cv2.rectangle(img, (W // 8, int(H * y0)), (W - W // 8, int(H * y1)), (0.3, 0.2, 0.12), max(2, W // 50))
    slab_tex = bank.add(img)
    metal = bank.add(tx.metal_texture(64, 128, rng, color=(0.7, 0.7, 0.72)))
    frame_tex = bank.add(tx.paint_texture(128, 256, rng, tuple(rng.uniform(0.6, 0.95, 3)), amplitude=0.05))
    slab = [(Shape("box", (w / 2, 0.02, h / 2), textures=(metal, metal, slab_tex, slab_tex, metal, metal), instance=inst,
                   density=200.0, offset=_FRONT_ALIGNED), pose(None, (w / 2, 0.0, h / 2)))]
    for sy in (-1, 1):  # handles on both sides
        slab.append((Shape("box", (0.06, 0.02, 0.012), textures=(metal,), instance=inst), pose(None, (w - 0.1, sy * 0.04, 1.0))))
    frame = [(Shape("box", (0.04, 0.06, h / 2 + 0.04), textures=(frame_tex,), density=300.0), pose(None, (x, 0.0, h / 2 + 0.04)))
             for x in (-0.045, w + 0.045)]
    frame.append((Shape("box", (w / 2 + 0.085, 0.06, 0.05), textures=(frame_tex,), density=300.0), pose(None, (w / 2, 0.0, h + 0.13))))
    return slab, frame


def build_stress_scene(preset: StressPreset) -> OfficeScene:
    """The scene of a stress preset: room, clutter and lights (:func:`~dynslam_lab.datasets.rooms.build_room`), then
    the movers with their instances (ids from 1; a carried box or pushed cart right after its person).

    The textures of the movers are made even when ``with_movers`` is False (and then dropped with the
    movers), so both versions have the same texture bank and the same pixels wherever no mover is seen.
    """
    bank = TextureBank()
    static, lighting = build_room(preset.room, preset.style, preset.lighting, preset.partitions, preset.clutter,
                                  preset.keep_out(), np.random.default_rng([preset.seed, 7101]), bank)
    movers: list = []
    instances: dict[int, tuple[str, str]] = {}
    next_id = 1

    def new_id(cls: str, motion: str) -> int:
        nonlocal next_id
        instances[next_id] = (cls, motion)
        next_id += 1
        return next_id - 1

    for i, spec in enumerate(preset.movers):
        rng = np.random.default_rng([preset.seed, 7102, i])
        w, d, h = spec.size
        a, b = preset.to_world(spec.start), preset.to_world(spec.end)
        seg = Segment((float(a[0]), float(a[1])), (float(b[0]), float(b[1])))
        turn = {"person": 0.7, "carried": 1.2}.get(spec.kind, 0.0)  # s to turn round (slower with a box in the arms)
        plan = make_plan(spec.pattern, spec.path_length, spec.speed, spec.accel, rng, delay=spec.delay, turn=turn)
        if spec.kind in ("person", "carried", "pushed"):
            k = h / 1.72
            look = person_look(bank, rng, k)
            arms = {"carried": CARRY_ARMS, "pushed": PUSH_ARMS}.get(spec.kind)
            person = PersonMover(new_id(PERSON, "walking"), look, seg, plan, arms=arms, face_path=spec.kind == "pushed",
                                 lean=0.12 if spec.kind == "pushed" else 0.0)
            movers.append(person)
            if spec.kind == "carried":
                inst = new_id("box", "carried")
                hw, hd, hh = float(rng.uniform(0.19, 0.23)), float(rng.uniform(0.14, 0.19)), float(rng.uniform(0.14, 0.22))
                tex = bank.add(tx.cardboard_texture(256, 256, rng))
                box = [(Shape("box", (hw, hd, hh), textures=(tex,), instance=inst, density=400.0), np.eye(4))]
                movers.append(AttachedMover(inst, box, person, pose(None, (0.0, (0.2 + hd) * k, 1.08 * k)), "carried"))
            elif spec.kind == "pushed":
                inst = new_id("cart", "pushed")
                movers.append(AttachedMover(inst, _cart(bank, rng, inst, w, d), person, pose(None, (0.0, 0.47, 0.0)), "pushed"))
        elif spec.kind == "door":
            inst = new_id("door", "swinging")
            slab, frame = _door(bank, rng, inst, w, h)
            e = (b - a) / np.linalg.norm(b - a)
            sign = 1.0 if float(np.dot([-e[1], e[0]], preset.forward)) > 0 else -1.0  # opens away from the camera
            T_hinge = pose(rot_z(float(np.arctan2(e[1], e[0]))), (float(a[0]), float(a[1]), 0.0))
            movers.append(HingedMover(inst, slab, T_hinge, plan, float(np.linalg.norm(b - a)), sign))
            static.extend((s, T_hinge @ P) for s, P in frame)
        else:
            motion = {"box": "sliding", "cart": "rolling", "panel": "sliding"}[spec.kind]
            inst = new_id(MOVER_CLASSES[spec.kind], motion)
            view_yaw = float(np.arctan2(preset.forward[1], preset.forward[0])) - np.pi / 2  # object +y along the view
            if spec.kind == "box":
                parts, yaw = _box_stack(bank, rng, inst, w, d, h), view_yaw + float(rng.uniform(-0.5, 0.5))
            elif spec.kind == "cart":
                parts, yaw = _cart(bank, rng, inst, w, d), seg.yaw - np.pi / 2
                parts = [(s, pose(None, (0.0, -d / 2, 0.0)) @ P) for s, P in parts]  # centred on its path
            else:
                parts, yaw = _panel(bank, rng, inst, w, h), view_yaw
            movers.append(RigidMover(inst, parts, seg, plan, yaw, motion))
    if not preset.with_movers:
        movers, instances = [], {}
    return OfficeScene(bank=bank, static=static, movers=movers, instances=instances, lighting=lighting)


# ------------------------------------------------------------------ presets
def describe(preset: StressPreset) -> str:
    """A few lines on a stress preset: room, camera, each mover."""
    W, D, H = preset.room
    lines = [f"{preset.name}: {preset.style} room {W:.1f} x {D:.1f} x {H:.1f} m, {preset.lighting} light, camera {preset.motion}, "
             f"{preset.n_frames} frames, seed {preset.seed}" + ("" if preset.with_movers else ", without movers")]
    for m in preset.movers:
        z0, z1 = m.depth_range
        lines.append(f"  {m.kind:<8} {m.pattern:<8} {m.speed:.2f} m/s at {z0:.2f}-{z1:.2f} m, size {m.size[0]:.2f} x {m.size[1]:.2f} "
                     f"x {m.size[2]:.2f} m, classes {', '.join(m.classes)}")
    return "\n".join(lines)


def _named() -> tuple[dict[str, StressPreset], dict[str, StressPreset]]:
    """The named stress scenes: seeds and overrides of :func:`random_scene_preset`, 300 frames each."""
    suite = {
        "boxes_xyz": random_scene_preset(11, name="boxes_xyz", motion="xyz", kinds=("box", "box"), distance=(1.2, 3.0),
                                         speed=(1.0, 1.6), style="noise", lighting="even"),
        "crowd_rpy": random_scene_preset(12, name="crowd_rpy", motion="rpy", kinds=("person",) * 4, distance=(1.0, 3.0), max_coverage=0.8, style="pattern",
                                         lighting="bright"),
        "close_halfsphere": random_scene_preset(13, name="close_halfsphere", motion="halfsphere", kinds=("panel", "person"),
                                                distance=(0.8, 1.6), style="flat", lighting="lamp", max_coverage=0.9),
        "cart_static": random_scene_preset(14, name="cart_static", motion="static", kinds=("pushed", "cart"), style="photo",
                                           lighting="window"),
        "carried_xyz": random_scene_preset(15, name="carried_xyz", motion="xyz", kinds=("carried", "person"), style="flat",
                                           lighting="even", patterns=("stop_go",)),
        "door_static": random_scene_preset(16, name="door_static", motion="static", kinds=("door", "person"), style="pattern",
                                           lighting="dim", patterns=("stop_go", "enter")),
        "panel_rpy": random_scene_preset(17, name="panel_rpy", motion="rpy", kinds=("panel", "box"), style="photo",
                                         lighting="even"),
        "enter_halfsphere": random_scene_preset(18, name="enter_halfsphere", motion="halfsphere", kinds=("person", "box", "cart"),
                                                patterns=("enter",), style="noise", lighting="bright"),
        "mixed_xyz": random_scene_preset(19, name="mixed_xyz", motion="xyz", kinds=("pushed", "box", "person"), max_coverage=0.7,
                                         style="pattern", lighting="dim"),
        "fast_static": random_scene_preset(20, name="fast_static", motion="static", kinds=("box", "person"), speed=(1.8, 2.0),
                                           style="noise", lighting="lamp"),
    }
    loops = {
        f"loop_{style}": random_scene_preset(30 + k, name=f"loop_{style}", motion="loop", kinds=(), style=style, lighting=light,
                                             n_frames=450)
        for k, (style, light) in enumerate((("noise", "bright"), ("pattern", "even"), ("photo", "window"), ("flat", "even")))
    }
    return suite, loops


_NAMED: tuple[dict[str, StressPreset], dict[str, StressPreset]] | None = None


def _named_presets() -> tuple[dict[str, StressPreset], dict[str, StressPreset]]:
    global _NAMED
    if _NAMED is None:
        _NAMED = _named()
    return _NAMED


def __getattr__(name: str):
    """The named presets, drawn on first use (PEP 562; drawing them all takes about a second):

    * ``STRESS_SUITE``: ~10 scenes of 300 frames covering every mover kind, every fixed-view camera
      motion, every room style and lighting family, coverage up to ~50 % (``synthetic_sequence(p)`` for each);
    * ``STRESS_LOOPS``: loops of 450 frames round four unseen rooms, one per style, without movers
      (place recognition);
    * ``STRESS_PRESETS``: both, by name (``dynslam synth NAME OUTDIR``).
    """
    if name == "STRESS_SUITE":
        return _named_presets()[0]
    if name == "STRESS_LOOPS":
        return _named_presets()[1]
    if name == "STRESS_PRESETS":
        suite, loops = _named_presets()
        return {**suite, **loops}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def stress_suite(n_frames: int | None = None, loops: bool = False) -> list[StressPreset]:
    """The presets of :data:`STRESS_SUITE` (or :data:`STRESS_LOOPS`), with another length if ``n_frames`` is given."""
    presets = list(_named_presets()[1 if loops else 0].values())
    return presets if n_frames is None else [replace(p, n_frames=int(n_frames)) for p in presets]
