"""``ipp-bench leaderboard --planners P --against FOLDER``: a new planner flown on a published
board's tasks, configurations and seeds, paired with every published row, the board left untouched."""

from __future__ import annotations

import json

import pytest
from lb_helpers import assert_same_results, results, run_tiny, tiny_plan

from ipp_bench.cli import main
from ipp_bench.eval.against import against_plan
from ipp_bench.eval.results import PUBLISHED_CSV
from ipp_bench.eval.results_csv import RESULTS_CSV
from ipp_bench.eval.run_json import RUN_JSON

NEW = "coverage:overlap=0.5"


def snapshot(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def against(published, out, *extra):
    return main(["leaderboard", "--planners", NEW, "--against", str(published), "--out", str(out),
                 "--backend", "serial", "--no-progress", *extra])


@pytest.fixture(scope="module")
def paired(reference_run, tmp_path_factory):
    """The reference run as a published board, and a folder paired with it."""
    import shutil

    root = tmp_path_factory.mktemp("against")
    published = root / "published"
    shutil.copytree(reference_run[0], published)
    before = snapshot(published)
    out = root / "mine"
    assert against(published, out) == 0
    return published, before, out


def test_only_the_new_planner_flies_on_the_published_seeds(paired):
    published, _, out = paired
    meta, theirs = json.loads((published / RUN_JSON).read_text()), json.loads((out / RUN_JSON).read_text())
    rows = results(out)
    assert {r["planner"] for r in rows} == {NEW}
    assert {(r["task"], r["seed"]) for r in rows} == {(t, s) for t in meta["tasks"] for s in meta["seeds"]}
    assert theirs["seeds"] == meta["seeds"]
    assert theirs["fingerprint"]["task_configs"] == meta["fingerprint"]["task_configs"]
    assert theirs["against"]["folder"] == str(published) and "against" in theirs["fingerprint"]


def test_the_new_rows_are_what_a_board_of_its_own_gives(paired, tmp_path):
    """Pairing changes nothing in the episodes: the same planner on a fresh board of the published
    board's arguments flies the same rows."""
    _, _, out = paired
    own = tmp_path / "own"
    run_tiny(own, tiny_plan(planners=(NEW,)), report=False)
    assert_same_results(results(out), results(own))


def test_the_published_board_is_only_read_and_copied_in(paired):
    published, before, out = paired
    assert snapshot(published) == before
    assert (out / PUBLISHED_CSV).read_bytes() == (published / RESULTS_CSV).read_bytes()


def test_the_report_pairs_the_new_planner_with_every_published_row(paired):
    _, _, out = paired
    md = (out / "leaderboard.md").read_text()
    assert md.index("## Aggregate over the benchmark tasks") < md.index("## Per task")
    for planner in ("random", "coverage", "greedy", "mcts:simulations=3"):
        assert f"`{planner}` (published)" in md
    assert f"`{NEW}` (published)" not in md and f"| `{NEW}` |" in md
    versus = md.split(f"## Uncertainty reduction: `{NEW}` minus each other planner")[1].split("## ")[0]
    for planner in ("random", "coverage", "greedy", "mcts:simulations=3"):
        assert f"| `{planner}` (published) | " in versus
    assert "won " in versus and "/2" in versus  # two paired episodes per cell


def test_the_same_command_resumes_and_a_folder_of_its_own_is_refused(paired, capsys):
    published, _, out = paired
    assert against(published, out) == 0
    assert "already complete" in capsys.readouterr().out
    code = main(["leaderboard", "--planners", NEW, "--tasks", *tiny_plan().tasks, "--episodes", "2", "--seed", "7",
                 "--env", "budget_s=40", "--env", "report_times=[20, 40]", "--out", str(out), "--backend", "serial"])
    assert code == 2 and "(against)" in capsys.readouterr().err


@pytest.mark.parametrize("extra, named", [
    (["--episodes", "3"], "--episodes 3: the board has 2 per task and planner"),
    (["--seed", "8"], "--seed 8: the board's episode seeds derive from seed 7"),
    (["--env", "budget_s=30"], "--env"),
    (["--tasks", "Grid15Eval-v1", "Hotspots15Eval-v2"], "--tasks ipp_bench/Hotspots15Eval-v2: not on the board"),
    (["--quick"], "--quick"),
])
def test_arguments_the_board_decides_are_refused_naming_them(reference_copy, tmp_path, capsys, extra, named):
    assert against(reference_copy, tmp_path / "x", *extra) == 2
    err = capsys.readouterr().err
    assert named in err and "leave these out" in err and "Traceback" not in err
    assert not (tmp_path / "x").exists()


def test_a_task_configuration_that_differs_is_refused_naming_the_field(reference_copy, tmp_path, capsys):
    meta = json.loads((reference_copy / RUN_JSON).read_text())
    meta["fingerprint"]["task_configs"]["ipp_bench/Grid20Eval-v1"]["graph"]["k"] = 7
    (reference_copy / RUN_JSON).write_text(json.dumps(meta))
    assert against(reference_copy, tmp_path / "x") == 2
    err = capsys.readouterr().err
    assert "ipp_bench/Grid20Eval-v1 graph.k: there 7, now 20" in err and "Traceback" not in err


def test_a_seed_set_that_differs_is_refused(reference_copy, tmp_path, capsys):
    meta = json.loads((reference_copy / RUN_JSON).read_text())
    meta["fingerprint"]["seed"] = 8  # its seeds are not what today's scheme derives from its base seed
    (reference_copy / RUN_JSON).write_text(json.dumps(meta))
    assert against(reference_copy, tmp_path / "x") == 2
    err = capsys.readouterr().err
    assert "episode seeds: there" in err and "today's scheme gives" in err and "would not pair" in err


def test_planners_on_the_board_an_incomplete_board_and_writing_into_it_are_refused(reference_copy, tmp_path, capsys):
    assert main(["leaderboard", "--planners", "greedy", "--against", str(reference_copy), "--out",
                 str(tmp_path / "x")]) == 2
    assert "greedy is on the board already" in capsys.readouterr().err
    assert against(reference_copy, reference_copy) == 2
    assert "is the published board itself" in capsys.readouterr().err
    assert main(["leaderboard", "--against", str(reference_copy), "--out", str(tmp_path / "x")]) == 2
    assert "--against needs --planners" in capsys.readouterr().err
    lines = (reference_copy / RESULTS_CSV).read_text().splitlines(keepends=True)
    (reference_copy / RESULTS_CSV).write_text("".join(lines[:-2]))  # the last episode's two rows
    with pytest.raises(ValueError, match=r"missing: 2 of the 32 rows run.json names\): an incomplete board"):
        against_plan(reference_copy, [NEW], log=lambda m: None, check_start=False)
    assert against(tmp_path / "nowhere", tmp_path / "x") == 2
    assert "not a leaderboard folder" in capsys.readouterr().err
