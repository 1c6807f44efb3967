"""The process backend: each worker flies a bounded number of episodes and is then replaced, with no more
jobs running at once than there are workers, every result delivered once and no process left behind."""

import os
import time
from collections import Counter

import pytest

from ipp_bench.eval.executors import EPISODES_PER_WORKER, ProcessExecutor


def _pid_square_and_span(job: int) -> tuple[int, int, float, float]:
    start = time.monotonic()
    time.sleep(0.02)
    return os.getpid(), job * job, start, time.monotonic()


def _most_at_once(spans: list[tuple[float, float]]) -> int:
    events = sorted([(s, 1) for s, _ in spans] + [(e, -1) for _, e in spans])
    running = most = 0
    for _, step in events:
        running += step
        most = max(most, running)
    return most


def _fly(executor: ProcessExecutor, jobs: list[int]) -> dict[int, tuple]:
    try:
        return dict(executor.imap_unordered(_pid_square_and_span, jobs))
    finally:
        executor.close()


def test_a_worker_is_replaced_after_its_episodes():
    jobs = list(range(14))
    out = _fly(ProcessExecutor(2, episodes_per_worker=3), jobs)
    assert {j: r[1] for j, r in out.items()} == {j: j * j for j in jobs}  # every job once, its own result
    per_worker = Counter(r[0] for r in out.values())
    assert max(per_worker.values()) <= 3 and len(per_worker) >= 5, per_worker  # 14 jobs, 3 a worker
    assert os.getpid() not in per_worker
    assert _most_at_once([(r[2], r[3]) for r in out.values()]) <= 2


def test_without_a_replacement_due_the_workers_fly_every_job():
    assert EPISODES_PER_WORKER >= 14
    out = _fly(ProcessExecutor(2), list(range(14)))
    assert len(Counter(r[0] for r in out.values())) <= 2


def test_a_bad_episode_count_per_worker_is_refused_in_one_line():
    with pytest.raises(ValueError, match="episodes_per_worker is 0: valid is an integer >= 1"):
        ProcessExecutor(2, episodes_per_worker=0)


def test_close_leaves_no_worker():
    executor = ProcessExecutor(2, episodes_per_worker=2)
    pools = []
    for _job, _result in executor.imap_unordered(_pid_square_and_span, list(range(7))):
        pools = [*executor._retired, *(s.pool for s in executor._slots if s is not None)]
    processes = [p for pool in pools for p in (pool._processes or {}).values()]
    executor.close()
    assert all(not p.is_alive() for p in processes)
