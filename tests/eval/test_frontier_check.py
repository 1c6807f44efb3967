"""``benchmarks/frontier_check.py``: issue 17's verdicts on rows whose differences are known exactly."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from lb_helpers import benchmark_script

from ipp_bench.eval.results import COLUMNS, format_header, format_rows

TIMES = (50.0, 100.0, 150.0, 200.0)


@pytest.fixture(scope="module")
def fc():
    return benchmark_script("frontier_check")


def _write(path: Path, rows: dict) -> Path:
    """rows[(task, planner)] = function(time, seed) -> reduction, as a leaderboard's results.csv."""
    out = []
    for (task, planner), f in rows.items():
        for seed in range(12):
            for t in TIMES:
                row = {c: 0.0 for c in COLUMNS}
                row.update(task=task, planner=planner, seed=seed, time_s=t, decisions=1,
                           uncertainty_reduction_pct=float(f(t, seed)))
                out.append(row)
    path.write_text(format_header() + format_rows(out))
    return path


def _base(t, seed):  # a different level per episode, so only paired differences are exact
    return 40.0 + 0.1 * t + 3.0 * np.sin(seed)


def test_v1_verdict_names_greedy_more_than_a_point_ahead_and_a_baseline_ahead_by_an_interval(fc, tmp_path):
    path = _write(tmp_path / "r.csv", {
        ("ipp_bench/Grid15Eval-v1", "greedy"): _base,
        ("ipp_bench/Grid15Eval-v1", "attention"): lambda t, s: _base(t, s) - (1.5 if t == 100.0 else 0.5),
        ("ipp_bench/Grid15Eval-v1", "coverage"): lambda t, s: _base(t, s) + (0.2 if t == 150.0 else -5.0),
        ("ipp_bench/Grid15Eval-v1", "cmaes"): lambda t, s: _base(t, s) + 3.0,  # not a paper baseline
        ("ipp_bench/Grid20Eval-v1", "greedy"): _base,
        ("ipp_bench/Grid20Eval-v1", "attention"): lambda t, s: _base(t, s) - 0.9,
        ("ipp_bench/Grid20Eval-v1", "mcts:simulations=24"): lambda t, s: _base(t, s) - 0.9 + (0.5 if s % 2 else -0.5),
    })
    text, verdicts = fc.check(fc.load([path]), "attention")
    assert verdicts == {"Grid15Eval-v1": False, "Grid20Eval-v1": True}
    assert "greedy -1.5 at 100 s" in text and "coverage ahead at 150 s" in text
    assert "cmaes ahead" not in text  # CMA-ES is ahead throughout, but it is not one of the paper's baselines
    # MCTS is level on average (+/-0.5 per episode): its interval includes 0
    assert re.search(r"\| mcts:simulations=24 \| [+-]0\.0 \[-0\.\d, \+0\.\d\]", text)


def test_h30_needs_two_intervals_above_greedy_and_reports_the_headroom_share(fc, tmp_path):
    task = "ipp_bench/Hotspots30Eval-v2"
    path = _write(tmp_path / "r.csv", {
        (task, "greedy"): _base,
        (task, "oracle"): lambda t, s: _base(t, s) + 10.0,
        (task, "attention"): lambda t, s: _base(t, s) + (4.0 if t < 150 else 0.0) + (1.0 if s % 2 else -1.0),
        (task, "coverage"): lambda t, s: _base(t, s) - 20.0,
    })
    text, verdicts = fc.check(fc.load([path]), "attention")
    assert verdicts == {"Hotspots30Eval-v2": True}
    assert "above 0 at 50, 100 s" in text and "40 % / 40 % / 0 % / 0 %" in text
    # the same rows with coverage's mean above attention's at 200 s: not met
    path = _write(tmp_path / "r2.csv", {
        (task, "greedy"): _base,
        (task, "attention"): lambda t, s: _base(t, s) + (4.0 if t < 150 else 0.0),
        (task, "coverage"): lambda t, s: _base(t, s) + (0.1 if t == 200.0 else -20.0),
    })
    text, verdicts = fc.check(fc.load([path]), "attention")
    assert verdicts == {"Hotspots30Eval-v2": False} and "coverage at 200 s" in text


def test_deployment_needs_cmaes_behind_by_an_interval_at_50_and_100_s(fc, tmp_path):
    task = "ipp_bench/MuJoCoWeed15-v1"
    rows = {(task, "cmaes"): _base, (task, "attention"): lambda t, s: _base(t, s) + (1.0 if t == 100.0 else 2.0)}
    assert fc.check(fc.load([_write(tmp_path / "a.csv", rows)]), "attention")[1] == {"MuJoCoWeed15-v1": True}
    rows[(task, "attention")] = lambda t, s: _base(t, s) + (1.0 if s % 2 else -0.5) * (t == 50.0) + 1.0 * (t != 50.0)
    assert fc.check(fc.load([_write(tmp_path / "b.csv", rows)]), "attention")[1] == {"MuJoCoWeed15-v1": False}


def test_no_rows_of_the_planner_is_one_line(fc, tmp_path, capsys):
    path = _write(tmp_path / "r.csv", {("ipp_bench/Grid15Eval-v1", "greedy"): _base})
    with pytest.raises(SystemExit) as err:
        fc.main([str(path)])
    assert err.value.code == 2 and "no task in these files has rows of --planner 'attention'" in capsys.readouterr().err


def test_a_file_that_is_no_results_csv_is_one_line(fc, tmp_path, capsys):
    path = tmp_path / "other.csv"
    path.write_text("task,planner,seed\nx,y,1\n")
    with pytest.raises(SystemExit) as err:
        fc.main([str(path)])
    msg = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.value.code == 2 and f"{path}: results.csv has columns" in msg and "expected" in msg
    assert "Traceback" not in msg


def test_other_weights_of_the_checked_planner_are_named_but_are_not_baselines(fc, tmp_path):
    h30, h15 = "ipp_bench/Hotspots30Eval-v2", "ipp_bench/Hotspots15Eval-v2"
    me, sibling = "attention:checkpoint=a.pt", "attention:checkpoint=b.pt"
    path = _write(tmp_path / "r.csv", {
        (h30, "greedy"): _base,
        (h30, me): lambda t, s: _base(t, s) + 4.0 + (1.0 if s % 2 else -1.0),
        (h30, sibling): lambda t, s: _base(t, s) + (5.0 if t == 200.0 else 0.0),  # mean ahead at 200 s
        (h30, "attention"): lambda t, s: _base(t, s) - 1.0,
        (h15, "greedy"): _base,
        (h15, me): _base,
        (h15, sibling): lambda t, s: _base(t, s) + 2.0,  # ahead by an interval at every time
    })
    text, verdicts = fc.check(fc.load([path]), me)
    assert verdicts == {"Hotspots15Eval-v2": True, "Hotspots30Eval-v2": True}
    assert "behind another baseline's mean: none" in text
    # H30 (the last task): only the time where its mean is ahead; the shipped `attention`, behind, is not named
    assert text.splitlines()[-1].endswith(f"not in the verdict): {sibling} at 200 s")
    assert f"not in the verdict): {', '.join(f'{sibling} at {t:g} s' for t in TIMES)}" in text  # H15
    # a baseline of another family ahead still decides: greedy's mean above at 200 s in H15 by an interval
    path = _write(tmp_path / "r2.csv", {(h15, "greedy"): lambda t, s: _base(t, s) + 2.0, (h15, me): _base})
    assert fc.check(fc.load([path]), me)[1] == {"Hotspots15Eval-v2": False}
