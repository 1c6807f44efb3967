"""The watchdog of a local Ray: ends its processes when the run that started it is gone.

Ray makes its raylet and GCS die with the process that started them, but its dashboard and
runtime-env agents only notice the raylet's death, then try to tell the (dead) GCS and wait for its
timeout: alive for a minute after a SIGKILL of the run. :class:`~ipp_bench.eval.ray_executor.RayExecutor`
therefore starts this module as a separate small Python for a local Ray it starts::

    python -m ipp_bench.eval.ray_watchdog OWNER_PID OWNER_START PERIOD_S

Every ``PERIOD_S`` it notes each process below the run (``OWNER_PID``, which started at
``OWNER_START``, the start time field of ``/proc/<pid>/stat``) whose command line names Ray. When the
run is gone (or its pid belongs to another process now), it SIGKILLs those of them still alive and
exits 0; a pid whose start time changed is another process and is left alone.
:meth:`~ipp_bench.eval.ray_executor.RayExecutor.close` stops the watchdog after its own clean shutdown.

Linux only (it reads ``/proc``). The standard library alone: the ``/proc`` helpers here are also the
ones :mod:`ipp_bench.eval.ray_executor` cleans up with.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from collections.abc import Iterable

#: the index of the start time among the fields of ``/proc/<pid>/stat`` after the command name
START_FIELD = 19


def stat_fields(pid: int | str) -> list[str] | None:
    """The fields of ``/proc/<pid>/stat`` after the command name (state first), or None (gone, or no /proc)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            stat = fh.read()
    except OSError:
        return None
    return stat[stat.rindex(")") + 2:].split()


def start_time(pid: int | str) -> str | None:
    """When process ``pid`` started (clock ticks since boot, as /proc says it), or None."""
    fields = stat_fields(pid)
    return None if fields is None else fields[START_FIELD]


def same_process_alive(pid: int, start: str) -> bool:
    """Whether ``pid`` is alive and still the process that started at ``start`` (not a reused pid)."""
    fields = stat_fields(pid)
    return fields is not None and fields[0] != "Z" and fields[START_FIELD] == start


def descendants(pid: int) -> list[tuple[int, str]]:
    """(pid, start time) of the live descendants of ``pid``, from /proc ([] where there is none)."""
    try:
        entries = [e for e in os.listdir("/proc") if e.isdigit()]
    except OSError:
        return []
    parents: dict[int, tuple[int, str]] = {}
    for entry in entries:
        fields = stat_fields(entry)
        if fields is not None and fields[0] != "Z":
            parents[int(entry)] = (int(fields[1]), fields[START_FIELD])
    out, frontier = [], [pid]
    while frontier:
        parent = frontier.pop()
        for child, (ppid, start) in parents.items():
            if ppid == parent:
                out.append((child, start))
                frontier.append(child)
    return out


def is_ray(pid: int) -> bool:
    """Whether process ``pid`` is one of Ray's (its command line names Ray: raylet, gcs_server, ray::...)."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            cmd = fh.read().replace(b"\0", b" ")
    except OSError:
        return False
    return cmd.startswith(b"ray::") or b"/ray/" in cmd


def kill_if_same(processes: Iterable[tuple[int, str]]) -> None:
    """SIGKILL each (pid, start time) that is still that process; a reused pid is left alone."""
    for pid, start in processes:
        if same_process_alive(pid, start):
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass


def watch(owner: int, owner_start: str, period_s: float) -> dict[int, str]:
    """Note the Ray processes below ``owner`` every ``period_s`` while it lives; then SIGKILL those
    still alive. Returns the ones noted (pid: start time)."""
    me = os.getpid()
    seen: dict[int, str] = {}
    while same_process_alive(owner, owner_start):
        for child, start in descendants(owner):
            if child != me and child not in seen and is_ray(child):
                seen[child] = start
        time.sleep(period_s)
    kill_if_same(seen.items())
    return seen


def main(argv: list[str] | None = None) -> int:
    """``OWNER_PID OWNER_START PERIOD_S``: :func:`watch`; exit status 0, or 2 for bad arguments."""
    args = sys.argv[1:] if argv is None else argv
    try:
        owner, owner_start, period_s = int(args[0]), args[1], float(args[2])
    except (IndexError, ValueError):
        print("usage: python -m ipp_bench.eval.ray_watchdog OWNER_PID OWNER_START PERIOD_S", file=sys.stderr)
        return 2
    if not period_s > 0:
        print(f"PERIOD_S = {period_s!r} is invalid: expected seconds > 0", file=sys.stderr)
        return 2
    watch(owner, owner_start, period_s)
    return 0


if __name__ == "__main__":
    sys.exit(main())
