"""The one timing helper the benchmarks share."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

__all__ = ["best_time"]


def best_time(fn: Callable[[], object], repeats: int) -> float:
    """The shortest wall time (s) of ``repeats`` calls of ``fn``."""
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best
