"""``ipp-bench`` (ipp_bench.cli) smoke tests through ``main([...])``; bad input is tests/test_bad_input.py."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from ipp_bench.cli import main
from ipp_bench.eval.executors import check_executor_args
from ipp_bench.eval.plan import QUICK_EPISODES

TINY = ["--env", "budget_s=40", "--env", "report_times=[20,40]"]
REPO = Path(__file__).resolve().parents[1]


def test_tasks_lists_ids_and_tags(capsys):
    assert main(["tasks"]) == 0
    out = capsys.readouterr().out
    assert "ipp_bench/Grid15Eval-v1" in out and "benchmark" in out and "train" in out


def test_evaluate_prints_the_metrics_and_renders(capsys, tmp_path):
    png = tmp_path / "final.png"
    assert main(["evaluate", "--task", "Grid15Eval-v1", "--planner", "greedy", "--seed", "3",
                 "--render", str(png), *TINY]) == 0
    out = capsys.readouterr().out
    assert "uncertainty red." in out and "decisions" in out
    assert out.count("%") >= 4  # two report times, two reductions
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert main(["evaluate", "--task", "Grid15Eval-v1", "--planner", "random", "--seed", "3", "--json", *TINY]) == 0
    data = json.loads(capsys.readouterr().out)
    assert [r["time_s"] for r in data["report"]] == [20.0, 40.0] and data["decisions"] > 0


@pytest.mark.parametrize("argv, message", [
    (["evaluate", "--task", "Grid15Eval-v1", "--planner", "nope"], "unknown planner 'nope'"),
    (["evaluate", "--task", "Nope-v0", "--planner", "random"], "unknown task"),
    (["evaluate", "--task", "Grid15Eval-v1", "--planner", "mcts:simulations=0"], "mcts.simulations"),
    (["leaderboard", "--planners", "greedy:depth=2"], "has no setting"),
    (["leaderboard", "--planners", "random", "--episodes", "0"], "episodes"),
    (["leaderboard", "--planners", "random", "--workers", "0"], "workers"),
    (["leaderboard", "--planners", "random", "--backend", "serial", "--address", "ray://x:1"], "--address"),
], ids=["planner", "task", "setting", "lb-setting", "episodes", "workers", "address"])
def test_bad_arguments_exit_2_with_the_message_and_no_traceback(argv, message, capsys, tmp_path):
    assert main([*argv, *(["--out", str(tmp_path / "o")] if argv[0] == "leaderboard" else [])]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "o" / "results.csv").exists()


def test_leaderboard_runs_resumes_and_refuses_other_arguments(capsys, tmp_path):
    out = tmp_path / "lb"
    argv = ["leaderboard", "--tasks", "Grid15Eval-v1", "--planners", "random", "coverage", "--episodes", "2",
            "--seed", "1", "--backend", "serial", "--no-progress", "--out", str(out), *TINY]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "[4/4]" in text and "leaderboard.md" in text
    assert {"results.csv", "run.json", "leaderboard.md", "runtime_per_decision.png"} <= {p.name for p in out.iterdir()}
    assert main(argv) == 0
    assert "4 already in" in capsys.readouterr().out
    assert main([*argv, "--seed", "2"]) == 2
    err = capsys.readouterr().err
    assert "seed" in err and "--out" in err


def test_quick_help_matches_the_constant(capsys):
    with pytest.raises(SystemExit):
        main(["leaderboard", "--help"])
    assert f"--quick: {QUICK_EPISODES}" in capsys.readouterr().out


def test_leaderboard_imports_neither_torch_nor_mujoco(tmp_path):
    code = (
        "import sys; from ipp_bench.cli import main; "
        f"rc = main(['leaderboard', '--tasks', 'Grid15Eval-v1', '--planners', 'random', '--episodes', '1', "
        f"'--backend', 'serial', '--progress', '--out', {str(tmp_path / 'lb')!r}, '--env', 'budget_s=20', "
        "'--env', 'report_times=[20]']); "
        "heavy = [m for m in ('torch', 'mujoco', 'stable_baselines3') if m in sys.modules]; "
        "assert rc == 0 and not heavy, (rc, heavy)"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "1/1" in proc.stderr  # the tqdm bar (forced on with --progress)


@pytest.mark.parametrize("command, extra", [("train", "train"), ("demo", "sim")])
def test_missing_subcommand_module_names_the_extra(command, extra, monkeypatch, capsys):
    from ipp_bench import cli

    module = cli._DELEGATED[command][0]  # the subcommand's own module
    monkeypatch.setitem(sys.modules, module, None)  # import now raises ImportError, as without the extra
    assert main([command, "--help"]) == 2
    err = capsys.readouterr().err
    assert f'pip install "ipp-bench[{extra}]"' in err and "Traceback" not in err


def test_ray_backend_without_ray_names_the_extra(monkeypatch, capsys, tmp_path):
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(ImportError, match=r'ipp-bench\[ray\]'):
        check_executor_args("ray")
    assert main(["leaderboard", "--planners", "random", "--backend", "ray", "--out", str(tmp_path / "o")]) == 2
    assert 'pip install "ipp-bench[ray]"' in capsys.readouterr().err


def test_evaluate_without_a_report_time_in_the_budget_prints_the_end_of_the_mission(capsys):
    assert main(["evaluate", "--task", "Grid15Eval-v1", "--planner", "greedy", "--env", "budget_s=12"]) == 0
    out = capsys.readouterr().out
    assert "no report time lies within the budget" in out and out.count("%") == 2


def test_evaluate_shows_progress_on_long_episodes_on_stderr(capsys, monkeypatch):
    import ipp_bench.cli as cli

    monkeypatch.setattr(cli, "EVALUATE_PROGRESS_EVERY_S", 0.0)  # every decision is "long"
    assert main(["evaluate", "--task", "Grid15Eval-v1", "--planner", "greedy", "--json", *TINY]) == 0
    out, err = capsys.readouterr()
    json.loads(out)  # stdout stays the JSON alone
    lines = [ln for ln in err.splitlines() if ln]
    assert lines and all(ln.startswith("  ... mission time ") and "of 40 s" in ln for ln in lines)


def test_a_reader_that_leaves_early_gets_no_traceback():
    """``ipp-bench power DIR | head -1``: the pipe closes before the output is written; no BrokenPipeError trace."""
    import subprocess
    import sys
    from pathlib import Path

    board = Path(__file__).resolve().parents[1] / "baselines" / "v2"
    proc = subprocess.Popen([sys.executable, "-m", "ipp_bench.cli", "power", str(board)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    proc.stdout.close()  # as head does once it has its lines
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 0 and "Traceback" not in err and "BrokenPipe" not in err, err


def test_fit_prior_says_what_it_does_and_how_long_before_the_work_then_each_stage(capsys, monkeypatch):
    """``fit-prior``: one line first (what, and roughly how long), then a line per stage, then the fit."""
    from ipp_bench.core import gp_fit

    fitted = gp_fit.fit_prior

    def fit_prior(*args, **kwargs):
        # nothing of the fit runs before the line that announces it
        assert "roughly" in capsys.readouterr().out
        return fitted(*args, **kwargs)

    monkeypatch.setattr(gp_fit, "fit_prior", fit_prior)
    assert main(["fit-prior", "--task", "Grid15Eval-v1", "--maps", "4"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("  [") and "drew 4 maps of 15 x 15 cells" in out[0]
    assert "likelihood maximised from start 1/2" in out[1] and "evaluations in" in out[1]
    assert "likelihood maximised from start 2/2" in out[2]
    assert out[3].startswith("  length_scale")


def test_fit_prior_names_a_rough_duration(capsys):
    assert main(["fit-prior", "--task", "Grid15Eval-v1", "--maps", "4"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first.startswith("ipp_bench/Grid15Eval-v1: fitting a Matern 3/2 prior to 4 regions maps")
    assert re.search(r"roughly \d+ (s|min)$", first), first
