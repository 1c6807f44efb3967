"""The report: Table I layout, bootstrap intervals, bold best, plots."""

from __future__ import annotations

import numpy as np
import pytest
from lb_helpers import PLANNERS

from ipp_bench.eval.aggregate import bootstrap_ci
from ipp_bench.eval.markdown import markdown_table
from ipp_bench.eval.report import write_report
from ipp_bench.eval.results_csv import COLUMNS, RESULTS_CSV, format_header, format_rows
from ipp_bench.eval.tables import EpisodeTable

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_bootstrap_ci_brackets_the_mean_and_is_reproducible():
    x = np.random.default_rng(0).normal(10.0, 2.0, size=40)
    mean, low, high = bootstrap_ci(x)
    assert mean == pytest.approx(x.mean())
    assert low < mean < high
    se = x.std(ddof=1) / np.sqrt(x.size)  # the percentile interval is close to mean +- 1.96 se
    assert high - low == pytest.approx(2 * 1.96 * se, rel=0.15)
    assert bootstrap_ci(x) == (mean, low, high)
    assert bootstrap_ci([3.0]) == (3.0, None, None)  # one episode: no interval
    assert bootstrap_ci([2.0, 2.0, 2.0]) == (2.0, 2.0, 2.0)
    with pytest.raises(ValueError):
        bootstrap_ci([])


def synthetic_rows():
    """Two planners on one task: 'good' reduces more at every time and is slower per decision."""
    rows = []
    for planner, base, dt in (("good", 60.0, 0.5), ("bad", 30.0, 0.001)):
        for i, seed in enumerate((1, 2, 3)):
            for t in (50.0, 100.0):
                rows.append(dict(task="ipp_bench/Toy-v0", planner=planner, seed=seed, time_s=t,
                                 trace_roi=100 - base - t / 10, rmse_roi=0.2,
                                 uncertainty_reduction_pct=base + t / 10 + i,
                                 rmse_reduction_pct=base / 2 + i, decisions=10, decision_time_mean_s=dt * (1 + i / 10),
                                 decision_time_max_s=2 * dt, episode_wall_s=1.0))
    return rows


def test_markdown_has_table_one_layout_and_bolds_the_best():
    table = markdown_table(EpisodeTable(synthetic_rows()))
    lines = table.strip().splitlines()
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    assert header == ["Environment", "Method", "Uncertainty reduction 50 s", "100 s",
                      "RMSE reduction 50 s", "100 s", "Runtime per decision [ms]"]
    good, bad = lines[2], lines[3]
    assert good.startswith("| **Toy-v0** | `good` |") and bad.startswith("|  | `bad` |")
    good_cells = [c.strip() for c in good.strip("|").split("|")]
    bad_cells = [c.strip() for c in bad.strip("|").split("|")]
    assert good_cells[2] == "**66.0%** [65.0, 67.0]"  # mean of 65, 66, 67 and its interval
    assert all(c.startswith("**") for c in good_cells[2:6]) and not any("**" in c for c in bad_cells[2:6])
    assert bad_cells[6].startswith("**1.10**") and not good_cells[6].startswith("**")  # lowest runtime


def test_equal_means_are_all_bold():
    rows = [dict(r, planner=p) for r in synthetic_rows() if r["planner"] == "good" for p in ("a", "b")]
    lines = markdown_table(EpisodeTable(rows)).strip().splitlines()[2:]
    assert all(line.count("**") >= 2 * 5 for line in lines)


def test_report_of_a_run_has_every_planner_and_the_plots(reference_run):
    out, summary = reference_run
    names = {p.name for p in summary.files}
    assert {"leaderboard.md", "curves_Grid15Eval-v1.png", "curves_Grid20Eval-v1.png",
            "runtime_per_decision.png"} <= names
    for p in summary.files:
        if p.suffix == ".png":
            data = p.read_bytes()
            assert data[:8] == PNG_MAGIC and len(data) > 10_000
    text = (out / "leaderboard.md").read_text()
    opening, md = text.split("## Per task")
    md, power = md.split("## Episodes for a")
    md += power[power.index("## Absolute values"):]  # the power section names planners as it needs
    assert opening.startswith("# ipp-bench leaderboard") and "## Aggregate over the benchmark tasks" in opening
    for planner in PLANNERS:  # two tasks, two tables, and (all but the reference) two paired tables
        assert md.count(f"`{planner}`") == 8  # greedy: its two tables, and named by the paired ones
        assert f"| `{planner}` | " in opening.split("Performance profile")[0]  # a row of the aggregate table
    assert "![performance profile](performance_profile.png)" in opening
    assert md.count("**Grid15Eval-v1**") == 4 and "Uncertainty reduction 20 s" in md
    assert "## Episodes for a ±3-point paired interval" in text
    assert "each planner minus `greedy`, on the same episodes" in md


def test_write_report_from_a_csv_alone(tmp_path):
    csv_path = tmp_path / RESULTS_CSV
    csv_path.write_text(format_header() + format_rows(synthetic_rows()))
    assert format_header().strip().split(",") == list(COLUMNS)
    written = write_report(csv_path, tmp_path)
    assert [p.name for p in written] == ["leaderboard.md", "performance_profile.png", "curves_Toy-v0.png",
                                         "runtime_per_decision.png"]
    assert "(the plot `performance_profile.png` draws every tau)" in written[0].read_text()
    assert "![runtime_per_decision](runtime_per_decision.png)" in written[0].read_text()
    assert "![performance_profile]" not in written[0].read_text()  # shown beside the aggregate, not again


def test_paired_comparison_against_the_reference():
    from ipp_bench.eval.markdown import paired_table

    table = paired_table(EpisodeTable(synthetic_rows()), "bad")
    good = [c.strip() for c in table.strip().splitlines()[2].strip("|").split("|")]
    # good - bad = 30 points at every episode and time: mean +30.0, a degenerate interval, won 3 of 3
    assert good[:2] == ["**Toy-v0**", "`good`"]
    assert good[2] == "+30.0 [+30.0, +30.0], won 3/3" and good[3] == "+30.0 [+30.0, +30.0], won 3/3"
    one = [r for r in synthetic_rows() if r["seed"] == 1]
    single = paired_table(EpisodeTable(one), "bad")
    assert "+30.0, won 1/1" in single and "no interval" not in single  # the report says it once, above


def test_one_episode_says_there_is_no_interval(tmp_path):
    one = [r for r in synthetic_rows() if r["seed"] == 1]
    csv_path = tmp_path / RESULTS_CSV
    csv_path.write_text(format_header() + format_rows(one))
    md = write_report(csv_path, tmp_path)[0].read_text()
    assert "[61.0, 61.0]" not in md
    assert md.count("no interval: 1 episode") == 1, md  # said once, not in every cell


def test_a_non_finite_mean_is_never_bold():

    rows = [dict(r) for r in synthetic_rows()]
    for r in rows:
        if r["planner"] == "good":
            r["uncertainty_reduction_pct"] = float("nan")
    table = markdown_table(EpisodeTable(rows))
    assert "**nan" not in table, table
    bad = next(line for line in table.splitlines() if "`bad`" in line)
    assert bad.split("|")[3].strip().startswith("**"), bad


def test_without_matplotlib_the_report_is_the_markdown_and_says_so(tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "matplotlib", None)
    csv_path = tmp_path / RESULTS_CSV
    csv_path.write_text(format_header() + format_rows(synthetic_rows()))
    notes = []
    written = write_report(csv_path, tmp_path, log=notes.append)
    assert [p.name for p in written] == ["leaderboard.md"]
    assert 'pip install "ipp-bench[eval]"' in written[0].read_text() and notes


def test_the_oracle_row_is_apart_never_bold_and_every_planner_has_its_distance_to_it():
    """The reference that reads the truth reduces most here; it is still never the best."""
    rows = synthetic_rows() + [dict(r, planner="oracle", uncertainty_reduction_pct=r["uncertainty_reduction_pct"] + 20,
                                    rmse_reduction_pct=r["rmse_reduction_pct"] + 20, decision_time_mean_s=1e-6)
                               for r in synthetic_rows() if r["planner"] == "good"]
    table = EpisodeTable(rows, planners=["oracle", "good", "bad"])  # even listed first, it is shown last
    lines = markdown_table(table).strip().splitlines()[2:]
    assert lines[0].startswith("| **Toy-v0** | `good` |") and "**66.0%**" in lines[0]
    assert "reference, knows the true ROI" in lines[2]
    oracle = lines[3]
    assert oracle.startswith("|  | `oracle` (reference) |") and "**" not in oracle
    from ipp_bench.eval.report import markdown_report
    md = markdown_report(table, reference="greedy")
    assert "each planner minus `oracle` (the headroom reference)" in md
    ref = markdown_report(table, reference="good")
    assert "each planner minus `good`" in ref and "`oracle` (reference) | +20.0" in ref
    assert "| `bad` | -50.0" in ref.split("minus `oracle`")[1]  # bad's distance to the oracle


def test_a_quick_board_says_its_intervals_are_wide_and_points_to_the_powered_boards():
    from ipp_bench.eval.report import markdown_report

    table = EpisodeTable(synthetic_rows())
    quick = markdown_report(table, command="ipp-bench leaderboard --quick", quick=True)
    assert "**Quick board**: 3 episodes per task and planner" in quick and "intervals are wide" in quick
    assert "powered boards in `baselines/`" in quick and "power rule" in quick
    assert quick.index("**Quick board**") < quick.index("## Aggregate over the benchmark tasks")
    assert "Quick board" not in markdown_report(table, command="ipp-bench leaderboard")


def test_published_rows_are_marked_and_the_new_planner_is_set_against_each():
    from ipp_bench.eval.report import markdown_report

    table = EpisodeTable(synthetic_rows(), published=["bad"])
    md = markdown_report(table, reference="bad", published_from="baselines/toy")
    assert "`bad` (published)" in md and "`good` (published)" not in md
    assert "copied from the published board `baselines/toy`" in md
    versus = md.split("`good` minus each other planner, on the same episodes")[1]
    assert "| **Toy-v0** | `bad` (published) | +30.0 [+30.0, +30.0], won 3/3 |" in versus


# -- no false significance --------------------------------------------------------------------------
def board_rows(planners, seeds, tasks=("ipp_bench/A-v0", "ipp_bench/B-v0"), spread=0.0):
    """Rows of ``planners`` (name -> base reduction) on ``tasks`` and ``seeds``, two report times;
    ``spread``: points added per episode index, planner by planner in turn (so the pairs overlap)."""
    rows = []
    for task in tasks:
        for k, (planner, base) in enumerate(planners.items()):
            for i, seed in enumerate(seeds):
                for t in (50.0, 100.0):
                    v = base + t / 10 + spread * ((i + k) % len(seeds))
                    rows.append(dict(task=task, planner=planner, seed=seed, time_s=t, trace_roi=1.0, rmse_roi=0.2,
                                     uncertainty_reduction_pct=v, rmse_reduction_pct=v / 2, decisions=3,
                                     decision_time_mean_s=0.01, decision_time_max_s=0.02, episode_wall_s=1.0))
    return rows


def _aggregate(md: str) -> str:
    return md.split("## Aggregate over the benchmark tasks")[1].split("## Per task")[0]


def test_one_episode_gives_no_interval_no_bold_and_no_rank_in_the_aggregate():
    from ipp_bench.eval.report import markdown_report

    rows = board_rows({"random": 20.0, "greedy": 60.0, "coverage": 40.0, "oracle": 80.0}, seeds=(1,))
    aggregate = _aggregate(markdown_report(EpisodeTable(rows)))
    tables = [line for line in aggregate.splitlines() if line.startswith("| ") and "`" in line]
    assert tables and not any("[" in line for line in tables), aggregate  # no [0.00, 0.00] nor [1.00, 1.00]
    assert not any("**" in line for line in tables), aggregate  # P(oracle > random) = 1.00 is not bold
    ranks = [line.split("|")[1].strip() for line in tables[:4]]
    assert ranks == ["1=", "1=", "1=", "–"], ranks  # one episode separates no planner
    assert "1 episode each" in aggregate and "1 episodes" not in aggregate
    assert "no intervals" in aggregate.lower() and "one episode" in aggregate


def test_the_score_scale_without_random_or_oracle_rows_reads_as_words():
    from ipp_bench.eval.report import markdown_report

    md = markdown_report(EpisodeTable(board_rows({"greedy": 60.0, "coverage": 40.0}, seeds=(1, 2, 3), spread=1.0)))
    assert "rows) (0)" not in md and "rows) (1)" not in md
    assert ("from a 0 % reduction (score 0; the board has no `random` rows) to a 100 % reduction (score 1; the "
            "board has no `oracle` rows)") in md
    partial = markdown_report(EpisodeTable(board_rows({"random": 20.0, "greedy": 60.0}, seeds=(1, 2, 3), spread=1.0)))
    assert "from `random` (0) to a 100 % reduction (score 1; the board has no `oracle` rows)" in partial


def test_below_the_power_rules_count_the_report_names_the_comparisons_it_cannot_decide():
    """``close`` is within a point of greedy with a spread of 9 points: 3 episodes decide nothing about
    it; ``far`` is 40 points below on every episode: decided however few the episodes."""
    from ipp_bench.eval.report import markdown_report

    rows = board_rows({"greedy": 60.0, "close": 60.5, "far": 20.0}, seeds=(1, 2, 3), spread=9.0)
    md = markdown_report(EpisodeTable(rows), reference="greedy")
    power = md.split("## Episodes for a")[1].split("## Absolute values")[0]
    undecided = power.split("cannot decide")[1]
    assert "**A-v0**" in undecided and "`close` at 50, 100 s" in undecided
    assert "`far`" not in undecided
    enough = board_rows({"greedy": 60.0, "far": 20.0}, seeds=(1, 2, 3))  # paired sd 0: 2 episodes suffice
    assert "cannot decide" not in markdown_report(EpisodeTable(enough), reference="greedy")
