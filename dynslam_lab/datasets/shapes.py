"""Analytic shapes of the synthetic scene: boxes, the room, capsules, cylinders, ellipsoids.

A :class:`Shape` is one primitive in its own local frame (with its texture indices, texel
density, tint and depth dropout); the scene places it in the world with a pose ``T_w_p``
(4x4, part to world). This module also holds the small rotation and pose helpers used to
build the scene and the camera paths, and the texture axes of box faces.

The ray intersections of the shapes are in :mod:`dynslam_lab.datasets.raycaster`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["KINDS", "Shape", "shape_corners", "rot_x", "rot_y", "rot_z", "pose", "look_at"]

KINDS = ("room", "box", "capsule", "cylinder", "ellipsoid")


# ------------------------------------------------------------------ small helpers
def rot_x(a: float) -> np.ndarray:
    """Rotation matrix ``(3, 3)`` about x by ``a`` radians."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a: float) -> np.ndarray:
    """Rotation matrix ``(3, 3)`` about y by ``a`` radians."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a: float) -> np.ndarray:
    """Rotation matrix ``(3, 3)`` about z by ``a`` radians."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def pose(R: np.ndarray | None = None, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    """4x4 pose from a rotation ``(3, 3)`` (identity if None) and a translation ``(3,)``."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    T[:3, 3] = t
    return T


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera pose ``T_w_c`` at ``eye`` looking at ``target`` (camera x right, y down, z forward)."""
    eye = np.asarray(eye, float)
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, float))
    n = np.linalg.norm(x)
    if n < 1e-9:
        raise ValueError("look_at: viewing direction is parallel to the up vector")
    x /= n
    y = np.cross(z, x)
    return pose(np.stack([x, y, z], axis=1), eye)


# --------------------------------------------------------------------- the shapes
@dataclass(frozen=True)
class Shape:
    """One analytic primitive in its local frame, with its surface appearance.

    Attributes
    ----------
    kind : ``"room"`` (box seen from inside), ``"box"``, ``"capsule"``, ``"cylinder"``, ``"ellipsoid"``.
    size : box/room: half extents ``(hx, hy, hz)`` m; capsule/cylinder: ``(r, r, l)`` radius and
        half-length of the axis segment along local z, m; ellipsoid: radii ``(a, b, c)`` m.
    textures : texture index per face ``(6,)`` for boxes and rooms (faces -x, +x, -y, +y, -z, +z),
        or one index for every face.
    instance : instance id written to the mask (0 = room/background).
    density : texels per metre on the surface (along the axis for round shapes).
    turn : texels per full turn around the axis (round shapes; the texture width for a seamless wrap).
    offset : ``(s0, t0)`` texel offset of the texture origin.
    tint : RGB multiplier of the texture colour.
    dropout : probability that the depth sensor misses a pixel of this shape (dark or glossy surfaces).
    """

    kind: str
    size: tuple[float, float, float]
    textures: tuple[int, ...] = (0,)
    instance: int = 0
    density: float = 250.0
    turn: float = 256.0
    offset: tuple[float, float] = (0.0, 0.0)
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    dropout: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"Shape.kind must be one of {KINDS}, got {self.kind!r}")
        if len(self.size) != 3 or min(self.size) <= 0:
            raise ValueError(f"Shape.size must be 3 positive lengths (m), got {self.size!r}")
        if len(self.textures) not in (1, 6):
            raise ValueError(f"Shape.textures needs 1 or 6 texture indices, got {len(self.textures)}")

    def __hash__(self) -> int:
        # computed once: the renderer keeps per-shape tables in dicts and looks ~190 shapes up per frame
        h = self.__dict__.get("_hash")
        if h is None:
            h = hash((self.kind, self.size, self.textures, self.instance, self.density, self.turn, self.offset, self.tint,
                      self.dropout))
            object.__setattr__(self, "_hash", h)
        return h

    def __getstate__(self) -> dict:
        # string hashes differ between processes: never carry the cached hash along
        return {k: v for k, v in self.__dict__.items() if k != "_hash"}

    def face_textures(self) -> tuple[int, ...]:
        """Six texture indices (one per face)."""
        return tuple(self.textures) * 6 if len(self.textures) == 1 else tuple(self.textures)

    @property
    def texel_density(self) -> float:
        """Mean texels per metre, for the mip level."""
        if self.kind in ("capsule", "cylinder", "ellipsoid"):
            r = 0.5 * (self.size[0] + self.size[1])
            return float(np.sqrt(self.density * self.turn / (2 * np.pi * r)))
        return float(self.density)


def shape_corners(shape: Shape) -> np.ndarray:
    """The 8 corners ``(8, 3)`` of the local bounding box of a shape (m)."""
    a, b, c = shape.size
    if shape.kind == "capsule":
        c = c + a
    sx, sy, sz = np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")
    return np.stack([sx.ravel() * a, sy.ravel() * b, sz.ravel() * c], axis=1)


# Texture axes of the six box faces: s = p . RIGHT[f], t = p . DOWN[f], so that a face seen from
# outside (box) or inside (room) shows its texture upright and not mirrored.
def _face_axes(inside: bool) -> tuple[np.ndarray, np.ndarray]:
    right = np.zeros((6, 3), np.float32)
    down = np.zeros((6, 3), np.float32)
    ez = np.array([0, 0, 1.0])
    for f in range(6):
        axis, sign = f // 2, (1 if f % 2 else -1)
        n_view = np.zeros(3)
        n_view[axis] = -sign if inside else sign
        if axis < 2:
            right[f] = np.cross(ez, n_view)
            down[f] = -ez
        else:
            right[f] = (1, 0, 0)
            down[f] = np.cross(n_view, right[f])
    return right, down


_BOX_AXES = _face_axes(inside=False)
_ROOM_AXES = _face_axes(inside=True)
_FACE_OFFSET = np.array([[0, 0], [397, 113], [211, 307], [557, 89], [131, 433], [283, 199]], np.float32)
