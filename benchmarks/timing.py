"""Timing helper shared by the benchmark scripts (run as ``python benchmarks/<script>.py``)."""

from __future__ import annotations

import time

import numpy as np


def per_frame(fn, n: int, repeat: int = 3) -> float:
    """Median over ``repeat`` runs of the mean time of ``n`` calls ``fn(i)`` [s], after one warm-up call."""
    fn(0)  # warm-up (GL context, caches)
    runs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for i in range(n):
            fn(i)
        runs.append((time.perf_counter() - t0) / n)
    return float(np.median(runs))
