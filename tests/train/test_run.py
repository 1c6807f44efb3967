"""A tiny run of the real `ipp-bench train` command: its run folder, resume, export, and the
refusals before a run folder exists."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ipp_bench.policies.checkpoint import load_checkpoint
from ipp_bench.train.args import VAL_SEED0, TrainArgs, check_warm_start_seeds

REPO = Path(__file__).resolve().parents[2]
TINY = ["--task", "ipp_bench/Grid15-v0", "--n-envs", "1", "--n-steps", "32", "--batch-size", "32",
        "--n-epochs", "1", "--embed-dim", "16", "--n-heads", "2", "--ff-dim", "32",
        "--eval-every", "32", "--eval-episodes", "1", "--checkpoint-every", "32", "--threads", "1",
        "--warm-start", "greedy", "--bc-episodes", "1", "--bc-rounds", "1", "--bc-round-episodes", "1",
        "--bc-epochs", "1", "--no-progress"]


def _train(*args, check=True):
    cmd = [sys.executable, "-m", "ipp_bench.cli", "train", *args]  # what `ipp-bench train` runs
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False)
    if check and proc.returncode != 0:
        raise AssertionError(f"{cmd} failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}")
    return proc


@pytest.mark.slow  # a real training subprocess: 10-25 s each on 2 cores
def test_tiny_training_run_then_resume(tmp_path, poison):
    run = tmp_path / "run"
    _train(*TINY, "--total-steps", "64", "--out", str(run))
    state = json.loads((run / "state.json").read_text())
    assert state["bc_done"] and state["ppo_steps"] == 64
    for name in ("config.json", "progress.csv", "warmstart/bc.pt", "checkpoints/latest.zip",
                 "checkpoints/step_64_steps.zip",
                 "export.pt", "export.json", "last.pt"):
        assert (run / name).is_file(), name
    assert any((run / "tb").iterdir())
    net, meta = load_checkpoint(run / "export.pt")
    assert net.cfg.embed_dim == 16 and meta["command"].startswith("ipp-bench train --task ipp_bench/Grid15-v0")
    steps_before = _logged_steps(run)
    assert 64 in steps_before

    # Refuses to overwrite, refuses to change the recipe on resume, continues from step 64.
    assert _train(*TINY, "--total-steps", "64", "--out", str(run), check=False).returncode == 2
    assert _train("--out", str(run), "--resume", "--n-epochs", "3", check=False).returncode == 2
    # latest.zip's pickled policy class is never unpickled: the resume uses the package's own.
    poison(run / "checkpoints" / "latest.zip", "policy_class", tmp_path / "ran")
    # Where the environments step is not part of the recipe: the resume steps them in this process.
    proc = _train("--out", str(run), "--resume", "--total-steps", "128", "--no-progress", "--vec-env", "dummy")
    assert "resuming PPO" in proc.stdout and "at step 64" in proc.stdout and "dummy vec env" in proc.stdout
    assert not (tmp_path / "ran").exists()
    state = json.loads((run / "state.json").read_text())
    assert state["ppo_steps"] == 128
    steps_after = _logged_steps(run)
    assert steps_after[: len(steps_before)] == steps_before and max(steps_after) == 128


@pytest.mark.slow  # a real training subprocess: 10-25 s each on 2 cores
def test_resume_of_an_archive_with_the_encoding_in_its_observations_is_one_line(tmp_path):
    """latest.zip of the earlier layout (pos_encoding observed per step) is refused, not a traceback."""
    import gymnasium as gym
    from sb3_contrib import MaskablePPO

    import ipp_bench.envs  # noqa: F401
    from ipp_bench.policies.sb3 import AttentionPolicy

    run = tmp_path / "run"
    _train(*TINY, "--total-steps", "32", "--out", str(run))
    old = MaskablePPO(AttentionPolicy, gym.make("ipp_bench/Grid15-v0"), n_steps=32, batch_size=32,
                      policy_kwargs={"net_config": {"embed_dim": 16, "n_heads": 2, "ff_dim": 32}})
    old.save(run / "checkpoints" / "latest.zip")
    proc = _train("--out", str(run), "--resume", "--total-steps", "64", check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.count("\n") == 1 and "does not fit" in proc.stderr and "latest.zip" in proc.stderr


def _logged_steps(run):
    import csv

    with open(run / "progress.csv") as fh:
        return [int(float(r["time/total_timesteps"])) for r in csv.DictReader(fh) if r["time/total_timesteps"]]


def test_bad_vec_env_is_refused_before_the_run_folder(tmp_path, capsys):
    from ipp_bench.train.command import main

    run = tmp_path / "run"
    with pytest.raises(SystemExit) as exit_:  # argparse: not one of the choices
        main([*TINY, "--vec-env", "threads", "--out", str(run)])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "--vec-env" in err and "subproc" in err and not run.exists()


def test_warm_start_with_a_non_graph_planner_is_refused_before_the_run_folder(tmp_path, capsys):
    from ipp_bench.train.command import main

    for bad, why in (("coverage", "roadmap planner"), ("nope", "unknown planner")):
        run = tmp_path / bad
        assert main([*TINY, "--warm-start", bad, "--total-steps", "32", "--out", str(run)]) == 2
        err = capsys.readouterr().err
        assert why in err and "--warm-start" in err and err.count("\n") == 1
        assert not run.exists()


def test_warm_start_episodes_never_reach_the_validation_seeds(tmp_path, capsys):
    # the warm start flies seeds seed * 1 000 003 + i, the validation VAL_SEED0 + j: with --seed 10 the two meet
    # once there are more than 30 validation episodes (10 000 030 - 10 000 000)
    def args(seed, eval_episodes):
        return TrainArgs(seed=seed, eval_episodes=eval_episodes, warm_start="greedy", bc_episodes=100,
                         bc_rounds=1, bc_round_episodes=50)

    assert 10 * 1_000_003 - VAL_SEED0 == 30
    for seed, eval_episodes in ((0, 100_000), (9, 100_000), (11, 100_000), (10, 30)):
        check_warm_start_seeds(args(seed, eval_episodes))  # disjoint: no error
    for seed, eval_episodes in ((10, 31), (10, 16_000)):
        with pytest.raises(ValueError, match=r"--seed 10: .*10000030\.\.10000179.*choose another seed"):
            check_warm_start_seeds(args(seed, eval_episodes))
    check_warm_start_seeds(TrainArgs(seed=10, eval_episodes=100, warm_start="none"))  # no warm start, no episodes
    from ipp_bench.train.command import main

    run = tmp_path / "run"
    assert main([*TINY, "--seed", "10", "--eval-episodes", "40", "--out", str(run)]) == 2
    err = capsys.readouterr().err
    assert "--seed 10" in err and err.count("\n") == 1 and not run.exists()


def test_export_refuses_missing_and_wrong_files(tmp_path, capsys):
    from ipp_bench.train.command import main

    assert main(["--export", str(tmp_path / "missing.zip")]) == 2
    err = capsys.readouterr().err
    assert "no such file" in err and err.count("\n") == 1
    junk = tmp_path / "junk.zip"
    junk.write_text("not a zip")
    assert main(["--export", str(junk)]) == 2
    err = capsys.readouterr().err
    assert "not a zip archive" in err and err.count("\n") == 1


@pytest.mark.slow  # a real training subprocess: 10-25 s each on 2 cores
def test_interrupted_warm_start_resumes_to_the_same_weights(tmp_path):
    """Ctrl-C (SIGTERM) after a DAgger round: --resume continues with the next round, same result."""
    import signal
    import time

    import torch

    ws = ["--bc-rounds", "2", "--bc-round-episodes", "2", "--total-steps", "32", "--eval-every", "10000"]
    ref = tmp_path / "ref"
    _train(*TINY, *ws, "--out", str(ref))
    run = tmp_path / "run"
    cmd = [sys.executable, "-m", "ipp_bench.cli", "train", *TINY, *ws, "--out", str(run)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    progress = run / "warmstart" / "progress.json"
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        if progress.is_file() and json.loads(progress.read_text())["rounds_done"] >= 1:
            proc.send_signal(signal.SIGTERM)
            break
        time.sleep(0.05)
    out, _ = proc.communicate(timeout=300)
    interrupted = proc.returncode == 130
    if interrupted:
        assert not json.loads((run / "state.json").read_text()).get("bc_done")
    resumed = _train("--out", str(run), "--resume", "--no-progress")
    if interrupted and json.loads(progress.read_text())["rounds_done"] < 3:
        assert "resuming the warm start after round" in resumed.stdout
    rows = (run / "warmstart" / "bc_log.csv").read_text().splitlines()
    ref_rows = (ref / "warmstart" / "bc_log.csv").read_text().splitlines()
    assert len(rows) == len(ref_rows)  # no round logged twice, none lost
    a = torch.load(run / "warmstart" / "bc.pt", weights_only=True)["state_dict"]
    b = torch.load(ref / "warmstart" / "bc.pt", weights_only=True)["state_dict"]
    assert all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.slow  # a real training subprocess: 10-25 s each on 2 cores
def test_init_checkpoint_must_match_the_network_options(tmp_path):
    import torch

    from ipp_bench.policies.checkpoint import save_checkpoint
    from ipp_bench.policies.network import AttentionNet, NetConfig

    torch.manual_seed(0)
    init = tmp_path / "init.pt"
    save_checkpoint(AttentionNet(NetConfig(embed_dim=16, n_heads=2, ff_dim=32)), init)
    run = tmp_path / "run"
    proc = _train(*TINY, "--init", str(init), "--out", str(run), check=False)  # the default: invariant features
    assert proc.returncode == 2 and "--init" in proc.stderr and "node_dim=5" in proc.stderr and not run.exists()
    proc = _train(*TINY, "--init", str(tmp_path / "missing.pt"), "--out", str(run), check=False)
    assert proc.returncode == 2 and "not found" in proc.stderr and not run.exists()
    _train(*TINY, "--no-invariant", "--init", str(init), "--total-steps", "32", "--out", str(run))


def _refused_in_one_line(cases, tmp_path, capsys):
    """Each (extra options, expected text): `ipp-bench train` exits 2 with one line saying it, and
    makes no run folder."""
    from ipp_bench.train.command import main

    for i, (extra, why) in enumerate(cases):
        run = tmp_path / f"r{i}"
        assert main([*TINY, *extra, "--total-steps", "32", "--out", str(run)]) == 2
        err = capsys.readouterr().err
        assert why in err and err.count("\n") == 1, (extra, err)
        assert not run.exists()


def test_mix_is_checked_before_the_run_folder(tmp_path, capsys):
    from ipp_bench.train.command import main

    cases = [
        (["--mix", "ipp_bench/Grid30Train-v1"], "PPO holds one roadmap"),
        (["--mix", "ipp_bench/Nope-v1"], "--mix 'ipp_bench/Nope-v1': unknown task 'ipp_bench/Nope-v1': valid are"),
        (["--mix", "ipp_bench/Grid15-v0"], "named twice"),
        (["--mix", "Grid15-v0"], "named twice"),  # the prefix is optional: the same task
        (["--val-task", "ipp_bench/Grid30Train-v1", "--val-task", "ipp_bench/Nope-v1"],
         "--val-task 'ipp_bench/Nope-v1': unknown task"),
    ]
    _refused_in_one_line(cases, tmp_path, capsys)
    assert main([*TINY, "--warm-start", "none", "--total-steps", "0", "--out", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert "--total-steps 0 with --warm-start none" in err and err.count("\n") == 1
    assert not (tmp_path / "none").exists()
    with pytest.raises(SystemExit):  # argparse: not one of the choices
        main([*TINY, "--reward", "last", "--out", str(tmp_path / "x")])
    assert "invalid choice: 'last'" in capsys.readouterr().err


def test_options_no_recipe_uses_are_gone(capsys):
    from ipp_bench.train.command import main

    for gone in ("--rate-skip", "--skip-teacher=far", "--reward-last=3", "--bc-distill", "--rate-skip-init=20"):
        with pytest.raises(SystemExit):
            main([*TINY, gone])
        assert "unrecognized arguments" in capsys.readouterr().err


def test_a_broken_task_file_is_one_line_before_the_run_folder(tmp_path, capsys):
    """`--task path/to/mine.toml` (as `evaluate` and `leaderboard` take it): a broken file is named with
    its line, in one line, before the run folder."""
    good = (REPO / "tasks" / "grid15_train_v1.toml").read_text()
    bad = tmp_path / "mine.toml"
    bad.write_text(good.replace("Grid15Train-v1", "MineBroken-v1").replace("k = 20", "k = 20.0"))
    line = good.splitlines().index("k = 20") + 1
    _refused_in_one_line([(["--task", str(bad)], f"--task '{bad}': {bad}:{line}: graph.k = 20.0 is invalid"),
                          (["--val-task", str(tmp_path / "missing.toml")],
                           f"--val-task '{tmp_path / 'missing.toml'}': {tmp_path / 'missing.toml'}: cannot be read")],
                         tmp_path, capsys)


@pytest.mark.slow  # a real training subprocess with worker processes: 10-30 s on 2 cores
def test_a_users_task_file_trains_in_worker_processes(tmp_path):
    """A task file is loaded in every worker process too (they do not inherit this one's registry), and
    it is validated on; the run folder's default name is the file's."""
    good = (REPO / "tasks" / "grid15_train_v1.toml").read_text()
    mine = tmp_path / "mine.toml"
    mine.write_text(good.replace("Grid15Train-v1", "MineTrain-v1").replace("budget_s = 200.0", "budget_s = 40.0"))
    assert "budget_s = 40.0" in mine.read_text()
    tiny = [a for a in TINY if a not in ("--task", "ipp_bench/Grid15-v0")]
    proc = subprocess.run([sys.executable, "-m", "ipp_bench.cli", "train", *tiny, "--task", str(mine),
                           "--n-envs", "2", "--vec-env", "subproc", "--total-steps", "64"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=600, check=False)
    assert proc.returncode == 0, proc.stderr
    (run,) = (tmp_path / "runs").iterdir()
    assert run.name.startswith("mine__attention__0__")
    assert json.loads((run / "state.json").read_text())["ppo_steps"] == 64
    assert f"training {mine}" in proc.stdout and "subproc vec env" in proc.stdout


def test_bad_numbers_and_folders_are_one_line_before_the_run_folder(tmp_path, capsys):
    from ipp_bench.train.command import main

    afile = tmp_path / "afile"
    afile.write_text("x")
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    cases = [
        (["--learning-rate", "nan"], "--learning-rate = nan is invalid: expected a finite number in (0, 1)"),
        (["--clip-range", "-0.1"], "--clip-range = -0.1 is invalid: expected a finite number > 0"),
        (["--ent-coef", "inf"], "--ent-coef = inf is invalid"),
        (["--max-grad-norm", "0"], "--max-grad-norm = 0.0 is invalid"),
        (["--target-kl", "-1"], "--target-kl = -1.0 is invalid"),
        (["--n-envs", "100000"], "--n-envs = 100000 is invalid: expected an integer in [1, 256]"),
        (["--bc-lr", "0"], "--bc-lr = 0.0 is invalid"),
    ]
    _refused_in_one_line(cases, tmp_path, capsys)
    import os

    folders = [(afile, "is a file, not a folder"), (afile / "run", f"{afile} is a file, not a folder")]
    if os.geteuid() != 0:  # root writes anywhere
        folders.append((locked / "run", "is not writable"))
    for out, why in folders:
        assert main([*TINY, "--total-steps", "32", "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert why in err and err.count("\n") == 1, err


def test_resume_with_damaged_files_names_the_file(tmp_path, capsys):
    from ipp_bench.train.command import main

    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    config = run / "config.json"
    for text, why in (("{not json", "config.json is damaged (Expecting property name"),
                      ("[1, 2]", "config.json is damaged (a JSON list"),
                      ('{"args": {"bogus": 1}}', "unknown ['bogus']")):
        config.write_text(text)
        assert main(["--out", str(run), "--resume"]) == 2
        err = capsys.readouterr().err
        assert why in err and err.count("\n") == 1, err
    import dataclasses


    config.write_text(json.dumps({"args": dataclasses.asdict(TrainArgs(out=str(run)))}))
    (run / "state.json").write_text('{"ppo_steps": 3')
    assert main(["--out", str(run), "--resume"]) == 2
    err = capsys.readouterr().err
    assert "state.json is damaged" in err and err.count("\n") == 1
    (run / "state.json").write_text('{"ppo_steps": 0}')
    (run / "checkpoints" / "latest.zip").write_bytes(b"PK\x03\x04 truncated")
    (run / "checkpoints" / "step_1024_steps.zip").write_bytes(b"")
    assert main(["--out", str(run), "--resume"]) == 2
    err = capsys.readouterr().err
    assert "latest.zip is corrupt" in err and "step_1024_steps.zip" in err and err.count("\n") == 1, err


def test_warm_start_for_names_the_expert_of_one_task_and_is_checked_before_the_run_folder(tmp_path, capsys):
    cfg = TrainArgs(task="ipp_bench/Grid15Train-v1", mix=["ipp_bench/Hotspots15Train-v2"], warm_start="greedy",
                    warm_start_for=["ipp_bench/Hotspots15Train-v2=mcts:simulations=4"])
    assert cfg.experts() == ["greedy", "mcts:simulations=4"]
    assert TrainArgs(warm_start="greedy").experts() == ["greedy"]
    cases = [
        (["--warm-start-for", "greedy"], "expected TASK=PLANNER"),
        (["--warm-start-for", "ipp_bench/Grid30Train-v1=greedy"], "one of the training tasks"),
        (["--warm-start-for", "ipp_bench/Grid15-v0=coverage"], "a roadmap planner"),
        (["--warm-start-for", "ipp_bench/Grid15-v0=nope"], "--warm-start 'nope' is invalid"),
        (["--warm-start", "none", "--warm-start-for", "ipp_bench/Grid15-v0=greedy"], "needs --warm-start"),
    ]
    _refused_in_one_line(cases, tmp_path, capsys)


@pytest.mark.slow  # builds the ten-hectare task: 10-20 s on 2 cores
def test_a_teacher_that_cannot_run_on_the_task_is_refused_before_the_run_folder(tmp_path, capsys):
    # a teacher that needs the dense belief, on a window-belief task: refused at its reset, before the run
    _refused_in_one_line([(["--task", "ipp_bench/Hotspots128Train-v2", "--warm-start", "oracle"],
                           "--warm-start oracle on ipp_bench/Hotspots128Train-v2: planner 'oracle' cannot run on")],
                         tmp_path, capsys)


def test_validate_scores_checkpoints_against_greedy_on_the_held_out_seeds(tmp_path, capsys):
    """``--validate CKPT``: the network's and greedy's figures on the same validation episodes, the
    difference per checkpoint, the best named; a missing file is one line."""
    import torch

    from ipp_bench.policies.checkpoint import save_checkpoint
    from ipp_bench.policies.network import AttentionNet, NetConfig
    from ipp_bench.train.command import main
    from ipp_bench.train.validation import evaluate_planner

    torch.manual_seed(0)
    ckpt = save_checkpoint(AttentionNet(NetConfig(embed_dim=16, n_heads=2, ff_dim=32)), tmp_path / "a.pt")
    figures = tmp_path / "val.json"
    assert main(["--validate", str(ckpt), "--val-task", "ipp_bench/Grid15-v0", "--eval-episodes", "1",
                 "--json", str(figures)]) == 0
    out = capsys.readouterr().out
    assert "| checkpoint | Grid15-v0 | mean score minus greedy |" in out
    assert f"best by the mean over 1 tasks: {ckpt}" in out
    data = json.loads(figures.read_text())
    greedy = evaluate_planner("greedy", "ipp_bench/Grid15-v0", 1, seed0=VAL_SEED0)
    assert data["greedy"]["ipp_bench/Grid15-v0"] == greedy
    (row,) = data["rows"]
    assert row["mean_minus_greedy"] == pytest.approx(row["figures"]["ipp_bench/Grid15-v0"]["val/score"]
                                                     - greedy["val/score"], abs=1e-12)
    assert main(["--validate", str(tmp_path / "missing.pt")]) == 2
    err = capsys.readouterr().err
    assert "no such checkpoint" in err and err.count("\n") == 1


def test_validate_of_several_checkpoints_gives_their_mean_and_sd_minus_greedy(tmp_path, capsys):
    """``--validate A B C``: per task and report time the mean and the sample sd over the checkpoints of each
    one's figure minus greedy's, as a table and in the JSON (a method judged over its training seeds)."""
    import torch

    from ipp_bench.policies.checkpoint import save_checkpoint
    from ipp_bench.policies.network import AttentionNet, NetConfig
    from ipp_bench.train.command import main

    paths = []
    for seed in range(3):
        torch.manual_seed(seed)
        paths.append(str(save_checkpoint(AttentionNet(NetConfig(embed_dim=16, n_heads=2, ff_dim=32)),
                                         tmp_path / f"s{seed}.pt")))
    figures = tmp_path / "val.json"
    assert main(["--validate", *paths, "--val-task", "ipp_bench/Grid15-v0", "--eval-episodes", "2",
                 "--json", str(figures)]) == 0
    out = capsys.readouterr().out
    assert "over the 3 checkpoints" in out
    data = json.loads(figures.read_text())
    task = "ipp_bench/Grid15-v0"
    greedy = data["greedy"][task]
    times = [k for k in greedy if k.startswith("val/unc_red_")]
    assert times
    for k in times:
        diffs = np.array([row["figures"][task][k] - greedy[k] for row in data["rows"]])
        cell = data["over_checkpoints"][task][k]
        assert cell["mean"] == pytest.approx(diffs.sum() / 3, abs=1e-12)
        assert cell["sd"] == pytest.approx(np.sqrt(((diffs - diffs.mean()) ** 2).sum() / 2), abs=1e-12)
        assert f"{cell['mean']:+.1f} ± {cell['sd']:.1f}" in out
    assert len({json.dumps(row["figures"][task]) for row in data["rows"]}) > 1  # the networks differ


def test_a_warm_start_alone_may_mix_map_sizes_and_weigh_a_task_twice():
    """The joint warm start: one fit over tasks of several roadmaps, a task named twice for twice its
    episodes, a teacher per task; PPO (one roadmap, each task once) refuses the same tasks."""
    import dataclasses

    from ipp_bench.train.args import check_args

    cfg = TrainArgs(task="ipp_bench/Grid15-v0", mix=["ipp_bench/Grid20Train-v1", "ipp_bench/Grid15-v0"],
                    total_steps=0, warm_start_for=["ipp_bench/Grid20Train-v1=mcts:simulations=2"])
    check_args(cfg)
    assert cfg.experts() == ["greedy", "mcts:simulations=2", "greedy"]
    with pytest.raises(ValueError, match="named twice"):
        check_args(dataclasses.replace(cfg, total_steps=32))
    with pytest.raises(ValueError, match="PPO holds one roadmap"):
        check_args(dataclasses.replace(cfg, mix=["ipp_bench/Grid20Train-v1"], total_steps=32))


def test_training_on_an_evaluation_task_warns_and_names_its_training_task(tmp_path, capsys):
    from ipp_bench.train.args import TrainArgs, evaluation_task_warnings
    from ipp_bench.train.command import main

    assert evaluation_task_warnings(TrainArgs(task="ipp_bench/Grid15Train-v1", mix=["Hotspots15Train-v2"])) == []
    assert evaluation_task_warnings(TrainArgs(task="ipp_bench/Grid15-v0")) == []
    (line,) = evaluation_task_warnings(TrainArgs(task="ipp_bench/Grid15Train-v1", mix=["Hotspots15Eval-v2"]))
    assert line.startswith("warning: ipp_bench/Hotspots15Eval-v2 is an evaluation task")
    assert line.endswith("its training task is ipp_bench/Hotspots15Train-v2")
    run = tmp_path / "run"
    args = [a if a != "ipp_bench/Grid15-v0" else "ipp_bench/Grid15Eval-v1" for a in TINY]
    assert main([*args, "--total-steps", "0", "--out", str(run)]) == 0
    out = capsys.readouterr().out
    assert "warning: ipp_bench/Grid15Eval-v1 is an evaluation task" in out
    assert "warning: ipp_bench/Grid15Eval-v1" in (run / "train.log").read_text()


@pytest.mark.slow  # two real training subprocesses: about 20 s on 2 cores
def test_a_write_that_fails_midway_is_one_line_leaves_no_temporary_file_and_resumes(tmp_path):
    """Files over 200 kB cannot be written (RLIMIT_FSIZE, as on a full disk or a quota): the run stops
    with one line naming the file, leaves every file whole and none temporary, and resumes to the end."""
    import resource
    import signal

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write fails (EFBIG) instead of killing
        resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))

    run = tmp_path / "run"
    cmd = [sys.executable, "-m", "ipp_bench.cli", "train", *TINY, "--total-steps", "96", "--out", str(run)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, preexec_fn=limit, check=False)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1, proc.stderr
    assert "cannot write" in proc.stderr and f"--out {run} --resume" in proc.stderr
    assert not [p for p in run.rglob("*") if "tmp" in p.name]
    json.loads((run / "state.json").read_text())
    _train("--out", str(run), "--resume")
    assert json.loads((run / "state.json").read_text())["ppo_steps"] == 96
