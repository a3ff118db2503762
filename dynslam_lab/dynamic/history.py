"""The screener's memory of earlier frames: images, depth, poses and verdicts.

The two-frame checks of the papers need the previous frame; the multi-frame check (DynaSLAM,
Bescos et al. 2018) and the temporal prior need several earlier ones. The screener keeps the
last ``length`` frames it screened (:class:`PastFrame`: grey image, depth,
the reduced depth of the dense tests, the dynamic region it judged) and learns their poses from
the SLAM system afterwards: each :class:`~dynslam_lab.dynamic.context.ScreeningContext` carries
the poses of the last tracked frames, keyed by timestamp, and :meth:`FrameHistory.update_poses`
writes them into the matching entries (so poses corrected by local BA or a loop closure replace
the old ones; an entry the system did not track keeps no pose and is never used as a reference).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = ["PastFrame", "FrameHistory", "FarFrame", "FarFrames", "reduce_depth"]


def reduce_depth(depth: np.ndarray, factor: int, max_spread: float = 0.05, min_valid: float = 0.25) -> np.ndarray:
    """Depth image reduced ``factor`` times per side: the mean of the valid readings of each block.

    A block whose valid readings have a standard deviation above ``max_spread`` times their mean
    (it straddles a depth edge) or with fewer than ``min_valid`` of its pixels read gets 0 (no reading), so that no
    reduced pixel floats between a foreground and a background surface. Returns
    ``(H // factor, W // factor)`` float32 metres (block means by ``cv2.resize`` ``INTER_AREA``).
    """
    d = np.asarray(depth, np.float32)
    h, w = d.shape
    hs, ws = h // factor, w // factor
    d = np.ascontiguousarray(d[: hs * factor, : ws * factor])
    size = (ws, hs)
    # two full-size temporaries only (each costs its page faults): 1 where read, then d^2 in the same buffer
    buf = cv2.threshold(d, 0.0, 1.0, cv2.THRESH_BINARY)[1]
    frac = cv2.resize(buf, size, interpolation=cv2.INTER_AREA)
    d = cv2.threshold(d, 0.0, 0.0, cv2.THRESH_TOZERO)[1]  # 0 where no reading (nan too)
    s1 = cv2.resize(d, size, interpolation=cv2.INTER_AREA)
    np.multiply(d, d, out=buf)
    s2 = cv2.resize(buf, size, interpolation=cv2.INTER_AREA)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = s1 / frac
        var = s2 / frac - mean * mean
    ok = (frac >= min_valid) & (var <= (max_spread * mean) ** 2)
    return np.where(ok, mean, 0.0).astype(np.float32)


@dataclass(eq=False)
class PastFrame:
    """One screened frame kept for later frames.

    Attributes
    ----------
    index, timestamp : the frame.
    gray : ``(H, W)`` uint8.
    depth : ``(H, W)`` float32 metres.
    small_depth : reduced depth of the dense tests (None until first needed).
    region : ``(h, w)`` bool dynamic pixels judged at that frame on the reduced grid, or None.
    T_w_c : ``(4, 4)`` pose from the SLAM system once known, else None.
    """

    index: int
    timestamp: float
    gray: np.ndarray
    depth: np.ndarray
    small_depth: np.ndarray | None = None
    region: np.ndarray | None = None
    T_w_c: np.ndarray | None = None
    cache: dict = field(default_factory=dict)


class _Kept:
    """Frames kept in a bounded deque, oldest first: length, iteration, ``clear``."""

    _frames: deque

    def __len__(self) -> int:
        return len(self._frames)

    def __iter__(self):
        return iter(self._frames)

    def clear(self) -> None:
        self._frames.clear()


class FrameHistory(_Kept):
    """The last ``length`` screened frames, newest last."""

    def __init__(self, length: int) -> None:
        if length < 1:
            raise ValueError(f"FrameHistory: length must be >= 1, got {length}")
        self.length = int(length)
        self._frames: deque[PastFrame] = deque(maxlen=self.length)

    @property
    def last(self) -> PastFrame | None:
        return self._frames[-1] if self._frames else None

    def push(self, frame: PastFrame) -> PastFrame | None:
        """Keep ``frame``; returns the oldest frame when it falls out of the history, else None."""
        evicted = self._frames[0] if len(self._frames) == self.length else None
        self._frames.append(frame)
        return evicted

    def update_poses(self, poses: dict[float, np.ndarray]) -> np.ndarray | None:
        """Set the pose of every kept frame whose timestamp is in ``poses`` (T_w_c by timestamp).

        Returns the correction ``T_new T_old^-1`` of the oldest kept frame that had a pose (what local BA
        or a loop closure did to the world around it: the screener drops its far frames after a large one),
        or None when no known pose changed."""
        if not poses:
            return None
        correction = None
        for f in self._frames:
            T = poses.get(float(f.timestamp))
            if T is not None:
                T = np.asarray(T, np.float64)
                if correction is None and f.T_w_c is not None:
                    correction = T @ np.linalg.inv(f.T_w_c)
                f.T_w_c = T
        if correction is not None and np.allclose(correction, np.eye(4), atol=1e-9):
            return None
        return correction

    def back(self, offset: int) -> PastFrame | None:
        """The frame ``offset`` positions before the newest one would be pushed (1 = the last one)."""
        if offset < 1 or offset > len(self._frames):
            return None
        return self._frames[-offset]

    def with_pose(self, offsets) -> list[PastFrame]:
        """Kept frames at these offsets (1 = last) that have a pose, each at most once, newest first.
        Where the frame at an offset has no pose, the nearest older frame with one stands in."""
        out: list[PastFrame] = []
        seen: set[int] = set()
        n = len(self._frames)
        for o in sorted(set(int(o) for o in offsets)):
            for k in range(o, n + 1):
                f = self._frames[-k]
                if f.T_w_c is not None:
                    if id(f) not in seen:
                        seen.add(id(f))
                        out.append(f)
                    break
        return out


@dataclass(eq=False)
class FarFrame:
    """A frame kept beyond the history for the free-space test (:mod:`.multiframe`): only its
    reduced depth, eroded (``(h, w)`` float32 m), and its pose (``T_w_c``, as last known)."""

    index: int
    T_w_c: np.ndarray
    depth_min: np.ndarray


class FarFrames(_Kept):
    """Frames older than the history, one every ``every`` frames, the last ``count`` of them: what
    the place looked like before a slow mover got there (ours; ``docs/robustness.md``)."""

    def __init__(self, every: int, count: int) -> None:
        if every < 1 or count < 0:
            raise ValueError(f"FarFrames: every >= 1 and count >= 0 required, got every={every}, count={count}")
        self.every = int(every)
        self._frames: deque[FarFrame] = deque(maxlen=max(int(count), 1))
        self.count = int(count)

    def offer(self, index: int, T_w_c: np.ndarray | None, depth_min) -> bool:
        """Keep a frame leaving the history when it has a pose and ``every`` frames passed since the
        last one kept; ``depth_min`` is called only then (it computes the eroded reduced depth)."""
        if self.count == 0 or T_w_c is None:
            return False
        if self._frames and index - self._frames[-1].index < self.every:
            return False
        self._frames.append(FarFrame(int(index), np.asarray(T_w_c, np.float64).copy(), np.asarray(depth_min(), np.float32)))
        return True
