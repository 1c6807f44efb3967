"""Where the leaderboard's episodes run: in this process, in a local process pool, or on Ray.

All three take a picklable module-level function and a list of jobs and yield ``(job, result)``
pairs as jobs finish (in completion order, which the leaderboard does not rely on), and raise
:class:`~ipp_bench.eval.jobs.JobFailed` for a job that gives no result. Each worker process runs
numpy's BLAS on one thread (:func:`ipp_bench.eval.jobs.init_worker`), so an episode's numbers are
the same whichever backend or worker count runs it.

- ``serial``: one job after another in this process.
- ``process``: worker processes (:class:`concurrent.futures.ProcessPoolExecutor`) with the ``forkserver``
  start method (``spawn`` where there is none), never ``fork`` (a forked BLAS or Ray thread pool can hang);
  each worker is replaced by a fresh one after :data:`EPISODES_PER_WORKER` episodes.
  Workers ignore Ctrl-C (the run's process handles it and stops them) and exit by themselves when
  the run's process dies (SIGTERM, SIGKILL), so no worker is left idle.
- ``ray``: one Ray task per job, :class:`~ipp_bench.eval.ray_executor.RayExecutor`.

Ctrl-C and SIGTERM wait while jobs are being submitted (a worker being forked when the signal
lands would be left behind, half started), and take effect right after.
"""

from __future__ import annotations

import multiprocessing
import os
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from ..core._threads import available_cpus, give_back_freed_memory
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


#: episodes a worker process flies before a fresh process replaces it: a bound on what grows with the maps and
#: planners a worker has flown (caches of roadmap legs; the heap a worker cannot give back). A fresh worker
#: costs its start (imports, loading the compiled search kernels: 2-4 s), so the quick leaderboard (about 50
#: episodes a worker) replaces none.
EPISODES_PER_WORKER = 100
#: after an episode, a worker holding more than this collects its garbage and returns its freed heap to the
#: OS (:func:`~ipp_bench.core._threads.give_back_freed_memory`), so that it holds what its next episode needs
#: rather than what its largest one took; below it, a worker skips that (milliseconds an episode)
GIVE_BACK_ABOVE_BYTES = 1 << 30


def _run_then_give_back(fn: Callable[[J], R], job: J) -> R:
    """In a worker: ``fn(job)``, then the freed memory back to the OS where the worker holds much."""
    try:
        return fn(job)
    finally:
        give_back_freed_memory(GIVE_BACK_ABOVE_BYTES)


class _Slot:
    """One worker process (a ProcessPoolExecutor of one), replaced after :data:`EPISODES_PER_WORKER` jobs."""

    def __init__(self, context, initargs):
        self.pool = ProcessPoolExecutor(max_workers=1, mp_context=context, initializer=init_worker,
                                        initargs=initargs)
        self.ran = 0


class ProcessExecutor:
    """``workers`` worker processes (``forkserver``, else ``spawn``); one BLAS thread each; each replaced by a
    fresh process after ``episodes_per_worker`` jobs (:data:`EPISODES_PER_WORKER`), so that no worker's memory
    grows with the length of a run. A job goes to a worker only when that worker is free."""

    name = "process"

    def __init__(self, workers: int, episodes_per_worker: int = EPISODES_PER_WORKER):
        check_workers(workers)
        if not (isinstance(episodes_per_worker, int) and episodes_per_worker >= 1):
            raise ValueError(f"episodes_per_worker is {episodes_per_worker!r}: valid is an integer >= 1")
        self.workers = workers
        self.episodes_per_worker = episodes_per_worker
        methods = multiprocessing.get_all_start_methods()
        self.start_method = "forkserver" if "forkserver" in methods else "spawn"
        self._slots: list[_Slot | None] = [None] * workers
        self._retired: list[ProcessPoolExecutor] = []

    def _free_slot(self, busy: set[int]) -> int:
        """A slot with no job running, its worker started or replaced as needed."""
        i = next(k for k in range(self.workers) if k not in busy)
        slot = self._slots[i]
        if slot is not None and slot.ran >= self.episodes_per_worker:
            slot.pool.shutdown(wait=False)  # its worker is idle: it exits; close() joins it
            self._retired.append(slot.pool)
            slot = None
        if slot is None:
            slot = self._slots[i] = _Slot(multiprocessing.get_context(self.start_method), (os.getpid(),))
        return i

    def imap_unordered(self, fn: Callable[[J], R], jobs: Sequence[J]) -> Iterator[tuple[J, R]]:
        queue = deque(jobs)
        pending: dict = {}  # future -> (job, slot)
        try:
            while queue or pending:
                # Ctrl-C or SIGTERM while a pool forks its worker would land between the worker's start
                # and the pool recording it: that worker, never stopped, then reads its start-up data
                # after the pool removed its queues, and prints a traceback. The signal waits until the
                # submissions (and every worker started by them) are recorded; it is raised right after.
                with signals_deferred():
                    busy = {slot for _, slot in pending.values()}
                    while queue and len(busy) < self.workers:
                        i = self._free_slot(busy)
                        job = queue.popleft()
                        pending[self._slots[i].pool.submit(_run_then_give_back, fn, job)] = (job, i)
                        self._slots[i].ran += 1
                        busy.add(i)
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    job, _ = pending.pop(fut)
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
        """Shut the workers down; ``abort``: stop them now instead of letting running jobs end."""
        pools = [*self._retired, *(s.pool for s in self._slots if s is not None)]
        self._slots = [None] * self.workers
        self._retired = []
        if abort:
            for pool in pools:
                for proc in list((getattr(pool, "_processes", None) or {}).values()):  # no public way to stop them
                    proc.terminate()
        for pool in pools:
            pool.shutdown(wait=True, cancel_futures=True)

    def describe(self) -> str:
        return (f"process pool, {self.workers} workers ({self.start_method}), "
                f"each replaced after {self.episodes_per_worker} episodes")


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
