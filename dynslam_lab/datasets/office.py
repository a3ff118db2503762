"""The synthetic office: room, furniture, textures and people, built once per scene and seed.

:func:`build_office` makes the room (walls with posters, whiteboards, a window, a door and
notice boards; carpet and ceiling tiles), the desk with monitors, keyboard, papers, a cup, a
bottle and a book, two chairs, two shelves of books, a filing cabinet, a plant, a side table
with a laptop and a sofa, and the movers of the scene kind (:mod:`dynslam_lab.datasets.people`).
Every procedural texture comes from :mod:`dynslam_lab.datasets.textures`, drawn from one
seeded generator in a fixed order, so a seed gives the same office every time.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from . import textures as tx
from .people import PersonLook, Sitter, SlidingObject, Walker, heading_rotation
from .shapes import _FACE_OFFSET, Shape, pose, rot_x, rot_z, shape_corners

__all__ = ["ROOM_MIN", "ROOM_MAX", "VIEW_EYE", "VIEW_TARGET", "LAMP", "FILL_LIGHTS", "AMBIENT", "PERSON",
           "Lighting", "OFFICE_LIGHTING", "TextureBank", "OfficeScene", "build_office", "person_look"]

# World frame: z up, floor at z = 0; the room spans x in [-3, 3], y in [-2.5, 3.2], z in [0, 2.7] (m).
ROOM_MIN = np.array([-3.0, -2.5, 0.0])
ROOM_MAX = np.array([3.0, 3.2, 2.7])
#: Where the fixed-view presets look from and at (m, world): the desk with people around it.
VIEW_EYE = np.array([0.0, -1.1, 1.45])
VIEW_TARGET = np.array([0.0, 1.7, 0.85])
#: The ceiling lamp ``(position m, intensity)``, directional fill lights ``(direction towards the
#: light, intensity)`` and the ambient term of the Lambertian shading.
LAMP = (np.array([0.3, 0.6, 2.55]), 0.8)
FILL_LIGHTS = ((np.array([-0.5, -0.6, 0.62]), 0.3), (np.array([0.7, 0.3, 0.65]), 0.22))
AMBIENT = 0.36

PERSON = "person"


@dataclass(frozen=True)
class Lighting:
    """The lights of a scene, fixed in the room (Lambertian shading in ``synthetic._shade``).

    Attributes
    ----------
    lamp : position of the point lamp (m, world); its light fades as ``1 / (1 + d^2 / 9 m^2)``.
    lamp_power : the lamp's intensity (1 = full white on a surface facing it at close range).
    fills : directional fill lights ``((dx, dy, dz), power)``, the direction pointing towards the light.
    ambient : the ambient term added everywhere.
    """

    lamp: tuple[float, float, float]
    lamp_power: float
    fills: tuple[tuple[tuple[float, float, float], float], ...]
    ambient: float

    def __post_init__(self) -> None:
        if len(self.lamp) != 3:
            raise ValueError(f"Lighting.lamp must be a 3-D position (m), got {self.lamp!r}")
        if self.lamp_power < 0 or self.ambient < 0 or any(p < 0 for _, p in self.fills):
            raise ValueError(f"Lighting: powers and ambient must be >= 0, got lamp_power={self.lamp_power}, "
                             f"ambient={self.ambient}, fills={self.fills}")
        if any(len(d) != 3 or not np.any(d) for d, _ in self.fills):
            raise ValueError(f"Lighting.fills: each direction must be a non-zero 3-vector, got {self.fills!r}")


#: The office's lights (the constants above as one :class:`Lighting`).
OFFICE_LIGHTING = Lighting(tuple(float(v) for v in LAMP[0]), LAMP[1],
                           tuple((tuple(float(v) for v in d), p) for d, p in FILL_LIGHTS), AMBIENT)


class TextureBank:
    """Collects the textures of a scene and hands out their indices."""

    def __init__(self) -> None:
        self.images: list[np.ndarray] = []

    def add(self, img: np.ndarray) -> int:
        self.images.append(img)
        return len(self.images) - 1

    def size(self, index: int) -> tuple[int, int]:
        """``(width, height)`` in texels."""
        h, w = self.images[index].shape[:2]
        return w, h


@dataclass
class OfficeScene:
    """The office: static parts, movers, instances and the texture bank.

    Build it with :func:`build_office` (the stress rooms of :mod:`~dynslam_lab.datasets.stress` use
    the same container). ``parts(t)`` lists every shape with its pose at time ``t`` (s);
    ``instances`` maps id -> ``(class, motion)``; ``lighting`` holds the lights.
    """

    bank: TextureBank
    static: list[tuple[Shape, np.ndarray]]
    movers: list
    instances: dict[int, tuple[str, str]] = field(default_factory=dict)
    lighting: Lighting = OFFICE_LIGHTING
    _posed: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def parts(self, t: float) -> list[tuple[Shape, np.ndarray]]:
        out = list(self.static)
        for m in self._mover_parts(t):
            out.extend(m)
        return out

    def _mover_parts(self, t: float) -> list[list[tuple[Shape, np.ndarray]]]:
        """Parts of each mover at time ``t``; the last few times are kept (a frame's render and the
        motion check of the next frame pose the movers at the same times)."""
        key = float(t)
        hit = self._posed.get(key)
        if hit is None:
            hit = [m.parts(key) for m in self.movers]
            if len(self._posed) >= 4:
                self._posed.pop(next(iter(self._posed)))
            self._posed[key] = hit
        return hit

    def displacement(self, t0: float, t1: float) -> dict[int, float]:
        """Largest displacement (m) of any bounding-box corner of each mover's parts from ``t0`` to ``t1``."""
        out: dict[int, float] = {}
        for m, a, b in zip(self.movers, self._mover_parts(t0), self._mover_parts(t1)):
            d = 0.0
            for (sh, Ta), (_, Tb) in zip(a, b):
                C = _corners(sh)
                pa = C @ Ta[:3, :3].T + Ta[:3, 3]
                pb = C @ Tb[:3, :3].T + Tb[:3, 3]
                d = max(d, float(np.linalg.norm(pa - pb, axis=1).max()))
            out[m.instance] = d
        return out

    def instance_bounds(self, t: float, margin: float = 0.0) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """World axis-aligned bounds ``(min (3,), max (3,))`` of each instance at time ``t`` (m)."""
        lo: dict[int, np.ndarray] = {}
        hi: dict[int, np.ndarray] = {}
        for sh, T in self.parts(t):
            if sh.instance == 0:
                continue
            P = shape_corners(sh) @ T[:3, :3].T + T[:3, 3]
            i = sh.instance
            lo[i] = np.minimum(lo.get(i, P.min(0)), P.min(0))
            hi[i] = np.maximum(hi.get(i, P.max(0)), P.max(0))
        return {i: (lo[i] - margin, hi[i] + margin) for i in lo}


_CORNERS: dict = {}


def _corners(shape: Shape) -> np.ndarray:
    """:func:`shape_corners` of a shape, computed once (read-only)."""
    c = _CORNERS.get(shape)
    if c is None:
        if len(_CORNERS) >= 20000:  # many scenes passed through: start afresh
            _CORNERS.clear()
        c = _CORNERS[shape] = shape_corners(shape)
        c.flags.writeable = False
    return c


def person_look(bank: TextureBank, rng: np.random.Generator, height: float = 1.0) -> PersonLook:
    """A person's clothes, head and skin: five new textures in ``bank`` drawn from ``rng``."""
    return PersonLook(
        shirt=bank.add(tx.fabric_texture(256, 256, rng)),
        trousers=bank.add(tx.denim_texture(256, 256, rng)),
        head=bank.add(tx.head_texture(256, 512, rng)),
        skin=bank.add(tx.skin_texture(128, 128, rng)),
        shoes=bank.add(tx.metal_texture(64, 128, rng, color=(0.08, 0.06, 0.05))),
        height=height,
    )


def _wall_texture(w_m: float, h_m: float, density: float, rng: np.random.Generator, items: list[tuple[str, float, float, float, float]],
                  color=(0.8, 0.78, 0.72)) -> np.ndarray:
    """A plaster wall ``w_m x h_m`` metres with posters, boards and notices.

    ``items`` are ``(kind, x, y, w, h)`` in metres from the wall's top-left corner (seen from inside).
    """
    W, H = tx.aligned(w_m * density), tx.aligned(h_m * density)
    img = tx.plaster_texture(H, W, rng, color)
    makers = {"poster": tx.poster, "whiteboard": tx.whiteboard, "paper": tx.paper_texture, "screen": tx.screen_texture,
              "wood": tx.wood_texture, "books": tx.book_texture}
    for kind, x, y, w, h in items:
        pw, ph = int(w * density), int(h * density)
        if kind == "notice":  # a cork board covered with sheets of paper
            board = tx.colorize(tx.fractal_noise(ph, pw, rng, base_cell=16, octaves=3), (0.45, 0.3, 0.15), (0.7, 0.5, 0.3))
            for _ in range(int(w * h * 40)):
                sw, sh = int(rng.uniform(0.1, 0.22) * density), int(rng.uniform(0.12, 0.3) * density)
                tx.paste(board, tx.paper_texture(sh, sw, rng), int(rng.integers(-sw // 2, pw)), int(rng.integers(-sh // 2, ph)))
            tex = board
        elif kind == "door":
            tex = tx.wood_texture(ph, pw, rng, color=(0.6, 0.42, 0.25))
            cv2.rectangle(tex, (pw // 10, ph // 12), (pw - pw // 10, ph // 2 - ph // 24), (0.35, 0.22, 0.12), max(2, pw // 60))
            cv2.rectangle(tex, (pw // 10, ph // 2 + ph // 24), (pw - pw // 10, ph - ph // 12), (0.35, 0.22, 0.12), max(2, pw // 60))
            cv2.circle(tex, (pw - pw // 8, ph // 2), max(3, pw // 25), (0.8, 0.8, 0.75), -1)
        elif kind == "window":
            tex = tx.colorize(tx.fractal_noise(ph, pw, rng, base_cell=pw / 3, octaves=5), (0.55, 0.7, 0.85), (0.95, 0.97, 1.0))
            for k in range(1, 3):
                cv2.line(tex, (k * pw // 3, 0), (k * pw // 3, ph), (0.9, 0.9, 0.9), max(3, pw // 50))
            cv2.line(tex, (0, ph // 2), (pw, ph // 2), (0.9, 0.9, 0.9), max(3, pw // 50))
            cv2.rectangle(tex, (0, 0), (pw - 1, ph - 1), (0.92, 0.92, 0.92), max(4, pw // 30))
        else:
            tex = makers[kind](ph, pw, rng)
        tx.paste(img, tex, int(x * density), int(y * density))
    return img


def build_office(scene: str, rng: np.random.Generator) -> OfficeScene:
    """Build the office for a scene kind: ``"walking"`` (two people walking), ``"sitting"`` (two
    people seated at the desk, a book moved now and then), ``"static"`` (nobody), ``"walking_one"``
    (one walker, for the loop preset).

    Instance ids: people first (1, 2), then the furniture; 0 is the room (walls, floor, ceiling, shelves).
    """
    if scene not in ("walking", "sitting", "static", "walking_one"):
        raise ValueError(f"unknown scene kind {scene!r}; choose walking, sitting, static or walking_one")
    bank = TextureBank()
    static: list[tuple[Shape, np.ndarray]] = []
    instances: dict[int, tuple[str, str]] = {}
    movers: list = []
    next_id = [3]

    def new_instance(cls: str, motion: str = "static") -> int:
        i = next_id[0]
        next_id[0] += 1
        instances[i] = (cls, motion)
        return i

    # ---------------------------------------------------------------- the room
    size = ROOM_MAX - ROOM_MIN
    dens_wall = 160.0
    back = _wall_texture(size[0], size[2], dens_wall, rng, [("poster", 3.6, 0.35, 0.6, 0.85), ("poster", 4.45, 0.5, 0.7, 0.5),
                                                        ("whiteboard", 1.0, 0.45, 1.6, 1.0), ("paper", 5.2, 0.9, 0.25, 0.33)])
    left = _wall_texture(size[1], size[2], dens_wall, rng, [("window", 0.6, 0.5, 1.6, 1.2), ("poster", 2.7, 0.45, 0.7, 1.0),
                                                        ("notice", 3.8, 0.6, 1.2, 0.8)])
    right = _wall_texture(size[1], size[2], dens_wall, rng, [("whiteboard", 0.6, 0.4, 2.0, 1.1), ("poster", 3.0, 0.5, 0.55, 0.8),
                                                         ("poster", 3.8, 0.4, 0.8, 0.6), ("paper", 4.8, 0.9, 0.3, 0.4)])
    front = _wall_texture(size[0], size[2], dens_wall, rng, [("door", 0.5, 0.6, 1.0, 2.1), ("notice", 2.2, 0.5, 1.4, 0.9),
                                                         ("poster", 4.1, 0.4, 0.8, 1.0), ("poster", 5.05, 0.7, 0.6, 0.45)])
    dens_floor = dens_wall
    floor = tx.floor_texture(tx.aligned(size[1] * dens_floor), tx.aligned(size[0] * dens_floor), rng, tile=int(0.5 * dens_floor))
    ceil = tx.ceiling_texture(tx.aligned(size[1] * dens_floor), tx.aligned(size[0] * dens_floor), rng, tile=int(0.6 * dens_floor))
    # faces -x (left wall), +x (right), -y (front), +y (back), -z (floor), +z (ceiling)
    faces = (bank.add(left), bank.add(right), bank.add(front), bank.add(back), bank.add(floor), bank.add(ceil))
    room = Shape("room", tuple(size / 2), textures=faces, density=dens_wall, offset=(0.0, 0.0))
    static.append((room, pose(None, (ROOM_MIN + ROOM_MAX) / 2)))

    # ------------------------------------------------------------------ textures
    wood = bank.add(tx.wood_texture(256, 512, rng))
    wood_dark = bank.add(tx.wood_texture(256, 512, rng, color=(0.35, 0.22, 0.12)))
    metal = bank.add(tx.metal_texture(128, 256, rng))
    plastic = bank.add(tx.metal_texture(128, 256, rng, color=(0.1, 0.1, 0.11)))
    screens = [bank.add(tx.screen_texture(192, 320, rng)) for _ in range(3)]
    books = bank.add(tx.book_texture(256, 512, rng))
    papers = bank.add(tx.paper_texture(256, 256, rng))
    keyboard = bank.add(tx.keyboard_texture(64, 256, rng))
    leaves = bank.add(tx.leaves_texture(256, 256, rng))
    cushion = bank.add(tx.fabric_texture(256, 256, rng))
    sofa_tex = bank.add(tx.denim_texture(256, 512, rng))
    ceramic = bank.add(tx.poster(128, 256, rng))

    def box(half, center, tex, inst=0, R=None, density=400.0, tint=(1.0, 1.0, 1.0), dropout=0.0, offset=None):
        if offset is None:
            offset = (float(rng.uniform(0, 512)), float(rng.uniform(0, 512)))
        shape = Shape("box", tuple(float(h) for h in half), textures=tex if isinstance(tex, tuple) else (tex,),
                      instance=inst, density=density, tint=tint, dropout=dropout, offset=offset)
        static.append((shape, pose(R, center)))
        return shape

    # ---------------------------------------------------------- desk ("dining table")
    desk = new_instance("dining table")
    box((0.9, 0.42, 0.015), (0.0, 1.5, 0.735), wood, desk, density=300.0)
    for sx in (-1, 1):
        for sy in (-1, 1):
            box((0.025, 0.025, 0.36), (sx * 0.85, 1.5 + sy * 0.37, 0.36), metal, desk)
    box((0.84, 0.01, 0.22), (0.0, 1.16, 0.47), wood_dark, desk, density=300.0)
    for k, (x, y, a) in enumerate([(-0.3, 1.3, 0.2), (0.7, 1.62, -0.4), (-0.75, 1.65, 0.1)]):
        box((0.105, 0.148, 0.001), (x, y, 0.751 + 0.001 * k), papers, desk, R=rot_z(a), density=1000.0)
    # monitors ("tv") with screens facing the camera side (-y)
    for k, x in enumerate((-0.42, 0.42)):
        tv = new_instance("tv")
        scr = screens[k]
        box((0.27, 0.025, 0.17), (x, 1.75, 1.08), plastic, tv)
        # the glossy screen in front of the body: the Kinect often gets no depth from it
        box((0.25, 0.002, 0.15), (x, 1.724, 1.09), (plastic, plastic, scr, plastic, plastic, plastic), tv, density=560.0,
            dropout=0.25, offset=(-float(_FACE_OFFSET[2, 0]) + 20.0, -float(_FACE_OFFSET[2, 1]) + 8.0))
        box((0.02, 0.02, 0.1), (x, 1.79, 0.85), plastic, tv)
        box((0.11, 0.08, 0.008), (x, 1.77, 0.758), plastic, tv)
    kb = new_instance("keyboard")
    box((0.22, 0.07, 0.012), (0.0, 1.33, 0.762), (plastic, plastic, plastic, plastic, plastic, keyboard), kb, density=560.0)
    cup = new_instance("cup")
    static.append((Shape("cylinder", (0.04, 0.04, 0.05), textures=(ceramic,), instance=cup, density=600.0, turn=256.0),
                   pose(None, (0.32, 1.3, 0.8))))
    bottle = new_instance("bottle")
    static.append((Shape("capsule", (0.035, 0.035, 0.09), textures=(ceramic,), instance=bottle, density=600.0, turn=256.0,
                         tint=(0.6, 0.9, 0.7)), pose(None, (-0.62, 1.32, 0.875))))
    # a book on the desk (pushed now and then in the sitting scene)
    bk = new_instance("book", "moved" if scene == "sitting" else "static")
    book_shape = Shape("box", (0.1, 0.14, 0.02), textures=(books,), instance=bk, density=500.0, offset=(100.0, 40.0))
    T_book = pose(rot_z(0.3), (0.45, 1.38, 0.771))
    if scene == "sitting":
        movers.append(SlidingObject(bk, [(book_shape, np.eye(4))], T_book))
    else:
        static.append((book_shape, T_book))

    # ------------------------------------------------------------------- chairs
    def chair(T_w: np.ndarray, tint) -> None:
        ch = new_instance("chair")
        parts = [
            (Shape("box", (0.23, 0.23, 0.035), textures=(cushion,), instance=ch, density=500.0, tint=tint), pose(None, (0, 0, 0.47))),
            (Shape("box", (0.22, 0.025, 0.24), textures=(cushion,), instance=ch, density=500.0, tint=tint, offset=(70.0, 30.0)),
             pose(rot_x(-0.1), (0, -0.24, 0.8))),
            (Shape("cylinder", (0.025, 0.025, 0.2), textures=(metal,), instance=ch, density=500.0, turn=256.0), pose(None, (0, 0, 0.24))),
            (Shape("box", (0.3, 0.025, 0.02), textures=(plastic,), instance=ch), pose(rot_z(0.7), (0, 0, 0.05))),
            (Shape("box", (0.3, 0.025, 0.02), textures=(plastic,), instance=ch), pose(rot_z(-0.7), (0, 0, 0.05))),
        ]
        static.extend((s, T_w @ P) for s, P in parts)

    seats = [pose(heading_rotation(0.0), (-1.3, 1.55, 0.0)), pose(heading_rotation(np.pi), (1.32, 1.45, 0.0))]
    chair(seats[0], (0.5, 0.6, 1.0))
    chair(seats[1], (1.0, 0.55, 0.45))

    # ---------------------------------------------------------- shelves and books
    def shelf(x0: float, x1: float, height: float, n_boards: int) -> None:
        y_back, depth = ROOM_MAX[1], 0.34
        yc = y_back - depth / 2
        xc, hw = 0.5 * (x0 + x1), 0.5 * (x1 - x0)
        for sx in (x0 + 0.015, x1 - 0.015):
            box((0.015, depth / 2, height / 2), (sx, yc, height / 2), wood, density=300.0)
        box((hw, 0.005, height / 2), (xc, y_back - 0.006, height / 2), wood_dark, density=300.0)
        zs = np.linspace(0.08, height - 0.015, n_boards)
        for z in zs:
            box((hw - 0.03, depth / 2, 0.012), (xc, yc, z), wood, density=300.0)
        for z0 in zs[:-1]:
            x = x0 + 0.04
            while True:
                w = float(rng.uniform(0.02, 0.05))
                h = float(rng.uniform(0.17, min(0.3, zs[1] - zs[0] - 0.05)))
                if x + 2 * w > x1 - 0.04:
                    break
                if rng.random() < 0.12:  # a gap
                    x += float(rng.uniform(0.05, 0.15))
                    continue
                bid = new_instance("book")
                tint = tuple(float(v) for v in rng.uniform(0.5, 1.2, 3))
                box((w, 0.11, h / 2), (x + w, yc - 0.03, z0 + 0.012 + h / 2), books, bid, density=600.0, tint=tint)
                x += 2 * w + 0.003

    shelf(-2.8, -1.5, 2.0, 5)
    shelf(1.5, 2.8, 1.6, 4)

    # --------------------------------------------------- side furniture (left, right, front)
    # a metal filing cabinet (no COCO class: part of the room, id 0)
    box((0.25, 0.45, 0.6), (ROOM_MIN[0] + 0.26, 0.4, 0.6), metal, 0, density=300.0, tint=(0.9, 0.95, 1.0))
    plant = new_instance("potted plant")
    static.append((Shape("cylinder", (0.13, 0.13, 0.12), textures=(ceramic,), instance=plant, density=500.0, turn=512.0),
                   pose(None, (ROOM_MIN[0] + 0.3, 0.2, 1.32))))
    static.append((Shape("ellipsoid", (0.24, 0.24, 0.3), textures=(leaves,), instance=plant, density=400.0, turn=512.0),
                   pose(None, (ROOM_MIN[0] + 0.3, 0.2, 1.68))))
    side = new_instance("dining table")
    box((0.4, 0.8, 0.015), (ROOM_MAX[0] - 0.42, 0.2, 0.735), wood, side, density=300.0)
    for sy in (-1, 1):
        for dx in (-0.35, 0.35):
            box((0.02, 0.02, 0.36), (ROOM_MAX[0] - 0.42 + dx, 0.2 + sy * 0.75, 0.36), metal, side)
    lap = new_instance("laptop")
    box((0.17, 0.12, 0.01), (ROOM_MAX[0] - 0.45, 0.1, 0.76), (plastic, plastic, plastic, plastic, plastic, keyboard), lap, density=560.0)
    box((0.17, 0.005, 0.11), (ROOM_MAX[0] - 0.32, 0.1, 0.86), (plastic, plastic, screens[2], plastic, plastic, plastic), lap,
        R=rot_z(np.pi / 2) @ rot_x(0.25), density=560.0)
    couch = new_instance("couch")
    box((0.95, 0.38, 0.2), (0.4, ROOM_MIN[1] + 0.45, 0.22), sofa_tex, couch, density=400.0)
    box((0.95, 0.1, 0.42), (0.4, ROOM_MIN[1] + 0.12, 0.42), sofa_tex, couch, density=400.0)
    for sx in (-1, 1):
        box((0.08, 0.38, 0.32), (0.4 + sx * 1.0, ROOM_MIN[1] + 0.45, 0.32), sofa_tex, couch, density=400.0)

    # ------------------------------------------------------------------- people
    def look(height: float) -> PersonLook:
        return person_look(bank, rng, height)

    if scene == "walking_one":  # the loop's walker keeps behind the desk, clear of the camera's circle
        instances[1] = (PERSON, "walking")
        movers.append(Walker(1, look(1.0), np.array([[1.8, 2.3], [-1.9, 2.3], [-1.9, 2.6], [1.8, 2.6]]), speed=0.8))
    elif scene == "walking":
        instances[1] = (PERSON, "walking")
        front_path = np.array([[-1.5, 0.05], [1.5, 0.05], [1.5, 0.4], [-1.5, 0.4]])
        movers.append(Walker(1, look(1.0), front_path, speed=0.9, start=1.0))
        instances[2] = (PERSON, "walking")
        # behind the desk to the left, round its left end, along its front, back round the right end
        back_path = np.array([[1.85, 2.4], [-1.95, 2.4], [-1.95, 0.8], [1.85, 0.8]])
        movers.append(Walker(2, look(0.96), back_path, speed=0.8, start=1.0))
    elif scene == "sitting":
        instances[1] = (PERSON, "sitting")
        instances[2] = (PERSON, "sitting")
        movers.append(Sitter(1, look(1.0), seats[0], phase=0.3))
        movers.append(Sitter(2, look(0.95), seats[1], phase=2.1))
    instances = dict(sorted(instances.items()))
    return OfficeScene(bank=bank, static=static, movers=movers, instances=instances)
