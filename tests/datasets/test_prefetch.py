"""The read-ahead of frames: order, a bad frame reported for that frame only, the reader thread
stopping with the iteration, and the same items without a thread."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from dynslam_lab.camera import PinholeCamera
from dynslam_lab.datasets.frame import Frame
from dynslam_lab.datasets.prefetch import FramePrefetcher, PrefetchConfig

CAM = PinholeCamera(500.0, 500.0, 16.0, 12.0, 32, 24)


class FakeSequence:
    """Frames whose grey level is their index; reading ``bad`` raises; counts the reads."""

    def __init__(self, n: int, bad: tuple[int, ...] = (), delay: float = 0.0) -> None:
        self.n, self.bad, self.delay = n, set(bad), delay
        self.reads: list[int] = []

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> Frame:
        self.reads.append(i)
        if self.delay:
            time.sleep(self.delay)
        if i in self.bad:
            raise OSError(f"frame {i}: cannot decode")
        rgb = np.full((24, 32, 3), i % 256, np.uint8)
        return Frame(index=i, timestamp=i / 30.0, rgb=rgb, depth=np.ones((24, 32), np.float32), camera=CAM)


def _reader_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "dynslam-prefetch"]


@pytest.mark.parametrize("queue_size", [0, 1, 4])
def test_order_and_a_bad_frame_for_that_frame_only(queue_size):
    seq = FakeSequence(40, bad=(7, 8, 30))
    with FramePrefetcher(seq, config=PrefetchConfig(queue_size=queue_size)) as frames:
        items = list(frames)
    assert [it.index for it in items] == list(range(40))
    for it in items:
        if it.index in (7, 8, 30):
            assert it.frame is None and isinstance(it.error, OSError) and f"frame {it.index}" in str(it.error)
        else:
            assert it.error is None and it.frame.index == it.index
            assert it.frame.__dict__["_gray"][0, 0] == it.index  # grey made by the reader
        assert it.wait_ms >= 0
    assert not _reader_threads()


def test_n_frames_limits_the_reads():
    seq = FakeSequence(30)
    items = list(FramePrefetcher(seq, n_frames=10, config=PrefetchConfig(queue_size=3)))
    assert [it.index for it in items] == list(range(10)) and max(seq.reads) == 9


def test_thread_stops_when_the_caller_stops():
    seq = FakeSequence(1000, delay=0.001)
    with FramePrefetcher(seq, config=PrefetchConfig(queue_size=2)) as frames:
        for it in frames:
            if it.index == 5:
                break
    assert not _reader_threads()
    assert max(seq.reads) <= 5 + 2 + 2  # read ahead at most the queue (+ the one in hand)
    # An exception in the caller stops it too.
    seq = FakeSequence(1000, delay=0.001)
    with pytest.raises(RuntimeError, match="caller"):
        with FramePrefetcher(seq, config=PrefetchConfig(queue_size=2)) as frames:
            for it in frames:
                if it.index == 3:
                    raise RuntimeError("caller failed")
    assert not _reader_threads() and max(seq.reads) <= 3 + 4


def test_reads_ahead_while_the_caller_works():
    """While the caller holds frame 0, the reader fills the queue (frames 1..4) and no further."""
    seq = FakeSequence(50)
    with FramePrefetcher(seq, config=PrefetchConfig(queue_size=4)) as frames:
        it = iter(frames)
        assert next(it).index == 0
        deadline = time.monotonic() + 10
        while len(seq.reads) < 6 and time.monotonic() < deadline:
            time.sleep(0.005)
        time.sleep(0.05)
        assert seq.reads == list(range(6))  # 4 queued + 1 blocked on the full queue
        assert [x.index for x in it] == list(range(1, 50))


def test_config_validation():
    with pytest.raises(ValueError, match="queue_size"):
        PrefetchConfig(queue_size=-1)
    with pytest.raises(ValueError, match="gray"):
        PrefetchConfig(gray=1)
    with pytest.raises(RuntimeError, match="once"):
        p = FramePrefetcher(FakeSequence(2))
        list(p)
        list(p)
