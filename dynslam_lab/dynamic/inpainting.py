"""Background inpainting of dynamic regions from earlier keyframes (Chang et al. 2021, Chang et al. 2021,
Sec. III-D, eq. 4). For display only: the paper never tracks on inpainted images, neither do we.

A historical keyframe ``F_k`` (colour, depth ``depth_k``, pose ``T_cw_k``) saw, at some earlier
moment, the background that a person now hides in the current frame ``F_c`` (pose ``T_cw_c``).
Its pixels are mapped into the current frame::

    F_c_map = K ( T_cw_c ( T_cw_k^-1 ( K^-1 F_k )_depth_k ) )_/depth_c        (4)

i.e. back-project each keyframe pixel with its depth, move it from keyframe to world to the
current camera, divide by the new depth and project with ``K``. The colours that land inside the
current dynamic mask fill it. "The current frame can be almost completely filled with 10-20
historical keyframes; however, backgrounds not presented in historical keyframes cannot be
repaired."

Our reading: keyframes are used newest first; a masked pixel takes the colour of the nearest
(smallest depth) keyframe point that lands on it (a z-buffer), and keeps it once filled; keyframe
pixels inside the keyframe's own dynamic mask are skipped (they show people, not background).
Vectorised per keyframe: one back-projection, one ``np.lexsort`` for the z-buffer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.se3 import se3_inv

__all__ = ["InpaintingConfig", "InpaintSource", "InpaintResult", "inpaint_background"]


@dataclass(frozen=True)
class InpaintingConfig:
    """Parameters of background inpainting (Chang et al. 2021, Sec. III-D)."""

    n_keyframes: int = 15  # keyframes used, newest first; Chang et al. 2021: "10-20"
    max_depth_m: float = 8.0  # keyframe depths beyond this are ignored (m); ours, 8.0 (Kinect range)

    def __post_init__(self) -> None:
        if self.n_keyframes < 1:
            raise ValueError(f"InpaintingConfig.n_keyframes must be >= 1, got {self.n_keyframes}")
        if self.max_depth_m <= 0:
            raise ValueError(f"InpaintingConfig.max_depth_m must be > 0 (metres), got {self.max_depth_m}")


@dataclass
class InpaintSource:
    """One historical keyframe: ``rgb (H, W, 3)`` uint8, ``depth (H, W)`` metres, ``T_w_c (4, 4)``,
    and its own dynamic ``mask (H, W)`` bool (or None)."""

    rgb: np.ndarray
    depth: np.ndarray
    T_w_c: np.ndarray
    mask: np.ndarray | None = None


@dataclass
class InpaintResult:
    """``rgb`` with the mask filled, ``depth`` (filled pixels get the mapped depth), ``filled``
    ``(H, W)`` bool pixels repaired, ``fill_ratio`` filled / masked."""

    rgb: np.ndarray
    depth: np.ndarray
    filled: np.ndarray
    fill_ratio: float


def inpaint_background(
    rgb: np.ndarray,
    depth: np.ndarray,
    mask: np.ndarray,
    T_w_c: np.ndarray,
    keyframes: list[InpaintSource],
    camera,
    config: InpaintingConfig = InpaintingConfig(),
) -> InpaintResult:
    """Fill ``mask`` of the current frame with colours mapped from ``keyframes`` by eq. 4.

    Parameters
    ----------
    rgb : ``(H, W, 3)`` uint8 current image; ``depth`` ``(H, W)`` metres.
    mask : ``(H, W)`` bool dynamic pixels to fill.
    T_w_c : ``(4, 4)`` current camera pose (camera to world).
    keyframes : historical keyframes, oldest first (the newest ``n_keyframes`` are used).
    camera : intrinsics of all images.
    """
    rgb = np.asarray(rgb)
    mask = np.asarray(mask, bool)
    h, w = mask.shape
    if rgb.shape[:2] != (h, w) or np.asarray(depth).shape != (h, w):
        raise ValueError(f"inpaint_background: rgb {rgb.shape}, depth {np.shape(depth)} and mask {mask.shape} differ")
    out_rgb = rgb.copy()
    out_depth = np.asarray(depth, np.float32).copy()
    filled = np.zeros((h, w), bool)
    todo = mask.copy()
    T_c_w = se3_inv(np.asarray(T_w_c, np.float64))
    for kf in list(keyframes)[::-1][: config.n_keyframes]:
        if not todo.any():
            break
        if kf.rgb.shape[:2] != (h, w) or kf.depth.shape != (h, w):
            raise ValueError(f"inpaint_background: keyframe images {kf.rgb.shape} / {kf.depth.shape} differ from {(h, w)}")
        ok = (kf.depth > 0) & (kf.depth < config.max_depth_m)
        if kf.mask is not None:
            ok &= ~np.asarray(kf.mask, bool)
        v, u = np.nonzero(ok)
        z = kf.depth[v, u].astype(np.float64)
        Xk = np.column_stack([(u - camera.cx) / camera.fx * z, (v - camera.cy) / camera.fy * z, z])
        T_c_k = T_c_w @ np.asarray(kf.T_w_c, np.float64)
        Xc = Xk @ T_c_k[:3, :3].T + T_c_k[:3, 3]
        front = Xc[:, 2] > 1e-6
        Xc, u, v = Xc[front], u[front], v[front]
        uc = np.round(camera.fx * Xc[:, 0] / Xc[:, 2] + camera.cx).astype(np.int64)
        vc = np.round(camera.fy * Xc[:, 1] / Xc[:, 2] + camera.cy).astype(np.int64)
        inside = (uc >= 0) & (uc < w) & (vc >= 0) & (vc < h)
        uc, vc, u, v, zc = uc[inside], vc[inside], u[inside], v[inside], Xc[inside, 2]
        want = todo[vc, uc]
        uc, vc, u, v, zc = uc[want], vc[want], u[want], v[want], zc[want]
        if len(uc) == 0:
            continue
        # z-buffer: for each target pixel keep the nearest source point
        target = vc * w + uc
        order = np.lexsort((zc, target))
        first = np.ones(len(order), bool)
        first[1:] = target[order][1:] != target[order][:-1]
        sel = order[first]
        out_rgb[vc[sel], uc[sel]] = kf.rgb[v[sel], u[sel]]
        out_depth[vc[sel], uc[sel]] = zc[sel]
        filled[vc[sel], uc[sel]] = True
        todo[vc[sel], uc[sel]] = False
    n_mask = int(mask.sum())
    return InpaintResult(out_rgb, out_depth, filled, float(filled.sum()) / n_mask if n_mask else 1.0)
