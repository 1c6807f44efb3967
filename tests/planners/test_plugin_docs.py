"""docs/planners.md, the page for plugin authors, says what runs: its example planner is executed
as written and flies an episode through the suite's one loop."""

from __future__ import annotations

import re
import sys
import types
from pathlib import Path

import pytest

from ipp_bench import planners
from ipp_bench.eval.runner import run_episode

DOC = Path(__file__).resolve().parents[2] / "docs" / "planners.md"


@pytest.fixture
def example_module(monkeypatch):
    code = re.search(r"```python\n(.*?)```", DOC.read_text(), re.S).group(1)
    module = types.ModuleType("docs_planner_example")
    monkeypatch.setitem(sys.modules, module.__name__, module)  # dataclasses look their module up
    exec(compile(code, str(DOC), "exec"), module.__dict__)
    monkeypatch.setitem(planners.REGISTRY, "lowest", f"{module.__name__}:LowestFirstPlanner")
    return module


def test_the_documented_example_planner_runs_an_episode(example_module):
    result = run_episode("ipp_bench/Grid15Eval-v1", "lowest:tie_break=random", seed=3, budget_s=40,
                         report_times=[20, 40])
    assert result.decisions > 0 and [r["time_s"] for r in result.report] == [20.0, 40.0]
    with pytest.raises(ValueError, match="lowest.tie_break = 'best' is invalid"):
        planners.make_planner("lowest:tie_break=best")


def test_the_documented_observation_keys_are_the_envs():
    import gymnasium as gym

    documented = set(re.findall(r"^\| `(\w+)` \|", DOC.read_text(), re.M))
    env = gym.make("ipp_bench/Grid15Eval-v1")
    assert documented == set(env.observation_space.spaces)


def test_attention_policy_is_importable_from_the_documented_place():
    pytest.importorskip("sb3_contrib")
    from ipp_bench.policies import AttentionPlanner, AttentionPolicy
    from ipp_bench.policies.planner import AttentionPlanner as planner_cls
    from ipp_bench.policies.sb3 import AttentionPolicy as policy_cls

    assert AttentionPolicy is policy_cls and AttentionPlanner is planner_cls
