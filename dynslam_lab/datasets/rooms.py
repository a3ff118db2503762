"""Rooms of the stress scenes: box rooms of any size in four surface families, clutter, partitions, lights.

:func:`build_room` makes the static part of a stress scene (:mod:`dynslam_lab.datasets.stress`):
a room ``[0, W] x [0, D] x [0, H]`` (world frame: z up, floor at z = 0, metres) whose walls,
floor and ceiling carry textures of one *style*:

* ``noise``: fine granite-like grain everywhere (dense, structureless texture);
* ``flat``: plain paint with faint stains, skirting boards, a framed picture about every 2 m (large
  weakly textured areas: few keypoints, most of them on the pictures and the room's edges);
* ``pattern``: repeated patterns (bricks, tiles or a wallpaper motif on the walls, a checkerboard or
  plank floor): many keypoints with near-identical descriptors;
* ``photo``: photographic prints edge to edge and hill-shaded relief murals
  (:mod:`dynslam_lab.datasets.photos`), a stone-like floor.

Clutter (crate stacks, cabinets, tables, shelves, columns) stands along the walls, partitions (wall
stubs) jut into the room and change its shape; neither enters the *keep-out* footprints the caller
gives (where the movers go, where the camera moves). The lights come in five families
(:data:`LIGHTINGS`). Static parts are background (instance id 0). Everything is drawn from one
seeded generator in a fixed order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import photos
from . import textures as tx
from .office import Lighting, TextureBank
from .shapes import Shape, pose, rot_z

__all__ = ["ROOM_STYLES", "LIGHTINGS", "DENSITY", "Footprint", "build_room", "room_lighting"]

ROOM_STYLES = ("noise", "flat", "pattern", "photo")
LIGHTINGS = ("even", "dim", "lamp", "bright", "window")
DENSITY = 160.0  # texels per metre on walls, floor and ceiling (as in the office)


@dataclass(frozen=True)
class Footprint:
    """An oriented rectangle on the floor: centre ``(cx, cy)``, unit axis ``(ux, uy)``, half-length
    ``a`` along the axis and half-width ``b`` across it (m)."""

    cx: float
    cy: float
    ux: float
    uy: float
    a: float
    b: float

    @staticmethod
    def of_segment(p0, p1, half_width: float, end_margin: float) -> "Footprint":
        """The region swept by a body of half-width ``half_width`` moving from ``p0`` to ``p1``
        (``end_margin`` beyond both ends)."""
        p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
        d = p1 - p0
        L = float(np.linalg.norm(d))
        u = d / L if L > 1e-9 else np.array([1.0, 0.0])
        c = 0.5 * (p0 + p1)
        return Footprint(float(c[0]), float(c[1]), float(u[0]), float(u[1]), 0.5 * L + end_margin, half_width)

    @staticmethod
    def box(cx: float, cy: float, hx: float, hy: float, yaw: float = 0.0) -> "Footprint":
        """A rectangle of half sizes ``hx, hy`` rotated by ``yaw`` (rad)."""
        return Footprint(cx, cy, float(np.cos(yaw)), float(np.sin(yaw)), hx, hy)

    def corners(self) -> np.ndarray:
        """``(4, 2)`` corners."""
        return np.array(self._corners())

    def _corners(self) -> list[tuple[float, float]]:
        ax, ay = self.a * self.ux, self.a * self.uy
        bx, by = -self.b * self.uy, self.b * self.ux
        return [(self.cx + sa * ax + sb * bx, self.cy + sa * ay + sb * by) for sa, sb in ((1, 1), (1, -1), (-1, -1), (-1, 1))]

    def overlaps(self, other: "Footprint", margin: float = 0.0) -> bool:
        """Whether the two rectangles, each grown by ``margin`` m, intersect (separating axes; plain floats,
        as the scene generator calls this a great many times)."""
        reach = np.hypot(self.a, self.b) + np.hypot(other.a, other.b) + 2 * margin
        if (self.cx - other.cx) ** 2 + (self.cy - other.cy) ** 2 > reach * reach:
            return False
        A, B = self.grown(margin)._corners(), other.grown(margin)._corners()
        for f in (self, other):
            for ax, ay in ((f.ux, f.uy), (-f.uy, f.ux)):
                pa = [x * ax + y * ay for x, y in A]
                pb = [x * ax + y * ay for x, y in B]
                if max(pa) < min(pb) or max(pb) < min(pa):
                    return False
        return True

    def grown(self, margin: float) -> "Footprint":
        return Footprint(self.cx, self.cy, self.ux, self.uy, self.a + margin, self.b + margin)

    def distance_to(self, p) -> float:
        """Distance (m) from point ``p (2,)`` to the rectangle (0 inside)."""
        d = np.asarray(p, float) - (self.cx, self.cy)
        la, lb = abs(d @ (self.ux, self.uy)), abs(d @ (-self.uy, self.ux))
        return float(np.hypot(max(la - self.a, 0.0), max(lb - self.b, 0.0)))

    def inside(self, lo, hi, margin: float = 0.0) -> bool:
        """Whether the rectangle lies in the axis-aligned box ``[lo, hi]`` shrunk by ``margin``."""
        C = self.corners()
        return bool(np.all(C >= np.asarray(lo) + margin) and np.all(C <= np.asarray(hi) - margin))


# ------------------------------------------------------------------- surfaces
def _palette(rng: np.random.Generator) -> np.ndarray:
    """A base colour of a room (RGB 0..1): muted, light."""
    hue = rng.uniform(0.45, 0.95, 3)
    return (0.55 * hue + 0.45 * hue.mean()).astype(np.float32)


def _skirting(img: np.ndarray, rng: np.random.Generator) -> None:
    """A dark skirting board along the bottom of a wall texture (in place)."""
    h = int(0.1 * DENSITY)
    img[-h:] = np.float32(rng.uniform(0.15, 0.4)) * np.array([1.0, 0.95, 0.9], np.float32)
    img[-h - 2 : -h] *= 0.6


def _wall_surface(style: str, kind: str, w_m: float, h_m: float, base: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Texture ``(H, W, 3)`` of a wall ``w_m x h_m`` m in a style; ``kind`` picks the pattern of ``pattern`` rooms."""
    W, H = tx.aligned(w_m * DENSITY), tx.aligned(h_m * DENSITY)
    if style == "noise":
        tint = base * rng.uniform(0.8, 1.15, 3).astype(np.float32)
        return tx.granite_texture(H, W, rng, np.clip(tint * 0.35, 0, 1), np.clip(tint * 1.1, 0, 1))
    if style == "flat":
        img = tx.paint_texture(H, W, rng, np.clip(base * rng.uniform(0.95, 1.1), 0, 1), amplitude=0.025)
        _skirting(img, rng)
        n = max(1, int(round(w_m / rng.uniform(1.5, 2.2))))
        for k in range(n):  # framed pictures about every 2 m: the only texture on the wall
            pw, ph = int(rng.uniform(0.4, 0.8) * DENSITY), int(rng.uniform(0.5, 0.9) * DENSITY)
            x = (k + rng.uniform(0.2, 0.8)) * w_m / n - 0.5 * pw / DENSITY
            tx.paste(img, tx.poster(ph, pw, rng), int(x * DENSITY), int(rng.uniform(0.4, 0.8) * DENSITY))
        return img
    if style == "pattern":
        if kind == "brick":
            img = tx.brick_texture(H, W, rng, brick=(int(0.24 * DENSITY), int(0.075 * DENSITY)), mortar=2,
                                   color=np.clip(base * (0.9, 0.5, 0.4) * 1.3, 0, 1))
        elif kind == "tiles":
            img = tx.tile_texture(H, W, rng, tile=int(0.2 * DENSITY), grout=2, colors=(np.clip(base * 1.1, 0, 1),))
        else:
            img = tx.wallpaper_texture(H, W, rng, period=int(rng.choice([0.25, 0.35, 0.45]) * DENSITY))
        _skirting(img, rng)
        return img
    if style == "photo":
        if rng.random() < 0.5:
            return tx.add_speckle(photos.photo_collage(H, W, rng, cell=int(rng.uniform(0.7, 1.1) * DENSITY)), rng, amount=0.15)
        img = tx.paint_texture(H, W, rng, np.clip(base, 0, 1), amplitude=0.04)
        x = int(rng.uniform(0.05, 0.3) * DENSITY)
        while x < W - 0.6 * DENSITY:  # large relief murals side by side
            pw, ph = int(rng.uniform(0.9, 2.0) * DENSITY), int(min(h_m - 0.6, rng.uniform(1.0, 1.8)) * DENSITY)
            tx.paste(img, photos.relief_image(ph, pw, rng), x, int(rng.uniform(0.2, 0.5) * DENSITY))
            x += pw + int(rng.uniform(0.1, 0.6) * DENSITY)
        return tx.add_speckle(img, rng, amount=0.15)
    raise ValueError(f"room style must be one of {ROOM_STYLES}, got {style!r}")


def _floor_surface(style: str, w_m: float, d_m: float, rng: np.random.Generator) -> np.ndarray:
    W, D = tx.aligned(w_m * DENSITY), tx.aligned(d_m * DENSITY)
    if style == "noise":
        return tx.granite_texture(D, W, rng, (0.12, 0.12, 0.13), tuple(rng.uniform(0.5, 0.8, 3)))
    if style == "flat":
        return tx.paint_texture(D, W, rng, tuple(rng.uniform(0.35, 0.6, 3)), amplitude=0.05)
    if style == "pattern":
        if rng.random() < 0.5:
            dark, light = rng.uniform(0.1, 0.3, 3), rng.uniform(0.7, 0.95, 3)
            return tx.tile_texture(D, W, rng, tile=int(0.4 * DENSITY), grout=2, colors=(light, dark), checker=True)
        planks = tx.wood_texture(D, W, rng, color=tuple(rng.uniform(0.4, 0.65, 3) * (1.0, 0.75, 0.5)))
        y = np.arange(D)
        planks[y % int(0.15 * DENSITY) < 2] *= 0.5  # plank joints every 15 cm
        return planks
    if style == "photo":
        stone = photos.relief_image(D, W, rng)
        grain = tx.granite_texture(D, W, rng, (0.75, 0.75, 0.75), (1.0, 1.0, 1.0))
        return np.clip(stone * grain * 1.1, 0, 1).astype(np.float32)
    raise ValueError(f"room style must be one of {ROOM_STYLES}, got {style!r}")


def _ceiling_surface(style: str, w_m: float, d_m: float, rng: np.random.Generator) -> np.ndarray:
    W, D = tx.aligned(w_m * DENSITY), tx.aligned(d_m * DENSITY)
    if style == "pattern":
        return tx.ceiling_texture(D, W, rng, tile=int(0.6 * DENSITY))
    return tx.paint_texture(D, W, rng, (0.88, 0.88, 0.86), amplitude=0.03)


# --------------------------------------------------------------------- lights
def room_lighting(kind: str, size, rng: np.random.Generator) -> Lighting:
    """Lights of a room of ``size = (W, D, H)`` m in a family:

    ``even`` (lamp 0.7, two fills 0.3/0.22, ambient 0.36: like the office), ``dim`` (everything at
    ~45 %: dark, low-contrast images), ``lamp`` (one strong, low lamp, a weak fill, ambient 0.15: strong
    gradients), ``bright`` (strong fills and ambient: washed out), ``window`` (one strong, nearly
    horizontal fill, as sun through a window, plus a weak lamp: walls facing away stay dark).
    """
    W, D, H = size
    lamp = (float(rng.uniform(0.2, 0.8) * W), float(rng.uniform(0.2, 0.8) * D), float(H - 0.15))

    def direction(z_lo: float, z_hi: float) -> tuple[float, float, float]:
        a = rng.uniform(0, 2 * np.pi)
        return (float(np.cos(a)), float(np.sin(a)), float(rng.uniform(z_lo, z_hi)))

    if kind == "even":
        return Lighting(lamp, 0.7, ((direction(0.5, 0.8), 0.3), (direction(0.5, 0.8), 0.22)), 0.36)
    if kind == "dim":
        return Lighting(lamp, 0.35, ((direction(0.5, 0.8), 0.12), (direction(0.5, 0.8), 0.08)), 0.16)
    if kind == "lamp":
        low = (lamp[0], lamp[1], float(H * rng.uniform(0.55, 0.75)))
        return Lighting(low, 1.5, ((direction(0.5, 0.8), 0.12),), 0.15)
    if kind == "bright":
        return Lighting(lamp, 0.6, ((direction(0.5, 0.8), 0.4), (direction(0.5, 0.8), 0.3)), 0.5)
    if kind == "window":
        return Lighting(lamp, 0.3, ((direction(0.1, 0.35), 0.75),), 0.22)
    raise ValueError(f"lighting must be one of {LIGHTINGS}, got {kind!r}")


# ---------------------------------------------------------------------- clutter
def _material(style: str, bank: TextureBank, rng: np.random.Generator) -> int:
    """A texture for a piece of clutter, matching the room's style."""
    if style == "flat" and rng.random() < 0.5:  # half the clutter of a flat room is plain too
        return bank.add(tx.paint_texture(128, 256, rng, tuple(rng.uniform(0.3, 0.85, 3)), amplitude=0.03))
    pick = int(rng.integers(3))
    if pick == 0:
        return bank.add(tx.wood_texture(256, 512, rng, color=tuple(rng.uniform(0.3, 0.6, 3) * (1.0, 0.75, 0.5))))
    if pick == 1:
        return bank.add(tx.metal_texture(128, 256, rng, color=tuple(rng.uniform(0.2, 0.6, 3))))
    return bank.add(tx.cardboard_texture(256, 256, rng))


def _clutter_item(style: str, bank: TextureBank, rng: np.random.Generator, H: float):
    """One piece of clutter: ``(parts in its frame (origin on the floor), half sizes (hx, hy))``."""
    kind = rng.choice(["crates", "cabinet", "table", "shelf", "column"], p=[0.3, 0.2, 0.2, 0.15, 0.15])
    tex = _material(style, bank, rng)

    def box(half, centre, t=tex, density=300.0):
        return (Shape("box", tuple(float(h) for h in half), textures=(t,), density=density,
                      offset=(float(rng.uniform(0, 512)), float(rng.uniform(0, 512)))), pose(None, centre))

    if kind == "crates":
        hx, hy = rng.uniform(0.2, 0.4), rng.uniform(0.18, 0.35)
        parts, z = [], 0.0
        for _ in range(int(rng.integers(1, 4))):
            hz = float(rng.uniform(0.15, 0.3))
            t = _material(style, bank, rng) if rng.random() < 0.5 else tex
            parts.append(box((hx * rng.uniform(0.8, 1.0), hy * rng.uniform(0.8, 1.0), hz), (0, 0, z + hz), t, 400.0))
            z += 2 * hz
        return parts, (hx, hy)
    if kind == "cabinet":
        hx, hy, hz = rng.uniform(0.25, 0.5), rng.uniform(0.2, 0.3), rng.uniform(0.5, 1.0)
        return [box((hx, hy, hz), (0, 0, hz))], (hx, hy)
    if kind == "table":
        hx, hy, top = rng.uniform(0.4, 0.75), rng.uniform(0.3, 0.45), rng.uniform(0.7, 0.8)
        parts = [box((hx, hy, 0.02), (0, 0, top))]
        parts += [box((0.025, 0.025, top / 2), (sx * (hx - 0.05), sy * (hy - 0.05), top / 2))
                  for sx in (-1, 1) for sy in (-1, 1)]
        if rng.random() < 0.7:
            item = _material(style, bank, rng)
            w, d, h = rng.uniform(0.1, 0.25, 3)
            parts.append(box((w, d, h), (rng.uniform(-0.5, 0.5) * hx, rng.uniform(-0.4, 0.4) * hy, top + 0.02 + h), item, 500.0))
        return parts, (hx, hy)
    if kind == "shelf":
        hx, hy, hz = rng.uniform(0.4, 0.7), 0.18, rng.uniform(0.7, 1.0)
        parts = [box((0.015, hy, hz), (sx * hx, 0, hz)) for sx in (-1, 1)]
        boards = np.linspace(0.05, 2 * hz - 0.02, int(rng.integers(3, 5)))
        parts += [box((hx, hy, 0.015), (0, 0, z)) for z in boards]
        for z0 in boards[:-1]:  # boxes and files on the boards
            x = -hx + 0.04
            while x < hx - 0.15:
                w = float(rng.uniform(0.05, 0.14))
                h = float(rng.uniform(0.08, min(0.18, (boards[1] - boards[0]) / 2 - 0.02)))
                if rng.random() < 0.8:
                    parts.append(box((w, hy * 0.8, h), (x + w, 0, z0 + 0.015 + h), _material(style, bank, rng), 600.0))
                x += 2 * w + 0.01
        return parts, (hx, hy)
    r = float(rng.uniform(0.12, 0.25))  # a column from floor to ceiling
    return [(Shape("cylinder", (r, r, H / 2), textures=(tex,), density=300.0, turn=512.0), pose(None, (0, 0, H / 2)))], (r, r)


def build_room(size, style: str, lighting: str, n_partitions: int, n_clutter: int, keep_out: list[Footprint],
               rng: np.random.Generator, bank: TextureBank) -> tuple[list[tuple[Shape, np.ndarray]], Lighting]:
    """The static parts of a stress room ``[0, W] x [0, D] x [0, H]`` and its lights.

    Parameters
    ----------
    size : ``(W, D, H)`` m.
    style : one of :data:`ROOM_STYLES`; lighting : one of :data:`LIGHTINGS`.
    n_partitions : wall stubs (0.6-1.6 m long, full height) jutting out of the walls.
    n_clutter : pieces of clutter along the walls (fewer if there is no room for them).
    keep_out : footprints no partition or clutter may enter (movers' paths, the camera's region).
    rng : draws everything; bank : receives the textures.
    """
    if style not in ROOM_STYLES:
        raise ValueError(f"room style must be one of {ROOM_STYLES}, got {style!r}")
    W, D, H = (float(v) for v in size)
    if min(W, D) < 2.0 or H < 2.0:
        raise ValueError(f"room size (W, D, H) must be at least 2 m each, got {size}")
    base = _palette(rng)
    kind = str(rng.choice(["brick", "tiles", "wallpaper"]))
    walls = [_wall_surface(style, kind, m, H, base, rng) for m in (D, D, W, W)]  # -x, +x, -y, +y
    faces = tuple(bank.add(img) for img in walls) + (bank.add(_floor_surface(style, W, D, rng)),
                                                     bank.add(_ceiling_surface(style, W, D, rng)))
    room = Shape("room", (W / 2, D / 2, H / 2), textures=faces, density=DENSITY)
    static: list[tuple[Shape, np.ndarray]] = [(room, pose(None, (W / 2, D / 2, H / 2)))]
    light = room_lighting(lighting, (W, D, H), rng)
    placed: list[Footprint] = []
    lo, hi = np.zeros(2), np.array([W, D])

    def free(fp: Footprint) -> bool:
        return (fp.inside(lo, hi, 0.02) and not any(fp.overlaps(k) for k in keep_out)
                and not any(fp.overlaps(p, 0.08) for p in placed))

    # partitions: wall stubs perpendicular to a wall, full height
    for _ in range(n_partitions):
        tex = bank.add(_wall_surface(style, kind, 1.6, H, base, rng))
        for _ in range(30):
            wall = int(rng.integers(4))
            length, half_t = float(rng.uniform(0.6, 1.6)), 0.06
            along = float(rng.uniform(0.5, (D if wall < 2 else W) - 0.5))
            if wall < 2:  # from the -x or +x wall, along x
                x = length / 2 if wall == 0 else W - length / 2
                fp = Footprint.box(x, along, length / 2, half_t)
            else:
                y = length / 2 if wall == 2 else D - length / 2
                fp = Footprint.box(along, y, half_t, length / 2)
            if fp.inside(lo, hi, -1e-6) and not any(fp.overlaps(k) for k in keep_out) and not any(fp.overlaps(q, 0.08) for q in placed):
                placed.append(fp)
                static.append((Shape("box", (fp.a, fp.b, H / 2), textures=(tex,), density=DENSITY,
                                     offset=(float(rng.uniform(0, 256)), 0.0)), pose(None, (fp.cx, fp.cy, H / 2))))
                break
    # clutter along the walls
    for _ in range(n_clutter):
        parts, (hx, hy) = _clutter_item(style, bank, rng, H)
        for _ in range(30):
            wall = int(rng.integers(4))
            gap = float(rng.uniform(0.03, 0.3))
            if wall < 2:  # its back to the -x / +x wall: turned by +-90 deg
                yaw = np.pi / 2 if wall == 0 else -np.pi / 2
                x = gap + hy if wall == 0 else W - gap - hy
                y = float(rng.uniform(hx + 0.05, D - hx - 0.05))
            else:
                yaw = 0.0 if wall == 3 else np.pi
                y = gap + hy if wall == 2 else D - gap - hy
                x = float(rng.uniform(hx + 0.05, W - hx - 0.05))
            fp = Footprint.box(x, y, hx, hy, yaw)
            if free(fp):
                placed.append(fp)
                T = pose(rot_z(yaw), (x, y, 0.0))
                static.extend((s, T @ P) for s, P in parts)
                break
    return static, light
