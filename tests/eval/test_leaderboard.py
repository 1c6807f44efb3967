"""Leaderboard runs (ipp_bench.eval.leaderboard, .results, .executors): CSV layout, same seeds for
every planner, resume, extension, refusal, backends."""

from __future__ import annotations

import json

import pytest
from lb_helpers import (
    EPISODES,
    PLANNERS,
    TASKS,
    TINY_ENV,
    assert_same_results,
    results,
    run_tiny,
    tiny_plan,
    without_timing,
)

import ipp_bench.eval.leaderboard as lb
from ipp_bench.eval.leaderboard import (
    COLUMNS,
    RESULTS_CSV,
    ResultsMismatchError,
    read_results,
)

REQUIRED = ("task", "planner", "seed", "time_s", "trace_roi", "rmse_roi", "uncertainty_reduction_pct",
            "rmse_reduction_pct", "decisions", "decision_time_mean_s", "decision_time_max_s")


# -- the run ----------------------------------------------------------------------------------------
def test_results_csv_has_the_columns_and_one_row_per_report_time(reference_run):
    out, summary = reference_run
    header = (out / RESULTS_CSV).read_text().splitlines()[0].split(",")
    assert set(REQUIRED) <= set(header)
    assert tuple(header) == COLUMNS
    rows = results(out)
    assert summary.ran == summary.total == len(TASKS) * len(PLANNERS) * EPISODES
    times = TINY_ENV["report_times"]
    assert len(rows) == summary.total * len(times)
    by_episode = {}
    for r in rows:
        by_episode.setdefault((r["task"], r["planner"], r["seed"]), []).append(r["time_s"])
    assert all(ts == [float(t) for t in times] for ts in by_episode.values())
    plan = tiny_plan()
    for task in TASKS:  # every planner meets the same episode seeds
        seeds = {p: sorted(s for (t, q, s) in by_episode if t == task and q == p) for p in plan.planners}
        assert all(v == sorted(plan.seeds) for v in seeds.values()), seeds
    for r in rows:
        assert r["decisions"] > 0 and r["decision_time_max_s"] >= r["decision_time_mean_s"] >= 0
        assert 0 < r["trace_roi"] and 0 < r["rmse_roi"]
    meta = json.loads((out / "run.json").read_text())
    assert meta["episodes"] == EPISODES and meta["seeds"] == list(plan.seeds)


def test_rerun_with_same_arguments_runs_nothing(reference_copy):
    before = (reference_copy / RESULTS_CSV).read_text()
    summary = run_tiny(reference_copy)
    assert (summary.ran, summary.skipped) == (0, summary.total)
    assert (reference_copy / RESULTS_CSV).read_text() == before


def test_resume_after_deleting_rows_completes_to_the_same_results(reference_run, reference_copy):
    path = reference_copy / RESULTS_CSV
    lines = path.read_text().splitlines(keepends=True)
    # drop one whole episode (its two rows) and one row of another (an incomplete episode)
    kept = [ln for i, ln in enumerate(lines) if i not in (1, 2, 9)]
    path.write_text("".join(kept))
    summary = run_tiny(reference_copy)
    assert summary.ran == 2
    new, ref = results(reference_copy), results(reference_run[0])
    assert without_timing(new) == without_timing(ref)
    untouched = [i for i in range(len(ref)) if i not in (0, 1, 8, 9)]  # the two episodes run again
    assert [new[i] for i in untouched] == [ref[i] for i in untouched]  # finished episodes were not rerun


def test_resume_after_a_torn_last_line(reference_run, reference_copy):
    path = reference_copy / RESULTS_CSV
    text = path.read_text()
    lines = text.splitlines(keepends=True)
    # an interrupted append: the last episode's first row whole, its second row cut mid-line
    torn = "".join(lines[:-1]) + lines[-1][: len(lines[-1]) // 2]
    path.write_text(torn)
    assert len(read_results(path)) == len(lines) - 2  # the torn line is not a row
    notes = []
    summary = run_leaderboard_with_notes(reference_copy, notes)
    assert summary.ran == 1
    assert any("torn" in n for n in notes) and any("incomplete" in n for n in notes)
    assert without_timing(results(reference_copy)) == without_timing(results(reference_run[0]))
    assert path.read_text().endswith("\n")


def run_leaderboard_with_notes(out, notes):
    return lb.run_leaderboard(tiny_plan(), out, backend="serial", progress=False, log=notes.append)


def test_interrupted_run_keeps_finished_episodes_and_resumes(reference_run, tmp_path, monkeypatch):
    out = tmp_path / "killed"
    real = lb.run_job
    calls = []

    def dying_job(job):
        if len(calls) == 5:
            raise KeyboardInterrupt
        calls.append(job)
        return real(job)

    plan = tiny_plan(tasks=TASKS[:1])
    monkeypatch.setattr(lb, "run_job", dying_job)
    with pytest.raises(lb.Interrupted, match="5 of 8 episodes kept"):
        run_tiny(out, plan)
    assert len(results(out)) == 5 * len(TINY_ENV["report_times"])  # every finished episode is on disk
    monkeypatch.setattr(lb, "run_job", real)
    summary = run_tiny(out, plan)
    assert summary.ran == summary.total - 5
    reference = [r for r in results(reference_run[0]) if r["task"] == TASKS[0]]
    assert without_timing(results(out)) == without_timing(reference)


def test_different_arguments_are_refused_naming_them(reference_copy):
    before = (reference_copy / RESULTS_CSV).read_text()
    with pytest.raises(ResultsMismatchError) as err:
        run_tiny(reference_copy, tiny_plan(seed=8, planners=["random", "greedy"]))
    message = str(err.value)
    assert "seed" in message and "planners" in message and "--out" in message
    assert "  tasks:" not in message and "task_configs" not in message  # only what differs is named
    with pytest.raises(ResultsMismatchError, match="budget_s"):
        run_tiny(reference_copy, tiny_plan(env_overrides={**TINY_ENV, "budget_s": 20, "report_times": [20]}))
    assert (reference_copy / RESULTS_CSV).read_text() == before


def test_more_episodes_extend_the_folder_and_fewer_are_refused(reference_run, reference_copy):
    before = results(reference_copy)
    summary = run_tiny(reference_copy, tiny_plan(episodes=EPISODES + 1))
    assert summary.skipped == len(TASKS) * len(PLANNERS) * EPISODES and summary.ran == len(TASKS) * len(PLANNERS)
    after = results(reference_copy)
    assert without_timing([r for r in after if r["seed"] in tiny_plan().seeds]) == without_timing(before)
    assert json.loads((reference_copy / "run.json").read_text())["episodes"] == EPISODES + 1
    with pytest.raises(ResultsMismatchError, match=f"--episodes {EPISODES + 1} or more"):
        run_tiny(reference_copy, tiny_plan(episodes=EPISODES))


def test_tuple_and_list_overrides_are_the_same_arguments(reference_copy):
    env = {"budget_s": 40, "report_times": (20.0, 40.0)}
    assert run_tiny(reference_copy, tiny_plan(env_overrides=env)).ran == 0


def test_results_without_run_json_are_refused(reference_copy):
    (reference_copy / "run.json").unlink()
    with pytest.raises(ResultsMismatchError, match="run.json"):
        run_tiny(reference_copy)


def test_a_second_concurrent_run_is_refused(reference_copy):
    with lb.ResultsStore(reference_copy, tiny_plan()), pytest.raises(ResultsMismatchError, match="in use"):
        run_tiny(reference_copy)


def test_process_pool_gives_the_same_results(reference_run, tmp_path):
    out = tmp_path / "process"
    summary = run_tiny(out, backend="process", workers=2)
    assert summary.ran == summary.total
    assert_same_results(results(out), results(reference_run[0]))


@pytest.mark.ray
def test_ray_gives_the_same_results(reference_run, tmp_path):
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        out = tmp_path / "ray"
        summary = run_tiny(out, backend="ray", workers=2)
        assert summary.ran == summary.total
        assert_same_results(results(out), results(reference_run[0]))
    finally:
        ray.shutdown()
