"""CPU time of each thread of a ``dynslam run``: where a frame's work goes when the stages overlap.

Usage::

    python benchmarks/thread_cpu.py SEQDIR --out OUT [any other ``dynslam run`` option]
    python benchmarks/thread_cpu.py ../seq/walking_xyz --out /tmp/r --filters full --detector onnx:yolox_nano.onnx

Runs ``dynslam run`` in this process and samples, every 0.2 s, the CPU time the kernel has charged to each
of its threads (``/proc/self/task/TID/stat``, user + system), naming each by the Python thread that runs on
it (``dynslam-detect``, ``dynslam-orb``, ``dynslam-screen``, ``dynslam-prefetch``, the main thread, ...);
threads no Python code runs on (onnxruntime's and OpenCV's own pools) are summed as ``native``. Prints a
table of seconds and milliseconds per frame. ``timing.csv`` says how long each stage *waited*; this says
how much *work* each thread did: when the sum over threads is about twice the wall time on two cores, both
are busy and only less work makes a frame faster (docs/speed.md). The main thread's figure includes the
start-up (imports, loading a model: ~2 s). Linux only. A thread that ends between two samples loses its
last 0.2 s at most.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from collections import Counter
from pathlib import Path


def _task_cpu() -> dict[int, float]:
    """CPU seconds (user + system) of each thread of this process, by kernel thread id."""
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:  # the thread ended meanwhile
            continue
        out[int(tid)] = (int(fields[11]) + int(fields[12])) / tick  # utime, stime (fields 14 and 15 of stat)
    return out


class ThreadSampler:
    """Samples :func:`_task_cpu` in a daemon thread; remembers each thread's last CPU time and name."""

    def __init__(self, period_s: float = 0.2) -> None:
        self.period_s = period_s
        self.cpu: dict[int, float] = {}
        self.names: dict[int, str] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="thread-cpu-sampler", daemon=True)

    def _sample(self) -> None:
        for t in threading.enumerate():
            if t.native_id is not None:
                self.names[t.native_id] = t.name
        self.cpu.update(_task_cpu())

    def _loop(self) -> None:
        while not self._stop.wait(self.period_s):
            self._sample()

    def __enter__(self) -> "ThreadSampler":
        self._sample()
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self._sample()

    def by_name(self) -> Counter:
        """CPU seconds per thread name (a pool's workers ``NAME_0``, ``NAME_1`` summed as ``NAME``)."""
        out: Counter = Counter()
        for tid, s in self.cpu.items():
            name = self.names.get(tid, "native")
            base, _, suffix = name.rpartition("_")
            out[base if base and suffix.isdigit() else name] += s
        return out


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help") or "--out" not in argv:
        print(__doc__)
        return 0 if argv and argv[0] in ("-h", "--help") else 2
    from dynslam_lab.cli import main as dynslam_main

    t0 = time.perf_counter()
    with ThreadSampler() as sampler:
        code = dynslam_main(["run", *argv])
    wall = time.perf_counter() - t0
    out = Path(argv[argv.index("--out") + 1])
    frames = json.loads((out / "summary.json").read_text()).get("frames", 0) if (out / "summary.json").is_file() else 0
    per = sampler.by_name()
    sampler_s = per.pop("thread-cpu-sampler", 0.0)
    total = sum(per.values())
    print(f"\nthread CPU of `dynslam run {' '.join(argv)}`: {frames} frames, {wall:.1f} s wall, {total:.1f} s CPU "
          f"({total / max(wall, 1e-9):.2f} cores; the sampler's own {sampler_s:.2f} s left out)")
    print(f"{'thread':<24} {'CPU s':>8} {'ms/frame':>9} {'share':>6}")
    for name, s in per.most_common():
        print(f"{name:<24} {s:8.2f} {1e3 * s / max(frames, 1):9.1f} {100 * s / max(total, 1e-9):5.1f}%")
    print(f"{'all':<24} {total:8.2f} {1e3 * total / max(frames, 1):9.1f}")
    return int(code or 0)


if __name__ == "__main__":
    sys.exit(main())
