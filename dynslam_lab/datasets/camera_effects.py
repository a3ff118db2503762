"""Camera effects on a recorded RGB-D sequence: what another camera, or another renderer, does differently.

The synthetic renderer (:mod:`~dynslam_lab.datasets.synthetic`) draws every frame with one exposure, a sharp
0.5 px lens and 30 frames a second. Real cameras and other renderers do not: TUM RGB-D's Kinect recorded with
auto-exposure on (the whole image brightens or darkens as a person in dark clothes walks by), a shaken hand-held
camera blurs, cheap lenses darken the corners, and sequences come at other frame rates. Methods tuned on one
renderer's images can fail on another's (docs/robustness.md, "Camera effects"). :func:`apply_camera_effects`
writes a copy of a sequence in the TUM layout with any of these effects, deterministically from ``seed``, so
that a run on the copy can be compared with a run on the original (``benchmarks/camera_effects.py``):

* **exposure**: the colour image times a gain that drifts from frame to frame (``log g`` a random walk with steps
  of ``exposure`` and, with probability ``exposure_jump_rate``, a jump of ``exposure_jump``), held to
  ``exposure_range``;
* **motion blur**: a straight blur of ``motion_blur_px`` px at most (a length drawn from half that to all of it,
  a direction drifting from frame to frame);
* **vignetting and response**: ``255 (I / 255)^gamma`` times ``1 - vignette r^2`` (``r`` = 1 at the corners);
* **noise**: extra Gaussian colour noise of ``noise`` grey levels;
* **resolution**: every image resized by ``scale`` (0.5: 640x480 -> 320x240, a smaller sensor or a renderer set
  to it; 1.5: 960x720) after the effects above, the colour image with area averaging (down) or bilinear
  interpolation (up), depth and instance masks with the nearest pixel (a depth never averaged across an edge), and
  ``camera.json`` written with the intrinsics scaled to match (:meth:`~dynslam_lab.camera.PinholeCamera.scaled`;
  a sequence without one gets the camera its folder name selects, scaled; distortion coefficients act on
  normalised coordinates and stay);
* **depth**: extra axial noise of ``depth_noise z^2`` m (Gaussian; 0.005: 2 cm at 2 m, a stereo camera's depth next to
  the Kinect's ~0.5 cm there) and a depth image ``depth_shift_px`` px off the colour image to the right (a registration
  error: depth edges beside colour edges); pixels without a reading keep none;
* **frame rate**: only every ``every``-th colour frame (``rgb.txt`` thinned, ``depth.txt`` to the depth frames
  nearest the kept colour frames, ``associations.txt`` to their rows; ``moving.txt``, when there is one, then lists
  for each kept frame the instances that moved since the last kept frame).

Depth, ground truth, masks and every other file are carried over unchanged (hard links where the file system
allows), except depth (under the depth effects and ``scale``), masks and ``camera.json`` (under ``scale``). The gain and blur of each frame go to
``camera_effects.csv``, the effects to ``camera_effects.json``.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from ..camera import camera_for_sequence, save_camera_json
from .tum import DatasetError, read_file_list, read_moving

__all__ = ["CameraEffects", "apply_camera_effects", "effects_record", "EFFECT_PRESETS"]


@dataclass(frozen=True)
class CameraEffects:
    """The effects :func:`apply_camera_effects` applies (the defaults change nothing)."""

    exposure: float = 0.0  # std of the per-frame step of the log gain (0.03: ~3 % a frame)
    exposure_jump: float = 0.15  # std of a sudden change of the log gain
    exposure_jump_rate: float = 0.0  # chance per frame of such a jump
    exposure_range: tuple[float, float] = (0.7, 1.3)  # the gain is held inside
    motion_blur_px: float = 0.0  # longest straight blur, px
    vignette: float = 0.0  # darkening at the image corners (0.35: 35 %)
    gamma: float = 1.0  # camera response 255 (I / 255)^gamma
    noise: float = 0.0  # extra Gaussian colour noise, grey levels
    every: int = 1  # keep every n-th frame
    scale: float = 1.0  # image size factor (0.5: half the width and height), intrinsics to match
    depth_noise: float = 0.0  # extra depth noise std per squared metre of depth (m / m^2)
    depth_shift_px: float = 0.0  # the depth image this many px right of the colour image (registration error)
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("exposure", "exposure_jump", "motion_blur_px", "noise"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"CameraEffects.{name} must be >= 0, got {getattr(self, name)}")
        if not 0 <= self.exposure_jump_rate <= 1:
            raise ValueError(f"CameraEffects.exposure_jump_rate must be in [0, 1], got {self.exposure_jump_rate}")
        lo, hi = self.exposure_range
        if not 0 < lo <= 1 <= hi:
            raise ValueError(f"CameraEffects.exposure_range must hold 1 with a positive low end, got {self.exposure_range}")
        if not 0 <= self.vignette < 1:
            raise ValueError(f"CameraEffects.vignette must be in [0, 1), got {self.vignette}")
        if not self.gamma > 0:
            raise ValueError(f"CameraEffects.gamma must be > 0, got {self.gamma}")
        if not 0.1 <= self.scale <= 4.0:
            raise ValueError(f"CameraEffects.scale must be in [0.1, 4], got {self.scale}")
        if not self.depth_noise >= 0 or not math.isfinite(self.depth_shift_px):
            raise ValueError(f"CameraEffects: depth_noise must be >= 0 (m/m^2) and depth_shift_px finite (px), got "
                             f"{self.depth_noise}, {self.depth_shift_px}")
        if int(self.every) != self.every or self.every < 1:
            raise ValueError(f"CameraEffects.every must be an integer >= 1, got {self.every}")

    @property
    def changes_depth(self) -> bool:
        return bool(self.depth_noise or self.depth_shift_px or self.scale != 1.0)

    @property
    def changes_colour(self) -> bool:
        return bool(self.exposure or (self.exposure_jump and self.exposure_jump_rate) or self.motion_blur_px
                    or self.vignette or self.gamma != 1.0 or self.noise)


#: Named effects for ``benchmarks/camera_effects.py`` (each one alone, at a strength a real camera shows).
EFFECT_PRESETS: dict[str, CameraEffects] = {
    "exposure": CameraEffects(exposure=0.03, exposure_jump_rate=0.03),
    "blur": CameraEffects(motion_blur_px=7.0),
    "vignette": CameraEffects(vignette=0.35, gamma=0.6),
    "noise": CameraEffects(noise=6.0),
    "rate15": CameraEffects(every=2),
    "rate10": CameraEffects(every=3),
    "half": CameraEffects(scale=0.5),
    "large": CameraEffects(scale=1.5),
    "depth_noisy": CameraEffects(depth_noise=0.005),
    "depth_shift": CameraEffects(depth_shift_px=2.0),
}


def _blur_kernel(length: float, angle: float) -> np.ndarray:
    """A straight blur of ``length`` px at ``angle`` (radians): the segment drawn with sub-pixel samples into an
    odd square kernel, normalised to sum 1."""
    half = int(math.ceil(length / 2)) + 1
    k = np.zeros((2 * half + 1, 2 * half + 1), np.float32)
    for s in np.linspace(-length / 2, length / 2, max(2, int(4 * length) + 1)):
        k[int(round(half + s * math.sin(angle))), int(round(half + s * math.cos(angle)))] += 1.0
    return k / k.sum()


def _resized(img: np.ndarray, size: tuple[int, int], nearest: bool) -> np.ndarray:
    """``img`` at ``size`` (width, height): the nearest pixel (depth, labels), else area averaging down and
    bilinear interpolation up."""
    if (img.shape[1], img.shape[0]) == size:
        return img
    down = size[0] < img.shape[1]
    interp = cv2.INTER_NEAREST if nearest else (cv2.INTER_AREA if down else cv2.INTER_LINEAR)
    return cv2.resize(img, size, interpolation=interp)


def _rewrite_images(src: Path, dst: Path, rels, what: str, change) -> None:
    """Each image ``rels`` (relative paths) of ``src`` written to ``dst`` as ``change(image)`` gives it."""
    for rel in rels:
        img = cv2.imread(str(src / rel), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise DatasetError(f"{src / rel}: cannot read the {what} image (missing or corrupt)")
        out = dst / rel
        out.parent.mkdir(parents=True, exist_ok=True)
        out.unlink(missing_ok=True)  # a link to the source's file is replaced, never written through
        if not cv2.imwrite(str(out), change(img)):
            raise OSError(f"{out}: cannot write the {what} image")


def _depth_changer(effects: CameraEffects, size: tuple[int, int] | None, depth_scale: float):
    """``change(raw)`` for :func:`_rewrite_images`: a 16-bit depth image resized (nearest pixel), shifted by
    ``depth_shift_px`` (nearest pixel; no reading where it uncovers the image) and given ``depth_noise``; zero
    (no reading) stays zero. The noise is drawn from ``seed`` in the order of the depth list."""
    rs = np.random.default_rng([effects.seed, 1])  # a stream of its own: the colour effects draw the same as without

    def change(raw: np.ndarray) -> np.ndarray:
        d = _resized(raw, size, nearest=True) if size is not None else raw
        if effects.depth_shift_px:
            h, w = d.shape[:2]
            M = np.float32([[1, 0, effects.depth_shift_px], [0, 1, 0]])
            d = cv2.warpAffine(d, M, (w, h), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        if effects.depth_noise:
            z = d.astype(np.float64) / depth_scale
            noisy = z + rs.standard_normal(z.shape) * effects.depth_noise * z * z
            out = np.clip(np.rint(noisy * depth_scale), 1, np.iinfo(d.dtype).max)
            d = np.where(d > 0, out, 0).astype(d.dtype)
        return d

    return change


def _colour_changer(effects: CameraEffects, size: tuple[int, int] | None, applied: list[tuple[float, float]]):
    """``change(img)`` for :func:`_rewrite_images`: a colour image with the exposure gain, response, vignetting,
    motion blur and noise of ``effects``, then resized to ``size``. Called on every frame in the order of the colour
    list (the gain and the blur direction drift from frame to frame, from ``seed``); appends each frame's ``(gain,
    blur length px)`` to ``applied``."""
    rs = np.random.default_rng(effects.seed)
    log_gain, angle = 0.0, float(rs.uniform(0, math.pi))
    lo, hi = (math.log(v) for v in effects.exposure_range)
    shade = None

    def change(img: np.ndarray) -> np.ndarray:
        nonlocal log_gain, angle, shade
        im = img.astype(np.float32)
        log_gain += rs.normal(0.0, effects.exposure) if effects.exposure else 0.0
        if effects.exposure_jump_rate and rs.random() < effects.exposure_jump_rate:
            log_gain += rs.normal(0.0, effects.exposure_jump)
        log_gain = min(max(log_gain, lo), hi)
        length = float(rs.uniform(0.5, 1.0) * effects.motion_blur_px) if effects.motion_blur_px else 0.0
        angle += float(rs.normal(0.0, 0.3))
        if effects.gamma != 1.0:
            im = np.float32(255.0) * (im / np.float32(255.0)) ** np.float32(effects.gamma)
        if effects.vignette:
            if shade is None:
                h, w = im.shape[:2]
                yy, xx = np.mgrid[:h, :w].astype(np.float32)
                r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
                shade = 1.0 - np.float32(effects.vignette) * r2
                shade = shade[..., None] if im.ndim == 3 else shade
            im *= shade
        im *= np.float32(math.exp(log_gain))
        if length >= 1.0:
            im = cv2.filter2D(im, -1, _blur_kernel(length, angle), borderType=cv2.BORDER_REFLECT)
        if effects.noise:
            im += rs.normal(0.0, effects.noise, im.shape).astype(np.float32)
        if size is not None:
            im = _resized(im, size, nearest=False)
        applied.append((math.exp(log_gain), length))
        return np.clip(np.rint(im), 0, 255).astype(img.dtype)

    return change


def _top_folders(rows) -> set[str]:
    """The top-level folders of a TUM list's files (``rgb``, ``depth``): copies of them are written, never linked."""
    return {Path(row[0]).parts[0] for row in rows if len(Path(row[0]).parts) > 1}


def _link_or_copy(src: Path, dst: Path) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _copy_tree(src: Path, dst: Path, skip: set[str]) -> None:
    for p in src.iterdir():
        if p.name in skip:
            continue
        if p.is_dir():
            (dst / p.name).mkdir()
            _copy_tree(p, dst / p.name, set())
        else:
            _link_or_copy(p, dst / p.name)


def _thin_list(src: Path, dst: Path, keep) -> list[float]:
    """``src`` (a TUM list file) with only the data lines ``keep(n, timestamp)`` accepts (``n`` counts the data
    lines), comments kept; returns the kept timestamps."""
    lines, kept, n = [], [], 0
    for line in src.read_text().splitlines():
        if not line.strip() or line.lstrip().startswith("#"):
            lines.append(line)
            continue
        ts = float(line.split()[0])
        if keep(n, ts):
            lines.append(line)
            kept.append(ts)
        n += 1
    dst.write_text("\n".join(lines) + "\n")
    return kept


def _nearest(stamps: np.ndarray, targets: list[float]) -> set[float]:
    """The entries of the sorted ``stamps`` nearest to each of ``targets``."""
    if not len(stamps) or not targets:
        return set()
    i = np.clip(np.searchsorted(stamps, targets), 1, len(stamps) - 1)
    left, right = stamps[i - 1], stamps[i]
    return {float(v) for v in np.where(np.abs(np.asarray(targets) - left) <= np.abs(right - np.asarray(targets)), left, right)}


def _thin_moving(src_root: Path, dst: Path, kept_rgb: list[float]) -> None:
    """``moving.txt`` for the kept colour frames: each lists the instances that moved in any frame since the
    previous kept one (the renderer's rows, read by :func:`~dynslam_lab.datasets.tum.read_moving`, are 'moved
    since the previous colour frame')."""
    rows = sorted(read_moving(src_root).items())
    out = ["# instances whose surface moved more than 1 mm since the previous kept colour frame",
           "# timestamp id id ..."]
    i, prev = 0, -math.inf
    for ts in kept_rgb:
        ids: set[int] = set()
        while i < len(rows) and rows[i][0] <= ts + 1e-6:
            if rows[i][0] > prev + 1e-6:
                ids |= rows[i][1]
            i += 1
        out.append(" ".join([f"{ts:.6f}", *(str(x) for x in sorted(ids))]))
        prev = ts
    dst.write_text("\n".join(out) + "\n")


def effects_record(src: str | Path, effects: CameraEffects) -> dict:
    """What ``camera_effects.json`` of a copy holds: its source and its effects, as JSON gives them back (the copy
    is recognised by this record: ``experiments.camera_effects.effect_copy``)."""
    return json.loads(json.dumps({"source": str(src), **asdict(effects)}))


def apply_camera_effects(src: str | Path, dst: str | Path, effects: CameraEffects) -> Path:
    """Write ``src`` (a sequence in the TUM layout) to the new folder ``dst`` with ``effects`` applied (module
    docstring). ``dst`` must not exist: the copy is made in a temporary folder beside it and renamed when
    complete, so an interrupted call leaves nothing behind and never touches a file it did not make. A colour
    image that cannot be read raises :class:`~dynslam_lab.datasets.tum.DatasetError` naming it."""
    src, dst = Path(src), Path(dst)
    if not (src / "rgb.txt").is_file() or not (src / "depth.txt").is_file():
        raise DatasetError(f"{src}: not a sequence in the TUM layout (rgb.txt and depth.txt expected)")
    if dst.exists():
        raise FileExistsError(f"{dst} exists; camera effects are written to a new folder only")
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dst.name}.", dir=dst.parent))
    try:
        size, camera = None, None
        if effects.changes_depth:  # the sequence's camera: its depth scale, and the new image size
            try:
                camera = camera_for_sequence(src)
            except ValueError as exc:
                raise DatasetError(f"{src}: cannot read the sequence's camera ({exc})") from exc
        if effects.scale != 1.0:
            camera = camera.scaled(effects.scale)
            size = (camera.width, camera.height)
        colour = effects.changes_colour or size is not None
        _, rgb_rows = read_file_list(src / "rgb.txt")
        depth_stamps, depth_rows = read_file_list(src / "depth.txt")
        skip = {"rgb.txt", "depth.txt", "associations.txt", "moving.txt"}
        if colour:  # written below (never hard links: writing one would change the source)
            skip |= _top_folders(rgb_rows)
        if effects.changes_depth:
            skip |= _top_folders(depth_rows)
        if size is not None:
            skip |= {"camera.json", "masks"}
        _copy_tree(src, tmp, skip)
        every = int(effects.every)
        kept = _thin_list(src / "rgb.txt", tmp / "rgb.txt", lambda n, ts: n % every == 0)
        # the depth frames nearest to the kept colour frames (a real sequence's depth list need not pair with its
        # colour list line by line), and the association file's rows of the kept colour frames
        near = _nearest(np.sort(depth_stamps), kept)
        _thin_list(src / "depth.txt", tmp / "depth.txt", lambda n, ts: ts in near)
        if (src / "associations.txt").is_file():
            kept_set = set(kept)
            _thin_list(src / "associations.txt", tmp / "associations.txt", lambda n, ts: ts in kept_set)
        if (src / "moving.txt").is_file():
            _thin_moving(src, tmp / "moving.txt", kept)
        stats = []
        if colour:  # every frame, kept or not: the same gains as the full-rate copy
            applied: list[tuple[float, float]] = []
            rels = [row[0] for row in rgb_rows]
            _rewrite_images(src, tmp, rels, "colour", _colour_changer(effects, size, applied))
            stats = [(rel, g, b) for rel, (g, b) in zip(rels, applied)]
        if effects.changes_depth:
            _rewrite_images(src, tmp, [row[0] for row in depth_rows], "depth", _depth_changer(effects, size, camera.depth_scale))
        if size is not None:
            save_camera_json(camera, tmp / "camera.json")
            if (src / "masks").is_dir():
                _rewrite_images(src, tmp, [p.relative_to(src) for p in sorted((src / "masks").glob("*.png"))], "mask",
                                lambda img: _resized(img, size, nearest=True))
        with open(tmp / "camera_effects.csv", "w") as f:
            f.write("rgb,gain,blur_px\n")
            f.writelines(f"{rel},{g:.6f},{b:.3f}\n" for rel, g, b in stats)
        (tmp / "camera_effects.json").write_text(json.dumps(effects_record(src, effects), indent=1))
        os.rename(tmp, dst)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return dst
