"""The watchdog of a local Ray (ipp_bench.eval.ray_watchdog), run for real as the Ray executor starts it.

A stand-in run (the owner) starts two children: one whose command line names Ray (a script under a
``ray/`` folder, as Ray's agents are ``.../ray/...`` scripts) and one that does not. The watchdog is
started by :func:`~ipp_bench.eval.ray_executor.start_ray_watchdog`, the executor's own launcher;
no Ray is needed.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ipp_bench.eval import ray_watchdog
from ipp_bench.eval.ray_executor import start_ray_watchdog

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="the watchdog reads /proc (Linux)")

PERIOD_S = 0.05
SLEEPER = "import time\ntime.sleep(120)\n"
OWNER = """import subprocess, sys, time
children = [subprocess.Popen([sys.executable, path]) for path in sys.argv[1:]]
print(" ".join(str(c.pid) for c in children), flush=True)
time.sleep(120)
"""


def _alive(pid: int) -> bool:
    fields = ray_watchdog.stat_fields(pid)
    return fields is not None and fields[0] != "Z"


def _wait(condition, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return condition()


@pytest.fixture
def owner(tmp_path):
    """A running owner process, its Ray-named child and its other child (pids); all ended afterwards."""
    (tmp_path / "ray").mkdir()
    (tmp_path / "other").mkdir()
    (tmp_path / "ray" / "agent.py").write_text(SLEEPER)
    (tmp_path / "other" / "helper.py").write_text(SLEEPER)
    proc = subprocess.Popen([sys.executable, "-c", OWNER, str(tmp_path / "ray" / "agent.py"),
                             str(tmp_path / "other" / "helper.py")], stdout=subprocess.PIPE, text=True)
    ray_child, other_child = (int(p) for p in proc.stdout.readline().split())
    children = [ray_child, other_child]
    try:
        yield proc, ray_child, other_child
    finally:
        for pid in [proc.pid, *children]:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
        proc.wait()


def test_the_proc_helpers_see_the_owners_children(owner):
    proc, ray_child, other_child = owner
    found = {pid for pid, _ in ray_watchdog.descendants(proc.pid)}
    assert {ray_child, other_child} <= found
    assert ray_watchdog.is_ray(ray_child) and not ray_watchdog.is_ray(other_child)
    start = ray_watchdog.start_time(ray_child)
    assert ray_watchdog.same_process_alive(ray_child, start)
    assert not ray_watchdog.same_process_alive(ray_child, str(int(start) + 1))  # a reused pid is another process


def test_when_the_owner_dies_the_watchdog_kills_its_ray_processes_and_exits(owner):
    proc, ray_child, other_child = owner
    watchdog = start_ray_watchdog(proc.pid, period_s=PERIOD_S)
    try:
        time.sleep(40 * PERIOD_S)  # it notes the owner's Ray processes every period
        assert watchdog.poll() is None, "the watchdog exited while the owner was alive"
        assert _alive(ray_child)
        proc.kill()  # as a SIGKILL of the run: nothing of the owner cleans up
        proc.wait()
        assert watchdog.wait(timeout=10) == 0
        assert _wait(lambda: not _alive(ray_child)), "the Ray process outlived its run"
        assert _alive(other_child), "the watchdog ended a process that is not Ray's"
    finally:
        if watchdog.poll() is None:
            watchdog.kill()
            watchdog.wait()


def test_a_watchdog_stopped_while_the_owner_lives_leaves_everything_alone(owner):
    """What RayExecutor.close does after its own clean shutdown: the watchdog is killed first."""
    proc, ray_child, other_child = owner
    watchdog = start_ray_watchdog(proc.pid, period_s=PERIOD_S)
    time.sleep(10 * PERIOD_S)
    watchdog.kill()
    watchdog.wait()
    time.sleep(5 * PERIOD_S)
    assert _alive(ray_child) and _alive(other_child) and proc.poll() is None


def test_bad_arguments_exit_2_with_a_usage_line():
    proc = subprocess.run([sys.executable, "-m", "ipp_bench.eval.ray_watchdog", "not-a-pid"], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2 and "usage: python -m ipp_bench.eval.ray_watchdog" in proc.stderr
    assert ray_watchdog.main(["1", "0", "0"]) == 2  # a period of 0 s
