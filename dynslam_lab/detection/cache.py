"""Detections saved per frame (npz) and read back, so sweeps do not rerun the network.

Layout of a cache directory::

    DIR/
      1341846313.553992.npz    one file per frame, named by the colour timestamp (6 decimals)
      ...

Each file holds ``boxes (N, 4) float32``, ``scores (N,) float32``, ``class_ids (N,) int64``,
``image_size (2,) int64``, ``source`` (str), and when the detector gave masks,
``masks_packed`` (the ``(N, H, W)`` bool masks packed 8 pixels per byte with
``numpy.packbits``; a person mask costs ~40 kB, a box-only frame a few hundred bytes).

:class:`CacheDetector` reads such a directory; with ``fallback`` (any detector) it runs the
fallback on a cache miss and writes the result, so the first pass over a sequence fills the
cache and later passes are free.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..datasets.frame import Frame
from .config import DetectionConfig
from .detections import Detections

__all__ = ["save_detections", "load_detections", "cache_key", "CacheDetector"]


def cache_key(frame: Frame) -> str:
    """File stem of a frame in a cache: its timestamp with 6 decimals (TUM's precision)."""
    return f"{frame.timestamp:.6f}"


def save_detections(path: str | Path, det: Detections) -> Path:
    """Write ``det`` to ``path`` (``.npz`` appended if missing); parent folders are created."""
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_name(path.name + ".npz")
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = dict(
        boxes=det.boxes.astype(np.float32),
        scores=det.scores.astype(np.float32),
        class_ids=det.class_ids.astype(np.int64),
        image_size=np.asarray(det.image_size, dtype=np.int64),
        source=np.asarray(det.source),
    )
    if det.masks is not None:
        h, w = det.image_size
        arrays["masks_packed"] = np.packbits(det.masks.reshape(len(det), h * w), axis=1)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    tmp.replace(path)  # atomic: an interrupted run never leaves a half-written cache file
    return path


def load_detections(path: str | Path) -> Detections:
    """Read a file written by :func:`save_detections`; clear error naming a bad file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: detection cache file not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            h, w = (int(v) for v in z["image_size"])
            n = len(z["scores"])
            masks = None
            if "masks_packed" in z.files:
                masks = np.unpackbits(z["masks_packed"], axis=1, count=h * w).reshape(n, h, w).astype(bool)
            return Detections(
                z["boxes"], z["scores"], z["class_ids"], (h, w), masks=masks, source=str(z["source"])
            )
    except (KeyError, ValueError, OSError) as exc:
        raise ValueError(f"{path}: not a detection cache file ({exc})") from exc


class CacheDetector:
    """Detections read from a cache directory (see the module docstring).

    Parameters
    ----------
    directory : the cache folder.
    fallback : a detector run on a cache miss (its result is then saved); None makes a
        miss an error naming the missing file.
    config : the detection parameters of the run (recorded with it; the fallback's when given).
    """

    def __init__(self, directory: str | Path, fallback=None, config: DetectionConfig | None = None) -> None:
        self.directory = Path(directory)
        self.fallback = fallback
        self.config = fallback.config if fallback is not None else (config or DetectionConfig())
        if fallback is None and not self.directory.is_dir():
            raise FileNotFoundError(f"{self.directory}: detection cache directory not found")
        self.source = f"cache:{self.directory}"
        self.hits = 0
        self.misses = 0

    def path_for(self, frame: Frame) -> Path:
        return self.directory / f"{cache_key(frame)}.npz"

    def detect(self, frame: Frame) -> Detections:
        path = self.path_for(frame)
        if path.is_file():
            self.hits += 1
            det = load_detections(path)
            if det.image_size != tuple(frame.shape):
                raise ValueError(f"{path}: cached for a {det.image_size} image, frame is {tuple(frame.shape)}")
            return det
        if self.fallback is None:
            raise FileNotFoundError(
                f"{path}: no cached detections for frame {frame.index} (t = {frame.timestamp:.6f})"
            )
        self.misses += 1
        det = self.fallback.detect(frame)
        save_detections(path, det)
        return det
