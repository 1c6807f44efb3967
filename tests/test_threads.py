"""The CPUs a process may keep busy (``core._threads.available_cpus``): its affinity mask within its cgroup's
CPU quota, read from cgroup v2 ``cpu.max`` or v1 ``cpu.cfs_quota_us`` / ``cpu.cfs_period_us``."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

from ipp_bench.core import _threads


def _cgroup(root, layout: str, quota: str, period: str = "100000"):
    if layout == "v2":
        (root / "cpu.max").write_text(f"{quota} {period}\n")
    else:
        (root / "cpu").mkdir()
        (root / "cpu" / "cpu.cfs_quota_us").write_text(f"{quota}\n")
        (root / "cpu" / "cpu.cfs_period_us").write_text(f"{period}\n")


@pytest.mark.parametrize("layout", ["v2", "v1"])
@pytest.mark.parametrize("quota, affinity, expected", [
    ("200000", 16, 2),  # a container limited to 2 CPUs on a 16-CPU host
    ("150000", 16, 2),  # 1.5 CPUs: rounded up
    ("50000", 16, 1),  # half a CPU: at least one
    ("800000", 4, 4),  # a quota above the affinity mask: the mask
])
def test_available_cpus_is_the_affinity_within_the_cgroup_quota(tmp_path, monkeypatch, layout, quota, affinity,
                                                                 expected):
    _cgroup(tmp_path, layout, quota)
    monkeypatch.setattr(_threads.os, "sched_getaffinity", lambda pid: set(range(affinity)))
    assert _threads.available_cpus(str(tmp_path)) == expected
    monkeypatch.setattr(_threads, "CGROUP_ROOT", str(tmp_path))
    assert _threads.available_cpus() == expected  # the default root is read at call time


@pytest.mark.parametrize("layout, quota", [("v2", "max"), ("v1", "-1"), ("none", "")])
def test_without_a_quota_the_affinity_mask_decides(tmp_path, monkeypatch, layout, quota):
    if layout != "none":
        _cgroup(tmp_path, layout, quota)
    monkeypatch.setattr(_threads.os, "sched_getaffinity", lambda pid: set(range(6)))
    assert _threads.available_cpus(str(tmp_path)) == 6


def test_the_training_s_workers_and_the_leaderboard_count_the_same_cpus(tmp_path, monkeypatch):
    pytest.importorskip("stable_baselines3")
    from ipp_bench.train.vec import worker_cpus

    _cgroup(tmp_path, "v2", "300000")
    monkeypatch.setattr(_threads, "CGROUP_ROOT", str(tmp_path))
    monkeypatch.setattr(_threads.os, "sched_getaffinity", lambda pid: set(range(16)))
    assert worker_cpus() == _threads.available_cpus() == 3


_FREED_HEAP = """
import sys
from ipp_bench.core._threads import give_back_freed_memory, resident_bytes

chunks = [bytes(2000) + bytes([i % 251]) for i in range(200_000)]  # 400 MB of small blocks on the heap
keep = bytes(2000) + b"x"  # allocated after them: the heap's top stays in use, free() cannot shrink it
del chunks
before = resident_bytes()
assert give_back_freed_memory(above_bytes=1 << 50) is False  # below the threshold: nothing done
untouched = resident_bytes()
trimmed = give_back_freed_memory(above_bytes=0)
print(before, untouched, resident_bytes(), trimmed)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc",
                    reason="malloc_trim is glibc's")
def test_freed_heap_goes_back_to_the_os_only_above_the_threshold():
    out = subprocess.run([sys.executable, "-c", _FREED_HEAP], capture_output=True, text=True, timeout=60, check=True)
    before, untouched, after, trimmed = out.stdout.split()
    assert int(untouched) > int(before) - 50e6  # the freed 400 MB still held
    assert trimmed == "True" and int(after) < int(before) - 300e6, out.stdout
