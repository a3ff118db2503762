"""Photo-like textures for the stress rooms, made from the sample data bundled with matplotlib.

Procedural noise has statistics no camera ever sees; photographs have the 1/f spectrum, the
edges and the large uniform regions of real surfaces. Two sources ship inside every matplotlib
installation (``matplotlib.get_data_path()/sample_data``), so nothing is downloaded:

* ``grace_hopper.jpg`` (512 x 600): the official US Navy portrait of Rear Admiral Grace Hopper, a
  work of the US federal government and so in the public domain (matplotlib added it as a
  public-domain image, matplotlib PR #1599). Only crops that leave out the face are used (the
  flag, the uniform, the ribbons), so that a person detector never fires on a static wall;
* ``jacksboro_fault_dem.npz`` (403 x 344 elevations) and ``topobathy.npz`` (120 x 91): digital
  elevation models bundled as matplotlib sample data (matplotlib states no licence of its own for
  them; see matplotlib issue #4930). They are hill-shaded here (Lambert's cosine law on the
  terrain's normal) and colour-mapped, which gives aerial-photograph-like relief images with
  natural texture statistics at every scale.

Every function takes a ``numpy.random.Generator``; the result depends only on it and on the files.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import cv2
import matplotlib
import numpy as np

__all__ = ["sample_data_path", "portrait_crops", "relief_image", "photo_collage", "PHOTO_SOURCES"]

#: The matplotlib sample files used, with their licence as stated in the module docstring.
PHOTO_SOURCES = {
    "grace_hopper.jpg": "US Navy photograph, public domain (US federal government work)",
    "jacksboro_fault_dem.npz": "elevation model shipped with matplotlib's sample data (no separate licence stated)",
    "topobathy.npz": "elevation model shipped with matplotlib's sample data (no separate licence stated)",
}

# Regions of the portrait without the face (rows y0:y1, columns x0:x1): the flag on the left,
# the uniform, name tag and ribbons at the bottom.
_PORTRAIT_REGIONS = ((0, 330, 0, 150), (420, 600, 0, 512), (330, 600, 0, 150))


def sample_data_path(name: str) -> Path:
    """Path of a file in matplotlib's ``sample_data``; a clear error if this installation lacks it."""
    path = Path(matplotlib.get_data_path()) / "sample_data" / name
    if not path.is_file():
        raise FileNotFoundError(f"{path}: matplotlib sample data file not found (needed for the 'photo' room style)")
    return path


@lru_cache(maxsize=1)
def _portrait() -> np.ndarray:
    img = cv2.imread(str(sample_data_path("grace_hopper.jpg")), cv2.IMREAD_COLOR)
    if img is None:
        raise OSError(f"{sample_data_path('grace_hopper.jpg')}: cannot read the image")
    out = cv2.cvtColor(img, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0
    out.flags.writeable = False
    return out


@lru_cache(maxsize=2)
def _elevation(name: str) -> np.ndarray:
    with np.load(sample_data_path(name)) as data:
        z = data["elevation"] if "elevation" in data.files else data["topo"]
        z = np.asarray(z, np.float32)
    z.flags.writeable = False
    return z


def portrait_crops(n: int, size: int, rng: np.random.Generator) -> list[np.ndarray]:
    """``n`` square crops ``(size, size, 3)`` float32 RGB of the portrait's face-free regions,
    each from a random place and scale (64-170 source pixels), flipped at random."""
    img = _portrait()
    out = []
    for _ in range(n):
        y0, y1, x0, x1 = _PORTRAIT_REGIONS[int(rng.integers(len(_PORTRAIT_REGIONS)))]
        side = int(rng.integers(64, min(170, y1 - y0, x1 - x0) + 1))
        y = int(rng.integers(y0, y1 - side + 1))
        x = int(rng.integers(x0, x1 - side + 1))
        crop = cv2.resize(img[y : y + side, x : x + side], (size, size), interpolation=cv2.INTER_CUBIC)
        if rng.random() < 0.5:
            crop = crop[:, ::-1]
        out.append(np.clip(crop, 0, 1).astype(np.float32))
    return out


# colour ramps (RGB 0..1) for the relief images: earth, stone, sepia, slate
_RAMPS = (
    ((0.12, 0.2, 0.38), (0.2, 0.45, 0.3), (0.55, 0.6, 0.35), (0.75, 0.65, 0.5), (0.95, 0.95, 0.92)),
    ((0.25, 0.24, 0.22), (0.45, 0.43, 0.4), (0.62, 0.6, 0.56), (0.8, 0.78, 0.74)),
    ((0.2, 0.12, 0.06), (0.45, 0.32, 0.18), (0.72, 0.58, 0.4), (0.92, 0.85, 0.7)),
    ((0.1, 0.13, 0.18), (0.3, 0.36, 0.44), (0.55, 0.6, 0.66), (0.85, 0.87, 0.9)),
)


def relief_image(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """A hill-shaded, colour-mapped crop of one of the elevation models, ``(h, w, 3)`` float32 RGB.

    A random window of the model (at least a third of it, random orientation) is resized to
    ``(h, w)``, shaded by Lambert's law ``max(0, n . l)`` for a light at a random azimuth and 35-60 deg
    elevation (``n`` the normal of the exaggerated terrain), and coloured by elevation with one of
    four ramps; brightness = 0.35 + 0.75 * shading.
    """
    z = _elevation(("jacksboro_fault_dem.npz", "topobathy.npz")[int(rng.random() < 0.3)])
    H, W = z.shape
    fh, fw = rng.uniform(0.35, 1.0, 2)
    ch, cw = max(8, int(H * fh)), max(8, int(W * fw))
    y, x = int(rng.integers(0, H - ch + 1)), int(rng.integers(0, W - cw + 1))
    win = np.array(z[y : y + ch, x : x + cw])
    win = np.rot90(win, int(rng.integers(4)))
    win = cv2.resize(np.ascontiguousarray(win), (w, h), interpolation=cv2.INTER_CUBIC)
    span = float(np.ptp(win)) or 1.0
    elev = (win - win.min()) / span
    # normals of the terrain, exaggerated so that relief shows at every scale
    gy, gx = np.gradient(elev * np.float32(rng.uniform(20.0, 60.0)))
    az, alt = rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(35.0, 60.0))
    light = np.array([np.cos(az) * np.cos(alt), np.sin(az) * np.cos(alt), np.sin(alt)], np.float32)
    shade = (-gx * light[0] - gy * light[1] + light[2]) / np.sqrt(gx * gx + gy * gy + 1.0)
    shade = np.clip(shade, 0.0, 1.0)
    ramp = np.array(_RAMPS[int(rng.integers(len(_RAMPS)))], np.float32)
    pos = np.linspace(0.0, 1.0, len(ramp))
    colour = np.stack([np.interp(elev, pos, ramp[:, c]) for c in range(3)], axis=-1)
    return np.clip(colour * (0.35 + 0.75 * shade)[..., None], 0, 1).astype(np.float32)


def photo_collage(h: int, w: int, rng: np.random.Generator, cell: int = 160) -> np.ndarray:
    """A wall covered edge to edge with photographic prints: relief images and portrait crops
    in a jittered grid of cells about ``cell`` texels wide, with thin dark gaps, ``(h, w, 3)`` float32."""
    img = np.full((h, w, 3), 0.12, np.float32)
    y = 0
    while y < h:
        ph = int(cell * rng.uniform(0.7, 1.4))
        x = int(-rng.integers(0, cell // 2))
        while x < w:
            pw = int(cell * rng.uniform(0.7, 1.6))
            if rng.random() < 0.4:
                tile = cv2.resize(portrait_crops(1, max(ph, pw), rng)[0], (pw, ph), interpolation=cv2.INTER_AREA)
            else:
                tile = relief_image(ph, pw, rng)
            x0, y0 = max(x, 0), y
            x1, y1 = min(x + pw - 3, w), min(y + ph - 3, h)
            if x1 > x0 and y1 > y0:
                img[y0:y1, x0:x1] = tile[: y1 - y0, x0 - x : x1 - x]
            x += pw
        y += ph
    return img
