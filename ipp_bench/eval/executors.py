"""Where the leaderboard's episodes run: in this process, in a local process pool, or on Ray.

All three take a picklable module-level function and a list of jobs and yield ``(job, result)``
pairs as jobs finish (in completion order, which the leaderboard does not rely on), and raise
:class:`~ipp_bench.eval.jobs.JobFailed` for a job that gives no result. Each worker process runs
numpy's BLAS on one thread (:func:`ipp_bench.eval.jobs.init_worker`), so an episode's numbers are
the same whichever backend or worker count runs it.

- ``serial``: one job after another in this process.
- ``process``: :class:`concurrent.futures.ProcessPoolExecutor` with the ``forkserver`` start
  method (``spawn`` where there is none), never ``fork`` (a forked BLAS or Ray thread pool can hang).
  Workers ignore Ctrl-C (the run's process handles it and stops them) and exit by themselves when
  the run's process dies (SIGTERM, SIGKILL), so no worker is left idle.
- ``ray``: one Ray task per job, :class:`~ipp_bench.eval.ray_executor.RayExecutor`.

Ctrl-C and SIGTERM wait while jobs are being submitted (a worker being forked when the signal
lands would be left behind, half started), and take effect right after.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from ..core._threads import available_cpus
from .jobs import WORKER_DIED, J, JobFailed, R, check_workers, failure_reason, init_worker, signals_deferred
from .ray_executor import RayExecutor, import_ray

BACKENDS = ("serial", "process", "ray")


class SerialExecutor:
    """Runs the jobs one after another in this process."""

    name = "serial"
    workers = 1

    def imap_unordered(self, fn: Callable[[J], R], jobs: Sequence[J]) -> Iterator[tuple[J, R]]:
        init_worker()
        for job in jobs:
            try:
                result = fn(job)
            except Exception as err:
                raise JobFailed(job, failure_reason(err)) from None
            yield job, result

    def close(self, abort: bool = False) -> None:
        pass

    def describe(self) -> str:
        return "serial (this process)"


class ProcessExecutor:
    """A pool of ``workers`` processes (``forkserver``, else ``spawn``); one BLAS thread each."""

    name = "process"

    def __init__(self, workers: int):
        check_workers(workers)
        self.workers = workers
        methods = multiprocessing.get_all_start_methods()
        self.start_method = "forkserver" if "forkserver" in methods else "spawn"
        self._pool: ProcessPoolExecutor | None = None

    def imap_unordered(self, fn: Callable[[J], R], jobs: Sequence[J]) -> Iterator[tuple[J, R]]:
        pending: dict = {}
        # Ctrl-C or SIGTERM while the pool forks its workers would land between a worker's start
        # and the pool recording it: that worker, never stopped, then reads its start-up data
        # after the pool removed its queues, and prints a traceback. The signal waits until
        # every job is submitted (and every worker recorded); it is raised right after.
        with signals_deferred():
            if self._pool is None:
                self._pool = ProcessPoolExecutor(max_workers=self.workers,
                                                 mp_context=multiprocessing.get_context(self.start_method),
                                                 initializer=init_worker, initargs=(os.getpid(),))
            for job in jobs:
                pending[self._pool.submit(fn, job)] = job
        try:
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    job = pending.pop(fut)
                    try:
                        result = fut.result()
                    except BrokenProcessPool:
                        raise JobFailed(job, WORKER_DIED) from None
                    except Exception as err:
                        raise JobFailed(job, failure_reason(err)) from None
                    yield job, result
        finally:
            for fut in pending:
                fut.cancel()

    def close(self, abort: bool = False) -> None:
        """Shut the pool down; ``abort``: stop the workers now instead of letting running jobs end."""
        if self._pool is None:
            return
        if abort:
            for proc in list(getattr(self._pool, "_processes", {}).values()):  # no public way to stop them
                proc.terminate()
        self._pool.shutdown(wait=True, cancel_futures=True)
        self._pool = None

    def describe(self) -> str:
        return f"process pool, {self.workers} workers ({self.start_method})"


def check_executor_args(backend: str, workers: int | None = None, address: str | None = None) -> None:
    """Validate executor arguments without starting anything.

    Raises:
        ValueError: unknown backend, workers < 1, or an address for a backend other than ray.
        ImportError: ``ray`` without Ray installed (names the extra to install).
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend {backend!r} is invalid: valid are {list(BACKENDS)}")
    if workers is not None:
        check_workers(workers)
    if address and backend != "ray":
        raise ValueError(f"--address is for the ray backend, not {backend!r} (add --backend ray)")
    if backend == "ray":
        import_ray()


def default_backend(workers: int | None = None) -> str:
    """``process`` when more than one worker would run, else ``serial``."""
    return "process" if (workers or available_cpus()) > 1 else "serial"


def make_executor(backend: str, workers: int | None = None, address: str | None = None):
    """The executor for ``backend`` (one of :data:`BACKENDS`).

    Args:
        backend: ``"serial"``, ``"process"`` or ``"ray"``.
        workers: processes of the pool / CPUs of a local Ray; default: the CPUs available.
        address: Ray cluster address (``ray`` only; ``RAY_ADDRESS`` when None).

    Raises:
        ValueError: unknown backend, workers < 1, or an address for a backend other than ray.
        ImportError: ``ray`` without Ray installed (names the extra to install).
    """
    check_executor_args(backend, workers, address)
    workers = workers or available_cpus()
    if backend == "serial":
        return SerialExecutor()
    if backend == "process":
        return ProcessExecutor(workers)
    return RayExecutor(workers, address)


__all__ = ["BACKENDS", "ProcessExecutor", "SerialExecutor", "check_executor_args", "default_backend",
           "make_executor"]
