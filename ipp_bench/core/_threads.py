"""CPUs and BLAS threading for the many small matrix products of the belief updates.

A Kalman update on a 15 x 15 map multiplies matrices of a few hundred rows: OpenBLAS threads
only add hand-over cost there, and on a busy machine they make an env step many times slower
(``benchmarks/RESULTS.md``). ipp-bench therefore runs numpy/scipy BLAS on one thread per
process (parallelism comes from running episodes in parallel). ``IPP_BENCH_BLAS_THREADS=N``
overrides it; torch's own thread pool is left alone.

:func:`keep_freed_memory` (used by ``ipp-bench train``) stops glibc from unmapping large freed
blocks, which made every large tensor of a training step page-fault afresh;
:func:`give_back_freed_memory` (used by the leaderboard's workers between episodes) does the opposite.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

#: where the cgroup CPU quota is read (v2 ``cpu.max``, v1 ``cpu/cpu.cfs_quota_us``)
CGROUP_ROOT = "/sys/fs/cgroup"

_applied = False


def available_cpus(cgroup_root: str | None = None) -> int:
    """CPUs this process may keep busy: those it may run on (its affinity mask, where the OS has one), within its
    cgroup's CPU quota (:func:`cgroup_cpu_quota`; ``cgroup_root``: where it is read, default :data:`CGROUP_ROOT`)."""
    try:
        cpus = max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover (macOS, Windows)
        cpus = max(1, os.cpu_count() or 1)
    quota = cgroup_cpu_quota(cgroup_root)
    return min(cpus, quota) if quota else cpus


def cgroup_cpu_quota(root: str | None = None) -> int | None:
    """The CPUs this process's cgroup may use (its CPU quota, rounded up), or None without a quota.

    A container limited to 2 CPUs on a larger host (``docker --cpus 2``) still sees every host CPU
    in its affinity mask; only the quota (cgroup v2 ``cpu.max``, v1 ``cpu/cpu.cfs_quota_us`` over
    ``cpu/cpu.cfs_period_us``, under ``root``, default :data:`CGROUP_ROOT`) tells how many it may keep busy."""
    base = Path(root or CGROUP_ROOT)
    try:
        quota, period = (base / "cpu.max").read_text().split()[:2]
        if quota == "max":
            return None
        return max(1, math.ceil(int(quota) / int(period)))
    except (OSError, ValueError, ZeroDivisionError):
        pass
    try:
        quota_us = int((base / "cpu" / "cpu.cfs_quota_us").read_text())
        period_us = int((base / "cpu" / "cpu.cfs_period_us").read_text())
    except (OSError, ValueError):
        return None
    return max(1, math.ceil(quota_us / period_us)) if quota_us > 0 and period_us > 0 else None


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
    mallopt = _glibc("mallopt")
    if mallopt is None:
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, _HEAP_RETAIN_BYTES)) and bool(mallopt(_M_TRIM_THRESHOLD, _HEAP_RETAIN_BYTES))


def resident_bytes() -> int | None:
    """This process's resident memory (bytes), from ``/proc/self/statm``; None where there is none."""
    try:
        return int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return None


def give_back_freed_memory(above_bytes: int) -> bool:
    """Where this process holds more than ``above_bytes``: collect its reference cycles and have glibc return
    the freed heap to the OS (``malloc_trim``). Without it a process holds on to its largest episode's heap:
    one MCTS episode at 600 simulations on a 30 x 30 map peaks at 4.6 GB and the process keeps 4.3 GB
    after it; 0.4 GB after this. Returns whether it trimmed (False where the C library is not glibc or the
    process holds no more than ``above_bytes``).
    """
    held = resident_bytes()
    if held is None or held <= above_bytes:
        return False
    import gc

    gc.collect()
    trim = _glibc("malloc_trim")
    return trim is not None and bool(trim(0))


def _glibc(function: str):
    """The C library's ``function`` (a ctypes function), or None where the C library is not glibc (macOS,
    Windows, musl without it)."""
    import ctypes
    import ctypes.util

    try:
        return getattr(ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6"), function)
    except (OSError, AttributeError):
        return None
