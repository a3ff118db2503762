"""Synthetic dynamic RGB-D sequences: a textured office with people, rendered like a Kinect.

The renderer ray-casts an analytic office (walls, desk, monitors, chairs, shelves of books,
two people built from capsules and ellipsoids) through the pinhole camera
(:mod:`dynslam_lab.datasets.scene`), textures it with mip-mapped procedural textures
(:mod:`dynslam_lab.datasets.textures`), shades it with Lambertian point lights, and
degrades colour and depth the way a Kinect v1 does:

* **axial depth noise** (Nguyen, Izadi & Lovell, "Modeling Kinect sensor noise for improved
  3D reconstruction and tracking", 3DIMPVT 2012, Sec. 3, Eq. 3)::

      sigma_z(z, theta) = 0.0012 + 0.0019 (z - 0.4)^2 + 0.0001 / sqrt(z) * theta^2 / (pi/2 - theta)^2   [m]

  with ``z`` the depth (m) and ``theta`` the angle between the surface normal and the ray;
* **disparity quantisation**: the Kinect measures disparity ``d = f b / z`` in steps of
  1/8 pixel (Khoshelham & Elberink, "Accuracy and resolution of Kinect depth data",
  Sensors 2012, Eqs. 5-9), so depth comes in steps ``dz = z^2 q / (f b)`` (``b`` = 7.5 cm,
  ``f`` = 580 px: 2.6 cm at 3 m, as in TUM fr3 depth images);
  the Gaussian part is reduced so that noise and quantisation together have the standard
  deviation of Nguyen's model (which was measured on quantised data);
* **holes**: no reading closer than 0.4 m or beyond 8 m, at grazing angles, at depth
  discontinuities, in the *projector shadow* (background seen by the camera but hidden
  from the IR projector 7.5 cm to its side), on glossy screens and dark (IR-absorbing)
  surfaces, increasingly beyond 4.5 m, and random small dropouts.

Sequences are written in the TUM RGB-D layout (``rgb/``, ``depth/``, ``rgb.txt``,
``depth.txt``, ``groundtruth.txt``) plus ``camera.json``, instance masks ``masks/``,
``instances.json`` and ``moving.txt``, so :class:`~dynslam_lab.datasets.tum.TumSequence`
reads them unchanged. See ``docs/synthetic.md``.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from dataclasses import asdict, dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from ..camera import CAMERA_PRESETS, PinholeCamera, save_camera_json
from ..geometry.se3 import pose_to_tum, so3_exp
from . import scene as sc
from .textures import TextureAtlas, build_atlas, sample_atlas

__all__ = [
    "DepthNoise",
    "ScenePreset",
    "PRESETS",
    "RENDER_VERSION",
    "RenderedFrame",
    "SyntheticRenderer",
    "get_preset",
    "frame_times",
    "camera_pose",
    "nguyen_sigma",
    "disparity_step",
    "kinect_depth",
    "render_frame",
    "render_sequence",
    "synthetic_sequence",
    "read_moving",
    "cache_key",
]

#: Bump when the output of the renderer changes: part of the cache key.
RENDER_VERSION = "12"
#: Colour timestamps start here (s), like the UNIX times of TUM sequences.
T0 = 1_600_000_000.0
#: An instance is "moving" in a frame when some point of its surface moved more than this (m).
MOVING_THRESHOLD = 0.001


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


@dataclass(frozen=True)
class ScenePreset:
    """One synthetic sequence: the scene, the camera motion and the sensor.

    Attributes
    ----------
    name : preset name (``walking_xyz``...).
    scene : ``walking`` (two people walking), ``sitting`` (two seated people, a book moved),
        ``static`` (no movers), ``walking_one`` (one walker).
    motion : camera motion ``static`` (tiny jitter), ``xyz`` (translation), ``rpy`` (rotation),
        ``halfsphere`` (on a half-sphere of 1 m diameter looking at the desk), ``loop`` (a closed
        circle round the room, looking outwards, back to the start pose).
    n_frames : default length (frames at 30 Hz).
    camera : intrinsics preset name in :data:`dynslam_lab.camera.CAMERA_PRESETS`.
    image_noise : std of the Gaussian colour noise, 8-bit levels.
    blur : std of the optical blur, pixels.
    depth : the depth sensor model.
    """

    name: str
    scene: str
    motion: str
    n_frames: int = 300
    camera: str = "default"
    image_noise: float = 2.0  # 8-bit levels (our choice: a clean Kinect colour image)
    blur: float = 0.5  # px (our choice: optics and demosaicing soften edges)
    depth: DepthNoise = field(default_factory=DepthNoise)

    def __post_init__(self) -> None:
        if self.scene not in ("walking", "sitting", "static", "walking_one"):
            raise ValueError(f"ScenePreset.scene must be walking, sitting, static or walking_one, got {self.scene!r}")
        if self.motion not in ("static", "xyz", "rpy", "halfsphere", "loop"):
            raise ValueError(f"ScenePreset.motion must be static, xyz, rpy, halfsphere or loop, got {self.motion!r}")
        if self.n_frames < 1:
            raise ValueError(f"ScenePreset.n_frames must be >= 1, got {self.n_frames}")
        if self.camera not in CAMERA_PRESETS:
            raise ValueError(f"ScenePreset.camera {self.camera!r} is not one of {sorted(CAMERA_PRESETS)}")
        if CAMERA_PRESETS[self.camera].has_distortion:
            raise ValueError(f"ScenePreset.camera {self.camera!r} has lens distortion, which the renderer does not "
                             "simulate; choose an undistorted preset (default, tum_fr3, bonn)")


def _presets() -> dict[str, ScenePreset]:
    out = {}
    for scene in ("walking", "sitting"):
        for motion in ("xyz", "static", "rpy", "halfsphere"):
            out[f"{scene}_{motion}"] = ScenePreset(f"{scene}_{motion}", scene, motion)
    for motion in ("xyz", "halfsphere", "rpy"):
        out[f"static_{motion}"] = ScenePreset(f"static_{motion}", "static", motion)
    out["loop"] = ScenePreset("loop", "static", "loop", n_frames=600)
    out["walking_loop"] = ScenePreset("walking_loop", "walking_one", "loop", n_frames=600)
    return out


#: The presets, mirroring TUM fr3 (walking/sitting x xyz/static/rpy/halfsphere) plus loops.
PRESETS: dict[str, ScenePreset] = _presets()


def get_preset(preset: str | ScenePreset) -> ScenePreset:
    """The preset of that name (or the preset itself); clear error for an unknown name."""
    if isinstance(preset, ScenePreset):
        return preset
    if preset not in PRESETS:
        raise ValueError(f"unknown synthetic preset {preset!r}; choose one of {', '.join(PRESETS)}")
    return PRESETS[preset]


# ---------------------------------------------------------------------------- time
def frame_times(n_frames: int) -> np.ndarray:
    """Times (s from the start) of ``n_frames`` colour frames at 30 Hz on the 100 Hz ground-truth grid.

    Frame ``i`` is taken at ``round(i * 100 / 30) / 100`` s (intervals of 30, 40, 30 ms), so every
    colour frame has an exact ground-truth pose in the 100 Hz ``groundtruth.txt``.
    """
    return np.round(np.arange(n_frames) * 100.0 / 30.0) / 100.0


# -------------------------------------------------------------------- camera paths
def _base_rotation() -> np.ndarray:
    return sc.look_at(sc.VIEW_EYE, sc.VIEW_TARGET)[:3, :3]


def camera_pose(motion: str, t: float, duration: float) -> np.ndarray:
    """Camera pose ``T_w_c (4, 4)`` of a motion preset at time ``t`` (s) of a ``duration`` s sequence.

    * ``static``: the fixed view with a hand-held tremor of ~2 mm and ~0.1 deg;
    * ``xyz``: translations along the camera axes, amplitudes 0.4 / 0.25 / 0.3 m (x / y / z);
    * ``rpy``: rotations about the camera axes: pitch 12 deg, yaw 20 deg, roll 15 deg;
    * ``halfsphere``: on a sphere of radius 0.5 m, azimuth +-60 deg, elevation 0..40 deg, looking at the desk;
    * ``loop``: round a circle of radius 0.85 m in the room centre, looking outwards, once in ``duration``
      with zero speed at both ends: the last pose equals the first.
    """
    w = 2 * np.pi
    R0 = _base_rotation()
    if motion == "static":
        dt = 0.002 * np.array([np.sin(w * 0.7 * t), np.sin(w * 0.45 * t + 1), np.sin(w * 0.3 * t + 2)])
        dr = np.radians(0.1) * np.array([np.sin(w * 0.5 * t + 3), np.sin(w * 0.35 * t), np.sin(w * 0.6 * t + 1)])
        return sc.pose(R0 @ so3_exp(dr), sc.VIEW_EYE + R0 @ dt)
    if motion == "xyz":
        dt = np.array([0.4 * np.sin(w * t / 10.0), 0.25 * np.sin(w * t / 8.0 + 0.5), 0.3 * np.sin(w * t / 12.0 + 1.0)])
        dt -= np.array([0.0, 0.25 * np.sin(0.5), 0.3 * np.sin(1.0)])  # start at the base view
        dr = np.radians(2.0) * np.array([np.sin(w * t / 7.0), np.sin(w * t / 9.0), 0.0])
        return sc.pose(R0 @ so3_exp(dr), sc.VIEW_EYE + R0 @ dt)
    if motion == "rpy":
        ang = np.radians([12.0 * np.sin(w * t / 7.0), 20.0 * np.sin(w * t / 9.0), 15.0 * np.sin(w * t / 11.0)])
        dt = 0.02 * np.array([np.sin(w * t / 5.0), np.sin(w * t / 6.0), np.sin(w * t / 4.0)])
        R = R0 @ sc.rot_x(ang[0]) @ sc.rot_y(ang[1]) @ sc.rot_z(ang[2])
        return sc.pose(R, sc.VIEW_EYE + dt)
    if motion == "halfsphere":
        phi = np.radians(60.0) * np.sin(w * t / 12.0)
        theta = np.radians(20.0) * (1.0 - np.cos(w * t / 9.0))
        fwd = sc.VIEW_TARGET - sc.VIEW_EYE
        fwd[2] = 0.0
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        centre = sc.VIEW_EYE + 0.5 * fwd
        eye = centre + 0.5 * (np.cos(theta) * (np.sin(phi) * right - np.cos(phi) * fwd) + np.sin(theta) * np.array([0, 0, 1.0]))
        return sc.look_at(eye, sc.VIEW_TARGET)
    if motion == "loop":
        tau = np.clip(t / max(duration, 1e-9), 0.0, 1.0)
        alpha = np.pi / 2 + 2 * np.pi * (tau - np.sin(2 * np.pi * tau) / (2 * np.pi))
        centre = np.array([0.0, 0.1, 1.4])
        eye = centre + 0.85 * np.array([np.cos(alpha), np.sin(alpha), 0.0])
        target = eye + np.array([np.cos(alpha), np.sin(alpha), -0.22])
        return sc.look_at(eye, target)
    raise ValueError(f"unknown camera motion {motion!r}")


# ---------------------------------------------------------------------- depth model
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
    cos : ``(H, W)`` ``|cos|`` of the angle between the surface normal and the ray.
    fx : unused by the default model (the disparity uses ``params.ir_focal``); kept so callers can pass the
        colour camera's focal length when ``params.ir_focal`` is 0.
    params : sensor model.
    rng : random generator of this frame.
    dropout : ``(H, W)`` probability of a missing reading per pixel (glossy surfaces), or None.

    Returns
    -------
    ``(H, W)`` float32 measured depth (m), 0 = no reading.
    """
    z = np.where(np.isfinite(z), z, np.float32(0.0)).astype(np.float32)
    has = z > 0
    hole = ~has | (z < params.z_min) | (z > params.z_max)
    if not params.enabled:
        return np.where(hole, np.float32(0.0), z)
    H, W = z.shape
    f32 = np.float32
    # Nguyen 2012 Eq. 3 in float32 (nguyen_sigma is the float64 reference)
    theta = np.arccos(np.clip(cos, f32(np.cos(np.radians(80.0))), f32(1.0)))  # incidence angle, <= 80 deg
    zs = np.maximum(z, f32(1e-3))
    sigma = (f32(params.sigma_0) + f32(params.sigma_2) * (z - f32(params.z_ref)) ** 2
             + f32(params.sigma_angle) / np.sqrt(zs) * theta * theta / (f32(np.pi / 2) - theta) ** 2)
    fb = f32((params.ir_focal or fx) * params.baseline)
    dz = z * z * f32(params.disparity_step) / fb
    sigma_g = np.sqrt(np.maximum(sigma * sigma - dz * dz / f32(12.0), f32(0.0)))
    zn = z + sigma_g * rng.standard_normal((H, W), dtype=np.float32)
    if params.disparity_step > 0:
        with np.errstate(divide="ignore", invalid="ignore"):
            q = f32(params.disparity_step)
            disp = np.round(fb / zn / q) * q
            zq = np.where(disp > 0, fb / disp, f32(0.0))
    else:
        zq = zn
    hole |= cos < params.min_cos
    # depth discontinuities: neighbours whose depth differs by more than edge_jump * z
    zz = np.where(has, z, 1e3)
    jump = np.zeros((H, W), bool)
    dx = np.abs(np.diff(zz, axis=1)) > params.edge_jump * np.minimum(zz[:, 1:], zz[:, :-1])
    dy = np.abs(np.diff(zz, axis=0)) > params.edge_jump * np.minimum(zz[1:], zz[:-1])
    jump[:, 1:] |= dx
    jump[:, :-1] |= dx
    jump[1:] |= dy
    jump[:-1] |= dy
    if params.edge_width > 0:
        k = 2 * params.edge_width + 1
        jump = cv2.dilate(jump.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)
    hole |= jump
    if params.shadow:
        # projector at +baseline along camera x: pixel u is hidden from it when a pixel u' > u
        # projects to a smaller projector column u' - d(u') < u - d(u) (it lies in front, on the projector's ray).
        d = np.where(has, fb / np.maximum(z, f32(1e-3)), f32(0.0))
        q = np.arange(W, dtype=np.float32)[None, :] - d
        suffix = np.minimum.accumulate(q[:, ::-1], axis=1)[:, ::-1]
        later = np.full_like(q, np.inf)
        later[:, :-1] = suffix[:, 1:]
        hole |= later < q - f32(0.05)  # strictly hidden (0.05 px: float round-off)
    seeds = (rng.random((H, W), dtype=np.float32) < params.dropout_rate).astype(np.uint8)
    hole |= cv2.dilate(seeds, np.ones((3, 3), np.uint8)).astype(bool)
    if dropout is not None:
        hole |= rng.random((H, W), dtype=np.float32) < dropout
    out = np.where(hole | (zq < params.z_min) | (zq > params.z_max), 0.0, zq)
    return out.astype(np.float32)


# -------------------------------------------------------------------------- renderer
@dataclass
class RenderedFrame:
    """One rendered frame.

    Attributes
    ----------
    index : frame number; timestamp : colour timestamp (s).
    rgb : ``(H, W, 3)`` uint8 RGB.
    depth : ``(H, W)`` float32 measured depth (m), 0 = no reading.
    depth_true : ``(H, W)`` float32 exact depth (m), 0 where no surface.
    instance_mask : ``(H, W)`` int32 instance ids (0 = room/background).
    T_w_c : ``(4, 4)`` camera pose (camera to world).
    moving : instance ids whose surface moved more than 1 mm since the previous frame.
    normal : ``(H, W, 3)`` float32 camera-frame normals (a view).
    """

    index: int
    timestamp: float
    rgb: np.ndarray
    depth: np.ndarray
    depth_true: np.ndarray
    instance_mask: np.ndarray
    T_w_c: np.ndarray
    moving: set[int]
    normal: np.ndarray


class SyntheticRenderer:
    """Renders the frames of one preset (builds the scene and its texture atlas once).

    Parameters
    ----------
    preset : a preset name or :class:`ScenePreset`.
    seed : seeds the textures and all sensor noise.
    n_frames : sequence length (the loop preset's path depends on it); default the preset's.
    """

    def __init__(self, preset: str | ScenePreset, seed: int = 0, n_frames: int | None = None) -> None:
        self.preset = get_preset(preset)
        self.seed = int(seed)
        self.n_frames = int(n_frames if n_frames is not None else self.preset.n_frames)
        if self.n_frames < 1:
            raise ValueError(f"n_frames must be >= 1, got {self.n_frames}")
        self.camera: PinholeCamera = CAMERA_PRESETS[self.preset.camera]
        self.scene, self.atlas = _build_scene(self.preset.scene, self.seed)
        self.times = frame_times(self.n_frames)
        self.duration = float(self.times[-1])

    @property
    def instances(self) -> dict[int, tuple[str, str]]:
        """Instance id -> ``(COCO class, motion)``."""
        return dict(self.scene.instances)

    def pose(self, t: float) -> np.ndarray:
        """Camera pose ``T_w_c`` at time ``t`` (s)."""
        return camera_pose(self.preset.motion, t, self.duration)

    def moving(self, index: int) -> set[int]:
        """Instances whose surface moved more than 1 mm between frames ``index - 1`` and ``index``."""
        if index <= 0:
            return set()
        disp = self.scene.displacement(self.times[index - 1], self.times[index])
        return {i for i, d in disp.items() if d > MOVING_THRESHOLD}

    def render(self, index: int, noise: bool = True, T_w_c: np.ndarray | None = None, t_scene: float | None = None) -> RenderedFrame:
        """Render frame ``index``.

        ``T_w_c`` overrides the camera pose and ``t_scene`` the time at which the scene is
        posed (both for experiments, e.g. the scene of one frame seen from the next camera);
        ``noise=False`` gives exact depth (range-limited) and a noise-free colour image.
        """
        if not 0 <= index < self.n_frames:
            raise IndexError(f"frame {index} out of range for {self.n_frames} frames")
        t = float(self.times[index])
        T = self.pose(t) if T_w_c is None else np.asarray(T_w_c, float)
        parts = self.scene.parts(t if t_scene is None else t_scene)
        rng = np.random.default_rng([self.seed, index, 17])
        rgb, depth, depth_true, mask, normal = _shade(parts, self.atlas, self.camera, T, self.preset, rng, noise, self.seed)
        return RenderedFrame(index, T0 + t, rgb, depth, depth_true, mask, T, self.moving(index), normal)


_NOISE_PAD = 64


@lru_cache(maxsize=2)
def _noise_bank(shape: tuple[int, ...], seed: int) -> np.ndarray:
    """Unit Gaussian noise of ``shape`` plus ``_NOISE_PAD`` pixels each way (float32), drawn once per seed."""
    rng = np.random.default_rng([seed, 4242])
    return rng.standard_normal((shape[0] + _NOISE_PAD, shape[1] + _NOISE_PAD) + tuple(shape[2:]), dtype=np.float32)


_RAY_LENGTHS: dict = {}


def _ray_lengths(camera: PinholeCamera, rays: np.ndarray) -> np.ndarray:
    key = (camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)
    if key not in _RAY_LENGTHS:
        _RAY_LENGTHS[key] = np.linalg.norm(rays, axis=-1).astype(np.float32)
    return _RAY_LENGTHS[key]


@lru_cache(maxsize=4)
def _build_scene(scene: str, seed: int) -> tuple[sc.OfficeScene, TextureAtlas]:
    rng = np.random.default_rng([seed, 1234])
    office = sc.build_office(scene, rng)
    return office, build_atlas(office.bank.images)


def _shade(parts, atlas: TextureAtlas, camera: PinholeCamera, T_w_c: np.ndarray, preset: ScenePreset,
           rng: np.random.Generator, noise: bool, noise_seed: int | None = None):
    """Ray cast, texture, light and degrade one frame.

    Returns ``rgb (H, W, 3) uint8``, ``depth (H, W) float32`` (m, 0 = hole), ``depth_true`` (m),
    ``mask (H, W) int32`` instance ids and ``normal (H, W, 3)`` (camera frame). ``noise=False``
    skips blur, colour noise and the depth sensor model (range limits only).
    """
    g = sc.raycast(parts, camera, T_w_c)
    hit = g.part >= 0
    pid = np.where(hit, g.part, 0).astype(np.intp)  # intp: numpy gathers with int32 indices are much slower
    face_tex = np.array([s.face_textures() for s, _ in parts], np.int32)
    tint = np.array([s.tint for s, _ in parts], np.float32)
    density = np.array([s.texel_density for s, _ in parts], np.float32)
    inst = np.array([s.instance for s, _ in parts], np.int32)
    drop = np.array([s.dropout for s, _ in parts], np.float32)
    z = np.where(hit, g.depth, np.float32(0.0))
    nx, ny, nz = g.normal_planes
    rx, ry = g.rays[..., 0], g.rays[..., 1]
    ray_len = _ray_lengths(camera, g.rays)
    cos = np.abs(nx * rx + ny * ry + nz) / ray_len  # |cos| of the incidence angle
    # pixel footprint in texels; the sqrt softens the isotropic blur of oblique surfaces (a cheap
    # stand-in for anisotropic filtering)
    footprint = z * (ray_len / np.float32(camera.fx)) / np.sqrt(np.maximum(cos, np.float32(0.1))) * density[pid]
    level = np.log2(np.maximum(footprint, np.float32(1e-6)))
    tex = face_tex.ravel()[pid * 6 + g.face.astype(np.intp)]
    albedo = sample_atlas(atlas, tex, g.s, g.t, level) * tint[pid]
    # Lambertian shading: a lamp (point light, fading with distance) and fill lights fixed in the room
    R_cw = T_w_c[:3, :3].T
    Lc = (R_cw @ (sc.LAMP[0] - T_w_c[:3, 3])).astype(np.float32)
    vx, vy, vz = Lc[0] - rx * z, Lc[1] - ry * z, Lc[2] - z
    d2 = vx * vx + vy * vy + vz * vz
    lam = np.maximum(nx * vx + ny * vy + nz * vz, 0.0) / np.sqrt(d2)
    light = np.float32(sc.AMBIENT) + np.float32(sc.LAMP[1]) * lam / (1.0 + d2 * np.float32(1 / 9.0))
    for direction, power in sc.FILL_LIGHTS:
        lc = (R_cw @ (direction / np.linalg.norm(direction))).astype(np.float32) * np.float32(power)
        light += np.maximum(nx * lc[0] + ny * lc[1] + nz * lc[2], 0.0)
    img = albedo * (light * np.float32(255.0))[..., None]
    if not hit.all():
        img[~hit] = 0.0
    if noise and preset.blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), preset.blur)
    if noise and preset.image_noise > 0:
        # sensor noise: a window at a random place in a noise image drawn once per (seed, size), with
        # random sign, costs far less than fresh Gaussian draws for every pixel of every frame
        bank = _noise_bank(img.shape, int(rng.integers(2**31)) if noise_seed is None else noise_seed)
        oy, ox = (int(v) for v in rng.integers(0, _NOISE_PAD, 2))
        sign = np.float32(1.0 if rng.random() < 0.5 else -1.0)
        img += bank[oy : oy + img.shape[0], ox : ox + img.shape[1]] * (sign * np.float32(preset.image_noise))
    rgb = np.clip(img + 0.5, 0, 255).astype(np.uint8)
    params = preset.depth if noise else replace(preset.depth, enabled=False)
    # chance of no reading: glossy parts, dark (IR-absorbing) albedo, long range
    lum = albedo @ np.array([0.299, 0.587, 0.114], np.float32)
    p_miss = np.maximum(drop[pid], np.float32(params.dark_dropout) * np.clip(1.0 - lum / np.float32(0.12), 0.0, 1.0))
    p_miss += np.float32(params.far_dropout) * np.clip((z - np.float32(4.5)) / np.float32(params.z_max - 4.5), 0.0, 1.0)
    depth = kinect_depth(z, cos, camera.fx, params, rng, dropout=np.where(hit, p_miss, np.float32(1.0)))
    mask = np.where(hit, inst[pid], 0).astype(np.int32)
    return rgb, depth, z, mask, g.normal


def render_frame(
    preset: str | ScenePreset,
    index: int = 0,
    seed: int = 0,
    n_frames: int | None = None,
    noise: bool = True,
) -> RenderedFrame:
    """Render one frame of a preset (for notebooks): rgb, depth, exact depth, instance mask, ``T_w_c``.

    The scene and its textures are built once per ``(scene, seed)`` and cached.
    Example: ``f = render_frame("walking_xyz", 40); plt.imshow(f.rgb)``.
    """
    n = n_frames if n_frames is not None else max(get_preset(preset).n_frames, index + 1)
    return SyntheticRenderer(preset, seed, n).render(index, noise=noise)


# ------------------------------------------------------------------------- writing
def _fmt(ts: float) -> str:
    return f"{ts:.6f}"


def render_sequence(
    preset: str | ScenePreset,
    outdir: str | Path,
    n_frames: int | None = None,
    seed: int = 0,
    progress: bool = True,
) -> Path:
    """Render a sequence into ``outdir`` in the TUM layout (see ``docs/synthetic.md``); returns ``outdir``.

    Writes ``rgb/TS.png``, ``depth/TS.png`` (16-bit, 5000 units/m, 0 = hole), ``masks/TS.png``
    (16-bit instance ids, named like the colour image), ``rgb.txt``, ``depth.txt`` (depth stamps
    2-9 ms off the colour ones), ``groundtruth.txt`` (100 Hz), ``camera.json``,
    ``instances.json``, ``moving.txt`` and ``synthetic.json`` (the preset and seed).
    """
    renderer = SyntheticRenderer(preset, seed, n_frames)
    p = renderer.preset
    out = Path(outdir)
    for sub in ("rgb", "depth", "masks"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    n = renderer.n_frames
    ts_rng = np.random.default_rng([seed, 99])
    offsets = ts_rng.uniform(0.002, 0.009, n) * np.where(ts_rng.random(n) < 0.5, -1.0, 1.0)
    rgb_lines = [f"# color images of synthetic sequence {p.name} (seed {seed})", "# timestamp filename"]
    depth_lines = [f"# depth maps of synthetic sequence {p.name} (seed {seed})", "# timestamp filename"]
    moving_lines = ["# instances whose surface moved more than 1 mm since the previous colour frame", "# timestamp id id ..."]
    frames = range(n)
    if progress:
        from tqdm.auto import tqdm

        frames = tqdm(frames, desc=f"render {p.name}", unit="frame")
    png = [cv2.IMWRITE_PNG_COMPRESSION, 1]

    def write(path: Path, img: np.ndarray) -> None:
        if not cv2.imwrite(str(path), img, png):
            raise OSError(f"{path}: cannot write image")

    # PNG encoding (OpenCV releases the GIL) overlaps with rendering the next frame
    from concurrent.futures import ThreadPoolExecutor

    pending: list = []
    with ThreadPoolExecutor(max_workers=2) as pool:
        for i in frames:
            f = renderer.render(i)
            ts = _fmt(f.timestamp)
            tsd = _fmt(f.timestamp + offsets[i])
            d16 = np.clip(np.round(f.depth * renderer.camera.depth_scale), 0, 65535).astype(np.uint16)
            pending += [
                pool.submit(write, out / "rgb" / f"{ts}.png", cv2.cvtColor(f.rgb, cv2.COLOR_RGB2BGR)),
                pool.submit(write, out / "depth" / f"{tsd}.png", d16),
                pool.submit(write, out / "masks" / f"{ts}.png", f.instance_mask.astype(np.uint16)),
            ]
            while len(pending) > 6:  # bound the images waiting in memory; re-raise write errors
                pending.pop(0).result()
            rgb_lines.append(f"{ts} rgb/{ts}.png")
            depth_lines.append(f"{tsd} depth/{tsd}.png")
            moving_lines.append(" ".join([ts] + [str(k) for k in sorted(f.moving)]))
        for fut in pending:
            fut.result()
    (out / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (out / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    (out / "moving.txt").write_text("\n".join(moving_lines) + "\n")
    # ground truth at 100 Hz, from 0.1 s before the first to 0.1 s after the last colour frame
    ticks = np.arange(-10, int(round(renderer.duration * 100)) + 11)
    gt_t = ticks / 100.0
    poses = np.stack([renderer.pose(t) for t in gt_t])
    rows = pose_to_tum(poses)
    gt_lines = ["# ground truth trajectory of the colour camera (T_w_c), synthetic", "# timestamp tx ty tz qx qy qz qw"]
    gt_lines += [_fmt(T0 + t) + " " + " ".join(f"{v:.6f}" for v in r) for t, r in zip(gt_t, rows)]
    (out / "groundtruth.txt").write_text("\n".join(gt_lines) + "\n")
    save_camera_json(renderer.camera, out / "camera.json")
    inst = {str(i): {"class": c, "motion": m} for i, (c, m) in renderer.instances.items()}
    (out / "instances.json").write_text(json.dumps(inst, indent=1) + "\n")
    meta = {"preset": asdict(p), "seed": seed, "n_frames": n, "render_version": RENDER_VERSION}
    (out / "synthetic.json").write_text(json.dumps(meta, indent=1) + "\n")
    return out


def _cache_root(cache_dir: str | Path | None) -> Path:
    if cache_dir is not None:
        return Path(cache_dir)
    base = os.environ.get("DYNSLAM_CACHE")
    root = Path(base) if base else Path.home() / ".cache" / "dynslam_lab"
    return root / "synthetic"


def cache_key(preset: str | ScenePreset, n_frames: int | None = None, seed: int = 0) -> str:
    """Folder name of a cached sequence: preset, length, seed and a hash of the renderer version and parameters."""
    p = get_preset(preset)
    n = int(n_frames if n_frames is not None else p.n_frames)
    h = hashlib.sha256(f"{RENDER_VERSION}|{p!r}|{CAMERA_PRESETS[p.camera]!r}".encode()).hexdigest()[:10]
    return f"{p.name}_n{n}_s{int(seed)}_{h}"


def synthetic_sequence(
    preset: str | ScenePreset,
    n_frames: int | None = None,
    seed: int = 0,
    cache_dir: str | Path | None = None,
    progress: bool = False,
) -> Path:
    """Path of a rendered sequence, rendering it only when it is not cached yet.

    The cache is ``cache_dir`` or ``$DYNSLAM_CACHE/synthetic/`` (default
    ``~/.cache/dynslam_lab/synthetic/``); the folder name is :func:`cache_key`. A sequence is
    rendered into a temporary folder beside it and renamed when complete, so an interrupted
    render never leaves a half sequence behind.
    """
    root = _cache_root(cache_dir)
    final = root / cache_key(preset, n_frames, seed)
    if (final / "synthetic.json").is_file():
        return final
    root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.", dir=root))
    try:
        render_sequence(preset, tmp, n_frames=n_frames, seed=seed, progress=progress)
        try:
            os.rename(tmp, final)
        except OSError:
            if not (final / "synthetic.json").is_file():  # not a concurrent render that finished first
                raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return final


def read_moving(root: str | Path) -> dict[float, set[int]]:
    """Read ``moving.txt`` of a synthetic sequence: colour timestamp -> ids of moving instances."""
    path = Path(root) / "moving.txt"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: moving.txt not found (only synthetic sequences have one)")
    out: dict[float, set[int]] = {}
    for lineno, line in enumerate(path.read_text().splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.split()
        try:
            out[float(parts[0])] = {int(x) for x in parts[1:]}
        except ValueError:
            raise ValueError(f"{path}:{lineno}: expected 'timestamp id id ...', got {s!r}") from None
    return out
