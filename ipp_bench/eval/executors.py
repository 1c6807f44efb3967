"""Where the leaderboard's episodes run: in this process, in a local process pool, or on Ray.

All three take a picklable module-level function and a list of jobs and yield ``(job, result)``
pairs as jobs finish (in completion order, which the leaderboard does not rely on). Each worker
process runs numpy's BLAS on one thread (:func:`ipp_bench.core._threads.limit_blas_threads`), so an
episode's numbers are the same whichever backend or worker count runs it.

- ``serial``: one job after another in this process.
- ``process``: :class:`concurrent.futures.ProcessPoolExecutor` with the ``forkserver`` start
  method (``spawn`` where there is none), never ``fork`` (a forked BLAS or Ray thread pool can hang).
  Workers ignore Ctrl-C (the run's process handles it and stops them) and exit by themselves when
  the run's process dies (SIGTERM, SIGKILL): a watchdog thread in each worker checks every
  half second that it is still there, so no worker is left idle.
- ``ray``: one Ray task per job (``num_cpus=1``) on the cluster at ``address`` /
  ``RAY_ADDRESS``, on an already initialised Ray, or on a local Ray started here. Needs
  ``pip install "ipp-bench[ray]"``; on a remote cluster ipp-bench must be installed there too.
  A local Ray started here ends with the run, even a killed one (a small watchdog process ends
  its agents, which would otherwise wait a minute for the dead GCS); a cluster reached by
  address is never touched.

Ctrl-C and SIGTERM wait while jobs are being submitted (a worker being forked when the signal
lands would be left behind, half started), and take effect right after.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import TypeVar

from ..core._threads import available_cpus, limit_blas_threads

BACKENDS = ("serial", "process", "ray")

J = TypeVar("J")
R = TypeVar("R")


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


#: the reason given for a job whose worker process vanished (SIGKILL, the kernel's OOM killer)
WORKER_DIED = ("a worker process died while it was running (killed by a signal, e.g. by the OS when memory "
               "ran out; the dead worker may have held another of the episodes running then)")


#: the most worker processes (process pool) or local Ray CPUs a run may ask for
MAX_WORKERS = 256
WATCH_PERIOD_S = 0.5  # [s] how often a pool worker checks that the run's process is alive


def init_worker(owner_pid: int | None = None) -> None:
    """Per-worker setup: one BLAS thread (numpy's and scipy's OpenBLAS both; measured in a fresh
    forkserver worker before ``limit_blas_threads`` loaded scipy.linalg itself, scipy's BLAS kept
    2 threads and greedy decisions were many times slower). In a pool worker (``owner_pid``: the
    run's process), Ctrl-C is left to the owner, and the worker exits when the owner is gone."""
    limit_blas_threads()
    if owner_pid is not None:
        _quiet_worker()
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


def _quiet_worker() -> None:
    """A worker does not repeat what the run's process has already said once (a task's newer version)."""
    import warnings

    from ..envs.registry import OutdatedTaskWarning

    warnings.filterwarnings("ignore", category=OutdatedTaskWarning)


def _call_in_worker(fn: Callable[[J], R], job: J) -> R:
    init_worker()
    _quiet_worker()
    return fn(job)


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
                raise JobFailed(job, _reason(err)) from None
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
        with _signals_deferred():
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
                        raise JobFailed(job, _reason(err)) from None
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


class _signals_deferred:
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


def _import_ray():
    try:
        import ray
    except ImportError:
        raise ImportError('the ray backend needs Ray: pip install "ipp-bench[ray]"') from None
    return ray


class _stderr_kept_unless_failed:
    """Hold what is written to file descriptor 2 (C++ libraries write there directly) while the
    block runs: replayed if it succeeds, dropped if it raises (the caller says it in one line)."""

    def __enter__(self):
        import tempfile

        self._buf = tempfile.TemporaryFile()
        try:
            sys.stderr.flush()
        except (AttributeError, ValueError):  # pragma: no cover
            pass
        self._saved = os.dup(2)
        os.dup2(self._buf.fileno(), 2)
        return self

    def __exit__(self, exc_type, *exc):
        os.dup2(self._saved, 2)
        os.close(self._saved)
        if exc_type is None:
            self._buf.seek(0)
            held = self._buf.read()
            if held:
                os.write(2, held)
        self._buf.close()
        return False


#: [s] how long a Ray cluster address has to answer (a gRPC connection made ready) before the run is refused
RAY_CONNECT_TIMEOUT_S = 10.0


def _require_answer(address: str, timeout_s: float = RAY_CONNECT_TIMEOUT_S) -> None:
    """Raise ExecutorError unless the Ray cluster at ``address`` (``host:port``, ``ray://host:port``,
    ``auto``) accepts a gRPC connection within ``timeout_s``: its GCS (or Ray Client server) speaks
    gRPC, a closed port or a host or listener that answers nothing does not."""
    if address in ("auto", "local"):
        return  # looked up by ray.init itself (a ConnectionError when there is none)
    try:
        import grpc
        from ray._private import services
    except ImportError:  # pragma: no cover (Ray brings grpcio)
        return
    try:
        target = address[len("ray://"):] if address.startswith("ray://") else \
            services.canonicalize_bootstrap_address(address)
    except Exception:
        raise ExecutorError(f"--address {address!r} is invalid: expected host:port (e.g. 10.0.0.5:6379), "
                            "ray://host:port or auto") from None
    if target is None:
        return
    channel = grpc.insecure_channel(target)
    try:
        grpc.channel_ready_future(channel).result(timeout=timeout_s)
    except grpc.FutureTimeoutError:
        raise ExecutorError(
            f"no Ray cluster answers at {address!r} (no connection within {timeout_s:g} s): start one with "
            "'ray start --head' or pass the address of a running one; without --address (and RAY_ADDRESS) a "
            "local Ray is started for the run") from None
    finally:
        channel.close()


class RayExecutor:
    """One Ray task per job on a Ray cluster.

    Args:
        workers: CPUs of the local Ray started when no cluster is given (ignored otherwise: the
            cluster's resources decide how many tasks run at once).
        address: cluster address; defaults to ``RAY_ADDRESS``. Without either, an already
            initialised Ray is used, else a local one is started (and shut down by :meth:`close`).
    """

    name = "ray"

    def __init__(self, workers: int, address: str | None = None):
        self._ray = _import_ray()
        ray = self._ray
        self.workers = workers
        self.address = address or os.environ.get("RAY_ADDRESS") or None
        self._owns = False
        self._local = False  # a local Ray started here (its processes are ours to clean up)
        self._watchdog: subprocess.Popen | None = None  # ends that Ray's processes if this process is killed
        self._subreaper = False
        # ray.init installs a C++ handler that dumps a stack and kills the process on SIGTERM; the
        # caller's handler (the leaderboard: stop like Ctrl-C, keep the episodes) is put back after it
        handler = signal.getsignal(signal.SIGTERM) if threading.current_thread() is threading.main_thread() else None
        if ray.is_initialized():
            self.where = "the Ray already initialised in this process"
        elif self.address:
            _require_answer(self.address)  # ray.init itself waits for minutes on an address that answers nothing
            try:
                with _stderr_kept_unless_failed():  # Ray's C++ client logs every failed retry
                    ray.init(address=self.address, log_to_driver=False)
            except ConnectionError:
                raise ExecutorError(
                    f"no Ray cluster found at {self.address!r}: start one with 'ray start --head' (on this "
                    "machine) or pass the address of a running one; without --address (and RAY_ADDRESS) a "
                    "local Ray is started for the run") from None
            self._owns = True
            self.where = f"the Ray cluster at {self.address}"
        else:
            # orphaned descendants (a helper whose parent, the raylet, died first) are re-parented
            # to this process rather than to init, so that close() still finds them
            self._subreaper = _set_child_subreaper(True)
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
            self._owns = True
            self._local = True
            self._watchdog = _start_ray_watchdog()
            self.where = f"a local Ray with {workers} CPUs"
        if callable(handler):
            signal.signal(signal.SIGTERM, handler)
        self._remote = ray.remote(num_cpus=1, max_retries=0)(_call_in_worker)

    def imap_unordered(self, fn: Callable[[J], R], jobs: Sequence[J]) -> Iterator[tuple[J, R]]:
        ray = self._ray
        # The jobs left when this stops early (a failed job, Ctrl-C, SIGTERM): close() follows at once,
        # and where this executor started Ray or connected to a cluster, ray.shutdown() ends a local
        # Ray's workers and a cluster ends the tasks of a driver that has gone. They are not cancelled
        # with force: a forced ray.cancel races with a task that is just finishing (Ray 2.60: "Check
        # failed ... Tried to complete task that was not pending", a C++ abort of this process with a
        # stack dump, exit 1, its Ray agents left running). Only in a Ray the caller initialised (which
        # stays up) are they cancelled, gently: pending ones dropped, running ones interrupted.
        refs = {}
        with _signals_deferred():  # every task submitted, or none: no half-made submission to clean up
            for job in jobs:
                refs[self._remote.remote(fn, job)] = job
        try:
            while refs:
                done, _ = ray.wait(list(refs), num_returns=1)
                for ref in done:
                    job = refs.pop(ref)
                    try:
                        result = ray.get(ref)
                    except ray.exceptions.RayTaskError as err:  # the job raised: its own exception
                        raise JobFailed(job, _reason(getattr(err, "cause", None) or err)) from None
                    except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError) as err:
                        raise JobFailed(job, f"{WORKER_DIED} ({type(err).__name__})") from None
                    yield job, result
        finally:
            if not self._owns:
                for ref in refs:
                    ray.cancel(ref)

    def close(self, abort: bool = False) -> None:
        if self._owns and self._ray.is_initialized():
            # a local Ray's helpers (raylet, dashboard and runtime-env agents) are this process's
            # descendants until the raylet dies; the agents then notice only after a heartbeat
            # timeout (seen: still alive a minute later), so the ones left after the shutdown go
            helpers = [p for p in _descendants(os.getpid()) if _is_ray(p[0])] if self._local else []
            self._ray.shutdown()
            if self._local:  # and those started meanwhile, or orphaned and re-parented here (subreaper)
                helpers = list(dict.fromkeys(helpers + [p for p in _descendants(os.getpid()) if _is_ray(p[0])]))
            if helpers:
                _reap(helpers)
                _wait_zombies([pid for pid, _ in helpers])
        if self._watchdog is not None:
            self._watchdog.kill()
            self._watchdog.wait()
            self._watchdog = None
        if self._subreaper:
            _set_child_subreaper(False)
            self._subreaper = False
        self._owns = False

    def describe(self) -> str:
        return f"Ray tasks on {self.where}"


#: The watchdog of a local Ray (a separate small Python, no imports beyond os, sys, time, signal).
#: Ray makes its raylet and GCS die with the process that started them, but its dashboard and
#: runtime-env agents only notice the raylet's death, then try to tell the (dead) GCS and wait for
#: its timeout: alive for a minute after a SIGKILL of the run. The watchdog notes every Ray process
#: below the run twice a second; when the run is gone, it SIGKILLs those still alive (a pid whose
#: start time changed is another process and is left alone), then exits. :meth:`RayExecutor.close`
#: stops it after its own clean shutdown.
_WATCHDOG = r"""
import os, signal, sys, time

owner, owner_start, period = int(sys.argv[1]), sys.argv[2], float(sys.argv[3])
me = os.getpid()


def stat(pid):
    try:
        with open("/proc/%s/stat" % pid) as fh:
            text = fh.read()
    except OSError:
        return None
    return text[text.rindex(")") + 2:].split()


def same(pid, start):
    f = stat(pid)
    return f is not None and f[0] != "Z" and f[19] == start


def is_rays(pid):
    try:
        with open("/proc/%s/cmdline" % pid, "rb") as fh:
            cmd = fh.read().replace(bytes(1), b" ")
    except OSError:
        return False
    return cmd.startswith(b"ray" + b"::") or (b"/" + b"ray/") in cmd


seen = {}
while same(owner, owner_start):
    parents = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            f = stat(entry)
            if f is not None and f[0] != "Z":
                parents[int(entry)] = (int(f[1]), f[19])
    frontier = [owner]
    while frontier:
        parent = frontier.pop()
        for child, (ppid, start) in parents.items():
            if ppid == parent:
                frontier.append(child)
                if child != me and child not in seen and is_rays(child):
                    seen[child] = start
    time.sleep(period)
for pid, start in seen.items():
    if same(pid, start):
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
"""
WATCHDOG_PERIOD_S = 0.5  # [s] how often the watchdog of a local Ray looks at the run and its Ray processes


def _start_ray_watchdog() -> subprocess.Popen | None:
    """Start :data:`_WATCHDOG` for this process (Linux: it reads /proc; elsewhere None)."""
    fields = _stat_fields(os.getpid())
    if fields is None:
        return None
    return subprocess.Popen([sys.executable, "-I", "-c", _WATCHDOG, str(os.getpid()), fields[19],
                             str(WATCHDOG_PERIOD_S)], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, close_fds=True)


def _stat_fields(pid: int | str) -> list[str] | None:
    """The fields of ``/proc/<pid>/stat`` after the command name (state first), or None (gone, or no /proc)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            stat = fh.read()
    except OSError:
        return None
    return stat[stat.rindex(")") + 2:].split()


def _descendants(pid: int) -> list[tuple[int, str]]:
    """(pid, start time) of the live descendants of ``pid``, from /proc ([] where there is none)."""
    try:
        entries = [e for e in os.listdir("/proc") if e.isdigit()]
    except OSError:
        return []
    parents: dict[int, tuple[int, str]] = {}
    for entry in entries:
        fields = _stat_fields(entry)
        if fields is not None and fields[0] != "Z":
            parents[int(entry)] = (int(fields[1]), fields[19])
    out, frontier = [], [pid]
    while frontier:
        parent = frontier.pop()
        for child, (ppid, start) in parents.items():
            if ppid == parent:
                out.append((child, start))
                frontier.append(child)
    return out


def _same_process_alive(pid: int, start: str) -> bool:
    """Whether ``pid`` is alive and still the process that started at ``start`` (not a reused pid)."""
    fields = _stat_fields(pid)
    return fields is not None and fields[0] != "Z" and fields[19] == start


def _is_ray(pid: int) -> bool:
    """Whether process ``pid`` is one of Ray's (its command line names Ray: raylet, gcs_server, ray::...)."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            cmd = fh.read().replace(b"\0", b" ")
    except OSError:
        return False
    return cmd.startswith(b"ray::") or b"/ray/" in cmd


def _reap(processes: list[tuple[int, str]], grace_s: float = 3.0) -> None:
    """SIGKILL those of ``processes`` (pid, start time) still alive after ``grace_s``; a pid whose
    start time changed is another process and is left alone."""
    deadline = time.monotonic() + grace_s
    alive = processes
    while alive and time.monotonic() < deadline:
        time.sleep(0.1)
        alive = [p for p in alive if _same_process_alive(*p)]
    for pid, start in alive:
        if _same_process_alive(pid, start):
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass


def _set_child_subreaper(on: bool) -> bool:
    """Linux ``prctl(PR_SET_CHILD_SUBREAPER)``: whether it is set now (False where unsupported)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(36, int(on), 0, 0, 0) == 0 and on  # 36: PR_SET_CHILD_SUBREAPER
    except (OSError, AttributeError):
        return False


def _wait_zombies(pids: list[int], timeout_s: float = 2.0) -> None:
    """Collect the exit status of those of ``pids`` that are (or became, as subreaper) our children,
    so that none stays a zombie; other processes' children are not touched."""
    deadline = time.monotonic() + timeout_s
    pending = list(pids)
    while pending and time.monotonic() < deadline:
        left = []
        for pid in pending:
            try:
                done, _ = os.waitpid(pid, os.WNOHANG)
            except ChildProcessError:  # not our child (its parent reaps it) or already collected
                continue
            if done == 0:
                left.append(pid)
        pending = left
        if pending:
            time.sleep(0.05)


def check_workers(workers: int) -> None:
    """Raise ValueError unless ``workers`` is in [1, :data:`MAX_WORKERS`]."""
    if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= MAX_WORKERS:
        raise ValueError(f"workers = {workers!r} is invalid: expected an integer in [1, {MAX_WORKERS}] "
                         f"(this machine has {available_cpus()} CPUs)")


def _reason(err: BaseException) -> str:
    """One line for a job's exception: its type and first line of message."""
    if isinstance(err, JobError):
        return str(err)
    text = str(err).strip().splitlines()
    return f"{type(err).__name__}: {text[0]}" if text else type(err).__name__


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
        _import_ray()


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


__all__ = ["BACKENDS", "MAX_WORKERS", "WORKER_DIED", "check_workers", "ExecutorError", "JobError", "JobFailed",
           "ProcessExecutor", "RayExecutor", "SerialExecutor", "available_cpus", "check_executor_args",
           "default_backend", "make_executor"]
