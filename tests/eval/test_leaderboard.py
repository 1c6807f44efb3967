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
from ipp_bench.eval.results import ResultsStore
from ipp_bench.eval.results_csv import COLUMNS, RESULTS_CSV, read_results
from ipp_bench.eval.run_json import ResultsMismatchError

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


def test_a_number_given_as_int_or_float_is_the_same_argument(reference_copy):
    """budget_s=40 made the folder; budget_s=40.0 (or report times as floats) resumes it."""
    env = {"budget_s": 40.0, "report_times": [20.0, 40]}
    notes = []
    summary = lb.run_leaderboard(tiny_plan(env_overrides=env), reference_copy, backend="serial", progress=False,
                                 log=notes.append)
    assert summary.ran == 0
    assert any("already complete" in n for n in notes)


def _edit_run_json(folder, edit):
    path = folder / "run.json"
    meta = json.loads(path.read_text())
    edit(meta["fingerprint"])
    path.write_text(json.dumps(meta))


def test_a_config_field_added_since_at_its_default_keeps_the_folder(reference_copy):
    """A folder written before a config field existed: today's default reproduces the older
    behaviour, so the folder is the same arguments; run.json is rewritten with the field."""
    def drop(fp):
        for record in fp["task_configs"].values():
            del record["sensor"]["noise_floor"]  # at its default (1.0) on every graph task
    _edit_run_json(reference_copy, drop)
    notes = []
    summary = run_leaderboard_with_notes(reference_copy, notes)
    assert summary.ran == 0 and any("older form" in n for n in notes)
    meta = json.loads((reference_copy / "run.json").read_text())
    assert all(r["sensor"]["noise_floor"] == 1.0 for r in meta["fingerprint"]["task_configs"].values())


def test_a_missing_field_away_from_its_default_is_refused_naming_it(reference_copy):
    def drop(fp):  # the tiny run overrides budget_s (40 s, default 150 s): a missing field means the default
        del fp["task_configs"][TASKS[0]]["mission"]["budget_s"]
    _edit_run_json(reference_copy, drop)
    with pytest.raises(ResultsMismatchError, match=r"task_configs.*\n.*Grid15Eval-v1 mission.budget_s"):
        run_tiny(reference_copy)


def test_a_changed_config_field_is_named(reference_copy):
    def change(fp):
        fp["task_configs"][TASKS[1]]["gp"]["length_scale"] = 9.0
    _edit_run_json(reference_copy, change)
    with pytest.raises(ResultsMismatchError, match=r"Grid20Eval-v1 gp.length_scale: there 9.0, now"):
        run_tiny(reference_copy)


def test_a_config_recorded_other_than_field_by_field_is_refused_naming_it(reference_copy):
    def to_digest(fp):
        fp["task_configs"][TASKS[0]] = "0123456789abcdef"
    _edit_run_json(reference_copy, to_digest)
    with pytest.raises(ResultsMismatchError, match=r"Grid15Eval-v1 a config record that is not field by field "
                                                   r'\("0123456789abcdef"\)'):
        run_tiny(reference_copy)


def test_results_without_run_json_are_refused(reference_copy):
    (reference_copy / "run.json").unlink()
    with pytest.raises(ResultsMismatchError, match="run.json"):
        run_tiny(reference_copy)


def test_a_second_concurrent_run_is_refused(reference_copy):
    with ResultsStore(reference_copy, tiny_plan()), pytest.raises(ResultsMismatchError, match="in use"):
        run_tiny(reference_copy)


def test_process_pool_gives_the_same_results(reference_run, tmp_path):
    out = tmp_path / "process"
    summary = run_tiny(out, backend="process", workers=2)
    assert summary.ran == summary.total
    assert_same_results(results(out), results(reference_run[0]))


@pytest.mark.ray
@pytest.mark.slow  # a local Ray start: 10 s of the 4-minute default run (CI runs -m slow too)
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


def test_a_run_that_loses_the_lock_never_touches_the_winners_folder(tmp_path, monkeypatch):
    """Two runs start at once on a new folder: the one that created it can lose the lock to the
    other (which found it existing); its cleanup must not delete the winner's folder."""
    from ipp_bench.eval import results as results_module

    out = tmp_path / "new"
    plan = tiny_plan()
    winner = ResultsStore(out, plan)
    real_lock = results_module.ResultsStore._lock

    def lock_after_the_winner(self):
        if self is not winner:
            winner.__enter__()  # the other run locks between this one's mkdir and its lock
        real_lock(self)

    monkeypatch.setattr(results_module.ResultsStore, "_lock", lock_after_the_winner)
    loser = ResultsStore(out, plan)
    with pytest.raises(ResultsMismatchError, match="in use by another leaderboard run"):
        loser.__enter__()
    assert loser._created and winner._created is False  # the loser made the folder
    assert out.is_dir()
    monkeypatch.setattr(results_module.ResultsStore, "_lock", real_lock)
    winner.begin()  # the winner still writes into its folder
    winner.__exit__(None, None, None)
    assert (out / "run.json").exists() and (out / RESULTS_CSV).exists()
    assert sorted(p.name for p in out.iterdir()) == ["results.csv", "run.json"]  # no lock file left


def test_a_planner_that_raises_stops_the_run_naming_the_episode_and_keeps_the_rest(tmp_path, monkeypatch):
    from lb_helpers import BoomPlanner

    from ipp_bench import planners

    monkeypatch.setitem(planners.REGISTRY, "boom", "lb_helpers:BoomPlanner")
    plan = tiny_plan(tasks=TASKS[:1], planners=["random", "boom"])
    from ipp_bench.planners.isolation import planner_seed

    # a planner other than the suite's gets a keyed hash of the episode's seed
    monkeypatch.setattr(BoomPlanner, "FAIL_SEED", planner_seed(plan.seeds[1], "lb_helpers:BoomPlanner"))
    out = tmp_path / "boom"
    with pytest.raises(lb.EpisodeFailed) as err:
        run_tiny(out, plan, command="ipp-bench leaderboard ...")
    message = str(err.value)
    assert f"episode Grid15Eval-v1 boom seed {plan.seeds[1]} failed: RuntimeError: boom in act" in message
    assert "lb_helpers.py" in message and "in act" in message  # where it was raised
    assert "3 of 4 episodes kept" in message and message.endswith("resume: ipp-bench leaderboard ...")
    assert "\n" not in message
    assert len(results(out)) == 3 * len(TINY_ENV["report_times"])  # the finished episodes are on disk
    monkeypatch.setattr(BoomPlanner, "FAIL_SEED", None)  # fixed: the rerun runs the failed one only
    assert run_tiny(out, plan).ran == 1


def test_a_failing_episode_in_a_worker_process_is_one_line_too(tmp_path):
    """An episode that raises inside a pool worker (its checkpoint vanished after the run was
    planned) ends the run with the same one line."""
    pytest.importorskip("torch")
    from ipp_bench.policies.checkpoint import SHIPPED_CHECKPOINT

    ckpt = tmp_path / "net.pt"
    ckpt.write_bytes(SHIPPED_CHECKPOINT.read_bytes() if hasattr(SHIPPED_CHECKPOINT, "read_bytes")
                     else open(SHIPPED_CHECKPOINT, "rb").read())
    plan = tiny_plan(tasks=TASKS[:1], planners=["random", f"attention:checkpoint={ckpt}"], episodes=1)
    ckpt.unlink()
    with pytest.raises(lb.EpisodeFailed, match=r"episode Grid15Eval-v1 attention:checkpoint=\S+ seed \d+ failed: \w+"):
        run_tiny(tmp_path / "lb", plan, backend="process", workers=2)


@pytest.mark.parametrize("spec, key, default", [("mcts:simulations=2", "search", "lowrank"),
                                                  ("cmaes:max_evals=24", "evaluation", "batched")])
def test_a_folder_flown_with_the_other_search_refuses_the_same_spec(tmp_path, spec, key, default):
    """MCTS and CMA-ES record their search in the folder: rows of the reference form (the defaults of
    an older suite, under the same spec) are refused, not extended with the fast form's."""
    pytest.importorskip("numba")
    out = tmp_path / "lb"
    plan = tiny_plan(tasks=TASKS[:1], planners=(spec,), episodes=1)
    assert plan.planner_fingerprints[spec] == {key: default}
    run_tiny(out, plan)
    meta = json.loads((out / "run.json").read_text())
    meta["fingerprint"]["planner_fingerprints"][spec] = {key: "reference"}  # as flown under an older default
    (out / "run.json").write_text(json.dumps(meta))
    with pytest.raises(ResultsMismatchError, match=f"planner_fingerprints.*{key}|{key}.*planner_fingerprints"):
        run_tiny(out, tiny_plan(tasks=TASKS[:1], planners=(spec,), episodes=1))


def test_rerun_refreshes_one_planners_rows_after_its_checkpoint_changed(tmp_path):
    """A retrained checkpoint: the folder refuses its planner's old rows; ``rerun`` drops and flies
    them again, every other row stays byte for byte, and the plain command is then complete."""
    torch = pytest.importorskip("torch")
    from ipp_bench.policies.checkpoint import save_checkpoint
    from ipp_bench.policies.network import AttentionNet, NetConfig

    ckpt = tmp_path / "net.pt"

    def write_net(seed):
        torch.manual_seed(seed)
        save_checkpoint(AttentionNet(NetConfig(embed_dim=16, n_heads=2, ff_dim=32)), ckpt)

    write_net(0)
    spec = f"attention:checkpoint={ckpt}"
    out = tmp_path / "lb"
    def plan():
        return tiny_plan(tasks=TASKS[:1], planners=("random", spec))

    run_tiny(out, plan(), command="ipp-bench leaderboard (the recorded command)")
    before = results(out)
    write_net(1)  # retrained: another network behind the same path
    with pytest.raises(ResultsMismatchError, match="planner_fingerprints"):
        run_tiny(out, plan())
    with pytest.raises(ValueError, match="--rerun greedy: not a planner of this run"):
        run_tiny(out, plan(), rerun=("greedy",))
    summary = run_tiny(out, plan(), rerun=(spec,), command="ipp-bench leaderboard (the recorded command)")
    assert summary.ran == EPISODES
    after = results(out)
    def keep(rows, p):
        return [r for r in without_timing(rows) if r["planner"] == p]

    assert keep(after, "random") == keep(before, "random")
    assert keep(after, spec) != keep(before, spec) and len(keep(after, spec)) == len(keep(before, spec))
    meta = json.loads((out / "run.json").read_text())
    assert meta["command"] == "ipp-bench leaderboard (the recorded command)"
    assert run_tiny(out, plan()).ran == 0  # the folder now holds what its command gives


def test_the_recorded_command_leaves_rerun_out_and_a_bad_rerun_is_one_line(tmp_path, capsys):
    from ipp_bench.cli import _without_option, main

    argv = ["leaderboard", "--rerun", "attention", "--out", "x", "--rerun=greedy", "--quick"]
    assert _without_option(argv, "--rerun") == ["leaderboard", "--out", "x", "--quick"]
    out = tmp_path / "lb"
    assert main(["leaderboard", "--tasks", TASKS[0], "--planners", "random", "--episodes", "1",
                 "--rerun", "greedy", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["ipp-bench: error: --rerun 'greedy' names no planner of this run: valid are ['random']"]
    assert not out.exists()


# -- the power rule ---------------------------------------------------------------------------------
def test_power_prints_the_episodes_each_task_needs(reference_run, capsys):
    from ipp_bench.cli import main
    from ipp_bench.eval.power import needed_per_task, power_rule

    out, _ = reference_run
    assert main(["power", str(out), "--half-width", "2"]) == 0
    text = capsys.readouterr().out
    cells = power_rule(read_results(out / RESULTS_CSV), "greedy", 2.0)
    assert "n = ceil((1.96 sd / 2)^2)" in text
    for task, cell in needed_per_task(cells).items():
        assert f"  {task}: {cell.needed} (flown {EPISODES}; set by {cell.planner} at {cell.time_s:g} s)" in text
    assert main(["power", str(out), "--half-width", "0"]) == 2
    assert "--half-width 0 is invalid: expected a number of points > 0" in capsys.readouterr().err
    assert main(["power", str(out), "--reference", "nobody"]) == 2
    assert "names no planner" in capsys.readouterr().err


def test_the_reports_power_target_is_an_argument(reference_copy, capsys):
    from ipp_bench.cli import main

    argv = ["leaderboard", "--tasks", *TASKS, "--planners", *PLANNERS, "--episodes", str(EPISODES), "--seed", "7",
            "--env", "budget_s=40", "--env", "report_times=[20, 40]", "--backend", "serial", "--out",
            str(reference_copy)]
    assert main([*argv, "--power", "-1"]) == 2
    assert "--power -1 is invalid" in capsys.readouterr().err
    assert main([*argv, "--power", "5"]) == 0
    assert "## Episodes for a ±5-point paired interval" in (reference_copy / "leaderboard.md").read_text()
