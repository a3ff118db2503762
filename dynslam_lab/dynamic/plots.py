"""Matplotlib views of a keypoint table: keypoints coloured by verdict and by reason.

Used by the notebooks ``04``-``07`` (and ``10_when_screening_fails``); kept here so that each notebook cell stays
short. ``draw_grid`` shows the reduced-grid evidence of the geometry stages.
"""

from __future__ import annotations

import numpy as np

__all__ = ["REASON_COLOURS", "draw_keypoints", "draw_table", "draw_grid"]

#: Colour of each reason (``""`` = static).
REASON_COLOURS = {
    "": "#2ca02c",  # static: green
    "semantic": "#d62728",  # red
    "depth_ransac": "#ff7f0e",  # orange
    "epipolar": "#9467bd",  # purple
    "multiview": "#1f77b4",  # blue
    "multiframe": "#bcbd22",  # olive
    "flow": "#e377c2",  # pink
    "temporal": "#7f3c8d",  # plum
    "regions": "#fdae61",  # light orange
    "level_rule": "#8c564b",  # brown
    "restored": "#17becf",  # cyan
    "oracle": "#000000",
}


def draw_keypoints(ax, image: np.ndarray, uv: np.ndarray, dynamic: np.ndarray, title: str = "", size: float = 9):
    """Image with keypoints ``uv (N, 2)``: red dynamic, green static."""
    ax.imshow(image, cmap="gray" if image.ndim == 2 else None)
    dynamic = np.asarray(dynamic, bool)
    ax.scatter(uv[~dynamic, 0], uv[~dynamic, 1], s=size, c="#2ca02c", label=f"static ({(~dynamic).sum()})")
    ax.scatter(uv[dynamic, 0], uv[dynamic, 1], s=size, c="#d62728", label=f"dynamic ({dynamic.sum()})")
    ax.set_title(title)
    ax.legend(loc="lower right", fontsize=7)
    ax.set_axis_off()


def draw_table(ax, image: np.ndarray, table, title: str = "", size: float = 9, region_alpha: float = 0.25):
    """Image, the table's region mask (tinted) and its keypoints coloured by ``reason``."""
    ax.imshow(image, cmap="gray" if image.ndim == 2 else None)
    if table.region_mask is not None and table.region_mask.any():
        tint = np.zeros((*table.region_mask.shape, 4))
        tint[table.region_mask] = (1.0, 0.0, 0.0, region_alpha)
        ax.imshow(tint)
    reasons = table.reason.astype(str)
    for r in dict.fromkeys(reasons):
        sel = reasons == r
        ax.scatter(table.uv[sel, 0], table.uv[sel, 1], s=size, c=REASON_COLOURS.get(r, "#7f7f7f"),
                   label=f"{r or 'static'} ({sel.sum()})")
    ax.set_title(title)
    ax.legend(loc="lower right", fontsize=7)
    ax.set_axis_off()


def draw_grid(ax, image: np.ndarray, fresh: np.ndarray, static: np.ndarray | None, region: np.ndarray | None,
              vanished: np.ndarray | None = None, title: str = "", alpha: float = 0.45):
    """The reduced-grid evidence of the geometry stages over the image: fresh evidence (white), cells
    confirmed static (green), background just uncovered (yellow) and the grown dynamic region (red)."""
    h, w = image.shape[:2]
    ax.imshow(image, cmap="gray" if image.ndim == 2 else None)
    layers = [(static, (0.1, 0.7, 0.2)), (vanished, (1.0, 0.85, 0.0)), (region, (0.9, 0.1, 0.1)), (fresh, (1.0, 1.0, 1.0))]
    for cells, colour in layers:
        if cells is None or not np.any(cells):
            continue
        tint = np.zeros((*np.asarray(cells).shape, 4))
        tint[np.asarray(cells, bool)] = (*colour, alpha)
        ax.imshow(tint, extent=(-0.5, w - 0.5, h - 0.5, -0.5), interpolation="nearest")
    ax.set_title(title)
    ax.set_axis_off()
