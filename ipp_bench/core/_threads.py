"""CPUs and BLAS threading for the many small matrix products of the belief updates.

A Kalman update on a 15 x 15 map multiplies matrices of a few hundred rows: OpenBLAS threads
only add hand-over cost there, and on a busy machine they make an env step many times slower
(``benchmarks/RESULTS.md``). ipp-bench therefore runs numpy/scipy BLAS on one thread per
process (parallelism comes from running episodes in parallel). ``IPP_BENCH_BLAS_THREADS=N``
overrides it; torch's own thread pool is left alone.

:func:`keep_freed_memory` (used by ``ipp-bench train``) stops glibc from unmapping large freed
blocks, which made every large tensor of a training step page-fault afresh.
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


# glibc mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_HEAP_RETAIN_BYTES = 1 << 30


def keep_freed_memory() -> bool:
    """Let glibc's malloc keep freed blocks for reuse instead of returning them to the OS.

    By default glibc serves every block above a few MB with a fresh ``mmap`` and unmaps it when
    freed, so each large tensor or array costs page faults and the kernel's zeroing of every page
    again. Training makes and frees such tensors many times per step (a (batch, 84, N) attention
    score tensor is 19 MB at 450 nodes and batch 128, 77 MB at 1800 nodes; the cost of an update with
    and without is in ``benchmarks/RESULTS.md``, "Training throughput"). The process then holds on to
    its peak heap. Returns False, changing nothing, where the C library is not glibc.
    """
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (macOS, Windows, musl without mallopt)
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, _HEAP_RETAIN_BYTES)) and bool(mallopt(_M_TRIM_THRESHOLD, _HEAP_RETAIN_BYTES))
