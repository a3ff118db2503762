"""The per-keypoint table: the spine of dynamic-feature screening.

Every screening stage of the four papers answers one question per keypoint ("is this
point on a moving thing?"). Instead of each stage deleting keypoints, all of them write
into one table with a row per keypoint: its pixel, its depth, the detection (class,
instance) it falls in, one boolean column per stage, a few numeric columns (epipolar
distance, reprojection error, ...) and the final ``dynamic`` verdict with the ``reason``
(the stage that decided it). A notebook shows the table; the tracker keeps the rows with
``dynamic == False``.

Pixels follow ``docs/architecture.md``: ``uv`` float ``(N, 2)``, x right, y down, and a
pixel is looked up at its nearest integer position.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["KeypointTable", "pixel_index", "values_at", "depth_at", "check_uv"]


def check_uv(uv: np.ndarray, name: str = "uv") -> np.ndarray:
    """``uv`` as a float64 ``(N, 2)`` array; a clear ``ValueError`` for any other shape."""
    arr = np.asarray(uv, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2) (pixel x, y), got {arr.shape}")
    return arr


def pixel_index(uv: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest integer pixel of each ``uv`` row.

    Returns
    -------
    rows, cols : ``(N,)`` int64, clipped into the image.
    inside : ``(N,)`` bool, the unclipped pixel lies inside the ``(H, W)`` image.
    """
    uv = check_uv(uv)
    h, w = shape[:2]
    finite = np.isfinite(uv).all(axis=1)
    safe = np.where(finite[:, None], uv, -1.0)
    cols = np.round(safe[:, 0]).astype(np.int64)
    rows = np.round(safe[:, 1]).astype(np.int64)
    inside = finite & (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
    return np.clip(rows, 0, h - 1), np.clip(cols, 0, w - 1), inside


def values_at(image: np.ndarray, uv: np.ndarray, outside=0):
    """Values of ``image (H, W)`` at the nearest pixels of ``uv (N, 2)``; ``outside`` off the image."""
    rows, cols, inside = pixel_index(uv, image.shape)
    out = image[rows, cols]
    if not inside.all():
        out = out.copy()
        out[~inside] = outside
    return out


def depth_at(depth: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Depth ``(N,)`` in metres at pixels ``uv (N, 2)``; ``nan`` where there is no reading
    (0, nan or off the image)."""
    z = values_at(np.asarray(depth), uv, outside=0).astype(np.float64)
    z[~(z > 0)] = np.nan
    return z


@dataclass
class KeypointTable:
    """One row per keypoint of a frame, filled by the screening stages.

    Attributes
    ----------
    uv : ``(N, 2)`` float64 pixels.
    depth : ``(N,)`` float64 metres at the keypoint, ``nan`` where the sensor has none.
    class_id : ``(N,)`` int64 COCO class of the detection the keypoint falls in, -1 for none.
    instance : ``(N,)`` int64 index of that detection in the frame's ``Detections``, -1 for none.
    motion_prob : ``(N,)`` float64 prior motion probability of the class (ASG-SLAM, Ge et al. 2024), 0 for none.
    stages : stage name -> ``(N,)`` bool, the keypoints that stage judged dynamic, in run order.
    values : column name -> ``(N,)`` float64 measurements behind the verdicts
        (``epipolar_px``, ``reprojection_px``, ``depth_error_m``, ...), ``nan`` where not measured.
    restored : ``(N,)`` bool, keypoints given back by motion-probability restoration.
    dynamic : ``(N,)`` bool, the final verdict; the tracker uses the rows where it is False.
    reason : ``(N,)`` str, the stage that made a keypoint dynamic (``""`` for static,
        ``"restored"`` for keypoints given back).
    region_mask : ``(H, W)`` bool pixels judged dynamic (for the dense map), or None.
    timings_ms : stage name -> milliseconds spent on this frame.
    """

    uv: np.ndarray
    depth: np.ndarray
    class_id: np.ndarray
    instance: np.ndarray
    motion_prob: np.ndarray
    dynamic: np.ndarray
    reason: np.ndarray
    stages: dict[str, np.ndarray] = field(default_factory=dict)
    values: dict[str, np.ndarray] = field(default_factory=dict)
    restored: np.ndarray | None = None
    region_mask: np.ndarray | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.uv = check_uv(self.uv)
        n = len(self.uv)
        self.depth = np.asarray(self.depth, np.float64).reshape(-1)
        self.class_id = np.asarray(self.class_id, np.int64).reshape(-1)
        self.instance = np.asarray(self.instance, np.int64).reshape(-1)
        self.motion_prob = np.asarray(self.motion_prob, np.float64).reshape(-1)
        self.dynamic = np.asarray(self.dynamic, bool).reshape(-1)
        self.reason = np.asarray(self.reason, dtype=object).reshape(-1)
        if self.restored is None:
            self.restored = np.zeros(n, bool)
        cols = {"depth": self.depth, "class_id": self.class_id, "instance": self.instance,
                "motion_prob": self.motion_prob, "dynamic": self.dynamic, "reason": self.reason,
                "restored": self.restored}
        cols.update({f"stage {k}": v for k, v in self.stages.items()})
        cols.update({f"value {k}": v for k, v in self.values.items()})
        for name, col in cols.items():
            if len(col) != n:
                raise ValueError(f"KeypointTable: column {name!r} has {len(col)} rows, uv has {n}")

    @classmethod
    def blank(cls, uv: np.ndarray, depth: np.ndarray | None = None) -> "KeypointTable":
        """A table with every keypoint static and no detection (the ``none`` filter)."""
        uv = check_uv(uv)
        n = len(uv)
        return cls(
            uv=uv,
            depth=np.full(n, np.nan) if depth is None else depth,
            class_id=np.full(n, -1), instance=np.full(n, -1), motion_prob=np.zeros(n),
            dynamic=np.zeros(n, bool), reason=np.full(n, "", dtype=object),
        )

    def __len__(self) -> int:
        return len(self.uv)

    @property
    def static(self) -> np.ndarray:
        """``(N,)`` bool, the keypoints the tracker may use."""
        return ~self.dynamic

    @property
    def n_dynamic(self) -> int:
        return int(self.dynamic.sum())

    def to_dataframe(self):
        """A pandas DataFrame with one row per keypoint (``u``, ``v``, depth, class, instance,
        motion_prob, one column per stage and value, ``restored``, ``dynamic``, ``reason``)."""
        import pandas as pd  # heavy (~0.3 s): only for the notebooks' table view

        data = {"u": self.uv[:, 0], "v": self.uv[:, 1], "depth_m": self.depth, "class_id": self.class_id,
                "instance": self.instance, "motion_prob": self.motion_prob}
        data.update(self.stages)
        data.update(self.values)
        data["restored"] = self.restored
        data["dynamic"] = self.dynamic
        data["reason"] = self.reason.astype(str)
        return pd.DataFrame(data)
