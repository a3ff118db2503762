"""Procedural textures and a mip-mapped texture atlas for the synthetic renderer.

Every surface of the synthetic office carries a texture made here from seeded noise, so a
feature detector finds corners at many scales, as on real walls, desks and clothes:

* fractal (multi-octave) value noise: random grids upsampled with bicubic interpolation,
  octave ``k`` with cell size ``base * 2**-k`` and amplitude ``persistence**k``
  (Perlin, "An image synthesizer", SIGGRAPH 1985, Sec. 4 "turbulence");
* blobs, stripes and plaids (clothes), wood grain, floor and ceiling tiles;
* printed-text-like patterns (random letters with OpenCV's Hershey fonts), posters,
  whiteboards and computer screens.

The noise layers tile (wrap around) seamlessly, so round parts (arms, heads) show no seam in
them; drawn details (text, shapes) are simply clipped at the texture's border.

Sampling uses mip-mapping (Williams, "Pyramidal parametrics", SIGGRAPH 1983): each texture
is stored with a pyramid of 2x box-filtered levels, and a pixel whose footprint covers
``rho`` texels reads level ``log2(rho)``, blending the two nearest levels (trilinear
filtering). Without it, a wall seen from afar aliases and its corners flicker from frame to
frame, which real cameras (whose optics integrate over the pixel) never show.
All levels of all textures are packed in one atlas image, so a whole frame is textured by
two :func:`cv2.remap` calls.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = [
    "fractal_noise",
    "colorize",
    "add_text",
    "add_speckle",
    "plaster_texture",
    "wood_texture",
    "floor_texture",
    "ceiling_texture",
    "fabric_texture",
    "denim_texture",
    "skin_texture",
    "head_texture",
    "screen_texture",
    "book_texture",
    "metal_texture",
    "poster",
    "whiteboard",
    "paste",
    "TextureAtlas",
    "build_atlas",
    "sample_atlas",
    "MIP_LEVELS",
]

#: Number of mip levels (level 0 = full resolution); texture sizes are multiples of 2**(MIP_LEVELS-1).
MIP_LEVELS = 6
_ALIGN = 2 ** (MIP_LEVELS - 1)
_PAD = 2  # wrap-around border (texels) around each level, for bilinear reads at the seams


def aligned(n: float) -> int:
    """Round a texture size up to a multiple of ``2**(MIP_LEVELS-1)`` texels (at least one)."""
    return int(max(_ALIGN, int(np.ceil(n / _ALIGN)) * _ALIGN))


# --------------------------------------------------------------------------- noise
def _tileable_upsample(grid: np.ndarray, h: int, w: int) -> np.ndarray:
    """Bicubic upsampling of a small periodic grid to ``(h, w)``, wrapping at the borders."""
    gh, gw = grid.shape
    padded = np.pad(grid, 2, mode="wrap")
    fy, fx = h / gh, w / gw
    big = cv2.resize(padded, (int(round((gw + 4) * fx)), int(round((gh + 4) * fy))), interpolation=cv2.INTER_CUBIC)
    oy, ox = int(round(2 * fy)), int(round(2 * fx))
    return big[oy : oy + h, ox : ox + w]


def fractal_noise(
    h: int,
    w: int,
    rng: np.random.Generator,
    base_cell: float = 64.0,
    octaves: int = 6,
    persistence: float = 0.6,
    aspect: float = 1.0,
) -> np.ndarray:
    """Tileable multi-octave value noise, ``(h, w)`` float32 scaled to [0, 1].

    Parameters
    ----------
    h, w : size in texels.
    rng : random generator (the only source of randomness).
    base_cell : cell size of the coarsest octave, texels.
    octaves : number of octaves; octave ``k`` has cells ``base_cell / 2**k`` and weight ``persistence**k``.
    aspect : cells are ``aspect`` times wider than tall (stretched noise for wood grain, denim).
    """
    out = np.zeros((h, w), np.float32)
    for k in range(octaves):
        cell = base_cell / 2**k
        gh = max(2, int(round(h / cell)))
        gw = max(2, int(round(w / (cell * aspect))))
        grid = rng.random((gh, gw)).astype(np.float32)
        out += persistence**k * _tileable_upsample(grid, h, w)
    out -= out.min()
    return out / max(float(out.max()), 1e-6)


def colorize(value: np.ndarray, c0, c1) -> np.ndarray:
    """Map a scalar field in [0, 1] ``(h, w)`` to colours between RGB ``c0`` and ``c1`` (0..1): ``(h, w, 3)``."""
    c0 = np.asarray(c0, np.float32)
    c1 = np.asarray(c1, np.float32)
    return c0 + value[..., None] * (c1 - c0)


def add_speckle(img: np.ndarray, rng: np.random.Generator, amount: float = 0.35, scales=(1.5, 3.0, 6.0),
                density: float = 0.015) -> np.ndarray:
    """Multiply ``img`` ``(h, w, 3)`` by sparse dark and bright Gaussian spots at several scales.

    Spots of radius ``scale`` texels appear at ``density / scale**2`` per texel with a relative
    contrast up to ``amount``: the small, blob-like details (pores, knots, dust, stitches) on
    which FAST/ORB corners fire at every viewing distance. Wraps around like the texture.
    """
    h, w = img.shape[:2]
    field = np.zeros((h, w), np.float32)
    for sc in scales:
        seeds = (rng.random((h, w)) < density / sc**2).astype(np.float32)
        seeds *= rng.uniform(-1.0, 1.0, (h, w)).astype(np.float32)
        pad = int(4 * sc)
        blob = cv2.GaussianBlur(np.pad(seeds, pad, mode="wrap"), (0, 0), sc)[pad : pad + h, pad : pad + w]
        field += blob * np.float32(2 * np.pi * sc * sc)
    return np.clip(img * (1.0 + amount * np.clip(field, -1.5, 1.5))[..., None], 0, 1).astype(np.float32)


_LETTERS = np.array(list("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789      .,:-"))
_FONTS = [cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX, cv2.FONT_HERSHEY_PLAIN]


def add_text(
    img: np.ndarray,
    rng: np.random.Generator,
    box: tuple[int, int, int, int],
    line_height: int,
    color=(0.05, 0.05, 0.1),
    fill: float = 0.8,
) -> None:
    """Write lines of random printed-text-like characters into ``img`` (float, in place).

    ``box`` is ``(x0, y0, x1, y1)`` texels; ``line_height`` the text line pitch in texels;
    ``fill`` the fraction of lines written (the rest left blank, like paragraphs).
    """
    x0, y0, x1, y1 = box
    x0, y0 = max(int(x0), 0), max(int(y0), 0)
    x1, y1 = min(int(x1), img.shape[1]), min(int(y1), img.shape[0])
    if x1 <= x0 or y1 <= y0:
        return
    # OpenCV draws text only into 8-bit images: draw coverage into a mask, then blend the colour.
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    scale = line_height / 30.0
    thick = max(1, int(round(line_height / 14)))
    font = _FONTS[int(rng.integers(len(_FONTS)))]
    y = line_height
    while y < y1 - y0:
        if rng.random() < fill:
            n = max(3, int((x1 - x0) / (line_height * 0.55) * rng.uniform(0.5, 1.0)))
            text = "".join(rng.choice(_LETTERS, n))
            cv2.putText(mask, text, (0, int(y)), font, scale, 255, thick, cv2.LINE_AA)
        y += line_height
    _blend(img[y0:y1, x0:x1], mask, color)


def _blend(region: np.ndarray, mask: np.ndarray, color) -> None:
    """Blend ``color`` into ``region`` (float, in place) with the 8-bit coverage ``mask``."""
    a = (mask.astype(np.float32) / 255.0)[..., None]
    region[...] = region * (1.0 - a) + np.asarray(color, np.float32) * a


def paste(dst: np.ndarray, src: np.ndarray, x: int, y: int) -> None:
    """Copy ``src`` into ``dst`` with its top-left corner at ``(x, y)``, clipped to ``dst``."""
    h, w = src.shape[:2]
    H, W = dst.shape[:2]
    xa, ya, xb, yb = max(x, 0), max(y, 0), min(x + w, W), min(y + h, H)
    if xb > xa and yb > ya:
        dst[ya:yb, xa:xb] = src[ya - y : yb - y, xa - x : xb - x]


def _rand_color(rng: np.random.Generator, lo: float = 0.15, hi: float = 0.9) -> np.ndarray:
    return rng.uniform(lo, hi, 3).astype(np.float32)


# ------------------------------------------------------------------- materials
def plaster_texture(h: int, w: int, rng: np.random.Generator, color=(0.78, 0.76, 0.7)) -> np.ndarray:
    """Painted wall: soft stains at a few scales plus fine grain, ``(h, w, 3)`` float32."""
    n = fractal_noise(h, w, rng, base_cell=160, octaves=7, persistence=0.55)
    img = colorize(n, np.asarray(color) * 0.78, np.minimum(np.asarray(color) * 1.12, 1.0))
    # scuffs and small marks: random dark ellipses
    for _ in range(int(h * w / 9000)):
        c = (int(rng.integers(w)), int(rng.integers(h)))
        ax = (int(rng.integers(2, 14)), int(rng.integers(2, 10)))
        shade = float(rng.uniform(0.35, 0.7))
        cv2.ellipse(img, c, ax, float(rng.uniform(0, 180)), 0, 360, tuple(float(v) * shade for v in color), -1, cv2.LINE_AA)
    return add_speckle(img, rng, amount=0.3)


def poster(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """A poster: a coloured picture of blobs and noise, a frame and a printed caption."""
    bg = _rand_color(rng, 0.1, 0.9)
    fg = _rand_color(rng, 0.1, 0.9)
    img = colorize(fractal_noise(h, w, rng, base_cell=max(h, w) / 3, octaves=6, persistence=0.65), bg, fg)
    for _ in range(int(rng.integers(4, 12))):
        c = (int(rng.integers(w)), int(rng.integers(int(h * 0.7))))
        r = int(rng.integers(max(3, w // 20), max(4, w // 5)))
        col = tuple(float(v) for v in _rand_color(rng, 0.0, 1.0))
        if rng.random() < 0.5:
            cv2.circle(img, c, r, col, -1, cv2.LINE_AA)
        else:
            cv2.rectangle(img, (c[0] - r, c[1] - r // 2), (c[0] + r, c[1] + r // 2), col, -1)
    cap = int(h * 0.78)
    img[cap:] = 0.92
    add_text(img, rng, (int(w * 0.06), cap, int(w * 0.94), h - 4), line_height=max(8, h // 18), fill=0.9)
    cv2.rectangle(img, (0, 0), (w - 1, h - 1), (0.08, 0.08, 0.08), max(2, w // 60))
    return img


def whiteboard(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """A whiteboard with handwriting-like text lines and a few diagrams, dark frame."""
    img = colorize(fractal_noise(h, w, rng, base_cell=w / 4, octaves=4), (0.86, 0.87, 0.88), (0.97, 0.97, 0.98))
    for color in [(0.1, 0.15, 0.6), (0.05, 0.05, 0.05), (0.7, 0.1, 0.1)]:
        x0 = int(rng.uniform(0.03, 0.5) * w)
        y0 = int(rng.uniform(0.03, 0.5) * h)
        add_text(img, rng, (x0, y0, min(w - 10, x0 + int(w * 0.45)), min(h - 10, y0 + int(h * 0.45))),
                 line_height=max(10, h // 14), color=color, fill=0.85)
    for _ in range(3):
        p = rng.integers([0, 0], [w, h], size=(4, 2)).astype(np.int32)
        cv2.polylines(img, [p], True, (0.1, 0.3, 0.1), max(1, h // 150), cv2.LINE_AA)
    cv2.rectangle(img, (0, 0), (w - 1, h - 1), (0.55, 0.56, 0.58), max(3, w // 80))
    return img


def wood_texture(h: int, w: int, rng: np.random.Generator, color=(0.55, 0.36, 0.2)) -> np.ndarray:
    """Wood: stretched noise bent into rings (grain along x) plus fine pores."""
    n = fractal_noise(h, w, rng, base_cell=max(h, w) / 4, octaves=5, aspect=6.0)
    y = np.arange(h, dtype=np.float32)[:, None]
    rings = 0.5 + 0.5 * np.sin(2 * np.pi * (y / 23.0 + 6.0 * n))
    fine = fractal_noise(h, w, rng, base_cell=16, octaves=3, aspect=4.0)
    v = 0.55 * rings + 0.3 * fine + 0.15 * n
    c = np.asarray(color, np.float32)
    return add_speckle(colorize(v, c * 0.6, np.minimum(c * 1.35, 1.0)), rng, amount=0.35)


def floor_texture(h: int, w: int, rng: np.random.Generator, tile: int = 100) -> np.ndarray:
    """Carpet tiles: per-tile colour and pile direction, coarse-to-fine speckle, dark joints every
    ``tile`` texels, and scattered stains and scraps of paper."""
    speck = fractal_noise(h, w, rng, base_cell=tile / 2, octaves=5, persistence=0.9)
    fine = rng.random((h, w)).astype(np.float32)
    v = 0.6 * speck + 0.4 * cv2.GaussianBlur(fine, (0, 0), 0.8) * 2.0 - 0.2
    img = colorize(np.clip(v, 0, 1), (0.12, 0.13, 0.17), (0.62, 0.62, 0.66))
    ty, tx = np.arange(h) // tile, np.arange(w) // tile
    shade = rng.uniform(0.7, 1.3, (ty.max() + 1, tx.max() + 1, 3)).astype(np.float32)
    shade = shade * 0.3 + shade.mean(axis=2, keepdims=True) * 0.7
    img *= shade[ty][:, tx]
    img[np.arange(h) % tile < 3] *= 0.35
    img[:, np.arange(w) % tile < 3] *= 0.35
    for _ in range(int(h * w / 6000)):  # stains, crumbs and scraps of paper
        c = (int(rng.integers(w)), int(rng.integers(h)))
        col = tuple(float(v) for v in _rand_color(rng, 0.05, 0.95))
        cv2.ellipse(img, c, (int(rng.integers(2, 12)), int(rng.integers(2, 8))), float(rng.uniform(0, 180)), 0, 360, col, -1, cv2.LINE_AA)
    return add_speckle(np.clip(img, 0, 1), rng, amount=0.4)


def ceiling_texture(h: int, w: int, rng: np.random.Generator, tile: int = 120) -> np.ndarray:
    """Suspended ceiling: pale tiles with pinhole noise, grid bars, a few bright lamp panels."""
    img = colorize(fractal_noise(h, w, rng, base_cell=24, octaves=4, persistence=0.8), (0.72, 0.72, 0.7), (0.9, 0.9, 0.88))
    img[np.arange(h) % tile < 3] = (0.55, 0.55, 0.56)
    img[:, np.arange(w) % tile < 3] = (0.55, 0.55, 0.56)
    for _ in range(max(1, h * w // (tile * tile * 6))):
        i, j = int(rng.integers(h // tile)), int(rng.integers(w // tile))
        img[i * tile + 6 : (i + 1) * tile - 6, j * tile + 6 : (j + 2) * tile - 6] = 1.0
        for k in range(1, 4):
            yy = i * tile + k * tile // 4
            img[yy - 1 : yy + 1, j * tile + 6 : (j + 2) * tile - 6] = 0.8
    return img


def fabric_texture(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Shirt fabric: a high-contrast plaid, stripes or a busy print (dark and light colours),
    with a printed logo and slogan, buttons, weave speckle and folds: clothes give a detector as
    many corners as the background, as on real people."""
    dark, light = _rand_color(rng, 0.03, 0.35), _rand_color(rng, 0.6, 0.98)
    y = np.arange(h, dtype=np.float32)[:, None]
    x = np.arange(w, dtype=np.float32)[None, :]
    p = float(rng.choice([10, 14, 20, 28]))
    kind = int(rng.integers(3))
    if kind == 0:  # plaid
        pat = ((np.sin(2 * np.pi * y / p) > 0.2).astype(np.float32) * 0.5
               + (np.sin(2 * np.pi * x / (p * 1.3)) > 0.4).astype(np.float32) * 0.5)
    elif kind == 1:  # stripes of two widths
        pat = np.broadcast_to(((np.sin(2 * np.pi * y / p) > 0.0) ^ (np.sin(2 * np.pi * y / (3.1 * p)) > 0.7)).astype(np.float32), (h, w)).copy()
    else:  # a busy print: scattered shapes on a plain ground
        pat = np.zeros((h, w), np.float32)
        for _ in range(int(h * w / (p * p * 1.5))):
            c = (int(rng.integers(w)), int(rng.integers(h)))
            r = int(rng.integers(2, int(p // 2) + 3))
            if rng.random() < 0.5:
                cv2.circle(pat, c, r, float(rng.uniform(0.6, 1.0)), -1, cv2.LINE_AA)
            else:
                cv2.rectangle(pat, (c[0] - r, c[1] - r), (c[0] + r, c[1] + r), float(rng.uniform(0.6, 1.0)), -1)
        pat = np.roll(pat, (int(h // 2), int(w // 2)), axis=(0, 1))  # seams of the drawing away from the wrap
    folds = fractal_noise(h, w, rng, base_cell=max(h, w) / 3, octaves=6, persistence=0.7)
    img = colorize(pat, dark, light) * (0.7 + 0.5 * folds[..., None])
    # a printed logo with a slogan, and buttons down the front (the front is at w/2 on round parts)
    x0, y0 = int(w * rng.uniform(0.3, 0.45)), int(h * rng.uniform(0.15, 0.35))
    bw, bh = w // 5, h // 5
    cv2.rectangle(img, (x0, y0), (x0 + bw, y0 + bh), tuple(float(v) for v in _rand_color(rng, 0.0, 1.0)), -1)
    cv2.circle(img, (x0 + bw // 4, y0 + bh // 2), max(3, bh // 4), tuple(float(v) for v in light), -1, cv2.LINE_AA)
    add_text(img, rng, (x0 + bw // 2, y0, x0 + bw, y0 + bh), line_height=max(6, bh // 3), color=(0.97, 0.97, 0.92), fill=1.0)
    for k in range(5):
        cv2.circle(img, (w // 2, int(h * (0.1 + 0.18 * k))), max(2, w // 90), (0.9, 0.9, 0.85), -1, cv2.LINE_AA)
    return add_speckle(np.clip(img, 0, 1), rng, amount=0.5)


def denim_texture(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Trousers: diagonal twill, worn patches and creases at several scales, light seams,
    stitched pockets and rivets."""
    n = fractal_noise(h, w, rng, base_cell=max(h, w) / 4, octaves=7, persistence=0.8)
    y = np.arange(h, dtype=np.float32)[:, None]
    x = np.arange(w, dtype=np.float32)[None, :]
    twill = 0.5 + 0.5 * np.sin(2 * np.pi * (x + y) / 5.0)
    base = _rand_color(rng, 0.08, 0.5)
    img = colorize(np.clip(0.75 * n + 0.25 * twill, 0, 1), base * 0.3, np.minimum(base * 2.0 + 0.15, 1))
    seam = tuple(float(v) for v in np.minimum(base * 2.5 + 0.35, 1))
    for k in range(4):  # seams and pocket outlines, double-stitched
        x0 = int((k + rng.uniform(0.1, 0.6)) * w / 4)
        cv2.line(img, (x0, 0), (x0, h), seam, 2, cv2.LINE_AA)
        y0 = int(rng.uniform(0.05, 0.6) * h)
        for m in (0, 3):
            cv2.rectangle(img, (x0 + 4 + m, y0 + m), (x0 + w // 9 - m, y0 + h // 6 - m), seam, 1, cv2.LINE_AA)
        cv2.circle(img, (x0 + 6, y0 + 3), 2, (0.85, 0.75, 0.4), -1, cv2.LINE_AA)
    return add_speckle(img, rng, amount=0.5)


def skin_texture(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Skin: warm tone with blotches and fine pores."""
    tone = np.array([0.85, 0.64, 0.5], np.float32) * rng.uniform(0.55, 1.05)
    n = fractal_noise(h, w, rng, base_cell=max(h, w) / 3, octaves=6, persistence=0.6)
    return add_speckle(colorize(n, tone * 0.75, np.minimum(tone * 1.15, 1)), rng, amount=0.2)


def head_texture(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Head wrapped around an ellipsoid: columns are the azimuth (face centre at ``w/2``),
    rows the height (row 0 = crown, last row = chin). Skin, hair on the crown and back,
    eyes, brows, nose and mouth."""
    img = skin_texture(h, w, rng)
    hair_col = _rand_color(rng, 0.02, 0.35)
    hair = colorize(fractal_noise(h, w, rng, base_cell=w / 8, octaves=5, aspect=0.2), hair_col * 0.5, hair_col * 1.4)
    yy = np.arange(h)[:, None] / h
    xx = np.abs(np.arange(w)[None, :] / w - 0.5)  # 0 at the face centre, 0.5 at the back
    hair_mask = (yy < 0.26 + 0.5 * xx) | ((xx > 0.3) & (yy < 0.8))
    img = np.where(hair_mask[..., None], hair, img)
    cx = w // 2
    for side in (-1, 1):
        ex = cx + side * w // 14
        cv2.ellipse(img, (ex, int(h * 0.42)), (max(2, w // 40), max(2, h // 30)), 0, 0, 360, (0.95, 0.95, 0.95), -1, cv2.LINE_AA)
        cv2.circle(img, (ex, int(h * 0.42)), max(1, w // 90), (0.1, 0.07, 0.05), -1, cv2.LINE_AA)
        cv2.line(img, (ex - w // 30, int(h * 0.35)), (ex + w // 30, int(h * 0.36)), tuple(float(v) for v in hair_col), max(1, h // 60))
    cv2.ellipse(img, (cx, int(h * 0.68)), (w // 22, max(2, h // 40)), 0, 0, 360, (0.55, 0.25, 0.25), -1, cv2.LINE_AA)
    cv2.line(img, (cx, int(h * 0.45)), (cx - w // 60, int(h * 0.57)), (0.55, 0.4, 0.32), max(1, h // 80))
    return img


def screen_texture(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """A computer screen: dark desktop, a few windows with title bars, text and a picture."""
    img = colorize(fractal_noise(h, w, rng, base_cell=w / 3, octaves=3), (0.02, 0.05, 0.15), (0.1, 0.2, 0.45))
    for _ in range(int(rng.integers(2, 5))):
        x0, y0 = int(rng.uniform(0, 0.5) * w), int(rng.uniform(0, 0.5) * h)
        x1, y1 = x0 + int(rng.uniform(0.3, 0.6) * w), y0 + int(rng.uniform(0.3, 0.6) * h)
        cv2.rectangle(img, (x0, y0), (x1, y1), (0.92, 0.92, 0.92), -1)
        cv2.rectangle(img, (x0, y0), (x1, y0 + h // 25), tuple(float(v) for v in _rand_color(rng, 0.2, 0.7)), -1)
        if rng.random() < 0.5:
            add_text(img, rng, (x0 + 4, y0 + h // 25, x1 - 4, y1 - 4), line_height=max(6, h // 28), color=(0.1, 0.1, 0.1))
        else:
            pic = poster(max(8, (y1 - y0) * 2 // 3), max(8, (x1 - x0) * 2 // 3), rng)
            paste(img, pic, x0 + (x1 - x0) // 6, y0 + (y1 - y0) // 4)
    return np.clip(img, 0, 1)


def book_texture(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Book covers and spines: coloured bands with bright title blocks and text."""
    img = np.zeros((h, w, 3), np.float32)
    x = 0
    while x < w:
        bw = int(rng.integers(12, 40))
        img[:, x : x + bw] = _rand_color(rng, 0.08, 0.85)
        for _ in range(int(rng.integers(1, 4))):
            y0 = int(rng.integers(0, max(1, h - 20)))
            img[y0 : y0 + int(rng.integers(4, 16)), x + 2 : x + bw - 2] = _rand_color(rng, 0.5, 1.0)
        x += bw
    img *= 0.8 + 0.4 * fractal_noise(h, w, rng, base_cell=32, octaves=4)[..., None]
    add_text(img, rng, (2, 2, w - 2, h - 2), line_height=max(7, h // 16), color=(0.95, 0.92, 0.8), fill=0.5)
    return np.clip(img, 0, 1)


def metal_texture(h: int, w: int, rng: np.random.Generator, color=(0.25, 0.25, 0.27)) -> np.ndarray:
    """Painted metal or plastic: brushed noise and scratches."""
    n = fractal_noise(h, w, rng, base_cell=max(h, w) / 4, octaves=6, aspect=3.0, persistence=0.7)
    img = colorize(n, np.asarray(color) * 0.6, np.minimum(np.asarray(color) * 1.6 + 0.05, 1))
    for _ in range(int(h * w / 3000)):
        p = rng.integers([0, 0], [w, h], size=2)
        q = p + rng.integers(-20, 20, size=2)
        cv2.line(img, tuple(int(v) for v in p), tuple(int(v) for v in q), (0.7, 0.7, 0.72), 1, cv2.LINE_AA)
    return add_speckle(img, rng, amount=0.4)


# ------------------------------------------------------------------- the atlas
@dataclass
class TextureAtlas:
    """All textures and their mip levels packed into one image.

    Attributes
    ----------
    image : ``(Ha, Wa, 3)`` uint8 RGB atlas (a view of the first three channels of ``rgba``).
    origin : ``(T, L, 2)`` float32 atlas pixel ``(x, y)`` of texel ``(0, 0)`` of level ``l`` of texture ``t``.
    size : ``(T, L, 2)`` float32 width and height of each level in texels.
    n_levels : number of mip levels ``L``.
    rgba : ``(Ha, Wa, 4)`` uint8 the same atlas with a fourth, zero channel (made from ``image`` when
        not given): :func:`cv2.remap` reads four-channel pixels about twice as fast as three-channel
        ones, with the same values in the first three channels.
    """

    image: np.ndarray
    origin: np.ndarray
    size: np.ndarray
    n_levels: int
    rgba: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.rgba is None:
            img = np.asarray(self.image)
            if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
                raise ValueError(f"TextureAtlas.image must be an (H, W, 3) uint8 image, got {img.shape} {img.dtype}")
            self.rgba = np.zeros(img.shape[:2] + (4,), np.uint8)
            self.rgba[..., :3] = img
        self.image = self.rgba[..., :3]

    @property
    def n_textures(self) -> int:
        return self.origin.shape[0]

    def texture_size(self, index: int) -> tuple[int, int]:
        """``(width, height)`` of level 0 of texture ``index``, texels."""
        w, h = self.size[index, 0]
        return int(w), int(h)


def build_atlas(textures: list[np.ndarray], n_levels: int = MIP_LEVELS, width: int = 4096) -> TextureAtlas:
    """Pack textures ``(h, w, 3)`` (float in [0, 1] or uint8) and their mip pyramids in one atlas.

    Sizes must be multiples of ``2**(n_levels-1)``. Each level is surrounded by a
    ``_PAD``-texel wrap-around border so bilinear reads across a seam stay inside the texture.
    Levels are placed with a simple shelf packer (tallest first).
    """
    align = 2 ** (n_levels - 1)
    levels: list[tuple[int, int, np.ndarray]] = []
    for ti, tex in enumerate(textures):
        tex = np.asarray(tex)
        if tex.ndim != 3 or tex.shape[2] != 3:
            raise ValueError(f"texture {ti}: expected an (h, w, 3) image, got shape {tex.shape}")
        if tex.shape[0] % align or tex.shape[1] % align:
            raise ValueError(f"texture {ti}: size {tex.shape[1]}x{tex.shape[0]} is not a multiple of {align} texels")
        if tex.dtype != np.uint8:
            tex = np.clip(np.asarray(tex, np.float32) * 255.0 + 0.5, 0, 255).astype(np.uint8)
        level = tex
        for li in range(n_levels):
            levels.append((ti, li, level))
            if li < n_levels - 1:  # (a texture of 2**(n_levels-1) texels ends with a 1-texel level)
                level = cv2.resize(level, (level.shape[1] // 2, level.shape[0] // 2), interpolation=cv2.INTER_AREA)
    width = max(width, max(lv.shape[1] for _, _, lv in levels) + 2 * _PAD)
    order = sorted(range(len(levels)), key=lambda k: -levels[k][2].shape[0])
    origin = np.zeros((len(textures), n_levels, 2), np.float32)
    size = np.zeros((len(textures), n_levels, 2), np.float32)
    places = []
    x = y = shelf_h = 0
    for k in order:
        ti, li, lv = levels[k]
        h, w = lv.shape[0] + 2 * _PAD, lv.shape[1] + 2 * _PAD
        if x + w > width:
            x, y, shelf_h = 0, y + shelf_h, 0
        places.append((k, x, y))
        origin[ti, li] = (x + _PAD, y + _PAD)
        size[ti, li] = (lv.shape[1], lv.shape[0])
        x += w
        shelf_h = max(shelf_h, h)
    height = y + shelf_h
    if height >= 32767 or width >= 32767:
        raise ValueError(f"texture atlas of {width}x{height} is too large for cv2.remap; use smaller textures")
    rgba = np.zeros((height, width, 4), np.uint8)
    for k, x, y in places:
        lv = levels[k][2]
        rgba[y : y + lv.shape[0] + 2 * _PAD, x : x + lv.shape[1] + 2 * _PAD, :3] = np.pad(lv, ((_PAD, _PAD), (_PAD, _PAD), (0, 0)),
                                                                                          mode="wrap")
    return TextureAtlas(image=rgba[..., :3], origin=origin, size=size, n_levels=n_levels, rgba=rgba)


def sample_atlas(
    atlas: TextureAtlas,
    tex: np.ndarray,
    s: np.ndarray,
    t: np.ndarray,
    level: np.ndarray,
) -> np.ndarray:
    """Trilinear texture lookup for a whole image.

    Parameters
    ----------
    atlas : the packed textures.
    tex : ``(H, W)`` int texture index per pixel (any value where unused).
    s, t : ``(H, W)`` float32 texture coordinates in level-0 texels (wrap around).
    level : ``(H, W)`` float32 mip level, ``log2`` of the pixel footprint in texels.

    Returns
    -------
    ``(H, W, 3)`` float32 RGB in [0, 1].
    """
    L = atlas.n_levels
    f32 = np.float32
    tex = np.asarray(tex).astype(np.intp, copy=False)
    # l0 = the finer of the two levels blended; l0 + 1 the coarser, with weight w1
    lv = np.clip(level, 0.0, f32(L - 1)).astype(np.float32, copy=False)
    l0 = lv.astype(np.intp)
    np.minimum(l0, L - 2, out=l0)
    w1 = lv - l0.astype(np.float32)
    # wrap around at level 0 (sizes halve exactly from level to level, so this wraps every level):
    # x = s - floor(s / w) * w
    w0 = np.take(np.ascontiguousarray(atlas.size[:, 0, 0]), tex)
    h0 = np.take(np.ascontiguousarray(atlas.size[:, 0, 1]), tex)
    x = np.divide(s, w0)
    np.floor(x, out=x)
    x *= w0
    np.subtract(s, x, out=x)
    y = np.divide(t, h0)
    np.floor(y, out=y)
    y *= h0
    np.subtract(t, y, out=y)
    scale = np.take(np.ldexp(f32(1.0), -np.arange(L)).astype(np.float32), l0)
    x *= scale
    y *= scale
    k = tex * L  # flat index of (texture, level l0)
    k += l0
    ox = atlas.origin[..., 0].ravel() - f32(0.5)
    oy = atlas.origin[..., 1].ravel() - f32(0.5)
    src = atlas.rgba
    mx, my = x + np.take(ox, k), y + np.take(oy, k)
    fine = cv2.remap(src, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    x *= f32(0.5)
    y *= f32(0.5)
    k += 1
    np.add(x, np.take(ox, k), out=mx)
    np.add(y, np.take(oy, k), out=my)
    coarse = cv2.remap(src, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    blended = cv2.cvtColor(cv2.blendLinear(fine, coarse, 1.0 - w1, w1), cv2.COLOR_RGBA2RGB)
    return np.multiply(blended, f32(1.0 / 255.0), dtype=np.float32)


def keyboard_texture(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Keyboard: dark plastic with a grid of light key caps carrying letters."""
    img = metal_texture(h, w, rng, color=(0.12, 0.12, 0.13))
    key = max(8, w // 16)
    mask = np.zeros((h, w), np.uint8)
    for y in range(2, h - key, key):
        for x in range(2 + (y // key % 2) * key // 3, w - key, key):
            cv2.rectangle(img, (x + 1, y + 1), (x + key - 2, y + key - 2), (0.78, 0.78, 0.76), -1)
            cv2.putText(mask, str(rng.choice(_LETTERS[:36])), (x + key // 4, y + 3 * key // 4), cv2.FONT_HERSHEY_PLAIN,
                        key / 24, 255, 1, cv2.LINE_AA)
    _blend(img, mask, (0.1, 0.1, 0.1))
    return img


def leaves_texture(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Foliage: many overlapping leaf ellipses in greens over dark shadow."""
    img = colorize(fractal_noise(h, w, rng, base_cell=w / 6, octaves=4), (0.02, 0.08, 0.02), (0.1, 0.25, 0.08))
    for _ in range(int(h * w / 120)):
        c = (int(rng.integers(w)), int(rng.integers(h)))
        g = float(rng.uniform(0.25, 0.75))
        cv2.ellipse(img, c, (int(rng.integers(4, 12)), int(rng.integers(2, 5))), float(rng.uniform(0, 180)), 0, 360,
                    (g * 0.35, g, g * 0.25), -1, cv2.LINE_AA)
    return img


def paper_texture(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Printed sheets: white paper with paragraphs of small text and a figure."""
    img = colorize(fractal_noise(h, w, rng, base_cell=w / 3, octaves=3), (0.86, 0.86, 0.84), (0.97, 0.97, 0.95))
    add_text(img, rng, (w // 12, h // 12, w - w // 12, h - h // 12), line_height=max(6, h // 30), fill=0.85)
    if rng.random() < 0.7:
        fig = poster(h // 4, w // 3, rng)
        paste(img, fig, w // 2, h // 2)
    return img


# ---------------------------------------------------------- stress-room materials
# Surfaces of the stress rooms (:mod:`dynslam_lab.datasets.rooms`) in four families: fine noise,
# large flat areas, repeated patterns and photographs (:mod:`dynslam_lab.datasets.photos`), and
# the non-COCO movers (cardboard, painted boards).
def paint_texture(h: int, w: int, rng: np.random.Generator, color, amplitude: float = 0.03) -> np.ndarray:
    """Flat paint: a plain colour with soft stains of relative amplitude ``amplitude`` (a weakly
    textured surface: ORB finds almost nothing on it), ``(h, w, 3)`` float32."""
    n = fractal_noise(h, w, rng, base_cell=max(h, w) / 3, octaves=3, persistence=0.5)
    c = np.asarray(color, np.float32)
    return np.clip(colorize(n, c * (1 - amplitude), c * (1 + amplitude)), 0, 1).astype(np.float32)


def granite_texture(h: int, w: int, rng: np.random.Generator, c0, c1) -> np.ndarray:
    """Fine noise everywhere: granite-like grains of 1-3 texels between colours ``c0`` and ``c1``
    over a faint mottle; dense, high-contrast, without structure above a few texels."""
    grains = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 0.7)
    grains = (grains - grains.min()) / max(float(np.ptp(grains)), 1e-6)
    mottle = fractal_noise(h, w, rng, base_cell=24, octaves=4, persistence=0.8)
    v = np.clip(1.6 * (0.75 * grains + 0.25 * mottle) - 0.3, 0, 1)
    return add_speckle(colorize(v, c0, c1), rng, amount=0.5, scales=(1.0, 2.0), density=0.03)


def brick_texture(h: int, w: int, rng: np.random.Generator, brick: tuple[int, int] = (40, 13), mortar: int = 2,
                  color=(0.62, 0.3, 0.2)) -> np.ndarray:
    """Bricks in running bond, ``brick = (length, height)`` texels, ``mortar`` texels of pale joint; each
    brick a slightly different shade with fine grain: a repeated pattern."""
    bl, bh = brick
    y = np.arange(h)[:, None]
    x = np.arange(w)[None, :]
    row = y // bh
    xs = x + (row % 2) * (bl // 2)
    col = xs // bl
    shade = rng.uniform(0.8, 1.15, (int(row.max()) + 2, int(w // bl) + 3)).astype(np.float32)
    base = np.asarray(color, np.float32) * shade[row, col][..., None]
    grain = fractal_noise(h, w, rng, base_cell=8, octaves=3, persistence=0.7)
    img = base * (0.85 + 0.3 * grain[..., None])
    joint = ((y % bh) < mortar) | ((xs % bl) < mortar)
    img[np.broadcast_to(joint, (h, w))] = (0.72, 0.7, 0.66)
    return np.clip(img, 0, 1).astype(np.float32)


def tile_texture(h: int, w: int, rng: np.random.Generator, tile: int = 48, grout: int = 2, colors=((0.85, 0.85, 0.82),),
                 checker: bool = False) -> np.ndarray:
    """Square tiles of ``tile`` texels with ``grout`` texels of dark joint; one colour (``colors[0]``) or
    a checkerboard of two (``checker``); a repeated pattern with almost no texture inside a tile."""
    y = np.arange(h)[:, None]
    x = np.arange(w)[None, :]
    c0 = np.asarray(colors[0], np.float32)
    c1 = np.asarray(colors[-1], np.float32)
    if checker:
        odd = ((y // tile + x // tile) % 2).astype(bool)
        img = np.where(odd[..., None], c1, c0).astype(np.float32)
    else:
        img = np.broadcast_to(c0, (h, w, 3)).astype(np.float32)
    img = img * (0.96 + 0.08 * fractal_noise(h, w, rng, base_cell=tile, octaves=2)[..., None])
    joint = ((y % tile) < grout) | ((x % tile) < grout)
    img[np.broadcast_to(joint, (h, w))] *= 0.45
    return np.clip(img, 0, 1).astype(np.float32)


def wallpaper_texture(h: int, w: int, rng: np.random.Generator, period: int = 64) -> np.ndarray:
    """Wallpaper: one motif of random shapes drawn in a ``period`` x ``period`` cell and repeated
    exactly (every copy has the same descriptors: a stress for matching), on a two-colour ground."""
    ground = _rand_color(rng, 0.55, 0.9)
    ink = _rand_color(rng, 0.05, 0.45)
    cell = np.broadcast_to(ground, (period, period, 3)).astype(np.float32).copy()
    for _ in range(int(rng.integers(3, 7))):
        c = (int(rng.integers(period)), int(rng.integers(period)))
        r = int(rng.integers(period // 12 + 1, period // 4 + 2))
        col = tuple(float(v) for v in (ink if rng.random() < 0.7 else _rand_color(rng, 0.1, 0.9)))
        kind = int(rng.integers(3))
        if kind == 0:
            cv2.circle(cell, c, r, col, -1, cv2.LINE_AA)
        elif kind == 1:
            cv2.rectangle(cell, (c[0] - r, c[1] - r // 2), (c[0] + r, c[1] + r // 2), col, -1)
        else:
            pts = (np.array(c) + rng.integers(-r, r + 1, (3, 2))).astype(np.int32)
            cv2.fillPoly(cell, [pts], col, cv2.LINE_AA)
    reps = (-(-h // period), -(-w // period), 1)
    return np.tile(cell, reps)[:h, :w].astype(np.float32)


def stripes_texture(h: int, w: int, rng: np.random.Generator, period: int = 24) -> np.ndarray:
    """Bold stripes of two random colours at a random angle (a painted board or a shirt-less mover)."""
    c0, c1 = _rand_color(rng, 0.05, 0.4), _rand_color(rng, 0.6, 0.95)
    a = rng.uniform(0, np.pi)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    v = (np.sin(2 * np.pi * (x * np.cos(a) + y * np.sin(a)) / period) > 0).astype(np.float32)
    img = colorize(cv2.GaussianBlur(v, (0, 0), 0.8), c0, c1)
    return add_speckle(img, rng, amount=0.25)


def cardboard_texture(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Cardboard: brown fibre noise, a band of packing tape, a printed label with text and arrows."""
    base = np.array([0.62, 0.46, 0.3], np.float32) * rng.uniform(0.8, 1.1)
    n = fractal_noise(h, w, rng, base_cell=max(h, w) / 4, octaves=6, persistence=0.6)
    img = colorize(n, base * 0.85, np.minimum(base * 1.12, 1))
    ty = int(rng.uniform(0.35, 0.55) * h)
    img[ty : ty + max(4, h // 10)] = img[ty : ty + max(4, h // 10)] * 0.7 + 0.3 * np.array([0.8, 0.72, 0.55], np.float32)
    lx, ly = int(rng.uniform(0.05, 0.5) * w), int(rng.uniform(0.05, 0.25) * h)
    lw, lh = int(w * rng.uniform(0.25, 0.4)), int(h * rng.uniform(0.15, 0.25))
    cv2.rectangle(img, (lx, ly), (lx + lw, ly + lh), (0.93, 0.93, 0.9), -1)
    add_text(img, rng, (lx + 3, ly, lx + lw - 3, ly + lh), line_height=max(6, lh // 4), fill=0.9)
    for k in range(2):  # "this side up" arrows
        ax = int(w * (0.7 + 0.12 * k))
        cv2.arrowedLine(img, (ax, int(h * 0.9)), (ax, int(h * 0.65)), (0.1, 0.1, 0.1), max(2, w // 80), cv2.LINE_AA,
                        tipLength=0.3)
    return add_speckle(img, rng, amount=0.3)
