"""Analytic scene geometry and a vectorised ray caster for the synthetic renderer.

A scene is a list of *parts*: a :class:`Shape` (box, room, capsule, cylinder or ellipsoid,
defined in its own local frame) placed in the world by a pose ``T_w_p`` (4x4). A frame is
rendered by casting one ray per pixel through the pinhole camera,

    X_c(t) = t * K^-1 (u, v, 1)^T,    t > 0,

so the ray parameter ``t`` of the first hit *is* the depth ``z`` (the third coordinate of
``X_c``), the quantity a Kinect measures. Each ray is moved into a part's local frame
(``o_p = T_p_c o_c``, ``d_p = R_p_c d_c``) and intersected in closed form:

* box (slab method, Kay & Kajiya, SIGGRAPH 1986): ``t_near = max_k min(t1_k, t2_k)``,
  ``t_far = min_k max(t1_k, t2_k)`` with ``t{1,2}_k = (-+h_k - o_k) / d_k``; a hit when
  ``t_near <= t_far``. The *room* is a box seen from inside: its hit is ``t_far``.
* capsule (segment of half-length ``l`` on the z axis, radius ``r``): the nearest of the
  infinite cylinder ``x^2 + y^2 = r^2`` (kept where ``|z| <= l``) and the two end spheres;
* cylinder with flat caps: the side as above plus the cap discs ``z = +-l``, ``x^2+y^2 <= r^2``;
* ellipsoid with radii ``(a, b, c)``: the unit sphere after scaling by ``1/(a, b, c)``
  (a linear map leaves ``t`` unchanged).

Only the pixels inside the screen rectangle of a part's projected bounding box are tested,
so small parts cost little. The result is a G-buffer: depth, part index, face, camera-frame
normal and texture coordinates per pixel; shading and sensor noise are applied in
:mod:`dynslam_lab.datasets.synthetic`.

The module also holds the office scene: the room, its furniture, the people (articulated
from capsules and ellipsoids, legs and arms swinging as they walk) and the camera paths.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from ..camera import PinholeCamera
from ..geometry.se3 import se3_inv

__all__ = [
    "Shape",
    "GBuffer",
    "raycast",
    "camera_rays",
    "OfficeScene",
    "build_office",
    "Walker",
    "Sitter",
    "SlidingObject",
    "person_parts",
    "walking_joints",
    "sitting_joints",
    "path_pose",
    "rot_x",
    "rot_y",
    "rot_z",
    "pose",
    "look_at",
    "shape_corners",
]

KINDS = ("room", "box", "capsule", "cylinder", "ellipsoid")
NEAR = 0.05  # m: rays start this far in front of the camera


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


# Rays are handled as structure-of-arrays: origin components are scalars (the camera centre in
# the part's frame), direction components are (h, w) arrays, so every step is one numpy
# operation over the pixels of a part's screen rectangle.
def _hit_t(shape: Shape, o: np.ndarray, d: tuple[np.ndarray, np.ndarray, np.ndarray]):
    """Ray parameter of the first hit ``(h, w)`` (``inf`` = miss) and per-kind auxiliary data."""
    a, b, c = (np.float32(v) for v in shape.size)
    dx, dy, dz = d
    if shape.kind in ("box", "room"):
        # slabs: entry and exit parameter per axis; which axis bounds the hit is decided later,
        # for the winning pixels only (see _box_axis)
        los, his = [], []
        with np.errstate(divide="ignore", invalid="ignore"):
            for ok, dk, hk in zip(o, d, (a, b, c)):
                inv = np.float32(1.0) / dk  # +-inf for rays parallel to the slab: min/max still work
                t1 = (-hk - ok) * inv
                t2 = (hk - ok) * inv
                los.append(np.minimum(t1, t2))
                his.append(np.maximum(t1, t2))
        tnear = np.maximum(np.maximum(los[0], los[1]), los[2])
        tfar = np.minimum(np.minimum(his[0], his[1]), his[2])
        if shape.kind == "room":
            return np.where((tfar >= tnear) & (tfar > NEAR), tfar, np.float32(np.inf)), his
        return np.where((tnear <= tfar) & (tnear > NEAR), tnear, np.float32(np.inf)), los
    ox, oy, oz = (np.float32(v) for v in o)
    if shape.kind in ("capsule", "cylinder"):
        r, l = a, c
        A = dx * dx + dy * dy
        B = ox * dx + oy * dy
        C = ox * ox + oy * oy - r * r
        disc = B * B - A * C
        with np.errstate(invalid="ignore", divide="ignore"):
            ts = (-B - np.sqrt(disc)) / A
            z = oz + ts * dz
            t = np.where((disc >= 0) & (A > 1e-12) & (np.abs(z) <= l) & (ts > NEAR), ts, np.inf)
        if shape.kind == "capsule":
            dd = A + dz * dz
            for zc in (-l, l):
                ocz = oz - zc
                Bs = B + dz * ocz
                disc_s = Bs * Bs - dd * (ox * ox + oy * oy + ocz * ocz - r * r)
                with np.errstate(invalid="ignore"):
                    tsph = (-Bs - np.sqrt(disc_s)) / dd
                    t = np.where((disc_s >= 0) & (tsph > NEAR) & (tsph < t), tsph, t)
            return t.astype(np.float32), None
        cap = np.zeros(dx.shape, np.int8)  # 0 side, 1 bottom cap, 2 top cap
        with np.errstate(divide="ignore"):
            inv = np.float32(1.0) / dz
        for k, zc in ((1, -l), (2, l)):
            with np.errstate(invalid="ignore"):
                tc = (zc - oz) * inv
            x = ox + tc * dx
            y = oy + tc * dy
            better = (tc > NEAR) & (x * x + y * y <= r * r) & (tc < t)
            t = np.where(better, tc, t)
            cap[better] = k
        return t.astype(np.float32), cap
    # ellipsoid: unit sphere after scaling by 1 / radii
    qx, qy, qz = ox / a, oy / b, oz / c
    ex, ey, ez = dx / a, dy / b, dz / c
    A = ex * ex + ey * ey + ez * ez
    B = ex * qx + ey * qy + ez * qz
    C = qx * qx + qy * qy + qz * qz - 1.0
    disc = B * B - A * C
    with np.errstate(invalid="ignore"):
        t = (-B - np.sqrt(disc)) / A
        return np.where((disc >= 0) & (t > NEAR), t, np.inf).astype(np.float32), None


def _surface(shape: Shape, p: np.ndarray, aux) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Local unit normal ``(N, 3)``, face index ``(N,)`` and texture coordinates ``s, t`` ``(N,)`` at hits ``p (N, 3)``."""
    a, b, c = (np.float32(v) for v in shape.size)
    if shape.kind in ("box", "room"):
        # the bounding slab: largest entry parameter (box) or smallest exit parameter (room)
        axis = np.argmin(aux, axis=1) if shape.kind == "room" else np.argmax(aux, axis=1)
        px, py, pz = p[:, 0], p[:, 1], p[:, 2]
        pa = np.where(axis == 0, px, np.where(axis == 1, py, pz))
        side = pa > 0
        face = 2 * axis.astype(np.int64) + side
        sgn = np.where(side, np.float32(1.0), np.float32(-1.0))
        if shape.kind == "room":
            sgn = -sgn  # normals point into the room
        zero = np.float32(0.0)
        n = np.stack([np.where(axis == 0, sgn, zero), np.where(axis == 1, sgn, zero), np.where(axis == 2, sgn, zero)], axis=1)
        right, down = _ROOM_AXES if shape.kind == "room" else _BOX_AXES
        half = np.array([a, b, c], np.float32)
        # texture origin at the face's top-left corner (plus a per-face shift on boxes, whose faces share a texture)
        s0 = (np.abs(right) @ half) * shape.density
        t0 = (np.abs(down) @ half) * shape.density
        if shape.kind == "box":
            s0 = s0 + _FACE_OFFSET[:, 0]
            t0 = t0 + _FACE_OFFSET[:, 1]
        rd = right * shape.density
        dd = down * shape.density
        s = px * rd[face, 0] + py * rd[face, 1] + pz * rd[face, 2] + s0[face]
        t = px * dd[face, 0] + py * dd[face, 1] + pz * dd[face, 2] + t0[face]
        return n, face, s.astype(np.float32), t.astype(np.float32)
    face = np.zeros(len(p), np.int64)
    if shape.kind in ("capsule", "cylinder"):
        n = p.copy()
        n[:, 2] -= np.clip(p[:, 2], -c, c)
        if shape.kind == "cylinder":
            cap = aux
            n[cap > 0] = 0.0
            n[cap == 1, 2] = -1.0
            n[cap == 2, 2] = 1.0
            face = np.where(cap == 1, 4, np.where(cap == 2, 5, 0))
    else:
        rad = np.array([a, b, c], np.float32)
        n = p / (rad * rad)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-9)
    s = (np.arctan2(p[:, 0], p[:, 1]) * np.float32(1 / (2 * np.pi)) + 0.5) * shape.turn
    t = -p[:, 2] * shape.density
    if shape.kind == "cylinder":
        on_cap = face > 0
        s = np.where(on_cap, p[:, 0] * shape.density, s)
        t = np.where(on_cap, p[:, 1] * shape.density, t)
    return n, face, s, t


@dataclass
class GBuffer:
    """Per-pixel result of ray casting one frame.

    Attributes
    ----------
    depth : ``(H, W)`` float32 true depth ``z`` in metres (``inf`` where no surface).
    part : ``(H, W)`` int32 index of the visible part (-1 = none).
    face : ``(H, W)`` int8 face of the part (0..5, boxes and cylinder caps; 0 for round sides).
    normal_planes : ``(3, H, W)`` float32 unit surface normal in the camera frame, one plane per axis.
    s, t : ``(H, W)`` float32 texture coordinates, level-0 texels.
    rays : ``(H, W, 3)`` float32 ray directions ``K^-1 (u, v, 1)`` in the camera frame (z = 1).
    """

    depth: np.ndarray
    part: np.ndarray
    face: np.ndarray
    normal_planes: np.ndarray
    s: np.ndarray
    t: np.ndarray
    rays: np.ndarray

    @property
    def normal(self) -> np.ndarray:
        """``(H, W, 3)`` view of the normals."""
        return np.moveaxis(self.normal_planes, 0, -1)


_RAY_CACHE: dict = {}


def camera_rays(camera: PinholeCamera) -> np.ndarray:
    """``(H, W, 3)`` float32 ray directions ``((u - cx)/fx, (v - cy)/fy, 1)`` (cached per camera)."""
    key = (camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)
    rays = _RAY_CACHE.get(key)
    if rays is None:
        v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float32)
        rays = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], axis=-1)
        rays = rays.astype(np.float32)
        rays.flags.writeable = False
        _RAY_CACHE[key] = rays
    return rays


def _screen_rects(parts: list[tuple[Shape, np.ndarray]], T_c_p: np.ndarray, camera: PinholeCamera) -> list:
    """Screen rectangles of all parts at once (``T_c_p`` is ``(P, 4, 4)``, part to camera).

    For each part: the pixel rectangle ``(r0, r1, c0, c1)`` covering the projection of its
    bounding box (the whole image when the box crosses the near plane, None when the part is
    behind the camera or off screen) and the smallest depth of its corners (m; ``-inf`` for the
    room, which is always cast).
    """
    C = np.stack([_corners_cached(sh) for sh, _ in parts])  # (P, 8, 3)
    X = np.einsum("pij,pkj->pki", T_c_p[:, :3, :3], C) + T_c_p[:, None, :3, 3]
    z = X[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = camera.fx * X[..., 0] / z + camera.cx
        v = camera.fy * X[..., 1] / z + camera.cy
    behind = z <= NEAR
    all_behind, any_behind = behind.all(axis=1), behind.any(axis=1)
    c0 = np.clip(np.floor(u.min(axis=1)), 0, camera.width).astype(int)
    c1 = np.clip(np.ceil(u.max(axis=1)) + 1, 0, camera.width).astype(int)
    r0 = np.clip(np.floor(v.min(axis=1)), 0, camera.height).astype(int)
    r1 = np.clip(np.ceil(v.max(axis=1)) + 1, 0, camera.height).astype(int)
    zmin = z.min(axis=1)
    out = []
    for k, (sh, _) in enumerate(parts):
        if sh.kind == "room":
            out.append(((0, camera.height, 0, camera.width), -np.inf))
        elif all_behind[k]:
            out.append((None, np.inf))
        elif any_behind[k]:
            out.append(((0, camera.height, 0, camera.width), float(zmin[k])))
        elif c1[k] <= c0[k] or r1[k] <= r0[k]:
            out.append((None, np.inf))
        else:
            out.append(((int(r0[k]), int(r1[k]), int(c0[k]), int(c1[k])), float(zmin[k])))
    return out


_CORNERS: dict = {}


def _corners_cached(shape: Shape) -> np.ndarray:
    c = _CORNERS.get(shape)
    if c is None:
        c = _CORNERS[shape] = shape_corners(shape)
    return c


def _select(aux, win: np.ndarray | None):
    """Auxiliary hit data of the winning pixels (flat indices ``win``; all when None)."""
    if aux is None:
        return None
    if isinstance(aux, list):  # box / room slab parameters -> (N, 3)
        return np.stack([a.ravel() if win is None else a.ravel()[win] for a in aux], axis=1)
    return aux.ravel() if win is None else aux.ravel()[win]


def _write(shape, k, T_c_p, o, d, t, aux, flat, depth, part_id, face, normal, s_map, t_map) -> None:
    """Store the hits ``t (N,)`` of part ``k`` (rays ``d``, 3 x ``(N,)``, local frame) at flat pixel indices."""
    p = np.stack([o[i] + t * d[i] for i in range(3)], axis=1)
    n_l, f, s, tt = _surface(shape, p, aux)
    depth.ravel()[flat] = t
    part_id.ravel()[flat] = k
    face.ravel()[flat] = f
    normal.reshape(3, -1)[:, flat] = T_c_p[:3, :3].astype(np.float32) @ n_l.T
    s_map.ravel()[flat] = s + np.float32(shape.offset[0])
    t_map.ravel()[flat] = tt + np.float32(shape.offset[1])


def raycast(parts: list[tuple[Shape, np.ndarray]], camera: PinholeCamera, T_w_c: np.ndarray) -> GBuffer:
    """Cast one ray per pixel into the parts and keep the nearest hit.

    Parts are visited nearest first (by their bounding box); a part whose nearest corner lies
    behind everything already drawn in its screen rectangle is skipped (occlusion culling).
    The room, which encloses every other part, is cast last and only through the pixels that
    are still empty.

    Parameters
    ----------
    parts : ``[(shape, T_w_p), ...]`` shapes with their poses (4x4, part to world).
    camera : pinhole intrinsics (no distortion is simulated).
    T_w_c : ``(4, 4)`` camera pose, camera to world.

    Returns
    -------
    :class:`GBuffer` of the frame; ``part`` indexes ``parts``.
    """
    H, W = camera.height, camera.width
    rays = camera_rays(camera)
    rx, ry = rays[..., 0], rays[..., 1]
    depth = np.full((H, W), np.inf, np.float32)
    part_id = np.full((H, W), -1, np.int32)
    face = np.zeros((H, W), np.int8)
    normal = np.zeros((3, H, W), np.float32)  # one plane per component
    s_map = np.zeros((H, W), np.float32)
    t_map = np.zeros((H, W), np.float32)
    T_c_w = se3_inv(np.asarray(T_w_c, float))
    T_c_p_all = T_c_w[None] @ np.stack([T for _, T in parts])
    T_p_c_all = se3_inv(T_c_p_all).astype(np.float32)  # camera in each part's frame
    todo = [(zmin, k, rect, T_c_p_all[k]) for k, (rect, zmin) in enumerate(_screen_rects(parts, T_c_p_all, camera))
            if rect is not None]
    todo.sort(key=lambda x: x[0])
    # Objects nearest first; the room (which encloses everything) last, on the pixels still empty.
    rooms = [x for x in todo if parts[x[1]][0].kind == "room"]
    todo = [x for x in todo if parts[x[1]][0].kind != "room"]
    for zmin, k, (r0, r1, c0, c1), T_c_p in todo:
        zview = depth[r0:r1, c0:c1]
        if zmin > NEAR and zmin >= zview.max():  # hidden behind what is already drawn
            continue
        shape = parts[k][0]
        R, o = T_p_c_all[k, :3, :3], T_p_c_all[k, :3, 3]
        # ray directions in the part's frame (contiguous copies first: arithmetic on strided views is slower)
        X, Y = np.ascontiguousarray(rx[r0:r1, c0:c1]), np.ascontiguousarray(ry[r0:r1, c0:c1])
        d = tuple(R[i, 0] * X + R[i, 1] * Y + R[i, 2] for i in range(3))
        t, aux = _hit_t(shape, o, d)
        win = np.flatnonzero(t < zview)
        if len(win) == 0:
            continue
        flat = (win // (c1 - c0) + r0) * W + (win % (c1 - c0) + c0)  # indices into the full image
        _write(shape, k, T_c_p, o, [di.ravel()[win] for di in d], t.ravel()[win], _select(aux, win), flat,
               depth, part_id, face, normal, s_map, t_map)
    for _, k, _, T_c_p in rooms:
        flat = np.flatnonzero(np.isinf(depth))
        if len(flat) == 0:
            continue
        shape = parts[k][0]
        R, o = T_p_c_all[k, :3, :3], T_p_c_all[k, :3, 3]
        X, Y = rx.ravel()[flat], ry.ravel()[flat]
        d = tuple(R[i, 0] * X + R[i, 1] * Y + R[i, 2] for i in range(3))
        t, aux = _hit_t(shape, o, d)
        ok = np.isfinite(t)
        if not ok.all():
            flat, t, d = flat[ok], t[ok], tuple(di[ok] for di in d)
            aux = [a[ok] for a in aux]
        _write(shape, k, T_c_p, o, list(d), t, _select(aux, None), flat, depth, part_id, face, normal, s_map, t_map)
    return GBuffer(depth=depth, part=part_id, face=face, normal_planes=normal, s=s_map, t=t_map, rays=rays)


# ======================================================================== the office
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


@dataclass
class OfficeScene:
    """The office: static parts, movers, instances and the texture bank.

    Build it with :func:`build_office`. ``parts(t)`` lists every shape with its pose at time
    ``t`` (s); ``instances`` maps id -> ``(COCO class, motion)``.
    """

    bank: TextureBank
    static: list[tuple[Shape, np.ndarray]]
    movers: list
    instances: dict[int, tuple[str, str]] = field(default_factory=dict)

    def parts(self, t: float) -> list[tuple[Shape, np.ndarray]]:
        out = list(self.static)
        for m in self.movers:
            out.extend(m.parts(t))
        return out

    def displacement(self, t0: float, t1: float) -> dict[int, float]:
        """Largest displacement (m) of any bounding-box corner of each mover's parts from ``t0`` to ``t1``."""
        out: dict[int, float] = {}
        for m in self.movers:
            a, b = m.parts(t0), m.parts(t1)
            d = 0.0
            for (sh, Ta), (_, Tb) in zip(a, b):
                C = shape_corners(sh)
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


def _wall_texture(w_m: float, h_m: float, density: float, rng: np.random.Generator, items: list[tuple[str, float, float, float, float]],
                  color=(0.8, 0.78, 0.72)) -> np.ndarray:
    """A plaster wall ``w_m x h_m`` metres with posters, boards and notices.

    ``items`` are ``(kind, x, y, w, h)`` in metres from the wall's top-left corner (seen from inside).
    """
    from . import textures as tx

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
    from . import textures as tx

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
        return PersonLook(
            shirt=bank.add(tx.fabric_texture(256, 256, rng)),
            trousers=bank.add(tx.denim_texture(256, 256, rng)),
            head=bank.add(tx.head_texture(256, 512, rng)),
            skin=bank.add(tx.skin_texture(128, 128, rng)),
            shoes=bank.add(tx.metal_texture(64, 128, rng, color=(0.08, 0.06, 0.05))),
            height=height,
        )

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
