"""``ipp-bench leaderboard --sweep NAME:KEY=V1,V2,...``: the spec, its refusals, its planners in the plan, a real
run with its report section, resume and refusal, and ``--against`` with a prefix of the published episodes."""

from __future__ import annotations

import csv

import pytest
from lb_helpers import TINY_ENV, results

from ipp_bench.cli import main
from ipp_bench.eval.against import against_plan
from ipp_bench.eval.plan import episode_seeds, make_plan
from ipp_bench.eval.results import PUBLISHED_CSV
from ipp_bench.eval.results_csv import RESULTS_CSV
from ipp_bench.eval.sweep import parse_sweep, sweep_specs

TASK = "ipp_bench/Grid15Eval-v1"
ENV = ["--env", "budget_s=40", "--env", "report_times=[20, 40]"]


@pytest.mark.parametrize("text, key, specs", [
    ("mcts:simulations=8,24,064", "simulations",
     ("mcts:simulations=8", "mcts:simulations=24", "mcts:simulations=64")),
    ("mcts:simulations=8,24,search=reference", "simulations",
     ("mcts:search=reference,simulations=8", "mcts:search=reference,simulations=24")),
    ("mcts:search=reference,simulations=8,24", "simulations",
     ("mcts:search=reference,simulations=8", "mcts:search=reference,simulations=24")),
    ("cmaes:max_evals=18,36", "max_evals", ("cmaes:max_evals=18", "cmaes:max_evals=36")),
    ("mcts:exploration=0.25,1", "exploration", ("mcts:exploration=0.25,simulations=24",
                                                "mcts:exploration=1.0,simulations=24")),
])
def test_a_sweep_is_one_canonical_spec_per_value(text, key, specs):
    sweep = parse_sweep(text)
    assert (sweep.key, sweep.specs) == (key, specs)


@pytest.mark.parametrize("text, named", [
    ("mcts", "expected NAME:KEY=V1,V2"),
    ("mcts:8,24", "value '8' comes before any KEY="),
    ("mcts:simulations=8", "no setting has more than one value (simulations=8)"),
    ("mcts:simulations=8,24,exploration=1,2", "simulations and exploration each have several values"),
    ("mcts:simulations=8,,24", "an empty value between commas"),
    ("mcts:simulations=8,24,simulations=64", "setting 'simulations' is given twice"),
    ("mcts:simulations=8,08", "simulations=8 and simulations=08 are the same setting"),
    ("mcts:simulations=8,abc", "simulations=abc: mcts.simulations = 'abc' is invalid: expected an integer"),
    ("cmaes:max_evals=6,36", "max_evals=6: cmaes.max_evals = 6 is invalid: expected an integer in [12"),
    ("mcts:search=lowrank,reference", "mcts.search = 'lowrank' is not a number"),
    ("mcts:nope=1,2", "planner 'mcts' has no setting ['nope']"),
    ("nope:x=1,2", "unknown planner 'nope'"),
])
def test_a_bad_sweep_is_refused_in_one_line_naming_it(text, named, tmp_path, capsys):
    with pytest.raises(ValueError) as err:
        parse_sweep(text)
    assert named in str(err.value) and str(err.value).startswith(f"--sweep {text!r}")
    out = tmp_path / "x"
    assert main(["leaderboard", "--sweep", text, "--tasks", TASK, "--out", str(out)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and named in lines[0] and "Traceback" not in lines[0]
    assert not out.exists()  # refused before any work


def test_the_sweep_expands_into_the_plan_and_its_jobs_on_the_same_seeds():
    swept = sweep_specs(["mcts:simulations=3,5", "cmaes:max_evals=18,36"])
    plan = make_plan([TASK], ["greedy", "mcts:simulations=5"], episodes=2, seed=7, env_overrides=TINY_ENV,
                     log=lambda m: None, check_start=False, sweeps=swept)
    # a sweep's point that is one of the planners flies once
    assert plan.planners == ("greedy", "mcts:simulations=5", "mcts:simulations=3", "cmaes:max_evals=18",
                             "cmaes:max_evals=36")
    jobs = plan.jobs()
    assert {(j.planner, j.seed) for j in jobs} == {(p, s) for p in plan.planners for s in episode_seeds(7, 2)}
    assert len(jobs) == 10
    assert plan.fingerprint()["planners"] == sorted(plan.planners)  # a rerun with another sweep is refused


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "board"
    argv = ["leaderboard", "--tasks", TASK, "--planners", "greedy", "attention", "--sweep", "mcts:simulations=2,4",
            "--episodes", "2", "--seed", "7", *ENV, "--out", str(out), "--backend", "serial", "--no-progress"]
    assert main(argv) == 0
    return out, argv


def test_a_sweep_flies_on_the_board_and_the_report_draws_the_frontier(swept):
    out, _ = swept
    rows = results(out)
    assert {r["planner"] for r in rows} == {"greedy", "attention", "mcts:simulations=2", "mcts:simulations=4"}
    seeds = {p: {r["seed"] for r in rows if r["planner"] == p} for p in {r["planner"] for r in rows}}
    assert all(s == set(episode_seeds(7, 2)) for s in seeds.values())
    md = (out / "leaderboard.md").read_text()
    section = md.split("## Quality against decision time", 1)[1]
    assert "![quality against decision time, Grid15Eval-v1](frontier_Grid15Eval-v1.png)" in section
    assert "| `mcts:simulations=2` | simulations=2 |" in section and "| `greedy` | – |" in section
    assert "Which MCTS setting is as good as `attention`" in section and "- at 40 s:" in section
    assert (out / "frontier_Grid15Eval-v1.png").stat().st_size > 10_000


def test_the_same_command_resumes_and_another_sweep_is_refused(swept, capsys):
    out, argv = swept
    before = (out / RESULTS_CSV).read_bytes()
    assert main(argv) == 0
    assert "already complete" in capsys.readouterr().out
    assert (out / RESULTS_CSV).read_bytes() == before
    other = [a if a != "mcts:simulations=2,4" else "mcts:simulations=2,8" for a in argv]
    assert main(other) == 2
    err = capsys.readouterr().err
    assert "mcts:simulations=8" in err and "planners: there" in err
    assert (out / RESULTS_CSV).read_bytes() == before


def test_a_sweep_against_a_prefix_of_a_published_board(swept, tmp_path, capsys):
    published, _ = swept
    out = tmp_path / "mine"
    argv = ["leaderboard", "--against", str(published), "--sweep", "mcts:simulations=2,3", "--episodes", "1",
            "--out", str(out), "--backend", "serial", "--no-progress"]
    assert main(argv) == 0
    log = capsys.readouterr().out
    assert "mcts:simulations=2 is on the board already" in log  # its published rows join the sweep
    first = episode_seeds(7, 1)
    assert {(r["planner"], r["seed"]) for r in results(out)} == {("mcts:simulations=3", first[0])}
    lines = (published / RESULTS_CSV).read_text().splitlines(keepends=True)
    kept = [ln for ln in lines[1:] if int(next(csv.reader([ln]))[2]) == first[0]]
    assert (out / PUBLISHED_CSV).read_text() == "".join(lines[:1] + kept) and len(kept) == 8  # 4 planners x 2 times
    assert "| `mcts:simulations=3` | simulations=3 |" in (out / "leaderboard.md").read_text()
    # the rest of the board's episodes extend the same folder; more than it has are refused
    assert main([a if a != "1" else "2" for a in argv]) == 0
    assert {r["seed"] for r in results(out)} == set(episode_seeds(7, 2))
    assert (out / PUBLISHED_CSV).read_bytes() == (published / RESULTS_CSV).read_bytes()
    capsys.readouterr()
    assert main([a if a != "1" else "3" for a in argv]) == 2
    assert "--episodes 3: the board has 2 per task and planner" in capsys.readouterr().err


def test_against_some_of_the_boards_tasks_plans_those_and_refuses_nothing_to_fly(reference_run, tmp_path):
    board = reference_run[0]
    plan = against_plan(board, ["coverage:overlap=0.5"], tasks=["Grid20Eval-v1"], episodes=1, log=lambda m: None,
                        check_start=False)
    assert plan.tasks == ("ipp_bench/Grid20Eval-v1",) and plan.seeds == tuple(episode_seeds(7, 1))
    with pytest.raises(ValueError, match="nothing to fly: every --sweep point is on the board already"):
        against_plan(board, [], sweeps=["mcts:simulations=3"], log=lambda m: None, check_start=False)
