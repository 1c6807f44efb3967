"""``ipp-bench leaderboard --isolate``: planners flown in a process of their own (on by default for plugins'
planners and ``--against`` submissions), the same numbers, and run.json and the report saying which."""

from __future__ import annotations

import json
import os
import sys

import pytest
from lb_helpers import assert_same_results, results

import ipp_bench.planners as planners
import ipp_bench.planners.isolation as isolation
from ipp_bench.cli import main
from ipp_bench.eval.plan import default_planners
from ipp_bench.eval.results_csv import RESULTS_CSV
from ipp_bench.eval.run_json import ISOLATED_KEY, RUN_JSON

TINY = ["--tasks", "Grid15Eval-v1", "--episodes", "1", "--env", "budget_s=20", "--env", "report_times=[20]",
        "--backend", "serial", "--no-progress"]
FLOWN = "Flown isolated: "


def leaderboard(out, *extra):
    return main(["leaderboard", *TINY, "--out", str(out), *extra])


def run_json(out):
    return json.loads((out / RUN_JSON).read_text())


@pytest.fixture(scope="module")
def boards(tmp_path_factory):
    """greedy flown in-process and isolated, on one tiny board each."""
    root = tmp_path_factory.mktemp("isolate")
    assert leaderboard(root / "plain", "--planners", "greedy") == 0
    assert leaderboard(root / "isolated", "--planners", "greedy", "--isolate") == 0
    return root / "plain", root / "isolated"


def test_isolate_gives_the_same_rows_and_says_so(boards):
    plain, isolated = boards
    assert_same_results(results(isolated), results(plain))
    assert run_json(isolated)[ISOLATED_KEY] == ["greedy"]
    assert ISOLATED_KEY not in run_json(plain)
    assert run_json(isolated)["fingerprint"] == run_json(plain)["fingerprint"]  # isolation changes no number
    md = (isolated / "leaderboard.md").read_text()
    assert f"{FLOWN}`greedy`" in md
    assert FLOWN not in (plain / "leaderboard.md").read_text()  # no isolated row: the report as before


def test_a_folder_flown_in_process_resumes_isolated_and_records_it(boards, tmp_path):
    import shutil

    out = tmp_path / "run"
    shutil.copytree(boards[0], out)
    assert leaderboard(out, "--planners", "greedy", "--isolate", "--episodes", "2") == 0
    assert run_json(out)[ISOLATED_KEY] == ["greedy"]  # one of its two episodes flew isolated
    assert f"{FLOWN}`greedy`" in (out / "leaderboard.md").read_text()


def test_an_against_submission_flies_isolated_and_the_published_record_is_kept(boards, tmp_path, capsys):
    """The published board flew greedy isolated: its rows keep saying so; the submission flies isolated too."""
    out = tmp_path / "mine"
    assert main(["leaderboard", "--planners", "coverage", "--against", str(boards[1]), "--out", str(out),
                 "--backend", "serial", "--no-progress"]) == 0
    assert run_json(out)[ISOLATED_KEY] == ["coverage"]
    md = (out / "leaderboard.md").read_text()
    line = next(x for x in md.splitlines() if x.startswith(FLOWN))
    assert "`greedy` (published)" in line and "`coverage`" in line
    assert "isolated (each in a process of its own): coverage" in capsys.readouterr().out


def test_a_team_task_with_isolate_is_refused_in_one_line_before_any_work(tmp_path, capsys):
    out = tmp_path / "lb"
    assert main(["leaderboard", "--tasks", "Hotspots30Team2Eval-v2", "--planners", "greedy", "--isolate",
                 "--episodes", "1", "--backend", "serial", "--no-progress", "--out", str(out)]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "Hotspots30Team2Eval-v2" in err and "greedy" in err and "team task" in err and "--isolate" in err
    assert not out.exists()


@pytest.fixture
def plugin(plugin_site, monkeypatch):
    """A plugin ``theirs`` "installed" on sys.path (a module and its .dist-info), on a fresh suite registry."""
    info = plugin_site("their_isolated")
    monkeypatch.setattr(planners, "REGISTRY", planners.PlannerRegistry(planners.BUILT_IN, plugins=True))
    yield info
    isolation.close_workers()


def test_a_plugins_planner_is_isolated_by_default(plugin, tmp_path):
    out = tmp_path / "lb"
    assert leaderboard(out, "--planners", "theirs", "greedy") == 0
    assert run_json(out)[ISOLATED_KEY] == ["theirs"]  # the suite's greedy flies in-process
    assert {r["planner"] for r in results(out)} == {"theirs", "greedy"}
    assert (out / RESULTS_CSV).exists()
    line = next(x for x in (out / "leaderboard.md").read_text().splitlines() if x.startswith(FLOWN))
    assert "`theirs`" in line and "`greedy`" not in line


def test_planning_and_flying_a_plugins_planner_never_imports_it_beside_the_truth(plugin, tmp_path):
    """The plugin's module marks every process that imports it: only planner processes do, never this one
    (the default list, the plan's settings and fingerprint, the start check and the episodes)."""
    marks = tmp_path / "imported-by"
    marks.mkdir()
    module = plugin.parent / "their_isolated" / "__init__.py"
    module.write_text(f"import os, pathlib\npathlib.Path({str(marks)!r}, str(os.getpid())).touch()\n"
                      + module.read_text())
    assert "theirs" in default_planners(log=lambda line: None)
    assert leaderboard(tmp_path / "lb", "--planners", "theirs", "--quick") == 0
    assert "their_isolated" not in sys.modules
    importers = {int(p.name) for p in marks.iterdir()}
    assert importers and os.getpid() not in importers


def test_sweeping_a_plugins_planner_never_imports_it_beside_the_truth(plugin, tmp_path):
    """A --sweep of a plugin's setting: its points' settings and the report's frontier come from the planner's
    own process; this one never imports the plugin."""
    marks = tmp_path / "imported-by"
    marks.mkdir()
    module = plugin.parent / "their_isolated" / "__init__.py"
    module.write_text(f"import os, pathlib\npathlib.Path({str(marks)!r}, str(os.getpid())).touch()\n"
                      + module.read_text())
    out = tmp_path / "lb"
    assert leaderboard(out, "--planners", "greedy", "--sweep", "theirs:index=0,1", "--quick") == 0
    assert "their_isolated" not in sys.modules
    importers = {int(p.name) for p in marks.iterdir()}
    assert importers and os.getpid() not in importers
    assert {r["planner"] for r in results(out)} == {"greedy", "theirs:index=0", "theirs:index=1"}
    assert "theirs" in (out / "leaderboard.md").read_text().split("Quality against decision time")[1]


def test_a_plugins_planner_on_a_team_task_is_refused_in_one_line(plugin, tmp_path, capsys):
    out = tmp_path / "lb"
    assert main(["leaderboard", "--tasks", "Hotspots30Team2Eval-v2", "--planners", "theirs", "--episodes", "1",
                 "--backend", "serial", "--no-progress", "--out", str(out)]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "Hotspots30Team2Eval-v2" in err and "theirs" in err and "plugin" in err
    assert not out.exists()
