"""Planning a leaderboard run (ipp_bench.eval.plan): seeds, canonical specs, bad arguments, quick mode."""

from __future__ import annotations

import pytest

import ipp_bench.eval.plan as plan_module
from ipp_bench.eval.plan import QUICK_EPISODES, QUICK_OVERRIDES, episode_seeds, make_plan
from ipp_bench.planners import REGISTRY, PlannerError, parse_spec, split_specs


def test_episode_seeds_are_deterministic_distinct_and_prefix_stable():
    seeds = episode_seeds(3, 5)
    assert seeds == episode_seeds(3, 5)
    assert len(set(seeds)) == 5
    assert episode_seeds(3, 2) == seeds[:2]
    assert episode_seeds(4, 5) != seeds
    assert all(0 <= s < 2**31 for s in seeds)
    with pytest.raises(ValueError, match="episodes"):
        episode_seeds(0, 0)


def test_plan_canonicalises_specs_and_resolves_short_task_names():
    plan = make_plan(tasks=["Grid15Eval-v1"], planners=["random", "mcts:simulations=007"], episodes=2)
    assert plan.tasks == ("ipp_bench/Grid15Eval-v1",)
    assert plan.planners == ("random", "mcts:simulations=7")
    assert len(plan.jobs()) == 4


@pytest.mark.parametrize("kwargs, match", [
    (dict(planners=["nope"]), "unknown planner 'nope'"),
    (dict(planners=["greedy:depth=3"]), "has no setting"),
    (dict(planners=["mcts:simulations=many"]), "mcts.simulations"),
    (dict(tasks=["Nope-v0"]), "unknown task"),
    (dict(planners=["random", "random"]), "given twice"),
    (dict(env_overrides={"budget_s": 10}), "no report time"),
    (dict(env_overrides={"no_such_field": 1}), "unknown config field"),
], ids=["planner", "setting", "value", "task", "duplicate", "budget", "override"])
def test_bad_arguments_fail_with_the_library_message(kwargs, match):
    args = dict(tasks=["Grid15Eval-v1"], planners=["random"], episodes=1, log=lambda m: None)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        make_plan(**args)


def test_quick_overrides_fit_every_planner_and_the_spec_wins():
    names = [n for n in QUICK_OVERRIDES if n in REGISTRY]
    assert names, "quick mode overrides no registered planner"
    plan = make_plan(tasks=["Grid15Eval-v1"], planners=names, quick=True, log=lambda m: None)
    assert plan.episodes == QUICK_EPISODES
    for spec in plan.planners:
        name, overrides = parse_spec(spec)
        assert {k: str(v) for k, v in QUICK_OVERRIDES[name].items()}.items() <= overrides.items()
    own = make_plan(tasks=["Grid15Eval-v1"], planners=["mcts:simulations=2"], quick=True)
    assert own.planners == ("mcts:simulations=2",)


def test_default_planners_leave_out_what_cannot_load_but_explicit_fails_loudly(monkeypatch):
    monkeypatch.setitem(REGISTRY, "ghost", "ipp_bench.planners.no_such_module:Ghost")
    monkeypatch.setattr(plan_module, "planner_names", lambda: ["random", "ghost"])
    notes = []
    plan = make_plan(tasks=["Grid15Eval-v1"], episodes=1, log=notes.append)
    assert plan.planners == ("random",)
    assert any("ghost" in n and "no_such_module" in n for n in notes)
    with pytest.raises(PlannerError, match="no_such_module"):
        make_plan(tasks=["Grid15Eval-v1"], planners=["ghost"], episodes=1)


def test_comma_separated_specs_split_where_a_new_planner_starts():
    assert split_specs(["random,coverage", "mcts:simulations=8,exploration=0.5,greedy"]) == [
        "random", "coverage", "mcts:simulations=8,exploration=0.5", "greedy"]
    assert split_specs(["greedy", "cmaes:max_evals=24"]) == ["greedy", "cmaes:max_evals=24"]


def test_a_quick_that_changes_nothing_is_no_quick_run():
    assert not make_plan(tasks=["Grid15Eval-v1"], planners=["random"], episodes=2, quick=True).quick
    assert make_plan(tasks=["Grid15Eval-v1"], planners=["random"], quick=True).quick  # fewer episodes
    assert make_plan(tasks=["Grid15Eval-v1"], planners=["mcts"], episodes=2, quick=True).quick  # cheaper MCTS


class _NoConfigPlanner:
    """A plugin that forgot its Config."""

    name = "noconfig"


def test_a_plugin_without_config_is_left_out_of_the_default_list_with_a_note(monkeypatch):
    from ipp_bench import planners
    from ipp_bench.eval.plan import make_plan

    monkeypatch.setitem(planners.REGISTRY, "noconfig", f"{__name__}:_NoConfigPlanner")
    monkeypatch.setitem(planners.REGISTRY, "missing", f"{__name__}:NoSuchClass")
    notes = []
    plan = make_plan(tasks=["Grid15Eval-v1"], episodes=1, log=notes.append)
    assert "noconfig" not in plan.planners and "missing" not in plan.planners and "random" in plan.planners
    assert any("'noconfig'" in n and "no Config dataclass" in n for n in notes), notes
    assert any("'missing'" in n and "NoSuchClass" in n for n in notes), notes
    with pytest.raises(ValueError, match="no Config dataclass"):  # asked for by name: refused
        make_plan(tasks=["Grid15Eval-v1"], planners=["noconfig"], episodes=1, log=notes.append)
