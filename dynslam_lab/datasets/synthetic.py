"""Synthetic dynamic RGB-D sequences: a textured office with people, rendered like a Kinect.

The renderer ray-casts an analytic office (walls, desk, monitors, chairs, shelves of books,
two people built from capsules and ellipsoids; :mod:`~dynslam_lab.datasets.office`,
:mod:`~dynslam_lab.datasets.people`) through the pinhole camera
(:mod:`~dynslam_lab.datasets.raycaster`), moved along the preset's camera path
(:mod:`~dynslam_lab.datasets.camera_paths`), textures it with mip-mapped procedural textures
(:mod:`~dynslam_lab.datasets.textures`), shades it with Lambertian lights (this module), and
degrades colour and depth the way a Kinect v1 does: 0.5 px optical blur and Gaussian colour
noise here, and in :mod:`~dynslam_lab.datasets.kinect` the axial depth noise of Nguyen, Izadi &
Lovell (3DIMPVT 2012, Eq. 3), the 1/8 px disparity quantisation of Khoshelham & Elberink
(Sensors 2012) and the holes (range limits, grazing angles, depth discontinuities, the projector
shadow, glossy, dark and far surfaces, random dropouts).

Sequences are written in the TUM RGB-D layout (``rgb/``, ``depth/``, ``rgb.txt``,
``depth.txt``, ``groundtruth.txt``) plus ``camera.json``, instance masks ``masks/``,
``instances.json`` and ``moving.txt``, so :class:`~dynslam_lab.datasets.tum.TumSequence`
reads them unchanged, plus ``coverage.csv`` (per frame, the image fraction the movers cover, their
distance and speed). Besides the office presets (:data:`PRESETS`) the renderer draws the stress
scenes of :mod:`~dynslam_lab.datasets.stress` (other rooms, non-COCO movers; a
:class:`~dynslam_lab.datasets.stress.StressPreset` goes wherever a preset goes). See ``docs/synthetic.md``.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
from tqdm.auto import tqdm

from ..camera import CAMERA_PRESETS, PinholeCamera, save_camera_json
from ..geometry.se3 import pose_to_tum
from . import scene as sc
from . import stress
from .camera_paths import OFFICE_RIG, camera_pose, frame_times
from .kinect import DepthNoise, disparity_step, kinect_depth, nguyen_sigma
from .office import OFFICE_LIGHTING, Lighting
from .raycaster import ray_grid
from .shapes import shape_corners
from .stress import StressPreset, random_scene_preset
from .textures import TextureAtlas, build_atlas, sample_atlas
from .tum import TumSequence

__all__ = [
    "DepthNoise",
    "ScenePreset",
    "StressPreset",
    "random_scene_preset",
    "PRESETS",
    "preset_names",
    "preset_from_meta",
    "read_coverage",
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
    "moving_instances",
    "truth_views",
    "cache_key",
]

#: Bump when the output of the renderer changes: part of the cache key.
RENDER_VERSION = "13"
#: Colour timestamps start here (s), like the UNIX times of TUM sequences.
T0 = 1_600_000_000.0
#: An instance is "moving" in a frame when some point of its surface moved more than this (m).
MOVING_THRESHOLD = 0.001


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


def get_preset(preset: str | ScenePreset | StressPreset) -> ScenePreset | StressPreset:
    """The preset of that name (or the preset itself); clear error for an unknown name.

    Names are the office presets (:data:`PRESETS`), the named stress scenes
    (:data:`~dynslam_lab.datasets.stress.STRESS_PRESETS`) and those with ``_nomovers`` appended (the
    same stress scene without its movers).
    """
    if isinstance(preset, (ScenePreset, StressPreset)):
        return preset
    if preset in PRESETS:
        return PRESETS[preset]
    named = stress.STRESS_PRESETS
    if preset in named:
        return named[preset]
    base = str(preset).removesuffix("_nomovers")
    if base != preset and base in named:
        return named[base].without_movers()
    raise ValueError(f"unknown synthetic preset {preset!r}; choose one of {', '.join(preset_names())}")


def preset_names() -> list[str]:
    """Every preset name :func:`get_preset` knows (office, then stress scenes; each of the latter also with ``_nomovers``)."""
    return list(PRESETS) + list(stress.STRESS_PRESETS)


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
    preset : a preset name, a :class:`ScenePreset` or a :class:`~dynslam_lab.datasets.stress.StressPreset`.
    seed : seeds all sensor noise, and the office's textures (a stress scene's textures come from
        its preset's own ``seed``).
    n_frames : sequence length (the loop's path depends on it); default the preset's.
    """

    def __init__(self, preset: str | ScenePreset | StressPreset, seed: int = 0, n_frames: int | None = None) -> None:
        self.preset = get_preset(preset)
        self.seed = int(seed)
        self.n_frames = int(n_frames if n_frames is not None else self.preset.n_frames)
        if self.n_frames < 1:
            raise ValueError(f"n_frames must be >= 1, got {self.n_frames}")
        self.camera: PinholeCamera = CAMERA_PRESETS[self.preset.camera]
        if isinstance(self.preset, StressPreset):
            self.scene, self.atlas = _build_stress(self.preset)
            self.rig = self.preset.rig
        else:
            self.scene, self.atlas = _build_scene(self.preset.scene, self.seed)
            self.rig = OFFICE_RIG
        _keep_frame_buffers_mapped()
        self.times = frame_times(self.n_frames)
        self.duration = float(self.times[-1])

    @property
    def instances(self) -> dict[int, tuple[str, str]]:
        """Instance id -> ``(class, motion)`` (COCO classes, and non-COCO ones for stress movers)."""
        return dict(self.scene.instances)

    def pose(self, t: float) -> np.ndarray:
        """Camera pose ``T_w_c`` at time ``t`` (s)."""
        return camera_pose(self.preset.motion, t, self.duration, self.rig)

    def mover_positions(self, t: float) -> dict[int, np.ndarray]:
        """World position ``(3,)`` (m) of a reference point of each mover at time ``t`` (s): its body origin
        (a door: its free edge; an office mover: the centre of its bounding box). Its speed is the mover's speed."""
        out = {}
        for m in self.scene.movers:
            if hasattr(m, "reference"):
                out[m.instance] = np.asarray(m.reference(t), float)
            else:
                C = np.concatenate([shape_corners(s) @ T[:3, :3].T + T[:3, 3] for s, T in m.parts(t)])
                out[m.instance] = 0.5 * (C.min(axis=0) + C.max(axis=0))
        return out

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
        rgb, depth, depth_true, mask, normal = _shade(parts, self.atlas, self.camera, T, self.preset, rng, noise, self.seed,
                                                      self.scene.lighting)
        return RenderedFrame(index, T0 + t, rgb, depth, depth_true, mask, T, self.moving(index), normal)


_NOISE_PAD = 64
_HEAP_PRIMED = False


def _keep_frame_buffers_mapped() -> None:
    """Let the C allocator recycle the frame-sized temporaries of rendering instead of unmapping them.

    A frame allocates and frees some hundred arrays of 1-4 MB. glibc's malloc gives such blocks back
    to the kernel (``munmap``, or trimming the top of the heap) as soon as they are freed, while
    its thresholds are low, and the next frame page-faults them in again: 3000-7000 faults per
    frame, 5-12 ms of a 35 ms frame on the development VM, and erratic from run to run. glibc
    raises its mmap threshold to the size of any mmapped block that is freed (and its trim
    threshold to twice that; ``mallopt(3)``, "dynamic mmap threshold"), so one 30 MB block
    allocated and freed here, once per process, makes every later frame reuse heap memory.
    Elsewhere this is just a short-lived allocation.
    """
    global _HEAP_PRIMED
    if not _HEAP_PRIMED:
        np.ones(30 << 20, np.uint8)  # touched (so really mapped), then freed at once
        _HEAP_PRIMED = True


@lru_cache(maxsize=2)
def _noise_bank(shape: tuple[int, ...], seed: int) -> np.ndarray:
    """Unit Gaussian noise of ``shape`` plus ``_NOISE_PAD`` pixels each way (float32), drawn once per seed."""
    rng = np.random.default_rng([seed, 4242])
    return rng.standard_normal((shape[0] + _NOISE_PAD, shape[1] + _NOISE_PAD) + tuple(shape[2:]), dtype=np.float32)


@lru_cache(maxsize=4)
def _scaled_noise_bank(shape: tuple[int, ...], seed: int, scale: np.float32) -> np.ndarray:
    """``_noise_bank(shape, seed) * scale`` (float32), kept for the two signs of a sequence's noise."""
    return _noise_bank(shape, seed) * scale


@lru_cache(maxsize=4)
def _build_scene(scene: str, seed: int) -> tuple[sc.OfficeScene, TextureAtlas]:
    rng = np.random.default_rng([seed, 1234])
    office = sc.build_office(scene, rng)
    return office, build_atlas(office.bank.images)


@lru_cache(maxsize=4)
def _build_stress_full(preset: StressPreset) -> tuple[sc.OfficeScene, TextureAtlas]:
    scene = stress.build_stress_scene(preset)
    return scene, build_atlas(scene.bank.images)


def _build_stress(preset: StressPreset) -> tuple[sc.OfficeScene, TextureAtlas]:
    """A stress scene and its atlas; without movers, the same scene (and atlas) with the movers dropped,
    so that both versions share every texel."""
    # the scene does not depend on these (nor on the camera motion, but for a loop's keep-out)
    full = replace(preset, name="", with_movers=True, n_frames=1, motion="loop" if preset.motion == "loop" else "static")
    scene, atlas = _build_stress_full(full)
    if preset.with_movers:
        return scene, atlas
    return replace(scene, movers=[], instances={}), atlas


_PART_ROWS: dict = {}


def _part_tables(parts) -> tuple[np.ndarray, ...]:
    """Per-part tables: texture of each face ``(P * 6,)``, tint ``(P, 3)`` (column-major: one contiguous
    column per channel) and whether each part is tinted, texel density, instance id and depth dropout ``(P,)`` (rows cached per shape: people are re-posed every frame,
    their shapes stay the same)."""
    rows = []
    for shape, _ in parts:
        row = _PART_ROWS.get(shape)
        if row is None:
            if len(_PART_ROWS) >= 20000:  # many scenes passed through: start afresh
                _PART_ROWS.clear()
            row = _PART_ROWS[shape] = (shape.face_textures(), shape.tint, shape.texel_density, shape.instance, shape.dropout)
        rows.append(row)
    face_tex, tint, density, inst, drop = zip(*rows)
    tint = np.array(tint, np.float32)
    return (np.array(face_tex, np.intp).ravel(), np.asfortranarray(tint), (tint != 1.0).any(axis=1),
            np.array(density, np.float32), np.array(inst, np.int32), np.array(drop, np.float32))


def _shade(parts, atlas: TextureAtlas, camera: PinholeCamera, T_w_c: np.ndarray, preset: ScenePreset | StressPreset,
           rng: np.random.Generator, noise: bool, noise_seed: int | None = None, lighting: Lighting = OFFICE_LIGHTING):
    """Ray cast, texture, light and degrade one frame.

    Returns ``rgb (H, W, 3) uint8``, ``depth (H, W) float32`` (m, 0 = hole), ``depth_true`` (m),
    ``mask (H, W) int32`` instance ids and ``normal (H, W, 3)`` (camera frame). ``noise=False``
    skips blur, colour noise and the depth sensor model (range limits only).

    Every per-pixel step is float32 in a fixed order (per-part values are gathered with
    ``np.take``; temporaries are reused with ``out=``), so a frame has the same bits every time.
    """
    g = sc.raycast(parts, camera, T_w_c)
    grid = ray_grid(camera)
    f32 = np.float32
    hit = g.part >= 0
    all_hit = bool(hit.all())  # the room encloses the camera: normally every ray hits
    # intp: numpy gathers with int32 indices are much slower
    pid = g.part.astype(np.intp) if all_hit else np.where(hit, g.part, 0).astype(np.intp)
    face_tex, tint, tint_any, density, inst, drop = _part_tables(parts)
    z = g.depth if all_hit else np.where(hit, g.depth, f32(0.0))
    nx, ny, nz = g.normal_planes
    rx, ry = grid.x, grid.y
    # |cos| of the incidence angle
    cos = nx * rx
    cos += ny * ry
    cos += nz
    np.abs(cos, out=cos)
    cos /= grid.length
    # pixel footprint in texels; the sqrt softens the isotropic blur of oblique surfaces (a cheap
    # stand-in for anisotropic filtering)
    tmp = np.maximum(cos, f32(0.1))
    np.sqrt(tmp, out=tmp)
    footprint = z * grid.length_per_fx
    footprint /= tmp
    footprint *= np.take(density, pid)
    level = np.maximum(footprint, f32(1e-6), out=footprint)
    np.log2(level, out=level)
    idx = pid * 6
    idx += g.face
    tex = np.take(face_tex, idx)
    albedo = sample_atlas(atlas, tex, g.s, g.t, level)
    if tint_any.any():  # tints (books, chairs...)
        cv2.multiply(albedo, cv2.merge([np.take(tint[:, c], pid) for c in range(3)]), dst=albedo)
    # Lambertian shading: a lamp (point light, fading with distance) and fill lights fixed in the room
    R_cw = T_w_c[:3, :3].T
    Lc = (R_cw @ (np.asarray(lighting.lamp, float) - T_w_c[:3, 3])).astype(np.float32)
    vx = rx * z
    np.subtract(Lc[0], vx, out=vx)
    vy = ry * z
    np.subtract(Lc[1], vy, out=vy)
    vz = np.subtract(Lc[2], z)
    d2 = vx * vx
    d2 += np.multiply(vy, vy, out=tmp)
    d2 += np.multiply(vz, vz, out=tmp)
    lam = nx * vx
    lam += np.multiply(ny, vy, out=tmp)
    lam += np.multiply(nz, vz, out=tmp)
    np.maximum(lam, 0.0, out=lam)
    lam /= np.sqrt(d2, out=tmp)
    lam *= f32(lighting.lamp_power)
    d2 *= f32(1 / 9.0)
    d2 += 1.0
    light = np.divide(lam, d2, out=lam)
    light += f32(lighting.ambient)  # a + b and b + a are the same in floating point
    for direction, power in lighting.fills:
        direction = np.asarray(direction, float)
        lc = (R_cw @ (direction / np.linalg.norm(direction))).astype(np.float32) * np.float32(power)
        fill = np.multiply(nx, lc[0], out=vx)
        fill += np.multiply(ny, lc[1], out=vy)
        fill += np.multiply(nz, lc[2], out=vz)
        light += np.maximum(fill, 0.0, out=fill)
    light *= f32(255.0)
    img = cv2.multiply(albedo, cv2.merge([light, light, light]))  # albedo * light per channel, as numpy would
    if not all_hit:
        img[~hit] = 0.0
    if noise and preset.blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), preset.blur)
    if noise and preset.image_noise > 0:
        # sensor noise: a window at a random place in a noise image drawn once per (seed, size), with
        # random sign, costs far less than fresh Gaussian draws for every pixel of every frame
        bank_seed = int(rng.integers(2**31)) if noise_seed is None else noise_seed
        oy, ox = (int(v) for v in rng.integers(0, _NOISE_PAD, 2))
        sign = np.float32(1.0 if rng.random() < 0.5 else -1.0)
        bank = _scaled_noise_bank(img.shape, bank_seed, sign * np.float32(preset.image_noise))
        img += bank[oy : oy + img.shape[0], ox : ox + img.shape[1]]
    img += f32(0.5)
    np.clip(img, 0, 255, out=img)
    rgb = img.astype(np.uint8)
    params = preset.depth if noise else replace(preset.depth, enabled=False)
    # chance of no reading: glossy parts, dark (IR-absorbing) albedo, long range
    lum = albedo @ np.array([0.299, 0.587, 0.114], np.float32)
    lum /= f32(0.12)
    np.subtract(1.0, lum, out=lum)
    np.clip(lum, 0.0, 1.0, out=lum)
    lum *= f32(params.dark_dropout)
    p_miss = np.maximum(np.take(drop, pid), lum, out=lum)
    far = np.subtract(z, f32(4.5), out=tmp)
    far /= f32(params.z_max - 4.5)
    np.clip(far, 0.0, 1.0, out=far)
    far *= f32(params.far_dropout)
    p_miss += far
    if not all_hit:
        p_miss[~hit] = 1.0
    depth = kinect_depth(z, cos, camera.fx, params, rng, dropout=p_miss)
    mask = np.take(inst, pid)
    if not all_hit:
        mask[~hit] = 0
    return rgb, depth, z, mask, g.normal


def render_frame(
    preset: str | ScenePreset | StressPreset,
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
    preset: str | ScenePreset | StressPreset,
    outdir: str | Path,
    n_frames: int | None = None,
    seed: int = 0,
    progress: bool = True,
) -> Path:
    """Render a sequence into ``outdir`` in the TUM layout (see ``docs/synthetic.md``); returns ``outdir``.

    Writes ``rgb/TS.png``, ``depth/TS.png`` (16-bit, 5000 units/m, 0 = hole), ``masks/TS.png``
    (16-bit instance ids, named like the colour image), ``rgb.txt``, ``depth.txt`` (depth stamps
    2-9 ms off the colour ones), ``groundtruth.txt`` (100 Hz), ``camera.json``,
    ``instances.json``, ``moving.txt``, ``coverage.csv`` (per frame: the image fraction covered by
    the instances moving in it and by all movers; per mover its fraction, mean true depth and
    speed) and ``synthetic.json`` (the preset, seed and the coverage, distance and speed statistics).
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
    mover_ids = [i for i, (_, m) in renderer.instances.items() if m != "static"]
    coverage = _CoverageLog(mover_ids, renderer)
    frames = range(n)
    if progress:
        frames = tqdm(frames, desc=f"render {p.name}", unit="frame")
    png = [cv2.IMWRITE_PNG_COMPRESSION, 1]

    def write(path: Path, img: np.ndarray) -> None:
        if not cv2.imwrite(str(path), img, png):
            raise OSError(f"{path}: cannot write image")

    # PNG encoding (OpenCV releases the GIL) overlaps with rendering the next frame
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
            coverage.add(ts, f)
        for fut in pending:
            fut.result()
    (out / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (out / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    (out / "moving.txt").write_text("\n".join(moving_lines) + "\n")
    (out / "coverage.csv").write_text(coverage.csv())
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
    meta = {"kind": "stress" if isinstance(p, StressPreset) else "office", "preset": asdict(p), "seed": seed, "n_frames": n,
            "render_version": RENDER_VERSION, "stats": coverage.stats()}
    (out / "synthetic.json").write_text(json.dumps(meta, indent=1) + "\n")
    return out


class _CoverageLog:
    """Per-frame truth of the movers for ``coverage.csv`` and the statistics in ``synthetic.json``."""

    #: an instance counts as seen in a frame when it covers at least this fraction of the image
    SEEN = 0.002

    def __init__(self, mover_ids: list[int], renderer: "SyntheticRenderer") -> None:
        self.ids = sorted(mover_ids)
        self.renderer = renderer
        self.rows: list[list[float]] = []
        self.stamps: list[str] = []
        self._last: tuple[float, dict] | None = None

    def add(self, ts: str, f: RenderedFrame) -> None:
        m = f.instance_mask.ravel()
        n_px = m.size
        top = max(self.ids + [int(m.max()), 0]) + 1
        count = np.bincount(m, minlength=top).astype(np.float64)
        zsum = np.bincount(m, weights=f.depth_true.ravel().astype(np.float64), minlength=top)
        moving = [i for i in f.moving if i < top]
        t = float(self.renderer.times[f.index])
        pos = self.renderer.mover_positions(t)
        row = [count[moving].sum() / n_px, count[self.ids].sum() / n_px]
        for i in self.ids:
            speed = 0.0
            if self._last is not None and t > self._last[0]:
                speed = float(np.linalg.norm(pos[i] - self._last[1][i]) / (t - self._last[0]))
            row += [count[i] / n_px, zsum[i] / count[i] if count[i] > 0 else float("nan"), speed]
        self._last = (t, pos)
        self.stamps.append(ts)
        self.rows.append(row)

    def csv(self) -> str:
        head = ["timestamp", "moving", "movers"] + [f"{k}_{i}" for i in self.ids for k in ("cover", "depth", "speed")]
        lines = [",".join(head)]
        for ts, row in zip(self.stamps, self.rows):
            vals = [f"{row[0]:.6f}", f"{row[1]:.6f}"]
            for k in range(len(self.ids)):
                c, z, v = row[2 + 3 * k : 5 + 3 * k]
                vals += [f"{c:.6f}", "nan" if np.isnan(z) else f"{z:.4f}", f"{v:.4f}"]
            lines.append(",".join([ts] + vals))
        return "\n".join(lines) + "\n"

    def stats(self) -> dict:
        """Max and mean coverage; per mover: class, motion, max coverage, frames seen, distance (min /
        median / max of its mean true depth over the frames it is seen in) and top speed."""
        if not self.rows:
            return {}
        R = np.array(self.rows, np.float64)
        out = {"moving_cover_max": round(float(R[:, 0].max()), 4), "moving_cover_mean": round(float(R[:, 0].mean()), 4),
               "movers_cover_max": round(float(R[:, 1].max()), 4), "movers_cover_mean": round(float(R[:, 1].mean()), 4),
               "instances": {}}
        classes = self.renderer.instances
        for k, i in enumerate(self.ids):
            c, z, v = R[:, 2 + 3 * k], R[:, 3 + 3 * k], R[:, 4 + 3 * k]
            seen = c >= self.SEEN
            zs = z[seen]
            out["instances"][str(i)] = {
                "class": classes[i][0], "motion": classes[i][1], "cover_max": round(float(c.max()), 4), "frames_seen": int(seen.sum()),
                "depth_min": round(float(zs.min()), 3) if len(zs) else None,
                "depth_median": round(float(np.median(zs)), 3) if len(zs) else None,
                "depth_max": round(float(zs.max()), 3) if len(zs) else None,
                "speed_max": round(float(v.max()), 3),
            }
        return out


def read_coverage(root: str | Path) -> dict[str, np.ndarray]:
    """``coverage.csv`` of a rendered sequence as columns: ``timestamp``, ``moving`` and ``movers`` (image
    fractions), and per mover instance ``ID`` ``cover_ID``, ``depth_ID`` (m, NaN when unseen) and ``speed_ID`` (m/s)."""
    path = Path(root) / "coverage.csv"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: coverage.csv not found (synthetic sequences rendered since renderer version 13 have one)")
    lines = path.read_text().splitlines()
    head = lines[0].split(",")
    try:
        data = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:] if ln.strip()], np.float64).reshape(-1, len(head))
    except ValueError as e:
        raise ValueError(f"{path}: malformed row ({e})") from None
    return {h: data[:, k] for k, h in enumerate(head)}


def preset_from_meta(meta: dict) -> ScenePreset | StressPreset:
    """The preset stored in a sequence's ``synthetic.json`` (as a dict), rebuilt."""
    d = meta["preset"]
    if meta.get("kind") == "stress":
        return StressPreset.from_dict(d)
    return ScenePreset(**{**d, "depth": DepthNoise(**d["depth"])})


def moving_instances(root: str | Path) -> list[int]:
    """Ids of the instances of a rendered sequence that move at some time (``instances.json``)."""
    path = Path(root) / "instances.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: instances.json not found (only synthetic sequences have one)")
    return sorted(int(k) for k, v in json.loads(path.read_text()).items() if v["motion"] != "static")


def truth_views(root: str | Path, frames) -> list[tuple]:
    """Truth views of frames of a rendered sequence, what :func:`dynslam_lab.mapping.dense.map_quality` scores a map with.

    The renderer is rebuilt from the sequence's ``synthetic.json``; for each frame index: the frame
    as stored with its depth replaced by the renderer's exact (noise-free) depth, the true
    ``T_w_c``, and the mask of the moving instances at that moment.
    """

    root = Path(root)
    meta_path = root / "synthetic.json"
    if not meta_path.is_file():
        raise FileNotFoundError(f"{meta_path}: synthetic.json not found (only synthetic sequences have one)")
    meta = json.loads(meta_path.read_text())
    preset = preset_from_meta(meta)
    renderer = SyntheticRenderer(preset, meta["seed"], meta["n_frames"])
    movers = moving_instances(root)
    seq = TumSequence(root)
    views = []
    for i in frames:
        rf = renderer.render(int(i), noise=False)
        f = seq[int(i)]
        f.depth = rf.depth_true
        views.append((f, rf.T_w_c, np.isin(rf.instance_mask, movers)))
    return views


def _cache_root(cache_dir: str | Path | None) -> Path:
    if cache_dir is not None:
        return Path(cache_dir)
    base = os.environ.get("DYNSLAM_CACHE")
    root = Path(base) if base else Path.home() / ".cache" / "dynslam_lab"
    return root / "synthetic"


def cache_key(preset: str | ScenePreset | StressPreset, n_frames: int | None = None, seed: int = 0) -> str:
    """Folder name of a cached sequence: preset, length, seed and a hash of the renderer version and parameters."""
    p = get_preset(preset)
    n = int(n_frames if n_frames is not None else p.n_frames)
    h = hashlib.sha256(f"{RENDER_VERSION}|{p!r}|{CAMERA_PRESETS[p.camera]!r}".encode()).hexdigest()[:10]
    return f"{p.name}_n{n}_s{int(seed)}_{h}"


def synthetic_sequence(
    preset: str | ScenePreset | StressPreset,
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
