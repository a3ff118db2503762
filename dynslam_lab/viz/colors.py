"""One colour scheme for every figure: matplotlib plots, notebooks and the 3D viewer.

A reader who learns in notebook 00 that the estimate is red and the ground truth near-black
finds the same colours in the 3D view (``dynslam view``) and in every later notebook. The
scheme is documented once, in ``docs/notebooks.md`` ("Colours").

* trajectories and cameras: ``estimate``, ``ground_truth``, ``keyframe``, ``current`` (the
  playback frame of the viewer), ``loop`` (loop-closure edges);
* keypoint verdicts: ``static``, ``dynamic``;
* screening stages, the stage that flagged a keypoint: ``semantic``, ``depth_ransac``,
  ``epipolar``, ``multiview``, ``flow``, ``level_rule``, ``restored``, ``oracle``;
* filters of a SLAM run (``dynslam run --filters``), for comparisons of several runs:
  :data:`FILTERS`.

Colours are stored once as 0-255 RGB tuples (what viser takes); :func:`hex_color` gives the
matplotlib form. Instance masks are drawn by :func:`instance_colors`: moving people in
saturated colours, everything else in greys, so that the people stand out whatever their ids.
"""

from __future__ import annotations

from typing import Iterable, Mapping

import numpy as np

__all__ = ["PALETTE", "STAGES", "FILTERS", "rgb", "hex_color", "filter_color", "instance_colors", "MOVER_COLORS"]

#: Every named colour, 0-255 RGB.
PALETTE: dict[str, tuple[int, int, int]] = {
    # trajectories and cameras
    "estimate": (230, 40, 30),  # red
    "ground_truth": (40, 40, 40),  # near-black (dashed in matplotlib)
    "keyframe": (255, 150, 0),  # orange
    "current": (0, 90, 220),  # blue: the frame the viewer's playback is at
    "loop": (0, 160, 160),  # teal
    # keypoint verdicts
    "static": (44, 160, 44),  # green
    "dynamic": (220, 0, 220),  # magenta
    # screening stages (the stage that flagged a keypoint)
    "semantic": (214, 39, 40),  # red: on an a-priori dynamic detection
    "depth_ransac": (255, 127, 14),  # orange
    "epipolar": (148, 103, 189),  # purple
    "multiview": (31, 119, 180),  # blue
    "flow": (227, 119, 194),  # pink
    "level_rule": (140, 86, 75),  # brown
    "restored": (23, 190, 207),  # cyan: given back by motion-probability restoration
    "oracle": (0, 0, 0),  # black: the renderer's truth
}

#: The screening stages in run order (``dynamic.screening``), each a key of :data:`PALETTE`.
STAGES = ("semantic", "depth_ransac", "epipolar", "multiview", "flow", "level_rule", "restored", "oracle")

#: Colour of each filter preset of ``dynslam run --filters`` (keys of :data:`PALETTE`).
FILTERS = {
    "none": (130, 130, 130),  # grey: no screening
    "semantic": PALETTE["semantic"],
    "depth_ransac": PALETTE["depth_ransac"],
    "geometry": PALETTE["epipolar"],
    "full": PALETTE["multiview"],
    "oracle": PALETTE["restored"],
}

#: Colours of moving people in instance images, one per person (saturated, far from grey).
MOVER_COLORS = ((220, 0, 220), (255, 127, 14), (0, 170, 230), (230, 200, 0), (214, 39, 40), (0, 180, 100))


def rgb(name: str) -> tuple[int, int, int]:
    """0-255 RGB of a named colour (a key of :data:`PALETTE`); a clear error otherwise."""
    try:
        return PALETTE[name]
    except KeyError:
        raise KeyError(f"no colour named {name!r}; known: {', '.join(PALETTE)}") from None


def hex_color(name_or_rgb: str | Iterable[int]) -> str:
    """Matplotlib ``'#rrggbb'`` of a named colour or a 0-255 RGB triple."""
    c = rgb(name_or_rgb) if isinstance(name_or_rgb, str) else tuple(int(x) for x in name_or_rgb)
    if len(c) != 3 or not all(0 <= x <= 255 for x in c):
        raise ValueError(f"hex_color: expected three values in 0..255, got {c}")
    return "#{:02x}{:02x}{:02x}".format(*c)


def filter_color(name: str) -> str:
    """Matplotlib colour of a filter preset (``none``, ``semantic``, ... ``oracle``); grey for others."""
    return hex_color(FILTERS.get(name, (100, 100, 100)))


def instance_colors(mask: np.ndarray, movers: Iterable[int] = (), classes: Mapping[int, str] | None = None) -> np.ndarray:
    """An ``(H, W, 3)`` uint8 image of an instance-id mask in which the movers stand out.

    Parameters
    ----------
    mask : ``(H, W)`` integer instance ids (0 = background).
    movers : ids of the instances that move in this frame: drawn in :data:`MOVER_COLORS`,
        in the order given.
    classes : id -> class name; instances of class ``person`` that do not move are drawn in
        a light purple-grey (people who stand still), all other ids in greys that differ
        from id to id (a fixed function of the id, so two frames agree).

    Returns
    -------
    uint8 RGB image.
    """
    m = np.asarray(mask)
    if m.ndim != 2:
        raise ValueError(f"instance_colors: mask must be (H, W), got shape {m.shape}")
    ids = np.unique(m)
    # greys 90..215 that differ between neighbouring ids (multiplicative hash of the id)
    lut_ids = ids.astype(np.int64)
    grey = 90 + ((lut_ids * 2654435761) % 126)
    colors = np.repeat(grey[:, None], 3, axis=1).astype(np.uint8)
    colors[lut_ids == 0] = (245, 245, 245)
    if classes:
        for k, i in enumerate(lut_ids):
            if classes.get(int(i)) == "person":
                colors[k] = (190, 170, 200)
    for n, i in enumerate(movers):
        colors[lut_ids == int(i)] = MOVER_COLORS[n % len(MOVER_COLORS)]
    return colors[np.searchsorted(ids, m)]
