"""benchmarks/thread_cpu.py: each thread's CPU, named by the Python thread that runs on it."""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import thread_cpu  # noqa: E402


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads /proc (Linux)")
def test_the_busy_thread_is_charged_and_the_idle_one_is_not():
    stop = threading.Event()

    def busy():  # pure Python: this thread's CPU only, whatever the BLAS
        t0 = time.thread_time()
        while time.thread_time() - t0 < 0.6:
            sum(range(1000))

    worker = threading.Thread(target=busy, name="burner_0")
    idle = threading.Thread(target=stop.wait, name="sleeper")
    with thread_cpu.ThreadSampler(period_s=0.05) as s:
        idle.start()
        worker.start()
        worker.join()
        stop.set()
        idle.join()
    per = s.by_name()
    assert 0.5 <= per["burner"] <= 1.0  # the pool-style suffix "_0" folded into the name; the last sample at exit
    assert per["sleeper"] < 0.05


def test_usage_without_out_prints_the_help(capsys):
    assert thread_cpu.main([]) == 2
    assert "--out" in capsys.readouterr().out
