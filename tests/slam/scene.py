"""A small ray-cast test world: a textured box room seen by a pinhole camera.

Every pixel's ray is intersected with the six walls of an axis-aligned box (vectorised); the
wall's texture (random blobs and squares, seeded) is sampled with ``cv2.remap``. The depth is
the exact z of the hit point, so poses and depths are ground truth for tracking tests.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from dynslam_lab.camera import CAMERA_PRESETS, PinholeCamera
from dynslam_lab.datasets.frame import Frame
from dynslam_lab.geometry.se3 import make_pose, so3_exp

ROOM = np.array([[-1.3, 1.3], [-0.95, 0.95], [-2.0, 2.6]])  # x, y, z extents (m)
TEX_PX_PER_M = 200.0


def make_textures(seed: int = 0, size: int = 1400) -> list[np.ndarray]:
    """Six grey textures (uint8) with corners at several scales."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(6):
        img = np.zeros((size, size), np.float32)
        for s in (3, 9, 27):
            n = rng.random((size // s + 1, size // s + 1)).astype(np.float32)
            img += cv2.resize(n, (size, size), interpolation=cv2.INTER_NEAREST)[:size, :size]
        img = img / 3.0 * 180
        for _ in range(400):
            x, y = rng.integers(0, size - 40, 2)
            w = int(rng.integers(8, 40))
            cv2.rectangle(img, (int(x), int(y)), (int(x) + w, int(y) + w), float(rng.integers(0, 255)), -1)
        out.append(np.clip(cv2.GaussianBlur(img, (3, 3), 0.8), 0, 255).astype(np.uint8))
    return out


def render(T_w_c: np.ndarray, textures: list[np.ndarray], camera: PinholeCamera | None = None) -> tuple[np.ndarray, np.ndarray]:
    """RGB ``(H, W, 3)`` uint8 and depth ``(H, W)`` float32 metres of the room from pose ``T_w_c``."""
    cam = camera or CAMERA_PRESETS["default"]
    v, u = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float64)
    d_c = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], -1).reshape(-1, 3)
    R, c = T_w_c[:3, :3], T_w_c[:3, 3]
    d_w = d_c @ R.T
    best_t = np.full(len(d_w), np.inf)
    tex_u = np.zeros(len(d_w), np.float32)
    tex_v = np.zeros(len(d_w), np.float32)
    face = np.full(len(d_w), -1)
    k = 0
    for axis in range(3):
        for side in range(2):
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (ROOM[axis, side] - c[axis]) / d_w[:, axis]
            p = c + t[:, None] * d_w
            a, b = [i for i in range(3) if i != axis]
            hit = (t > 0) & (t < best_t)
            best_t = np.where(hit, t, best_t)
            tex_u = np.where(hit, (p[:, a] - ROOM[a, 0]) * TEX_PX_PER_M, tex_u).astype(np.float32)
            tex_v = np.where(hit, (p[:, b] - ROOM[b, 0]) * TEX_PX_PER_M, tex_v).astype(np.float32)
            face = np.where(hit, k, face)
            k += 1
    gray = np.zeros(len(d_w), np.uint8)
    mu = tex_u.reshape(cam.height, cam.width)
    mv = tex_v.reshape(cam.height, cam.width)
    for f in range(6):
        sel = face == f
        if sel.any():
            s = cv2.remap(textures[f], mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
            gray[sel] = s.ravel()[sel]
    depth = (best_t * d_c[:, 2]).astype(np.float32)  # z = t * d_c.z (d_c.z = 1)
    img = gray.reshape(cam.height, cam.width)
    return np.repeat(img[:, :, None], 3, axis=2), depth.reshape(cam.height, cam.width)


def trajectory(n: int, kind: str = "xyz") -> np.ndarray:
    """``(n, 4, 4)`` smooth camera poses (30 Hz): ``xyz`` translation, ``arc`` turning."""
    poses = []
    for i in range(n):
        s = i / 30.0
        if kind == "xyz":
            t = np.array([0.25 * np.sin(0.9 * s), 0.12 * np.sin(1.3 * s), 0.2 * np.sin(0.7 * s)])
            R = so3_exp(np.array([0.04 * np.sin(0.8 * s), 0.08 * np.sin(0.6 * s), 0.02 * np.sin(s)]))
        else:
            t = np.array([0.6 * np.sin(0.4 * s), 0.05 * np.sin(s), 0.3 * np.cos(0.4 * s) - 0.3])
            R = so3_exp(np.array([0.0, 0.5 * np.sin(0.4 * s), 0.0]))
        poses.append(make_pose(R, t))
    return np.stack(poses)


@lru_cache(maxsize=4)
def _frames_cached(n: int, kind: str, seed: int) -> tuple[Frame, ...]:
    return tuple(_render_frames(n, kind, seed, CAMERA_PRESETS["default"]))


def frames(n: int, kind: str = "xyz", seed: int = 0) -> list[Frame]:
    """Rendered frames with ground-truth poses (cached per session; frames are shared, do not edit)."""
    return list(_frames_cached(n, kind, seed))


def _render_frames(n: int, kind: str, seed: int, cam: PinholeCamera) -> list[Frame]:
    tex = make_textures(seed)
    out = []
    for i, T in enumerate(trajectory(n, kind)):
        rgb, depth = render(T, tex, cam)
        out.append(Frame(index=i, timestamp=i / 30.0, rgb=rgb, depth=depth, camera=cam, T_w_c_gt=T))
    return out
