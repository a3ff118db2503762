"""Dense optical flow with an adaptive threshold (Chang et al., IEEE TIM 2021, Chang et al. 2021, Sec. III-C).

A detector finds the person but not the chair, box or microphone the person pushes or carries.
Chang et al. 2021 finds those "human-driven" objects in dense Farneback flow between adjacent frames.
The flow intensity of pixel ``i`` is ``pixel_i = sqrt(u_i^2 + v_i^2)``; its mean over the ``n``
pixels of the person mask is::

    p_bar = (1 / n) sum_i sqrt(u_i^2 + v_i^2)                             (3)

and ``2 p_bar`` is the adaptive threshold: pixels moving faster than twice the person's mean
flow are "obviously moving"; the regions they form that overlap the person mask are the
human-driven objects, and the dynamic region is the mask together with them (Fig. 5).

Our reading and the choices we had to make:

* **Resolution.** Flow runs on images scaled by ``scale`` (default 0.25, i.e. 160x120 for
  640x480) to meet the time budget; flow vectors are reported in full-resolution pixels.
* **Direction.** Flow is computed from the current to the previous image, so that it lives on
  the pixels of the current frame (where the keypoints and the mask are).
* **Camera motion.** With a moving camera the static background flows too. When a rough pose
  (from :mod:`.multiview`) and the current depth are known, we subtract the flow the camera
  motion alone would cause (back-project with depth, move, re-project): what remains is the
  motion of objects. The paper's TUM cameras move slowly; this makes the threshold meaningful
  on fast synthetic cameras as well. Switch it off with ``compensate_ego_motion=False``.
* **Overlap.** A region counts when it overlaps the person mask grown by ``touch_px``; a floor
  ``min_flow_px`` keeps sensor noise out when the person stands still (``p_bar`` near 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry.se3 import se3_inv
from .epipolar import run_beside

__all__ = ["FlowConfig", "FlowResult", "farneback_flow", "farneback_flow_async", "ego_motion_flow", "human_driven_regions",
           "flow_regions"]


@dataclass(frozen=True)
class FlowConfig:
    """Parameters of adaptive-threshold dense flow (Chang et al. 2021, Sec. III-C)."""

    factor: float = 2.0  # adaptive threshold = factor * mean flow in the person mask; Chang et al. 2021: 2
    scale: float = 0.25  # image scale for Farneback (0.25 -> 160x120 at 640x480); ours, for speed
    min_flow_px: float = 2.0  # floor of the threshold (full-resolution px); ours, 2.0
    touch_px: int = 8  # a region counts when it overlaps the person mask grown by this (full-res px); ours, 8
    min_region_px: int = 200  # smallest region kept (full-resolution pixels); ours, 200
    compensate_ego_motion: bool = True  # subtract the flow of the camera motion; ours, True
    pyr_scale: float = 0.5  # Farneback pyramid scale; OpenCV sample value 0.5
    levels: int = 3  # Farneback pyramid levels; OpenCV sample value 3
    winsize: int = 9  # Farneback averaging window (px at the reduced scale); ours, 9 (15 at full scale)
    iterations: int = 3  # Farneback iterations per level; OpenCV sample value 3
    poly_n: int = 5  # Farneback polynomial neighbourhood; OpenCV sample value 5
    poly_sigma: float = 1.1  # Farneback Gaussian sigma; OpenCV recommends 1.1 for poly_n 5

    def __post_init__(self) -> None:
        if not 0 < self.scale <= 1:
            raise ValueError(f"FlowConfig.scale must be in (0, 1], got {self.scale}")
        if self.factor <= 0 or self.min_flow_px < 0:
            raise ValueError("FlowConfig: factor must be > 0 and min_flow_px >= 0")
        if self.touch_px < 0 or self.min_region_px < 0:
            raise ValueError(f"FlowConfig: touch_px and min_region_px must be >= 0, got {self.touch_px}, {self.min_region_px}")
        if not 0 < self.pyr_scale < 1:
            raise ValueError(f"FlowConfig.pyr_scale must be in (0, 1), got {self.pyr_scale}")
        for name in ("levels", "winsize", "iterations", "poly_n"):
            if getattr(self, name) < 1:
                raise ValueError(f"FlowConfig.{name} must be >= 1, got {getattr(self, name)}")
        if not self.poly_sigma > 0:
            raise ValueError(f"FlowConfig.poly_sigma must be > 0, got {self.poly_sigma}")


@dataclass
class FlowResult:
    """Adaptive-threshold flow of one frame.

    Attributes
    ----------
    region : ``(H, W)`` bool human-driven regions at full resolution: the connected regions whose
        flow exceeds the threshold and that overlap the (grown) person mask; the mask's own fast
        parts (a swinging arm) are included.
    threshold_px : the threshold used (``max(factor * p_bar, min_flow_px)``), full-res px, or nan.
    mean_flow_px : ``p_bar`` of eq. 3 (full-res px), or nan without a person mask.
    magnitude : ``(h, w)`` float32 residual flow magnitude at the reduced scale (full-res px).
    """

    region: np.ndarray
    threshold_px: float
    mean_flow_px: float
    magnitude: np.ndarray


def farneback_flow(gray: np.ndarray, prev_gray: np.ndarray, config: FlowConfig = FlowConfig()) -> np.ndarray:
    """Dense flow from the current to the previous image at ``config.scale``.

    Returns ``(h, w, 2)`` float32: for each reduced pixel of the current image, the displacement
    to its position in the previous image, in **full-resolution** pixels.
    """
    if gray.shape != prev_gray.shape or gray.ndim != 2:
        raise ValueError(f"farneback_flow: images must be equal (H, W) grey, got {gray.shape} and {prev_gray.shape}")
    h, w = gray.shape
    sw, sh = max(int(round(w * config.scale)), 8), max(int(round(h * config.scale)), 8)
    a = cv2.resize(gray, (sw, sh), interpolation=cv2.INTER_AREA)
    b = cv2.resize(prev_gray, (sw, sh), interpolation=cv2.INTER_AREA)
    flow = cv2.calcOpticalFlowFarneback(a, b, None, config.pyr_scale, config.levels, config.winsize,
                                        config.iterations, config.poly_n, config.poly_sigma, 0)
    flow[..., 0] *= w / sw
    flow[..., 1] *= h / sh
    return flow


def farneback_flow_async(gray: np.ndarray, prev_gray: np.ndarray, config: FlowConfig = FlowConfig()):
    """:func:`farneback_flow` started in the screener's worker thread (:func:`~.epipolar.run_beside`): the flow
    needs the two images only, so it runs while the geometric stages judge the frame. A future of the flow."""
    return run_beside(farneback_flow, gray, prev_gray, config)


def ego_motion_flow(depth: np.ndarray, camera, T_p_c: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Flow (full-res px) that the camera motion alone gives each pixel of a reduced grid.

    Parameters
    ----------
    depth : ``(H, W)`` current depth, metres.
    camera : intrinsics of the full image.
    T_p_c : ``(4, 4)`` current camera -> previous camera.
    shape : ``(h, w)`` of the reduced grid.

    Returns ``(h, w, 2)`` float32, ``nan`` where there is no depth.
    """
    H, W = depth.shape
    h, w = shape
    # centres of the reduced pixels in full-resolution coordinates
    u = (np.arange(w) + 0.5) * (W / w) - 0.5
    v = (np.arange(h) + 0.5) * (H / h) - 0.5
    uu, vv = np.meshgrid(u, v)
    z = cv2.resize(depth.astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST).astype(np.float64)
    z[~(z > 0)] = np.nan
    X = np.stack([(uu - camera.cx) / camera.fx * z, (vv - camera.cy) / camera.fy * z, z], axis=-1).reshape(-1, 3)
    Xp = X @ T_p_c[:3, :3].T + T_p_c[:3, 3]
    with np.errstate(invalid="ignore", divide="ignore"):
        up = camera.fx * Xp[:, 0] / Xp[:, 2] + camera.cx
        vp = camera.fy * Xp[:, 1] / Xp[:, 2] + camera.cy
    return np.stack([up.reshape(h, w) - uu, vp.reshape(h, w) - vv], axis=-1).astype(np.float32)


def human_driven_regions(
    magnitude: np.ndarray, person_mask: np.ndarray, config: FlowConfig = FlowConfig(), scale_to_full: float = 1.0
) -> tuple[np.ndarray, float, float]:
    """Eq. 3 and the ``2 p_bar`` threshold on a flow magnitude image.

    Parameters
    ----------
    magnitude : ``(h, w)`` flow magnitude (full-res px), ``nan`` = unknown.
    person_mask : ``(h, w)`` bool mask of the a-priori dynamic objects at the same size.
    scale_to_full : full-resolution pixels per pixel of this grid (for the area and touch sizes).

    Returns
    -------
    region : ``(h, w)`` bool regions above threshold overlapping the (grown) mask.
    threshold : ``max(factor * p_bar, min_flow_px)``; nan when the mask is empty.
    p_bar : eq. 3; nan when the mask is empty.
    """
    mag = np.asarray(magnitude, np.float32)
    person = np.asarray(person_mask, bool)
    if mag.shape != person.shape:
        raise ValueError(f"human_driven_regions: magnitude {mag.shape} and mask {person.shape} differ")
    vals = mag[person & np.isfinite(mag)]
    if len(vals) == 0:
        return np.zeros_like(person), float("nan"), float("nan")
    p_bar = float(vals.mean())
    thr = max(config.factor * p_bar, config.min_flow_px)
    fast = np.nan_to_num(mag, nan=0.0) > thr
    n, labels, stats, _ = cv2.connectedComponentsWithStats(fast.astype(np.uint8), connectivity=8)
    r = max(int(round(config.touch_px / scale_to_full)), 0)
    grown = person
    if r > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        grown = cv2.dilate(person.astype(np.uint8), kernel).astype(bool)
    touching = np.zeros(n, bool)
    touching[np.unique(labels[grown & fast])] = True
    touching[0] = False
    min_area = config.min_region_px / scale_to_full**2
    touching &= stats[:, cv2.CC_STAT_AREA] >= min_area
    return touching[labels], thr, p_bar


def flow_regions(
    gray: np.ndarray,
    prev_gray: np.ndarray,
    person_mask: np.ndarray,
    depth: np.ndarray | None = None,
    camera=None,
    T_c_p: np.ndarray | None = None,
    config: FlowConfig = FlowConfig(),
    flow: np.ndarray | None = None,
) -> FlowResult:
    """The whole stage on one frame: flow, optional ego-motion removal, adaptive threshold.

    Parameters
    ----------
    gray, prev_gray : ``(H, W)`` uint8 current and previous images.
    person_mask : ``(H, W)`` bool a-priori dynamic mask of the current frame.
    depth, camera, T_c_p : current depth (m), intrinsics and rough pose previous -> current, to
        remove camera motion (skipped when any is None or ``compensate_ego_motion`` is off).
    flow : :func:`farneback_flow` of the two images when already computed (e.g. by :func:`farneback_flow_async`).
    """
    H, W = gray.shape
    if person_mask.shape != (H, W):
        raise ValueError(f"flow_regions: person_mask {person_mask.shape} differs from image {(H, W)}")
    if flow is None:
        flow = farneback_flow(gray, prev_gray, config)
    h, w = flow.shape[:2]
    if config.compensate_ego_motion and depth is not None and camera is not None and T_c_p is not None:
        ego = ego_motion_flow(depth, camera, se3_inv(T_c_p), (h, w))
        residual = flow - ego  # nan where no depth: those pixels are not judged
    else:
        residual = flow
    mag = np.sqrt(residual[..., 0] ** 2 + residual[..., 1] ** 2)
    small_mask = cv2.resize(person_mask.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)
    region_small, thr, p_bar = human_driven_regions(mag, small_mask, config, scale_to_full=W / w)
    region = cv2.resize(region_small.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST).astype(bool)
    return FlowResult(region, thr, p_bar, mag)
