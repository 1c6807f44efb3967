"""Every registered planner flies the MuJoCo task to the end of its budget (one clock for all).

The MuJoCo mission's clock charges the velocity ramps on top of length / speed. A planner that
derived affordability on its own (MCTS from the roadmap's nominal costs) once offered a leg the
task's mask refused, ending in "action 7 is invalid (masked ...)" at ``budget_s=12`` on seed 2.
Short budgets make the end of the budget, where the clocks disagree, come quickly.
"""

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("mujoco")

import ipp_bench.envs as envs  # noqa: E402
from ipp_bench.envs.registry import is_team_task  # noqa: E402
from ipp_bench.eval.runner import run_episode  # noqa: E402
from ipp_bench.planners import is_team_planner, planner_names  # noqa: E402

MUJOCO_TASKS = sorted(t for t, s in envs.TASKS.items()
                      if s.entry_point.startswith("ipp_bench.sim") and not is_team_task(t))
TEAM_TASKS = sorted(t for t, s in envs.TASKS.items() if s.entry_point.startswith("ipp_bench.sim") and is_team_task(t))
# cheap settings: the budget's end, not the quality of the look-ahead, is under test
CHEAP = {"mcts": "mcts:simulations=8", "cmaes": "cmaes:max_evals=24"}
# 12 s: the budget of the case above; 17 s, a second end, with -m slow
BUDGETS = [12.0, pytest.param(17.0, marks=pytest.mark.slow)]


class _Envs(dict):
    """(task, budget) -> one env per module, made on first use by ``make(task, budget)``."""

    def __init__(self, make):
        super().__init__()
        self.make = make

    def __missing__(self, key):
        task, budget = key
        self[key] = self.make(task, budget_s=budget, report_times=[budget], image_size=48)
        return self[key]


@pytest.fixture(scope="module")
def envs_by_task_and_budget():
    made = _Envs(lambda task, **kw: gym.make(task, **kw).unwrapped)
    yield made
    for e in made.values():
        e.close()


@pytest.mark.parametrize("planner", [p for p in planner_names() if not is_team_planner(p)])
@pytest.mark.parametrize("budget", BUDGETS)
@pytest.mark.parametrize("task", [t if t.endswith("-v1") else pytest.param(t, marks=pytest.mark.slow)
                                  for t in MUJOCO_TASKS])  # v0's stop-and-go clock: with -m slow
def test_every_planner_flies_to_the_end_of_the_budget(envs_by_task_and_budget, task, planner, budget):
    if planner == "attention":
        pytest.importorskip("torch")
    env = envs_by_task_and_budget[(task, budget)]
    for seed in (0, 1, 2, 3):
        result = run_episode(task, CHEAP.get(planner, planner), seed, env=env)
        mission = env.mission
        assert result.decisions >= 1
        assert mission.time_s <= mission.budget_s + 1e-9
        # the end: nothing the clock affords is left (graph), or no leg worth flying (continuous)
        assert not env.action_masks().any() or planner in ("coverage", "cmaes")
        assert np.isfinite(mission.metrics()["trace_roi"])


@pytest.fixture(scope="module")
def team_envs_by_task_and_budget():
    made = _Envs(envs.make_env)
    yield made
    for e in made.values():
        e.close()


@pytest.mark.parametrize("planner", planner_names())
@pytest.mark.parametrize("budget", BUDGETS)
@pytest.mark.parametrize("task", TEAM_TASKS)
def test_every_planner_flies_every_drone_of_a_team_to_the_end_of_its_budget(team_envs_by_task_and_budget, task,
                                                                             planner, budget):
    if planner == "attention":
        pytest.importorskip("torch")
    env = team_envs_by_task_and_budget[(task, budget)]
    for seed in (0, 1):
        result = run_episode(task, CHEAP.get(planner, planner), seed, env=env)
        assert result.decisions >= env.team.size
        for i, seat in enumerate(env.seats):
            assert seat.mission.time_s <= seat.mission.budget_s + 1e-9
            assert not env.uav_mask(i).any() or planner in ("coverage", "cmaes", "team-coverage")
        assert env.sim_team.legs == [None] * env.team.size  # every committed leg was flown to its end
        assert np.isfinite(env.mission.metrics()["trace_roi"])
