"""Small hand-built two-layer RGB-D scenes with known motion, for the screening tests.

A textured wall in two fronto-parallel halves (left at ``z_wall``, right at ``z_wall2``: two
depths, so that no single rigid motion explains a moving person) and a textured "person"
rectangle at ``z_person`` in front of it. The camera translates by ``t`` (metres, camera x/y) between
frames: a point at depth ``z`` shifts by ``-f t / z`` pixels (exact for a translating pinhole
camera and fronto-parallel planes). The person moves on its own by ``person_shift_px`` too.
Truth: the person's pixels are dynamic, the wall's static.
"""

from __future__ import annotations

import cv2
import numpy as np

from dynslam_lab.camera import PinholeCamera
from dynslam_lab.datasets.frame import Frame
from dynslam_lab.detection.detections import Detections
from dynslam_lab.geometry.se3 import make_pose

CAM = PinholeCamera(525.0, 525.0, 319.5, 239.5, name="test")


def texture(h: int, w: int, seed: int) -> np.ndarray:
    """A blotchy grey texture with plenty of corners (uint8)."""
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, size=(h // 8 + 1, w // 8 + 1), dtype=np.uint8)
    img = cv2.resize(small, (w, h), interpolation=cv2.INTER_NEAREST)
    img = cv2.GaussianBlur(img, (3, 3), 0.8)
    return img


def _shift(img: np.ndarray, dx: float, dy: float) -> np.ndarray:
    M = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]])
    return cv2.warpAffine(img, M, (img.shape[1], img.shape[0]), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def two_layer_frames(
    n: int = 2,
    t_step=(0.02, 0.0),
    person_shift_px=(2.0, 12.0),
    z_wall: float = 3.0,
    z_wall2: float = 6.0,
    z_person: float = 1.5,
    box=(260, 140, 380, 420),
    seed: int = 0,
):
    """``n`` frames: list of (Frame, person mask (H, W) bool, Detections with the person box+mask)."""
    h, w = CAM.height, CAM.width
    pad = 200
    wall_tex = texture(h + 2 * pad, w + 2 * pad, seed)
    wall2_tex = texture(h + 2 * pad, w + 2 * pad, seed + 7)
    right = np.zeros((h, w), bool)
    right[:, w // 2 :] = True
    person_tex = texture(h + 2 * pad, w + 2 * pad, seed + 1)
    x1, y1, x2, y2 = box
    frames = []
    for k in range(n):
        tx, ty = t_step[0] * k, t_step[1] * k
        wall = _shift(wall_tex, -CAM.fx * tx / z_wall, -CAM.fy * ty / z_wall)[pad : pad + h, pad : pad + w]
        wall2 = _shift(wall2_tex, -CAM.fx * tx / z_wall2, -CAM.fy * ty / z_wall2)[pad : pad + h, pad : pad + w]
        wall = np.where(right, wall2, wall)
        pdx = -CAM.fx * tx / z_person + person_shift_px[0] * k
        pdy = -CAM.fy * ty / z_person + person_shift_px[1] * k
        person = _shift(person_tex, pdx, pdy)[pad : pad + h, pad : pad + w]
        mask_base = np.zeros((h, w), np.uint8)
        mask_base[y1:y2, x1:x2] = 1
        mask = _shift(mask_base.astype(np.float32), pdx, pdy) > 0.5
        gray = np.where(mask, person, wall).astype(np.uint8)
        depth = np.where(mask, z_person, np.where(right, z_wall2, z_wall)).astype(np.float32)
        rgb = np.repeat(gray[:, :, None], 3, axis=2)
        inst = mask.astype(np.int32)
        T_w_c = make_pose(np.eye(3), np.array([tx, ty, 0.0]))
        frame = Frame(index=k, timestamp=k / 30.0, rgb=rgb, depth=depth, camera=CAM, T_w_c_gt=T_w_c,
                      instance_mask=inst, instance_classes={1: "person"})
        ys, xs = np.nonzero(mask)
        if len(xs) == 0:
            dets = Detections.empty((h, w), with_masks=True, source="test")
        else:
            dets = Detections(np.array([[xs.min(), ys.min(), xs.max(), ys.max()]]), np.array([0.9]), np.array([0]),
                              (h, w), masks=mask[None], source="test")
        frames.append((frame, mask, dets))
    return frames
