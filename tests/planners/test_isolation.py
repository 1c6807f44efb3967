"""Isolated episodes (``fly_episode(..., isolate=True)``): the same episode as in-process, bit for bit, and a
planner that reads the truth the three ways an in-process planner can finds none of it.

The probe planners below live in this module and join a local registry; the planner's process imports them
by name (it gets this process's ``sys.path``).
"""

from __future__ import annotations

import gc
import importlib.util
import json
import multiprocessing as mp
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from ipp_bench.core.mission import Mission
from ipp_bench.envs import make_env
from ipp_bench.planners import REGISTRY, PlannerError
from ipp_bench.planners.base import GraphPlanner
from ipp_bench.planners.episode import fly_episode, start_episode
from ipp_bench.planners.isolation import (
    _POOL,
    close_workers,
    describe_planner,
    isolated_by_default,
    planner_seed,
    target_of,
)
from ipp_bench.planners.robot import RobotMission

TASK = "ipp_bench/Hotspots15Eval-v2"
TWIN = "ipp_bench/Weed15Twin-v1"
BUDGET_S = 60.0


@pytest.fixture(scope="module", autouse=True)
def _end_planner_processes():
    yield
    close_workers()


def _planner_processes() -> list:
    return [p for p in mp.active_children() if p.name.startswith("ipp-bench planner")]


# -- probe planners ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ProbeConfig:
    out: str = ""  # where the probe writes what it found (JSON)


def _first(obs) -> int:
    return int(np.flatnonzero(obs["action_mask"])[0])


def _truth_sum(mission) -> float | None:
    truth = getattr(mission, "truth", None)
    return None if truth is None else float(np.sum(truth))


def _frames() -> dict:
    """Walk up the interpreter's frames for an env or mission among their locals."""
    found: dict = {"truth": None, "missions": 0}
    frame = sys._getframe(1)
    while frame is not None:
        for value in list(frame.f_locals.values()):
            mission = value if isinstance(value, Mission) else getattr(value, "mission", None)
            if isinstance(mission, Mission):
                found["missions"] += 1
                found["truth"] = found["truth"] if found["truth"] is not None else _truth_sum(mission)
        frame = frame.f_back
    return found


def _table(view) -> dict:
    from ipp_bench.planners.base import _ENVS

    mission = _ENVS[view].mission
    return {"truth": _truth_sum(mission), "missions": int(isinstance(mission, Mission))}


def _gc() -> dict:
    missions = [o for o in gc.get_objects() if isinstance(o, Mission)]
    truths = [s for s in map(_truth_sum, missions) if s is not None]
    return {"truth": truths[0] if truths else None, "missions": len(missions),
            "kinds": sorted({type(m).__name__ for m in missions})}


class ReadsTruth(GraphPlanner):
    """Tries the three in-process reads of the truth at its first decision, writes what each found."""

    name = "reads-truth"
    Config = ProbeConfig

    def act(self, obs):
        if self.settings.out and not Path(self.settings.out).exists():
            found = {"frames": _frames(), "table": _table(self.view), "gc": _gc()}
            Path(self.settings.out).write_text(json.dumps(found))
        return _first(obs)


class RedrawsField(GraphPlanner):
    """Draws a field itself from the task's config and the seed ``reset`` gets."""

    name = "redraws-field"
    Config = ProbeConfig

    def reset(self, view, seed):
        super().reset(view, seed)
        from ipp_bench.envs.graph import GraphIPPEnv

        twin = GraphIPPEnv(view.config)
        twin.reset(seed=seed)
        Path(self.settings.out).write_text(json.dumps({"truth": _truth_sum(twin.mission), "seed": seed}))

    def act(self, obs):
        return _first(obs)


class Raises(GraphPlanner):
    name = "raises"
    Config = ProbeConfig

    def act(self, obs):
        raise RuntimeError("boom in act")


class ResetRaises(GraphPlanner):
    name = "reset-raises"
    Config = ProbeConfig

    def reset(self, view, seed):
        raise KeyError("no start")


class Exits(GraphPlanner):
    name = "exits"
    Config = ProbeConfig

    def act(self, obs):
        sys.exit(3)


class Dies(GraphPlanner):
    name = "dies"
    Config = ProbeConfig

    def act(self, obs):
        os._exit(7)  # the planner's process ends without a word (only ever flown isolated)


class PosesAsOracle(ReadsTruth):
    """Asks for the true ROI under the reference planner's name (in a registry of its own)."""

    name = "oracle"
    reads_truth = True


PROBES = REGISTRY.copy()
for _cls in (ReadsTruth, RedrawsField, Raises, ResetRaises, Exits, Dies):
    PROBES.register(_cls.name, _cls)
POSERS = REGISTRY.copy()
POSERS.register("oracle", PosesAsOracle)


def _fly(task, spec, seed, isolate, registry=None):
    env = make_env(task, budget_s=BUDGET_S)
    actions = []
    result = fly_episode(env, spec, seed, isolate=isolate, registry=registry,
                         on_decision=lambda d: actions.append(np.asarray(d.action).tolist()))
    return env, result, actions


# -- the same episode -------------------------------------------------------------------------------------------
SPECS = [(TASK, "greedy"), (TASK, "random"), (TASK, "coverage"), (TASK, "mcts:simulations=4"),
         (TASK, "cmaes:max_evals=24,popsize=6"), (TASK, "oracle"), (TWIN, "greedy"),
         (TWIN, "cmaes:max_evals=12,popsize=6"), ("ipp_bench/Hotspots30Eval-v2", "greedy"),
         ("ipp_bench/Hotspots128Eval-v2", "greedy")]  # the window belief
if importlib.util.find_spec("torch") is not None:
    SPECS.append((TASK, "attention"))


@pytest.mark.parametrize("task, spec", [pytest.param(t, s, id=f"{t.split('/')[1]}-{s}",
                                                     marks=[pytest.mark.slow] if "128" in t else [])
                                        for t, s in SPECS])
@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=pytest.mark.slow)])
def test_isolated_episode_equals_the_in_process_one(task, spec, seed):
    _, inside, acts_in = _fly(task, spec, seed, isolate=False)
    _, apart, acts_apart = _fly(task, spec, seed, isolate=True)
    assert apart.isolated and not inside.isolated
    assert acts_apart == acts_in  # every decision
    assert apart.report == inside.report  # bit for bit, not only to 1e-12
    assert apart.final == inside.final
    assert apart.history == inside.history
    assert apart.total_reward == inside.total_reward
    assert apart.decisions == inside.decisions > 0


def test_a_parcel_carries_a_belief_bit_for_bit_and_its_file_is_removed(monkeypatch, tmp_path):
    from ipp_bench.planners import isolation
    from ipp_bench.planners.robot import unpack

    monkeypatch.setattr(isolation, "PARCEL_DIR", str(tmp_path))
    env = make_env(TASK, budget_s=BUDGET_S)
    env.reset(seed=0)
    model = env.mission.belief_model
    data, path, sizes = isolation.pack(model)
    copy = unpack((data, path, sizes))
    assert np.array_equal(copy.field.mean, model.field.mean) and np.array_equal(copy.field.cov, model.field.cov)
    assert copy.field.mean.flags.writeable and copy.field._cov.flags.writeable
    fly_episode(env, "greedy", 0, isolate=True)
    assert [p.name for p in tmp_path.iterdir()] == [Path(path).name]  # the episode's own parcel is gone


def test_the_planner_process_is_kept_warm_across_episodes_and_tasks():
    fly_episode(make_env(TASK, budget_s=BUDGET_S), "greedy", 0, isolate=True)
    worker = _POOL[("greedy", id(REGISTRY))]
    fly_episode(make_env(TWIN, budget_s=BUDGET_S), "greedy", 1, isolate=True)
    assert _POOL[("greedy", id(REGISTRY))] is worker and worker.process.is_alive()


# -- the truth is out of reach ----------------------------------------------------------------------------------
def test_in_process_a_planner_reads_the_truth_all_three_ways(tmp_path):
    out = tmp_path / "found.json"
    env, _, _ = _fly(TASK, f"reads-truth:out={out}", 0, isolate=False, registry=PROBES)
    found = json.loads(out.read_text())
    truth = float(env.mission.truth.sum())
    for way in ("frames", "table", "gc"):  # why isolation is needed: each read finds the episode's truth
        assert found[way]["truth"] == pytest.approx(truth), way


def test_isolated_a_planner_finds_no_truth(tmp_path):
    out = tmp_path / "found.json"
    _, result, _ = _fly(TASK, f"reads-truth:out={out}", 0, isolate=True, registry=PROBES)
    found = json.loads(out.read_text())
    assert result.decisions > 0
    for way in ("frames", "table", "gc"):
        assert found[way]["truth"] is None, way
    assert found["table"]["missions"] == 1 and found["frames"]["missions"] >= 1  # the robot's own mission ...
    assert found["gc"]["kinds"] == [RobotMission.__name__]  # ... which has no truth; the world's is not there


def test_only_the_suite_s_own_reference_planner_gets_the_true_roi():
    for isolate in (False, True):
        with pytest.raises(ValueError, match="sets reads_truth, but only the suite's reference planners"):
            _fly(TASK, "oracle", 0, isolate=isolate, registry=POSERS)


@pytest.mark.parametrize("isolate", [False, True])
def test_a_planner_s_seed_draws_another_field_than_the_episode_s(tmp_path, isolate):
    """A planner other than the suite's gets a keyed hash of the episode's seed (the same in-process and isolated):
    handed to the task's field generator, it draws another field. (What this does not hide: docs/planners.md.)"""
    out = tmp_path / "found.json"
    env, _, _ = _fly(TASK, f"redraws-field:out={out}", 3, isolate=isolate, registry=PROBES)
    found = json.loads(out.read_text())
    assert found["seed"] == planner_seed(3, target_of("redraws-field", PROBES)) != 3
    assert found["truth"] != pytest.approx(float(env.mission.truth.sum()))


def test_the_suite_s_own_planners_get_the_episode_s_seed():
    assert planner_seed(3, target_of("random")) == 3 and planner_seed(3, target_of("greedy", PROBES)) == 3
    assert planner_seed(3, target_of(REGISTRY.make_planner("random"))) == 3
    assert planner_seed(3, target_of("reads-truth", PROBES)) not in (3, planner_seed(4, target_of("raises", PROBES)))


# -- errors, refusals and clean-up ------------------------------------------------------------------------------
def test_a_reset_that_raises_gives_the_in_process_one_line_error():
    with pytest.raises(PlannerError) as inside:
        _fly(TASK, "reset-raises", 0, isolate=False, registry=PROBES)
    with pytest.raises(PlannerError) as apart:
        _fly(TASK, "reset-raises", 0, isolate=True, registry=PROBES)
    assert str(apart.value) == str(inside.value)
    assert "its reset raised KeyError: 'no start' (at " in str(apart.value) and "\n" not in str(apart.value)


def test_a_decision_that_raises_comes_back_in_one_line_and_the_process_stays_usable():
    with pytest.raises(PlannerError, match=r"planner 'raises': its act raised RuntimeError: boom in act \(at .*"
                                           r"test_isolation.py:\d+\)"):
        _fly(TASK, "raises", 0, isolate=True, registry=PROBES)
    worker = _POOL[("raises", id(PROBES))]
    assert worker.alive
    with pytest.raises(RuntimeError, match="planner 'exits' called sys.exit during a decision"):
        _fly(TASK, "exits", 0, isolate=True, registry=PROBES)


def test_a_planner_process_that_dies_is_reported_and_gone():
    with pytest.raises(PlannerError, match=r"planner 'dies': its process ended \(exit code 7\)"):
        _fly(TASK, "dies", 0, isolate=True, registry=PROBES)
    assert ("dies", id(PROBES)) not in _POOL
    assert not [p for p in _planner_processes() if p.name.endswith(" dies")]


def test_a_run_stopped_with_ctrl_c_ends_its_planner_process():
    env = make_env(TASK, budget_s=BUDGET_S)

    def stop(decision):
        if decision.index == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        fly_episode(env, "coverage", 0, isolate=True, on_decision=stop)
    assert ("coverage", id(REGISTRY)) not in _POOL
    assert not [p for p in _planner_processes() if p.name.endswith(" coverage")]


def test_close_workers_leaves_no_process():
    fly_episode(make_env(TASK, budget_s=BUDGET_S), "random", 0, isolate=True)
    assert _planner_processes()
    close_workers()
    assert not _planner_processes() and not _POOL


def test_what_cannot_be_isolated_is_refused_in_one_line():
    team = make_env("ipp_bench/Hotspots30Team2Eval-v2")
    with pytest.raises(ValueError, match="isolate=True flies single-UAV tasks: ipp_bench/Hotspots30Team2Eval-v2 is a "
                                         "team task"):
        fly_episode(team, "greedy", 0, isolate=True)
    env = make_env(TASK, budget_s=BUDGET_S)
    with pytest.raises(ValueError, match="isolate=True takes a planner spec"):
        fly_episode(env, REGISTRY.make_planner("greedy"), 0, isolate=True)

    class Rotors:  # a platform whose clock a planner's process cannot keep (the MuJoCo world's, say)
        def begin(self, mission):
            pass

        def leg_durations(self, mission, start_xyz, end_xyzs):
            return np.full(len(np.atleast_2d(end_xyzs)), 1.0)

        def read_here(self, mission, time_s):
            return []

    env._make_mission = lambda truth, rng, start: Mission(env.config, truth, rng, start, sensor=env.sensor,
                                                          platform=Rotors())
    with pytest.raises(ValueError, match="its legs are flown by Rotors, whose clock a planner's process cannot keep"):
        start_episode(env, "greedy", 0, isolate=True)


def test_isolation_looks_the_suite_s_registry_up_where_it_is_defined(monkeypatch):
    import ipp_bench.planners as planners

    monkeypatch.setattr(planners, "REGISTRY", PROBES)  # swapped in one place: isolation's default follows
    try:
        assert describe_planner("reads-truth")["name"] == "reads-truth"
        assert ("reads-truth", id(PROBES)) in _POOL
    finally:
        close_workers()


def test_a_planner_is_described_without_importing_it_here():
    facts = describe_planner("mcts:simulations=7")
    assert facts["name"] == "mcts" and facts["kind"] == "graph" and facts["settings"]["simulations"] == 7
    assert not isolated_by_default("greedy") and not isolated_by_default("mcts:simulations=7")
    with pytest.raises(ValueError, match="unknown planner 'nope'"):
        describe_planner("nope")
