"""A planner from another package joins the registry through the ``ipp_bench.planners`` entry point;
a probe planner joins a local registry, which the suite's never sees.

The plugin tests "install" a tiny package the way pip leaves one on disk (the module and a ``.dist-info``
folder with ``entry_points.txt``) in a folder on ``sys.path``, and run it through the CLI, on a fresh
suite registry (so the plugin leaves no trace in later tests).
"""

from __future__ import annotations

import re
import textwrap
from dataclasses import dataclass

import numpy as np
import pytest

import ipp_bench.planners as planners
from ipp_bench.cli import main
from ipp_bench.core.gains import first_best
from ipp_bench.envs import make_env
from ipp_bench.planners.episode import fly_episode, start_episode
from ipp_bench.planners.greedy import GreedyPlanner

TASK = "ipp_bench/Grid15Eval-v1"

@pytest.fixture
def installed_plugin(plugin_site, monkeypatch):
    plugin_site("their_planners")
    monkeypatch.setattr(planners, "REGISTRY", planners.PlannerRegistry(planners.BUILT_IN, plugins=True))


def test_an_installed_plugin_is_found_by_name_and_runs(installed_plugin, tmp_path, capsys):
    assert "theirs" in planners.planner_names()
    assert planners.make_planner("theirs").name == "first"
    out = tmp_path / "lb"
    assert main(["leaderboard", "--tasks", "Grid15Eval-v1", "--planners", "theirs", "greedy", "--episodes", "1",
                 "--backend", "serial", "--no-progress", "--out", str(out), "--env", "budget_s=20",
                 "--env", "report_times=[20]"]) == 0
    assert "`theirs`" in (out / "leaderboard.md").read_text()


def test_a_plugin_never_replaces_a_built_in_name(installed_plugin, tmp_path):
    info = next(tmp_path.glob("site/*.dist-info"))
    (info / "entry_points.txt").write_text("[ipp_bench.planners]\ngreedy = their_planners:FirstPlanner\n")
    assert planners.planner_class("greedy").__module__ == "ipp_bench.planners.greedy"


# -- local registries -------------------------------------------------------------------------------


@dataclass(frozen=True)
class KnobConfig:
    power: float = 1.0  # [-] greedy's score raised to this power (1: greedy itself)


class KnobGreedy(GreedyPlanner):
    """A probe: greedy's score to a power, which changes nothing at power 1 (scores are positive)."""

    name = "knob"
    Config = KnobConfig

    def act(self, obs):
        scores = self.scores(obs)
        return first_best(np.where(np.isfinite(scores), np.maximum(scores, 0.0) ** self.settings.power, -np.inf))


def _suite_state():
    return dict(planners.REGISTRY), planners.planner_names()


def test_a_probe_in_a_local_registry_flies_and_the_suites_registry_never_sees_it():
    before = _suite_state()
    probes = planners.REGISTRY.copy()
    planners.register("knob", KnobGreedy, registry=probes)
    assert "knob" in probes.names() and set(planners.planner_names()) < set(probes.names())
    assert _suite_state() == before
    with pytest.raises(ValueError, match="unknown planner 'knob'"):
        planners.make_planner("knob")
    env = make_env(TASK)
    greedy = fly_episode(env, "greedy", 3)
    knob = fly_episode(env, "knob:power=1", 3, registry=probes)  # the suite's planners are there too
    assert knob.report == greedy.report and knob.decisions == greedy.decisions
    assert isinstance(planners.make_planner("knob:power=2", registry=probes), KnobGreedy)
    assert probes.make_planner("knob:power=2").settings == KnobConfig(power=2.0)
    with pytest.raises(ValueError, match="knob.power = 'high' is invalid: expected a number"):
        probes.make_planner("knob:power=high")
    assert _suite_state() == before


def test_registries_are_apart_both_ways():
    a = planners.PlannerRegistry({"greedy": planners.BUILT_IN["greedy"]})
    b = a.copy()
    b.register("knob", KnobGreedy)
    a.register("random", planners.BUILT_IN["random"])
    assert a.names() == ["greedy", "random"] and b.names() == ["greedy", "knob"]
    del b["greedy"]
    assert "greedy" in a and "greedy" not in b
    assert b["knob"] == f"{__name__}:KnobGreedy" and b.planner_class("knob") is KnobGreedy
    b["knob"] = "ipp_bench.planners.greedy:GreedyPlanner"  # a target replaces the class
    assert b.planner_class("knob") is GreedyPlanner


def test_a_probe_cannot_grant_itself_the_truth_from_a_local_registry():
    class Peeker(GreedyPlanner):
        name = "oracle"
        reads_truth = True

    probes = planners.PlannerRegistry()
    probes.register("oracle", Peeker)
    env = make_env(TASK)
    with pytest.raises(ValueError, match="only the suite's reference planners"):
        start_episode(env, "oracle", 0, registry=probes)
    assert planners.planner_class("oracle").__module__ == "ipp_bench.planners.oracle"


@pytest.mark.parametrize("name, target, message", [
    ("a:b", "x:Y", "planner name 'a:b' is invalid"),
    ("", "x:Y", "planner name '' is invalid"),
    ("probe", "no_colon", "planner 'probe': target 'no_colon' is invalid: expected 'module:Class' or a class"),
    ("probe", 3, "target 3 is invalid"),
])
def test_a_bad_registration_is_one_line(name, target, message):
    probes = planners.PlannerRegistry()
    with pytest.raises(ValueError, match=re.escape(message)):
        probes.register(name, target)
    assert probes.names() == []


# -- a plugin that fails: one line naming it, what it raised and where ------------------------------------------

FAILING = '''
import sys
from dataclasses import dataclass

import numpy as np

from ipp_bench.planners.base import GraphPlanner

{at_import}


@dataclass(frozen=True)
class BadConfig:
    """No settings."""


class BadPlanner(GraphPlanner):
    name = "bad"
    Config = BadConfig

    def __init__(self, config=None):
        super().__init__(config)
        {at_init}

    def reset(self, view, seed):
        super().reset(view, seed)
        {at_reset}

    def act(self, obs):
        {at_act}
        return int(np.flatnonzero(obs["action_mask"])[0])
'''

QUIET = {"at_import": "", "at_init": "pass", "at_reset": "pass", "at_act": "pass"}


def _install_failing(tmp_path, monkeypatch, **where):
    site = tmp_path / "failing_site"
    (site / "bad_planners").mkdir(parents=True)
    code = FAILING.format(**{**QUIET, **where})
    (site / "bad_planners" / "__init__.py").write_text(code)
    info = site / "bad_planners-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: bad-planners\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[ipp_bench.planners]\nbad = bad_planners:BadPlanner\n")
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.delitem(__import__("sys").modules, "bad_planners", raising=False)
    monkeypatch.setattr(planners, "REGISTRY", planners.PlannerRegistry(planners.BUILT_IN, plugins=True))
    line = next(i for i, text in enumerate(code.splitlines(), 1) if "Boom" in text or "sys.exit" in text)
    return f"{site / 'bad_planners' / '__init__.py'}:{line}"


ENTRY = "planner 'bad' (entry point 'bad = bad_planners:BadPlanner' of 'ipp_bench.planners')"


@pytest.mark.parametrize("where, raised, message", [
    ("at_import", "raise RuntimeError('Boom at import')",
     ENTRY + ": importing bad_planners raised RuntimeError: Boom at import (at {at})"),
    ("at_import", "import no_such_module_Boom",
     ENTRY + ": importing bad_planners raised ModuleNotFoundError: No module named 'no_such_module_Boom' (at {at})"),
    ("at_import", "sys.exit(0)", ENTRY + ": importing bad_planners raised SystemExit (sys.exit(0)) (at {at})"),
    ("at_init", "raise KeyError('Boom')", ENTRY + ": building it raised KeyError: 'Boom' (at {at})"),
    ("at_init", "sys.exit(3)", ENTRY + ": building it raised SystemExit (sys.exit(3)) (at {at})"),
    ("at_reset", "raise ZeroDivisionError('Boom')",
     "planner 'bad': its reset raised ZeroDivisionError: Boom (at {at})"),
    ("at_reset", "sys.exit()", "planner 'bad': its reset raised SystemExit (sys.exit(None)) (at {at})"),
], ids=["import-raises", "import-misses-a-module", "import-exits", "init-raises", "init-exits", "reset-raises",
        "reset-exits"])
def test_a_plugin_failing_before_its_first_decision_is_one_line(tmp_path, monkeypatch, capsys, where, raised,
                                                               message):
    at = _install_failing(tmp_path, monkeypatch, **{where: raised})
    assert main(["evaluate", "--task", TASK, "--planner", "bad", "--env", "budget_s=20",
                 "--env", "report_times=[20]"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "ipp-bench: error: " + message.format(at=at), err


def test_a_plugin_that_calls_sys_exit_in_a_decision_fails_the_episode_in_one_line(tmp_path, monkeypatch, capsys):
    at = _install_failing(tmp_path, monkeypatch, at_act="sys.exit(0)")
    with pytest.raises(RuntimeError, match=re.escape(f"planner 'bad' called sys.exit during a decision: SystemExit "
                                                     f"(sys.exit(0)) (at {at})")):
        fly_episode(make_env(TASK, budget_s=20.0, report_times=[20.0]), "bad", 0)
    assert main(["evaluate", "--task", TASK, "--planner", "bad", "--env", "budget_s=20",
                 "--env", "report_times=[20]"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "called sys.exit during a decision" in err and "seed 0 failed" in err, err


def test_a_plugin_whose_config_raises_is_one_line(tmp_path, monkeypatch):
    site = tmp_path / "cfg_site"
    site.mkdir()
    (site / "cfg_planners.py").write_text(textwrap.dedent('''
        from dataclasses import dataclass
        from ipp_bench.planners.base import GraphPlanner

        @dataclass(frozen=True)
        class C:
            x: int = 1
            def __post_init__(self):
                raise TypeError("Boom in config")

        class P(GraphPlanner):
            name = "cfg"
            Config = C
    '''))
    monkeypatch.syspath_prepend(str(site))
    probes = planners.PlannerRegistry({"cfg": "cfg_planners:P"})
    with pytest.raises(planners.PlannerError, match=r"^planner 'cfg' \(cfg_planners:P\): its Config raised "
                                                    r"TypeError: Boom in config \(at .*cfg_planners.py:9\)$"):
        probes.make_planner("cfg")
    monkeypatch.delitem(__import__("sys").modules, "cfg_planners", raising=False)
