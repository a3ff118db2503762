"""A vectorised ray caster for analytic shapes: the geometry pass of the synthetic renderer.

A frame is rendered by casting one ray per pixel through the pinhole camera,

    X_c(t) = t * K^-1 (u, v, 1)^T,    t > 0,

so the ray parameter ``t`` of the first hit *is* the depth ``z`` (the third coordinate of
``X_c``), the quantity a Kinect measures. Each ray is moved into a part's local frame
(``o_p = T_p_c o_c``, ``d_p = R_p_c d_c``) and intersected in closed form:

* box (slab method, Kay & Kajiya, SIGGRAPH 1986): ``t_near = max_k min(t1_k, t2_k)``,
  ``t_far = min_k max(t1_k, t2_k)`` with ``t{1,2}_k = (-+h_k - o_k) / d_k``; a hit when
  ``t_near <= t_far``. The *room* is a box seen from inside: its hit is ``t_far``. The face hit
  is the slab that bounds the hit (the largest entry parameter, or for the room the smallest
  exit parameter), on the side of the sign of the hit coordinate along that axis;
* capsule (segment of half-length ``l`` on the z axis, radius ``r``): the nearest of the
  infinite cylinder ``x^2 + y^2 = r^2`` (kept where ``|z| <= l``) and the two end spheres;
* cylinder with flat caps: the side as above plus the cap discs ``z = +-l``, ``x^2+y^2 <= r^2``;
* ellipsoid with radii ``(a, b, c)``: the unit sphere after scaling by ``1/(a, b, c)``
  (a linear map leaves ``t`` unchanged).

How a frame is cast (:func:`raycast`):

1. every part's bounding box is projected to a screen rectangle (a box crossing the near
   plane is clipped to it first) and the parts are sorted by the depth of their nearest corner;
2. parts are visited nearest first; a part whose nearest corner lies behind everything
   already drawn in its rectangle is skipped (occlusion culling); otherwise its hit ``t`` is
   computed for the pixels of its rectangle and kept where it is nearer than the depth buffer.
   The ray directions of a rectangle are built from one row of ``x`` and one column of ``y``
   (``d_p = R x + R y + R z``, the ray's x depends on the column only, its y on the row only);
3. the room, which encloses every other part, is cast last on the pixels still empty;
4. surface attributes (face, camera-frame normal, texture coordinates) of boxes and the room
   are computed once, for the pixels they finally own, all boxes in one vectorised pass
   (per-part values gathered by part index): no work is spent on box pixels that a nearer
   part covers later. Round parts (few, with curved normals) get theirs when they are drawn.

The result is a :class:`GBuffer`: depth, part index, face, camera-frame normal and texture
coordinates per pixel; shading and sensor noise are applied in
:mod:`dynslam_lab.datasets.synthetic` and :mod:`dynslam_lab.datasets.kinect`.

Arithmetic is float32 in a fixed order: the same scene, camera and pose give the same bits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import PinholeCamera
from ..geometry.se3 import se3_inv
from .shapes import _BOX_AXES, _FACE_OFFSET, _ROOM_AXES, Shape, shape_corners

__all__ = ["NEAR", "GBuffer", "camera_rays", "raycast"]

NEAR = 0.05  # m: rays start this far in front of the camera

# The 12 edges of a bounding box, as index pairs into the corners of shape_corners
# (corner index = 4 ix + 2 iy + iz for signs ix, iy, iz in {0: -, 1: +}).
_BOX_EDGES = np.array([(a, a | bit) for a in range(8) for bit in (1, 2, 4) if not a & bit])


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


# ------------------------------------------------------------------------ camera rays
@dataclass(frozen=True)
class RayGrid:
    """Ray directions of one camera, in the layouts the renderer needs (all float32, read-only).

    ``rays (H, W, 3)``; ``x``, ``y`` ``(H, W)`` contiguous copies of its first two planes;
    ``x_row (W,)`` (the x of every column: the same in every row) and ``y_col (H, 1)``;
    ``length (H, W)`` the Euclidean length of each ray, and ``length_per_fx = length / fx``.
    """

    rays: np.ndarray
    x: np.ndarray
    y: np.ndarray
    x_row: np.ndarray
    y_col: np.ndarray
    length: np.ndarray
    length_per_fx: np.ndarray


_GRIDS: dict = {}


def ray_grid(camera: PinholeCamera) -> RayGrid:
    """The :class:`RayGrid` of a camera (computed once per intrinsics)."""
    key = (camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)
    grid = _GRIDS.get(key)
    if grid is None:
        v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float32)
        rays = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], axis=-1)
        rays = rays.astype(np.float32)
        x, y = np.ascontiguousarray(rays[..., 0]), np.ascontiguousarray(rays[..., 1])
        length = np.linalg.norm(rays, axis=-1).astype(np.float32)
        grid = RayGrid(rays=rays, x=x, y=y, x_row=x[0].copy(), y_col=y[:, :1].copy(), length=length,
                       length_per_fx=length / np.float32(camera.fx))
        for a in (grid.rays, grid.x, grid.y, grid.x_row, grid.y_col, grid.length, grid.length_per_fx):
            a.flags.writeable = False
        _GRIDS[key] = grid
    return grid


def camera_rays(camera: PinholeCamera) -> np.ndarray:
    """``(H, W, 3)`` float32 ray directions ``((u - cx)/fx, (v - cy)/fy, 1)`` (cached per camera)."""
    return ray_grid(camera).rays


# ------------------------------------------------------------------ per-shape tables
_SLAB_KINDS = ("box", "room")
# Face f of a box or room lies on axis f // 2, on its + side when f is odd. Its texture
# coordinates are s = p . right[f], t = p . down[f] (scaled by the density, plus an origin);
# each of right[f] and down[f] has a single non-zero entry, on axis _S_AXIS[f] and _T_AXIS[f]
# (see shapes._face_axes), so s = p[_S_AXIS[f]] * rd + s0 with the same bits as the full dot product.
_S_AXIS = np.array([1, 1, 0, 0, 0, 0])
_T_AXIS = np.array([2, 2, 2, 2, 1, 1])


@dataclass(frozen=True)
class _SlabInfo:
    """Texture mapping of the six faces of a box or room: ``s = p[_S_AXIS] * cs + s0 + offset``, likewise ``t``."""

    cs: np.ndarray  # (6,) float32 texels per metre along s (signed)
    s0: np.ndarray  # (6,) float32 texture origin
    ct: np.ndarray
    t0: np.ndarray
    offset: np.ndarray  # (2,) float32 the shape's texel offset


# Per-shape tables, looked up by value (people are re-posed every frame from equal shapes). A
# scene has a few hundred distinct shapes; the caches are emptied if many scenes pass through.
_CACHE_LIMIT = 20000
_SLAB_INFO: dict = {}
_CORNERS: dict = {}
_HALF: dict = {}


def _remember(cache: dict, shape: Shape, value):
    if len(cache) >= _CACHE_LIMIT:
        cache.clear()
    cache[shape] = value
    return value


def _slab_info(shape: Shape) -> _SlabInfo:
    info = _SLAB_INFO.get(shape)
    if info is None:
        right, down = _ROOM_AXES if shape.kind == "room" else _BOX_AXES
        half = np.array([np.float32(v) for v in shape.size], np.float32)
        # texture origin at the face's top-left corner (plus a per-face shift on boxes, whose faces share a texture)
        s0 = (np.abs(right) @ half) * shape.density
        t0 = (np.abs(down) @ half) * shape.density
        if shape.kind == "box":
            s0 = s0 + _FACE_OFFSET[:, 0]
            t0 = t0 + _FACE_OFFSET[:, 1]
        rd = right * shape.density
        dd = down * shape.density
        f = np.arange(6)
        for m, axis in ((rd, _S_AXIS), (dd, _T_AXIS)):
            others = m.copy()
            others[f, axis] = 0.0
            assert not others.any(), "texture axes of a box face must be coordinate axes"
        info = _remember(_SLAB_INFO, shape, _SlabInfo(
            cs=rd[f, _S_AXIS].astype(np.float32), s0=s0.astype(np.float32), ct=dd[f, _T_AXIS].astype(np.float32),
            t0=t0.astype(np.float32), offset=np.array(shape.offset, np.float32)))
    return info


def _corners_cached(shape: Shape) -> np.ndarray:
    c = _CORNERS.get(shape)
    if c is None:
        c = _remember(_CORNERS, shape, shape_corners(shape))
    return c


def _face_normals(R_c_p: np.ndarray, inside: bool) -> np.ndarray:
    """Camera-frame normals ``(..., 6, 3)`` float32 of the faces of boxes with rotations ``R_c_p (..., 3, 3)``
    (``inside``: of a room, pointing in).

    Face ``f`` has the local normal ``+-e_(f // 2)``; rotated, that is ``+-`` a column of ``R_c_p``
    (float32), exactly what the matrix product with the one-hot local normal gives.
    """
    cols = np.swapaxes(R_c_p.astype(np.float32), -1, -2)[..., [0, 0, 1, 1, 2, 2], :]  # column f // 2 for face f
    sgn = np.array([-1, 1, -1, 1, -1, 1], np.float32)[:, None]
    return cols * (-sgn if inside else sgn)


# ------------------------------------------------------------------ intersections
# Rays are handled as structure-of-arrays: origin components are scalars (the camera centre in
# the part's frame), direction components are arrays, so every step is one numpy operation
# over the pixels of a part's screen rectangle (or over a list of pixels).
def _slabs(D: np.ndarray, c1: np.ndarray, c2: np.ndarray, entry: bool = True):
    """Entry and exit parameters ``(lo, hi)`` (each shaped like ``D``) of the three slabs of a box or room.

    ``D`` holds the ray directions, one row per axis; ``c1 = -h - o`` and ``c2 = h - o`` (per axis,
    shaped to broadcast against ``D``) the slab planes relative to the ray origin. ``entry=False``
    skips the entry parameters (None). Called under :func:`raycast`'s ``np.errstate``.
    """
    inv = np.float32(1.0) / D  # +-inf for rays parallel to the slab: min/max still work
    t1 = c1 * inv
    t2 = np.multiply(inv, c2, out=inv)
    hi = np.maximum(t1, t2)
    lo = np.minimum(t1, t2, out=t1) if entry else None
    return lo, hi


def _hit_round(shape: Shape, o: np.ndarray, d):
    """Ray parameter of the first hit (``inf`` = miss) of a capsule, cylinder or ellipsoid, and for
    a cylinder the cap hit per ray (0 side, 1 bottom, 2 top; None for the others). Called under
    :func:`raycast`'s ``np.errstate`` (misses give NaN and inf on the way)."""
    a, b, c = (np.float32(v) for v in shape.size)
    dx, dy, dz = d
    ox, oy, oz = (np.float32(v) for v in o)
    if shape.kind in ("capsule", "cylinder"):
        r, l = a, c
        A = dx * dx + dy * dy
        B = ox * dx + oy * dy
        C = ox * ox + oy * oy - r * r
        disc = B * B - A * C
        ts = (-B - np.sqrt(disc)) / A
        z = oz + ts * dz
        t = np.where((disc >= 0) & (A > 1e-12) & (np.abs(z) <= l) & (ts > NEAR), ts, np.inf)
        if shape.kind == "capsule":
            dd = A + dz * dz
            for zc in (-l, l):
                ocz = oz - zc
                Bs = B + dz * ocz
                disc_s = Bs * Bs - dd * (ox * ox + oy * oy + ocz * ocz - r * r)
                tsph = (-Bs - np.sqrt(disc_s)) / dd
                t = np.where((disc_s >= 0) & (tsph > NEAR) & (tsph < t), tsph, t)
            return t.astype(np.float32), None
        cap = np.zeros(dx.shape, np.int8)  # 0 side, 1 bottom cap, 2 top cap
        inv = np.float32(1.0) / dz
        for k, zc in ((1, -l), (2, l)):
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
    t = (-B - np.sqrt(disc)) / A
    return np.where((disc >= 0) & (t > NEAR), t, np.inf).astype(np.float32), None


def _round_surface(shape: Shape, p: np.ndarray, cap) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Local unit normal ``(N, 3)``, face ``(N,)`` and texture coordinates ``s, t`` ``(N,)`` at hits
    ``p (N, 3)`` of a round shape: ``s`` wraps round the axis (``turn`` texels per turn), ``t`` runs
    along it (``density`` texels per metre); cylinder caps (faces 4, 5) are mapped flat."""
    a, b, c = (np.float32(v) for v in shape.size)
    face = np.zeros(len(p), np.int64)
    if shape.kind in ("capsule", "cylinder"):
        n = p.copy()
        n[:, 2] -= np.clip(p[:, 2], -c, c)
        if shape.kind == "cylinder":
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


def _slab_face(axis: np.ndarray, p: np.ndarray):
    """Face index (0..5) of box or room hits ``p (3, N)`` bounded by slab ``axis (N,)``, and the
    coordinates ``p[_S_AXIS[face]]``, ``p[_T_AXIS[face]]`` that map to the texture's s and t."""
    on_x, on_z = axis == 0, axis == 2
    pa = np.where(on_x, p[0], np.where(axis == 1, p[1], p[2]))
    face = 2 * axis.astype(np.intp)
    face += pa > 0
    return face, np.where(on_x, p[1], p[0]), np.where(on_z, p[1], p[2])


# ------------------------------------------------------------------------ screen rects
def _screen_rects(parts: list[tuple[Shape, np.ndarray]], T_c_p: np.ndarray, camera: PinholeCamera):
    """Screen rectangles of all parts at once (``T_c_p`` is ``(P, 4, 4)``, part to camera).

    Returns ``rects (P, 4)`` int, per part the pixel rectangle ``(r0, r1, c0, c1)`` covering the
    projection of its bounding box (clipped to the near plane ``z = NEAR`` when the box crosses
    it); ``zmin (P,)`` the smallest depth of its corners (m; ``-inf`` for the room, which is
    always cast whole); and ``visible (P,)``, False for parts behind the camera or off screen.
    """
    C = np.stack([_corners_cached(sh) for sh, _ in parts])  # (P, 8, 3)
    X = np.einsum("pij,pkj->pki", T_c_p[:, :3, :3], C) + T_c_p[:, None, :3, 3]
    z = X[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = camera.fx * X[..., 0] / z + camera.cx
        v = camera.fy * X[..., 1] / z + camera.cy
    behind = z <= NEAR
    all_behind, any_behind = behind.all(axis=1), behind.any(axis=1)
    umin, umax = u.min(axis=1), u.max(axis=1)
    vmin, vmax = v.min(axis=1), v.max(axis=1)
    for k in np.flatnonzero(any_behind & ~all_behind):
        # the box cut by the near plane: the corners in front and the points where edges cross the plane
        A, B = X[k, _BOX_EDGES[:, 0]], X[k, _BOX_EDGES[:, 1]]
        cross = (A[:, 2] > NEAR) != (B[:, 2] > NEAR)
        A, B = A[cross], B[cross]
        P = A + ((NEAR - A[:, 2]) / (B[:, 2] - A[:, 2]))[:, None] * (B - A)
        Q = np.concatenate([X[k][~behind[k]], P])
        uq = camera.fx * Q[:, 0] / np.maximum(Q[:, 2], NEAR) + camera.cx
        vq = camera.fy * Q[:, 1] / np.maximum(Q[:, 2], NEAR) + camera.cy
        umin[k], umax[k], vmin[k], vmax[k] = uq.min(), uq.max(), vq.min(), vq.max()
    c0 = np.clip(np.floor(umin), 0, camera.width).astype(int)
    c1 = np.clip(np.ceil(umax) + 1, 0, camera.width).astype(int)
    r0 = np.clip(np.floor(vmin), 0, camera.height).astype(int)
    r1 = np.clip(np.ceil(vmax) + 1, 0, camera.height).astype(int)
    zmin = z.min(axis=1)
    rects = np.stack([r0, r1, c0, c1], axis=1)
    visible = ~(all_behind | (c1 <= c0) | (r1 <= r0))
    room = np.array([sh.kind == "room" for sh, _ in parts])
    rects[room] = (0, camera.height, 0, camera.width)
    zmin[room] = -np.inf
    visible |= room
    return rects, zmin, visible


# ------------------------------------------------------------------------ the caster
def raycast(parts: list[tuple[Shape, np.ndarray]], camera: PinholeCamera, T_w_c: np.ndarray) -> GBuffer:
    """Cast one ray per pixel into the parts and keep the nearest hit.

    Parts are visited nearest first (by their bounding box); a part whose nearest corner lies
    behind everything already drawn in its screen rectangle is skipped (occlusion culling).
    The room, which encloses every other part, is cast last and only through the pixels that
    are still empty. Ties between parts go to the part visited first.

    Parameters
    ----------
    parts : ``[(shape, T_w_p), ...]`` shapes with their poses (4x4, part to world).
    camera : pinhole intrinsics (no distortion is simulated).
    T_w_c : ``(4, 4)`` camera pose, camera to world.

    Returns
    -------
    :class:`GBuffer` of the frame; ``part`` indexes ``parts``.
    """
    if len(parts) == 0:
        raise ValueError("raycast: the list of parts is empty")
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        return _raycast(parts, camera, T_w_c)


def _raycast(parts: list[tuple[Shape, np.ndarray]], camera: PinholeCamera, T_w_c: np.ndarray) -> GBuffer:
    H, W = camera.height, camera.width
    grid = ray_grid(camera)
    depth = np.full((H, W), np.inf, np.float32)
    part_id = np.full((H, W), -1, np.int32)
    # every pixel a part takes gets its face, normal and texture coordinates written; the pixels
    # no ray hits are zeroed at the end
    face = np.empty((H, W), np.int8)
    normal = np.empty((3, H, W), np.float32)  # one plane per component
    s_map = np.empty((H, W), np.float32)
    t_map = np.empty((H, W), np.float32)
    # box hits keep their slab axis (in `face`) and local ray direction until the surface pass
    dbuf = np.empty((3, H, W), np.float32)
    T_c_w = se3_inv(np.asarray(T_w_c, float))
    T_c_p_all = T_c_w[None] @ np.stack([T for _, T in parts])
    T_p_c_all = se3_inv(T_c_p_all).astype(np.float32)  # camera in each part's frame
    o_all = T_p_c_all[:, :3, 3]  # (P, 3) camera centre in each part's frame
    # slab planes relative to the camera centre, per part and axis: -h - o and h - o (float32)
    half = np.array([_half_size(sh) for sh, _ in parts])
    c1_all, c2_all = -half - o_all, half - o_all
    # columns of R_p_c shaped (P, 3, 1, 1), to build a rectangle's directions by broadcasting
    Rx, Ry, Rz = (T_p_c_all[:, :3, j, None, None] for j in range(3))
    rects, zmins, visible = _screen_rects(parts, T_c_p_all, camera)
    ks = np.flatnonzero(visible)
    ks = ks[np.argsort(zmins[ks], kind="stable")]  # nearest first; equal depths in list order
    todo = [(z, k, tuple(rc)) for z, k, rc in zip(zmins[ks].tolist(), ks.tolist(), rects[ks].tolist())]
    # Objects nearest first; the room (which encloses everything) last, on the pixels still empty.
    rooms = [x for x in todo if parts[x[1]][0].kind == "room"]
    todo = [x for x in todo if parts[x[1]][0].kind != "room"]
    boxes = []
    for zmin, k, (r0, r1, c0, c1) in todo:
        zview = depth[r0:r1, c0:c1]
        if zmin > NEAR and zmin >= zview.max():  # hidden behind what is already drawn
            continue
        shape = parts[k][0]
        # ray directions in the part's frame, (3, rows, cols): d_i = R_i0 x(u) + R_i1 y(v) + R_i2
        D = Rx[k] * grid.x_row[c0:c1] + Ry[k] * grid.y_col[r0:r1]
        D += Rz[k]
        if shape.kind == "box":
            lo, hi = _slabs(D, c1_all[k, :, None, None], c2_all[k, :, None, None])
            a01 = np.maximum(lo[0], lo[1])
            tnear = np.maximum(a01, lo[2])
            win = tnear <= hi.min(axis=0)
            win &= tnear > NEAR
            win &= tnear < zview
            if not win.any():
                continue
            boxes.append(k)
            np.copyto(zview, tnear, where=win)
            np.copyto(part_id[r0:r1, c0:c1], k, where=win)
            # the bounding slab: the largest entry parameter (the first of equal ones)
            axis = (lo[1] > lo[0]).view(np.int8)
            np.copyto(axis, 2, where=lo[2] > a01)
            np.copyto(face[r0:r1, c0:c1], axis, where=win)
            np.copyto(dbuf[:, r0:r1, c0:c1], D, where=win)
            continue
        o = o_all[k]
        t, cap = _hit_round(shape, o, D)
        win = np.flatnonzero(t < zview)
        if len(win) == 0:
            continue
        flat = (win // (c1 - c0) + r0) * W + (win % (c1 - c0) + c0)  # indices into the full image
        dw = np.take(D.reshape(3, -1), win, axis=1)
        tw = t.ravel()[win]
        p = np.stack([o[i] + tw * dw[i] for i in range(3)], axis=1)
        n_l, f, s, tt = _round_surface(shape, p, None if cap is None else cap.ravel()[win])
        depth.ravel()[flat] = tw
        part_id.ravel()[flat] = k
        face.ravel()[flat] = f
        n_c = T_c_p_all[k, :3, :3].astype(np.float32) @ n_l.T
        for i in range(3):
            normal[i].ravel()[flat] = n_c[i]
        s_map.ravel()[flat] = s + np.float32(shape.offset[0])
        t_map.ravel()[flat] = tt + np.float32(shape.offset[1])
    for _, k, _ in rooms:
        _cast_room(parts[k][0], k, T_p_c_all[k], T_c_p_all[k], c1_all[k], c2_all[k], grid, depth, part_id, face, normal,
                   s_map, t_map)
    if boxes:
        _box_surfaces(parts, boxes, o_all, T_c_p_all, depth, part_id, face, dbuf, normal, s_map, t_map)
    missed = part_id < 0
    if missed.any():
        for a in (face, normal[0], normal[1], normal[2], s_map, t_map):
            a[missed] = 0
    return GBuffer(depth=depth, part=part_id, face=face, normal_planes=normal, s=s_map, t=t_map, rays=grid.rays)


def _half_size(shape: Shape) -> np.ndarray:
    """``shape.size`` as float32 ``(3,)`` (cached per shape)."""
    h = _HALF.get(shape)
    if h is None:
        h = _remember(_HALF, shape, np.array([np.float32(v) for v in shape.size], np.float32))
    return h


def _cast_room(shape: Shape, k: int, T_p_c: np.ndarray, T_c_p: np.ndarray, c1: np.ndarray, c2: np.ndarray, grid: RayGrid,
               depth, part_id, face, normal, s_map, t_map) -> None:
    """Cast the room (a box seen from inside) through the empty pixels and write their surface."""
    empty = depth == np.inf
    if not empty.any():
        return
    R, o = T_p_c[:3, :3], T_p_c[:3, 3]
    D = R[:, 0, None] * grid.x[empty]  # (3, N) ray directions in the room's frame
    D += R[:, 1, None] * grid.y[empty]
    D += R[:, 2, None]
    # From inside the room (-h < o < h on every axis) each slab's entry parameter is negative and
    # its exit parameter positive, so t_near <= t_far holds and the entry parameters are not needed.
    inside = bool(np.all(c1 < 0) and np.all(c2 > 0))
    lo, hi = _slabs(D, c1[:, None], c2[:, None], entry=not inside)
    h01 = np.minimum(hi[0], hi[1])
    tfar = np.minimum(h01, hi[2])
    ok = tfar > NEAR
    ok &= tfar < np.inf
    if not inside:
        ok &= tfar >= lo.max(axis=0)
    # the bounding slab: the smallest exit parameter (the first of equal ones)
    axis = (hi[1] < hi[0]).view(np.int8)
    np.copyto(axis, 2, where=hi[2] < h01)
    if not ok.all():
        empty[empty] = ok
        tfar, axis, D = tfar[ok], axis[ok], D[:, ok]
    D *= tfar
    D += o[:, None]  # hit points p = o + t d
    f, ps, pt = _slab_face(axis, D)
    info = _slab_info(shape)
    depth[empty] = tfar
    part_id[empty] = k
    face[empty] = f
    n = _face_normals(T_c_p[:3, :3], inside=True)
    for i in range(3):
        normal[i][empty] = np.take(n[:, i], f)
    ps *= np.take(info.cs, f)
    ps += np.take(info.s0, f)
    ps += info.offset[0]
    s_map[empty] = ps
    pt *= np.take(info.ct, f)
    pt += np.take(info.t0, f)
    pt += info.offset[1]
    t_map[empty] = pt


def _box_surfaces(parts, boxes: list[int], o_all, T_c_p_all, depth, part_id, face, dbuf, normal, s_map, t_map) -> None:
    """Face, normal and texture coordinates of every pixel a box owns, in one pass over all boxes.

    The hit point is ``p = o + t d`` (``o`` the camera centre in the box frame, ``d`` the ray
    direction kept from the cast); per-box values (``o``, face normals, texture mapping) are
    gathered by part index.
    """
    P = len(parts)
    is_box = np.zeros(P + 1, bool)
    is_box[np.asarray(boxes) + 1] = True
    mine = np.take(is_box, part_id + 1)  # the pixels boxes own
    if not mine.any():
        return
    k = part_id[mine].astype(np.intp)
    axis = face[mine]
    t = depth[mine]
    p = np.stack([dbuf[i][mine] for i in range(3)])
    p *= t
    p += np.take(o_all.T, k, axis=1)  # hit points p = o + t d
    f, ps, pt = _slab_face(axis, p)
    fi = 6 * k
    fi += f
    # per (part, face) tables; parts that are not boxes keep zeros (never indexed)
    b = np.asarray(boxes)
    infos = [_slab_info(parts[i][0]) for i in boxes]
    n_tab = np.zeros((P, 6, 3), np.float32)
    n_tab[b] = _face_normals(T_c_p_all[b, :3, :3], inside=False)
    cs, s0, ct, t0 = (np.zeros((P, 6), np.float32) for _ in range(4))
    off = np.zeros((P, 2), np.float32)
    for tab, name in ((cs, "cs"), (s0, "s0"), (ct, "ct"), (t0, "t0"), (off, "offset")):
        tab[b] = np.stack([getattr(info, name) for info in infos])
    face[mine] = f
    n_tab = n_tab.reshape(-1, 3)
    for i in range(3):
        normal[i][mine] = np.take(n_tab[:, i], fi)
    ps *= np.take(cs, fi)
    ps += np.take(s0, fi)
    ps += np.take(off[:, 0], k)
    s_map[mine] = ps
    pt *= np.take(ct, fi)
    pt += np.take(t0, fi)
    pt += np.take(off[:, 1], k)
    t_map[mine] = pt
