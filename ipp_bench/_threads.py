"""CPUs and BLAS threading for the many small matrix products of the belief updates.

A Kalman update on a 15 x 15 map multiplies matrices of a few hundred rows: OpenBLAS threads
only add hand-over cost there, and on a busy 2-core machine they made an env step 10-30x slower
(8 ms instead of 0.5 ms, measured). ipp-bench therefore runs numpy/scipy BLAS on one thread per
process (parallelism comes from running episodes in parallel). ``IPP_BENCH_BLAS_THREADS=N``
overrides it; torch's own thread pool is left alone.
"""

from __future__ import annotations

import os

_applied = False


def available_cpus() -> int:
    """CPUs this process may run on (the affinity mask where the OS has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover (macOS, Windows)
        return max(1, os.cpu_count() or 1)


def limit_blas_threads() -> None:
    """Apply the BLAS thread limit once per process (idempotent)."""
    global _applied
    if _applied:
        return
    raw = os.environ.get("IPP_BENCH_BLAS_THREADS", "1")
    try:
        n = int(raw)
        if n < 1:
            raise ValueError
    except ValueError:
        raise ValueError(f"IPP_BENCH_BLAS_THREADS={raw!r} is invalid: expected an integer >= 1") from None
    import scipy.linalg  # noqa: F401  (load scipy's BLAS so that the limit reaches it too)
    from threadpoolctl import ThreadpoolController

    controller = ThreadpoolController()
    for lib in controller.lib_controllers:
        if lib.user_api == "blas" and "torch" not in lib.filepath:
            lib.set_num_threads(n)
    _applied = True
