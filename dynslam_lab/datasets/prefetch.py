"""Frames read ahead on another core: a reader thread fills a bounded queue.

PNG decoding costs 14-18 ms per 640x480 RGB-D frame, a fifth of a tracked frame. ``cv2.imread``
and ``cv2.cvtColor`` release the GIL, so a reader thread decodes frame ``t + 1 .. t + k`` while the
main thread tracks frame ``t``. A frame that cannot be read is passed on as its error, at its place
in the order, so the caller handles it for that frame only and the run goes on. The thread stops
when the iteration stops (end of sequence, ``break``, an exception in the caller, ``close()``).

Usage::

    with FramePrefetcher(sequence, n_frames=300) as frames:
        for item in frames:          # PrefetchedFrame(index, frame, error, wait_ms)
            if item.error is not None:
                ...                  # that frame only
            else:
                system.process(item.frame)
"""

from __future__ import annotations

import queue
import threading
import time
from dataclasses import dataclass
from typing import Iterator

from .frame import Frame

__all__ = ["PrefetchConfig", "PrefetchedFrame", "FramePrefetcher"]


@dataclass(frozen=True)
class PrefetchConfig:
    """Parameters of the read-ahead.

    Attributes
    ----------
    queue_size : frames decoded ahead of the one being processed (frames; ours). Each 640x480
        RGB-D frame holds ~2.5 MB; 4 is enough to absorb a slow read behind one keyframe.
        0 reads in the calling thread (no thread; the same items in the same order).
    gray : also convert each frame to grey in the reader thread (ORB needs it; ours).
    """

    queue_size: int = 4
    gray: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.queue_size, int) or isinstance(self.queue_size, bool) or self.queue_size < 0:
            raise ValueError(f"PrefetchConfig.queue_size: expected an int >= 0 (frames), got {self.queue_size!r}")
        if not isinstance(self.gray, bool):
            raise ValueError(f"PrefetchConfig.gray: expected a bool, got {self.gray!r}")


@dataclass
class PrefetchedFrame:
    """One item of the iteration.

    Attributes
    ----------
    index : frame index in the sequence.
    frame : the frame, or None when it could not be read.
    error : the exception reading it raised, or None.
    wait_ms : time the consumer waited for this item (ms): the reading the read-ahead did not hide.
    """

    index: int
    frame: Frame | None
    error: Exception | None
    wait_ms: float = 0.0


_END = object()


class FramePrefetcher:
    """Iterate frames ``0 .. n_frames - 1`` of ``sequence`` (anything indexable returning a
    :class:`~dynslam_lab.datasets.frame.Frame`), read ahead by one thread.

    Parameters
    ----------
    sequence : indexable sequence of frames (``sequence[i]``, ``len(sequence)``).
    n_frames : frames to read (default: all).
    config : :class:`PrefetchConfig`.

    Iterate it once; use it as a context manager (or call :meth:`close`) so the reader thread
    stops when the caller stops early.
    """

    def __init__(self, sequence, n_frames: int | None = None, config: PrefetchConfig = PrefetchConfig()) -> None:
        n = len(sequence) if n_frames is None else min(len(sequence), int(n_frames))
        if n < 0:
            raise ValueError(f"FramePrefetcher: n_frames must be >= 0, got {n_frames}")
        self.sequence = sequence
        self.n_frames = n
        self.config = config
        self._stop = threading.Event()
        self._queue: queue.Queue = queue.Queue(maxsize=max(config.queue_size, 1))
        self._thread: threading.Thread | None = None
        self._started = False

    # ------------------------------------------------------------ reading
    def _read(self, index: int) -> PrefetchedFrame:
        try:
            frame = self.sequence[index]
            if self.config.gray:
                _ = frame.gray  # cached on the frame
            return PrefetchedFrame(index, frame, None)
        except Exception as exc:  # passed on: the consumer handles this frame only
            return PrefetchedFrame(index, None, exc)

    def _put(self, item) -> bool:
        """Put unless stopped; False when the consumer has gone."""
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def _worker(self) -> None:
        try:
            for i in range(self.n_frames):
                if self._stop.is_set() or not self._put(self._read(i)):
                    return
        finally:
            self._put(_END)

    # ---------------------------------------------------------- iteration
    def __iter__(self) -> Iterator[PrefetchedFrame]:
        if self._started:
            raise RuntimeError("FramePrefetcher: iterate it only once (make a new one)")
        self._started = True
        if self.config.queue_size == 0:
            yield from self._iter_sync()
            return
        self._thread = threading.Thread(target=self._worker, name="dynslam-prefetch", daemon=True)
        self._thread.start()
        try:
            while True:
                t0 = time.perf_counter()
                item = self._queue.get()
                if item is _END:
                    return
                item.wait_ms = 1e3 * (time.perf_counter() - t0)
                yield item
        finally:
            self.close()

    def _iter_sync(self) -> Iterator[PrefetchedFrame]:
        for i in range(self.n_frames):
            if self._stop.is_set():
                return
            t0 = time.perf_counter()
            item = self._read(i)
            item.wait_ms = 1e3 * (time.perf_counter() - t0)
            yield item

    @property
    def alive(self) -> bool:
        """Whether the reader thread is running."""
        return self._thread is not None and self._thread.is_alive()

    def close(self, timeout: float = 5.0) -> None:
        """Stop the reader thread and wait for it (at most ``timeout`` s; it finishes the frame
        it is decoding)."""
        self._stop.set()
        while True:  # unblock a reader waiting on a full queue
            try:
                self._queue.get_nowait()
            except queue.Empty:
                break
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout)

    def __enter__(self) -> "FramePrefetcher":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
