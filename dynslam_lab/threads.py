"""Thread settings of the numerical libraries, set deliberately in one place."""

from __future__ import annotations

import contextlib

from threadpoolctl import threadpool_limits

__all__ = ["blas_single_thread"]


def blas_single_thread() -> contextlib.AbstractContextManager:
    """A context limiting BLAS to one thread.

    The optimisation problems of SLAM are small; a multi-threaded BLAS on a shared machine spends
    more time waiting for its threads than computing (local BA measured 10x slower)."""
    return threadpool_limits(limits=1, user_api="blas")
