"""Helpers of the eval tests: tiny leaderboards (40 s missions, cheap planners, two episodes)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from ipp_bench.eval.leaderboard import run_leaderboard
from ipp_bench.eval.plan import make_plan
from ipp_bench.eval.results_csv import RESULTS_CSV, TIMING_COLUMNS, read_results

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def benchmark_script(name: str):
    """``benchmarks/<name>.py`` imported as a module (the test skips in an installed copy without it)."""
    import pytest

    path = BENCHMARKS / f"{name}.py"
    if not path.is_file():
        pytest.skip("benchmarks/ is not beside the package (an installed copy, not the repository)")
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


TASKS = ("ipp_bench/Grid15Eval-v1", "ipp_bench/Grid20Eval-v1")
PLANNERS = ("random", "coverage", "greedy", "mcts:simulations=3")
TINY_ENV = {"budget_s": 40, "report_times": [20, 40]}
EPISODES = 2


def tiny_plan(**kwargs):
    args = dict(tasks=TASKS, planners=PLANNERS, episodes=EPISODES, seed=7, env_overrides=TINY_ENV, log=lambda m: None)
    args.update(kwargs)
    return make_plan(**args)


def run_tiny(out, plan=None, backend="serial", workers=None, **kwargs):
    return run_leaderboard(plan or tiny_plan(), out, backend=backend, workers=workers, progress=False,
                           log=lambda m: None, **kwargs)


def without_timing(rows):
    """Rows with the wall-time columns removed (those differ from run to run)."""
    return [{k: v for k, v in r.items() if k not in TIMING_COLUMNS} for r in rows]


def results(out):
    return read_results(out / RESULTS_CSV)


def assert_same_results(got, want):
    """Equal rows (timing columns aside); on failure, name the first differing episodes."""
    got, want = without_timing(got), without_timing(want)
    if got != want:
        diff = [(a, b) for a, b in zip(got, want) if a != b][:3]
        raise AssertionError(f"{len(got)} vs {len(want)} rows; first differences (got, want): {diff}")


class BoomPlanner:
    """A plugin planner whose ``act()`` raises on the episode of seed ``FAIL_SEED`` (its 3rd decision)."""

    FAIL_SEED = None  # set by the test
    name = "boom"

    from ipp_bench.planners.simple import RandomConfig as Config

    def __init__(self, config=None):
        from ipp_bench.planners.simple import RandomPlanner

        self._inner = RandomPlanner()
        self.kind = self._inner.kind

    def reset(self, view, seed):
        self._seed, self._calls = seed, 0
        self._inner.reset(view, seed)

    def act(self, obs):
        self._calls += 1
        if self._seed == BoomPlanner.FAIL_SEED and self._calls == 3:
            raise RuntimeError("boom in act")
        return self._inner.act(obs)
