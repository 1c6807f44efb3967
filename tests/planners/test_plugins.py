"""A planner from another package joins the registry through the ``ipp_bench.planners`` entry point.

The test "installs" a tiny package the way pip leaves one on disk (the module and a ``.dist-info``
folder with ``entry_points.txt``) in a folder on ``sys.path``, and runs it through the CLI.
"""

from __future__ import annotations

import textwrap

import pytest

import ipp_bench.planners as planners
from ipp_bench.cli import main

PLANNER = '''
from dataclasses import dataclass

import numpy as np

from ipp_bench.planners.base import GraphPlanner


@dataclass(frozen=True)
class FirstConfig:
    """No settings: always the first affordable neighbour."""


class FirstPlanner(GraphPlanner):
    name = "first"
    Config = FirstConfig

    def act(self, obs):
        return int(np.flatnonzero(obs["action_mask"])[0])
'''


@pytest.fixture
def installed_plugin(tmp_path, monkeypatch):
    site = tmp_path / "site"
    (site / "their_planners").mkdir(parents=True)
    (site / "their_planners" / "__init__.py").write_text(textwrap.dedent(PLANNER))
    info = site / "their_planners-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: their-planners\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[ipp_bench.planners]\ntheirs = their_planners:FirstPlanner\n")
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setattr(planners, "_plugins_loaded", False)
    monkeypatch.setattr(planners, "REGISTRY", dict(planners.REGISTRY))
    yield
    monkeypatch.delitem(__import__("sys").modules, "their_planners", raising=False)


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
