"""The ``ray`` backend of the leaderboard: one Ray task per episode.

:class:`RayExecutor` runs one task per job (``num_cpus=1``) on the cluster at ``address`` /
``RAY_ADDRESS``, on an already initialised Ray, or on a local Ray started here. Needs
``pip install "ipp-bench[ray]"``; on a remote cluster ipp-bench must be installed there too.

A local Ray started here ends with the run, even a killed one: :meth:`RayExecutor.close` shuts it
down and ends the helpers left behind, and :mod:`ipp_bench.eval.ray_watchdog`, a small separate
process, ends its agents if the run is killed before it can. A cluster reached by address is never
touched.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from .jobs import WORKER_DIED, ExecutorError, J, JobFailed, R, call_in_worker, failure_reason, signals_deferred
from .ray_watchdog import descendants, is_ray, kill_if_same, same_process_alive, start_time

#: [s] how long a Ray cluster address has to answer (a gRPC connection made ready) before the run is refused
RAY_CONNECT_TIMEOUT_S = 10.0
#: [s] how often the watchdog of a local Ray looks at the run and its Ray processes
WATCHDOG_PERIOD_S = 0.5


def import_ray():
    """The ``ray`` module, or an ImportError that names the extra to install."""
    try:
        import ray
    except ImportError:
        raise ImportError('the ray backend needs Ray: pip install "ipp-bench[ray]"') from None
    return ray


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
        self._ray = import_ray()
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
            self._watchdog = start_ray_watchdog(os.getpid())
            self.where = f"a local Ray with {workers} CPUs"
        if callable(handler):
            signal.signal(signal.SIGTERM, handler)
        self._remote = ray.remote(num_cpus=1, max_retries=0)(call_in_worker)

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
        with signals_deferred():  # every task submitted, or none: no half-made submission to clean up
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
                        raise JobFailed(job, failure_reason(getattr(err, "cause", None) or err)) from None
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
            # timeout, so the ones left after the shutdown go
            helpers = [p for p in descendants(os.getpid()) if is_ray(p[0])] if self._local else []
            self._ray.shutdown()
            if self._local:  # and those started meanwhile, or orphaned and re-parented here (subreaper)
                helpers = list(dict.fromkeys(helpers + [p for p in descendants(os.getpid()) if is_ray(p[0])]))
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


def start_ray_watchdog(owner_pid: int, period_s: float = WATCHDOG_PERIOD_S) -> subprocess.Popen | None:
    """Start ``python -m ipp_bench.eval.ray_watchdog`` for the run ``owner_pid`` (Linux: it reads
    /proc; elsewhere, or when that process is gone, None). The package's folder leads the child's
    ``PYTHONPATH``, so the module is found wherever this process found it."""
    owner_start = start_time(owner_pid)
    if owner_start is None:
        return None
    root = str(Path(__file__).resolve().parents[2])  # the folder that holds ipp_bench/
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p)}
    return subprocess.Popen([sys.executable, "-m", "ipp_bench.eval.ray_watchdog", str(owner_pid), owner_start,
                             str(period_s)], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, close_fds=True, env=env)


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


def _reap(processes: list[tuple[int, str]], grace_s: float = 3.0) -> None:
    """SIGKILL those of ``processes`` (pid, start time) still alive after ``grace_s``; a pid whose
    start time changed is another process and is left alone."""
    deadline = time.monotonic() + grace_s
    alive = processes
    while alive and time.monotonic() < deadline:
        time.sleep(0.1)
        alive = [p for p in alive if same_process_alive(*p)]
    kill_if_same(alive)


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


__all__ = ["RAY_CONNECT_TIMEOUT_S", "RayExecutor", "import_ray", "start_ray_watchdog"]
