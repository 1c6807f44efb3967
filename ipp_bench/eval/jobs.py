"""What every executor shares: how a job's failure is told, and how a worker process is set up.

A backend (:mod:`ipp_bench.eval.executors`, :mod:`ipp_bench.eval.ray_executor`) raises
:class:`JobFailed`, and only that, for a job that gives no result, so the caller keeps what finished
and names the job whatever ran it. Each worker runs numpy's BLAS on one thread
(:func:`ipp_bench.core._threads.limit_blas_threads`), so an episode's numbers are the same whichever
backend or worker count runs it. A pool worker ignores Ctrl-C (the run's process handles it and
stops the pool) and exits by itself when the run's process dies (SIGTERM, SIGKILL): a watch thread
checks every :data:`WATCH_PERIOD_S` that the run is still there, so no worker is left idle.
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Callable
from typing import TypeVar

from ..core._threads import available_cpus, limit_blas_threads

J = TypeVar("J")
R = TypeVar("R")

#: the most worker processes (process pool) or local Ray CPUs a run may ask for
MAX_WORKERS = 256
WATCH_PERIOD_S = 0.5  # [s] how often a pool worker checks that the run's process is alive

#: the reason given for a job whose worker process vanished (SIGKILL, the kernel's OOM killer)
WORKER_DIED = ("a worker process died while it was running (killed by a signal, e.g. by the OS when memory "
               "ran out; the dead worker may have held another of the episodes running then)")


class ExecutorError(RuntimeError):
    """A backend that cannot start (e.g. no Ray cluster at the address); the message says how to fix it."""


class JobFailed(RuntimeError):
    """One job failed: it raised (``reason``: its one-line message) or its worker process died.

    Every backend raises this, and only this, for a job that gives no result, so the caller keeps
    what finished and names the job, whatever ran it.
    """

    def __init__(self, job, reason: str):
        super().__init__(reason)
        self.job, self.reason = job, reason


class JobError(RuntimeError):
    """What a job function raises for a failure it has already put in one line (the executors
    pass its message on as the :class:`JobFailed` reason, unchanged)."""


def failure_reason(err: BaseException) -> str:
    """One line for a job's exception: its type and first line of message (a :class:`JobError`'s as it is)."""
    if isinstance(err, JobError):
        return str(err)
    text = str(err).strip().splitlines()
    return f"{type(err).__name__}: {text[0]}" if text else type(err).__name__


def check_workers(workers: int) -> None:
    """Raise ValueError unless ``workers`` is in [1, :data:`MAX_WORKERS`]."""
    if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= MAX_WORKERS:
        raise ValueError(f"workers = {workers!r} is invalid: expected an integer in [1, {MAX_WORKERS}] "
                         f"(this machine has {available_cpus()} CPUs)")


def init_worker(owner_pid: int | None = None) -> None:
    """Per-worker setup: one BLAS thread (numpy's and scipy's OpenBLAS both: scipy's BLAS is a
    library of its own, which ``limit_blas_threads`` loads before it limits it). In a pool worker
    (``owner_pid``: the run's process), Ctrl-C is left to the owner, and the worker exits when the
    owner is gone."""
    limit_blas_threads()
    if owner_pid is not None:
        quiet_worker()
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        threading.Thread(target=_exit_with_owner, args=(owner_pid, os.getppid()), daemon=True,
                         name="ipp-bench-owner-watch").start()


def _owner_gone(owner_pid: int, parent_pid: int) -> bool:
    if os.getppid() != parent_pid:  # our parent (the owner, or its forkserver) died: we were re-parented
        return True
    try:
        os.kill(owner_pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # pragma: no cover (a pid reused by another user's process)
        return True
    return False


def _exit_with_owner(owner_pid: int, parent_pid: int) -> None:
    while not _owner_gone(owner_pid, parent_pid):
        threading.Event().wait(WATCH_PERIOD_S)
    os._exit(1)


def quiet_worker() -> None:
    """A worker does not repeat what the run's process has already said once (a task's newer version)."""
    import warnings

    from ..envs.registry import OutdatedTaskWarning

    warnings.filterwarnings("ignore", category=OutdatedTaskWarning)


def call_in_worker(fn: Callable[[J], R], job: J) -> R:
    """``fn(job)`` in a worker that was not set up by :func:`init_worker` (a Ray worker)."""
    init_worker()
    quiet_worker()
    return fn(job)


class signals_deferred:
    """Hold SIGINT and SIGTERM while the block runs (in the main thread; elsewhere a no-op): a signal
    that arrives meanwhile is handled, by the handler that was set, when the block ends."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __enter__(self):
        self._held: list[tuple[int, object]] = []
        self._saved = {}
        if threading.current_thread() is not threading.main_thread():
            return self
        for sig in self.SIGNALS:
            self._saved[sig] = signal.signal(sig, lambda signum, frame: self._held.append((signum, frame)))
        return self

    def __exit__(self, *exc):
        for sig, handler in self._saved.items():
            signal.signal(sig, handler)
        if self._held:
            signum, frame = self._held[0]
            handler = self._saved[signum]
            if callable(handler):
                handler(signum, frame)  # the leaderboard's: KeyboardInterrupt
            elif handler == signal.SIG_DFL:
                os.kill(os.getpid(), signum)
        return False


__all__ = ["MAX_WORKERS", "WORKER_DIED", "ExecutorError", "JobError", "JobFailed", "call_in_worker",
           "check_workers", "failure_reason", "init_worker", "signals_deferred"]
