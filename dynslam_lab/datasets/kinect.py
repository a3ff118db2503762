"""The Kinect v1 depth sensor model of the synthetic renderer.

:func:`kinect_depth` turns an exact depth image into a Kinect-like one:

* **axial depth noise** (Nguyen, Izadi & Lovell, "Modeling Kinect sensor noise for improved
  3D reconstruction and tracking", 3DIMPVT 2012, Sec. 3, Eq. 3)::

      sigma_z(z, theta) = 0.0012 + 0.0019 (z - 0.4)^2 + 0.0001 / sqrt(z) * theta^2 / (pi/2 - theta)^2   [m]

  with ``z`` the depth (m) and ``theta`` the angle between the surface normal and the ray
  (:func:`nguyen_sigma` is the float64 reference);
* **disparity quantisation**: the Kinect measures disparity ``d = f b / z`` in steps of
  1/8 pixel (Khoshelham & Elberink, "Accuracy and resolution of Kinect depth data",
  Sensors 2012, Eqs. 5-9), so depth comes in steps ``dz = z^2 q / (f b)`` (:func:`disparity_step`);
  the Gaussian part is reduced so that noise and quantisation together have the standard
  deviation of Nguyen's model (which was measured on quantised data);
* **holes**: no reading closer than ``z_min`` or beyond ``z_max``, at grazing angles, at depth
  discontinuities, in the *projector shadow* (background seen by the camera but hidden from the
  IR projector ``b`` to its side), where the caller's per-pixel dropout probability says so
  (glossy, dark or far surfaces), and random small dropouts.

The parameters are the fields of :class:`DepthNoise`; see ``docs/synthetic.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["DepthNoise", "nguyen_sigma", "disparity_step", "kinect_depth"]


@dataclass(frozen=True)
class DepthNoise:
    """Parameters of the simulated Kinect v1 depth sensor."""

    sigma_0: float = 0.0012  # m, constant term of the axial noise (Nguyen 2012, Eq. 3)
    sigma_2: float = 0.0019  # m/m^2, quadratic term (Nguyen 2012, Eq. 3)
    z_ref: float = 0.4  # m, depth of the quadratic term's minimum (Nguyen 2012, Eq. 3)
    sigma_angle: float = 0.0001  # m*sqrt(m), angle term weight (Nguyen 2012, Eq. 3)
    baseline: float = 0.075  # m, IR projector to IR camera (Khoshelham & Elberink 2012, Sec. 2)
    ir_focal: float = 580.0  # px, focal length of the IR camera that measures disparity (Khoshelham &
    #   Elberink 2012 calibration, ~580 px; gives the 2.6 cm steps at 3 m seen in TUM fr3 depth images)
    disparity_step: float = 0.125  # px, disparity resolution 1/8 px (Khoshelham & Elberink 2012, Sec. 2.2)
    z_min: float = 0.4  # m, nearest reading (Kinect v1 specification; TUM)
    z_max: float = 8.0  # m, farthest reading (Kinect v1 practical range; our choice, few TUM readings lie beyond)
    min_cos: float = 0.12  # no reading where |cos| of the incidence angle is below this (~83 deg)
    edge_jump: float = 0.04  # relative depth jump between neighbours counted as a discontinuity (our choice)
    edge_width: int = 1  # px, holes grow this far around discontinuities (our choice)
    shadow: bool = True  # simulate the projector shadow beside foreground objects
    dropout_rate: float = 0.0008  # seeds of random holes per pixel, each grown to a 3x3 blob (our choice)
    dark_dropout: float = 0.6  # miss probability on black surfaces (albedo -> 0), fading out at albedo 0.12 (our choice:
    #   dark materials absorb the IR pattern)
    far_dropout: float = 0.35  # miss probability reached at z_max, growing linearly from 4.5 m (our choice)
    enabled: bool = True  # False: exact depth (still with range limits), for tests and figures

    def __post_init__(self) -> None:
        if self.z_min <= 0 or self.z_max <= self.z_min:
            raise ValueError(f"DepthNoise: need 0 < z_min < z_max, got {self.z_min}, {self.z_max}")
        if self.baseline <= 0 or self.disparity_step < 0:
            raise ValueError("DepthNoise: baseline must be positive and disparity_step non-negative")



def nguyen_sigma(z: np.ndarray, theta: np.ndarray | float = 0.0, params: DepthNoise = DepthNoise()) -> np.ndarray:
    """Axial noise std (m) of Kinect depth ``z`` (m) at incidence angle ``theta`` (rad), Nguyen 2012 Eq. 3."""
    z = np.asarray(z, np.float64)
    th = np.clip(np.asarray(theta, np.float64), 0.0, np.radians(80.0))
    zs = np.maximum(z, 1e-3)
    return params.sigma_0 + params.sigma_2 * (z - params.z_ref) ** 2 + params.sigma_angle / np.sqrt(zs) * th**2 / (np.pi / 2 - th) ** 2


def disparity_step(z: np.ndarray, params: DepthNoise = DepthNoise()) -> np.ndarray:
    """Depth quantisation step (m) at depth ``z`` (m): ``z^2 q / (f b)`` (Khoshelham & Elberink 2012, Eq. 9),
    ``f`` the IR camera's focal length (px), ``b`` the baseline (m), ``q`` the disparity step (px)."""
    return np.asarray(z, np.float64) ** 2 * params.disparity_step / (params.ir_focal * params.baseline)


def kinect_depth(
    z: np.ndarray,
    cos: np.ndarray,
    fx: float,
    params: DepthNoise,
    rng: np.random.Generator,
    dropout: np.ndarray | None = None,
) -> np.ndarray:
    """Turn a true depth image into a Kinect-like one (noise, quantisation, holes).

    Parameters
    ----------
    z : ``(H, W)`` true depth (m), ``inf`` or 0 where no surface.
    cos : ``(H, W)`` ``|cos|`` of the angle between the surface normal and the ray (used as float32).
    fx : unused by the default model (the disparity uses ``params.ir_focal``); kept so callers can pass the
        colour camera's focal length when ``params.ir_focal`` is 0.
    params : sensor model.
    rng : random generator of this frame.
    dropout : ``(H, W)`` probability of a missing reading per pixel (glossy surfaces), or None.

    Returns
    -------
    ``(H, W)`` float32 measured depth (m), 0 = no reading.
    """
    f32 = np.float32
    cos = np.asarray(cos, np.float32)  # the model runs in float32 (the renderer passes float32)
    z = np.asarray(z)
    if z.dtype != np.float32 or not np.isfinite(z).all():
        z = np.where(np.isfinite(z), z, f32(0.0)).astype(np.float32)
    has = z > 0
    hole = z < params.z_min
    hole |= ~has
    hole |= z > params.z_max
    if not params.enabled:
        return np.where(hole, f32(0.0), z)
    H, W = z.shape
    # Nguyen 2012 Eq. 3 in float32 (nguyen_sigma is the float64 reference); the steps below keep the
    # order of the equation's operations, with temporaries reused in place
    theta = np.clip(cos, f32(np.cos(np.radians(80.0))), f32(1.0))
    np.arccos(theta, out=theta)  # incidence angle, <= 80 deg
    sigma = np.subtract(z, f32(params.z_ref))
    np.square(sigma, out=sigma)
    sigma *= f32(params.sigma_2)
    sigma += f32(params.sigma_0)
    angle = np.maximum(z, f32(1e-3))
    np.sqrt(angle, out=angle)
    np.divide(f32(params.sigma_angle), angle, out=angle)
    angle *= theta
    angle *= theta
    np.subtract(f32(np.pi / 2), theta, out=theta)
    np.square(theta, out=theta)
    angle /= theta
    sigma += angle
    fb = f32((params.ir_focal or fx) * params.baseline)
    # Gaussian part: sqrt(sigma^2 - dz^2 / 12), dz = z^2 q / (f b) the quantisation step
    dz = z * z
    dz *= f32(params.disparity_step)
    dz /= fb
    sigma *= sigma
    dz *= dz
    dz /= f32(12.0)
    sigma -= dz
    np.maximum(sigma, f32(0.0), out=sigma)
    np.sqrt(sigma, out=sigma)
    zn = rng.standard_normal((H, W), dtype=np.float32)
    zn *= sigma
    zn += z
    if params.disparity_step > 0:
        with np.errstate(divide="ignore", invalid="ignore"):
            q = f32(params.disparity_step)
            disp = np.divide(fb, zn, out=zn)
            disp /= q
            np.round(disp, out=disp)
            disp *= q
            zq = np.where(disp > 0, fb / disp, f32(0.0))
    else:
        zq = zn
    hole |= cos < params.min_cos
    # depth discontinuities: neighbours whose depth differs by more than edge_jump * z
    all_have = bool(has.all())
    zz = z if all_have else np.where(has, z, 1e3)
    jump = np.zeros((H, W), bool)
    dx = np.abs(np.diff(zz, axis=1)) > params.edge_jump * np.minimum(zz[:, 1:], zz[:, :-1])
    dy = np.abs(np.diff(zz, axis=0)) > params.edge_jump * np.minimum(zz[1:], zz[:-1])
    jump[:, 1:] |= dx
    jump[:, :-1] |= dx
    jump[1:] |= dy
    jump[:-1] |= dy
    if params.edge_width > 0:
        k = 2 * params.edge_width + 1
        jump = cv2.dilate(jump.view(np.uint8), np.ones((k, k), np.uint8)).view(bool)
    hole |= jump
    if params.shadow:
        # projector at +baseline along camera x: pixel u is hidden from it when a pixel u' > u
        # projects to a smaller projector column u' - d(u') < u - d(u) (it lies in front, on the projector's ray).
        d = np.maximum(z, f32(1e-3))
        np.divide(fb, d, out=d)
        if not all_have:
            d[~has] = 0.0
        q = np.subtract(np.arange(W, dtype=np.float32)[None, :], d, out=d)
        # later[u] = min over u' > u of q[u']: a running minimum from the right, by doubling windows
        # (log2 W vectorised steps, two buffers in turn; min is exact, so any order gives the same values)
        later = np.full_like(q, np.inf)
        later[:, :-1] = q[:, 1:]
        spare = np.empty_like(q)
        step = 1
        while step < W - 1:
            np.minimum(later[:, :-step], later[:, step:], out=spare[:, :-step])
            spare[:, -step:] = later[:, -step:]
            later, spare = spare, later
            step *= 2
        q -= f32(0.05)
        hole |= later < q  # strictly hidden (0.05 px: float round-off)
    seeds = rng.random((H, W), dtype=np.float32) < params.dropout_rate
    hole |= cv2.dilate(seeds.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
    if dropout is not None:
        hole |= rng.random((H, W), dtype=np.float32) < dropout
    hole |= zq < params.z_min
    hole |= zq > params.z_max
    zq[hole] = 0.0
    return zq
