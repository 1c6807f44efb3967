"""A tiny run of the real `ipp-bench train` command, its resume, and the export it writes."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("sb3_contrib")

from ipp_bench.policies.checkpoint import load_checkpoint
from ipp_bench.policies.train import VAL_SEED0, TrainArgs, add_train_arguments, check_warm_start_seeds, command_line
from ipp_bench.policies.warmstart import soft_target

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
def test_tiny_training_run_then_resume(tmp_path):
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
    # Where the environments step is not part of the recipe: the resume steps them in this process.
    proc = _train("--out", str(run), "--resume", "--total-steps", "128", "--no-progress", "--vec-env", "dummy")
    assert "resuming PPO" in proc.stdout and "at step 64" in proc.stdout and "dummy vec env" in proc.stdout
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


def test_command_line_round_trips_through_the_parser():
    import argparse
    import shlex

    cfg = TrainArgs(total_steps=1234, warm_start="greedy", learning_rate=3e-5, progress=False, gain_feature=True)
    assert "--gain-feature" in command_line(cfg) and "--no-progress" in command_line(cfg)
    argv = shlex.split(command_line(cfg))[2:]
    ns = add_train_arguments(argparse.ArgumentParser()).parse_args(argv)
    parsed = {k: v for k, v in vars(ns).items() if k in TrainArgs.__dataclass_fields__ and v is not None}
    again = TrainArgs(**parsed)
    assert again == cfg


def test_val_task_is_repeatable_and_reads_earlier_run_folders():
    import argparse

    from ipp_bench.policies.train import _val_tasks

    parser = add_train_arguments(argparse.ArgumentParser())
    ns = parser.parse_args(["--val-task", "ipp_bench/Grid15Train-v1", "--val-task", "ipp_bench/Grid30Train-v1"])
    cfg = TrainArgs(val_task=ns.val_task)
    assert [t for t, _ in _val_tasks(cfg)] == ["ipp_bench/Grid15Train-v1", "ipp_bench/Grid30Train-v1"]
    assert command_line(cfg).count("--val-task") == 2
    # the recorded commands of earlier checkpoints (--val-task '') and their config.json ("val_task": "")
    assert TrainArgs(val_task=parser.parse_args(["--val-task", ""]).val_task).val_task == []
    assert TrainArgs(val_task="").val_task == [] and TrainArgs(val_task="ipp_bench/Grid30Train-v1").val_task == [
        "ipp_bench/Grid30Train-v1"]
    assert [t for t, _ in _val_tasks(TrainArgs(mix=["ipp_bench/Hotspots15Train-v2"]))] == [
        "ipp_bench/Grid15Train-v1", "ipp_bench/Hotspots15Train-v2"]


def test_soft_targets():
    import numpy as np

    s = np.array([1.0, 0.95, 0.5, -np.inf])
    t = soft_target(0, s, 4, 0.1)
    assert t[3] == 0 and t.argmax() == 0 and t[1] > t[2] > 0 and abs(t.sum() - 1) < 1e-6
    assert soft_target(2, None, 4, 0.1).tolist() == [0, 0, 1, 0]
    assert soft_target(1, s, 4, 0.0).tolist() == [0, 1, 0, 0]


def test_a_network_teachers_logits_are_its_policy_under_distillation():
    import numpy as np

    from ipp_bench.policies.warmstart import PolicyLogits

    logits = np.array([2.0, 0.5, -np.inf, 1.0]).view(PolicyLogits)
    for temperature in (1.0, 0.5):
        z = np.exp(np.array([2.0, 0.5, 1.0]) / temperature)
        expected = np.insert(z / z.sum(), 2, 0.0)
        assert np.allclose(soft_target(0, logits, 4, temperature), expected, atol=1e-7)
    assert soft_target(0, logits, 4, 0.0).tolist() == [1, 0, 0, 0]
    # the same numbers as plain scores are greedy's gains, not a policy: p ~ exp((s / s_max - 1) / T)
    assert not np.allclose(soft_target(0, np.array([2.0, 0.5, -np.inf, 1.0]), 4, 1.0), expected, atol=1e-3)


def test_distillation_labels_with_the_teachers_policy_and_its_avoid_rule():
    """Under ``--bc-distill`` an ``attention`` teacher's label is the softmax of the logits it decided on: the
    network's own policy, with the neighbours its rules exclude (here the 8 m level from 50 s on) at 0."""
    import numpy as np

    from ipp_bench.envs import make_env
    from ipp_bench.planners import view_for
    from ipp_bench.policies.warmstart import PolicyLogits, make_expert

    env = make_env("ipp_bench/Hotspots15Eval-v2", altitudes=[8.0, 10.0, 14.0], k=21)
    expert = make_expert("attention:stall_legs=0,avoid_altitude=8,avoid_from_s=50", distill=True)
    obs, _ = env.reset(seed=0)
    expert.planner.reset(view_for(expert.planner, env), 0)
    z = env.roadmap.positions[:, 2]
    late_with_low = 0
    while obs["action_mask"].any():
        t = env.mission.time_s
        action, logits = expert(obs)
        assert isinstance(logits, PolicyLogits) and action == int(np.argmax(logits))
        target = soft_target(action, logits, len(logits), 1.0)
        nb_low = np.isclose(z[obs["neighbours"]], 8.0)
        raw = expert.planner.probabilities(obs)  # the network's policy without the rule
        if t < 50.0:
            assert np.allclose(target, raw, atol=1e-6)
        elif (obs["action_mask"].astype(bool) & ~nb_low).any():
            assert target[nb_low].sum() == 0.0 and abs(target.sum() - 1) < 1e-6
            late_with_low += bool((raw[nb_low] > 1e-3).any())
        obs, *_ = env.step(action)
    assert late_with_low > 0  # the rule took probability off the 8 m level that the network gave it


def test_options_are_generated_from_the_dataclass():
    import argparse

    parser = add_train_arguments(argparse.ArgumentParser())
    flags = {a.dest for a in parser._actions}
    assert {f for f in TrainArgs.__dataclass_fields__} <= flags
    assert "(default 1e-05)" in parser.format_help()  # the help shows the dataclass default


def test_bad_vec_env_is_refused_before_the_run_folder(tmp_path):
    run = tmp_path / "run"
    proc = _train(*TINY, "--vec-env", "threads", "--out", str(run), check=False)
    assert proc.returncode == 2 and "--vec-env" in proc.stderr and "subproc" in proc.stderr and not run.exists()


def test_warm_start_with_a_non_graph_planner_is_refused_before_the_run_folder(tmp_path):
    for bad, why in (("coverage", "roadmap planner"), ("nope", "unknown planner")):
        run = tmp_path / bad
        proc = _train(*TINY, "--warm-start", bad, "--total-steps", "32", "--out", str(run), check=False)
        assert proc.returncode == 2 and why in proc.stderr and "--warm-start" in proc.stderr
        assert not run.exists()


def test_warm_start_episodes_never_reach_the_validation_seeds(tmp_path):
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
    run = tmp_path / "run"
    proc = _train(*TINY, "--seed", "10", "--eval-episodes", "40", "--out", str(run), check=False)
    assert proc.returncode == 2 and "--seed 10" in proc.stderr and "Traceback" not in proc.stderr
    assert not run.exists()


def test_export_refuses_missing_and_wrong_files(tmp_path):
    proc = _train("--export", str(tmp_path / "missing.zip"), check=False)
    assert proc.returncode == 2 and "no such file" in proc.stderr and "Traceback" not in proc.stderr
    junk = tmp_path / "junk.zip"
    junk.write_text("not a zip")
    proc = _train("--export", str(junk), check=False)
    assert proc.returncode == 2 and "not a zip archive" in proc.stderr and "Traceback" not in proc.stderr


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
    proc = _train(*TINY, "--gain-feature", "--init", str(init), "--out", str(run), check=False)
    assert proc.returncode == 2 and "--init" in proc.stderr and "node_dim=5" in proc.stderr and not run.exists()
    proc = _train(*TINY, "--init", str(tmp_path / "missing.pt"), "--out", str(run), check=False)
    assert proc.returncode == 2 and "not found" in proc.stderr and not run.exists()
    _train(*TINY, "--init", str(init), "--total-steps", "32", "--out", str(run))


def _refused_in_one_line(cases, tmp_path, capsys):
    """Each (extra options, expected text): `ipp-bench train` exits 2 with one line saying it, and
    makes no run folder."""
    from ipp_bench.policies.train import main

    for i, (extra, why) in enumerate(cases):
        run = tmp_path / f"r{i}"
        assert main([*TINY, *extra, "--total-steps", "32", "--out", str(run)]) == 2
        err = capsys.readouterr().err
        assert why in err and err.count("\n") == 1, (extra, err)
        assert not run.exists()


def test_mix_and_skip_teacher_are_checked_before_the_run_folder(tmp_path, capsys):
    from ipp_bench.policies.train import main

    cases = [
        (["--mix", "ipp_bench/Grid30Train-v1"], "one PPO run holds one roadmap"),
        (["--mix", "ipp_bench/Nope-v1"], "--mix 'ipp_bench/Nope-v1': unknown task 'ipp_bench/Nope-v1': valid are"),
        (["--mix", "ipp_bench/Grid15-v0"], "named twice"),
        (["--mix", "Grid15-v0"], "named twice"),  # the prefix is optional: the same task
        (["--skip-teacher", "far"], "--skip-teacher far needs --rate-skip"),
        (["--bc-distill"], "--bc-distill needs a network teacher (attention:...)"),
        (["--warm-start", "none", "--bc-distill"], "--bc-distill needs --warm-start attention:..."),
        (["--val-task", "ipp_bench/Grid30Train-v1", "--val-task", "ipp_bench/Nope-v1"],
         "--val-task 'ipp_bench/Nope-v1': unknown task"),
    ]
    _refused_in_one_line(cases, tmp_path, capsys)
    with pytest.raises(SystemExit):  # argparse: not one of the choices
        main([*TINY, "--rate-skip", "--skip-teacher", "oracle", "--out", str(tmp_path / "x")])
    assert "invalid choice: 'oracle'" in capsys.readouterr().err


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
    from ipp_bench.policies.train import main

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
        (["--rate-skip", "--rate-skip-init", "nan"], "--rate-skip-init = nan is invalid"),
        (["--reward", "metric", "--reward-last", "0"], "--reward-last = 0.0 is invalid: expected a finite number in (0, 100]"),
        (["--reward", "metric", "--reward-last", "101"], "--reward-last = 101.0 is invalid"),
        (["--reward", "paper", "--reward-last", "3"], "--reward-last 3 weighs the metric reward's report times: it "
                                                      "needs --reward metric (given --reward paper)"),
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
    from ipp_bench.policies.train import main

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
    import json

    from ipp_bench.policies.train import TrainArgs

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
        # a teacher that needs the dense belief, on a window-belief task: refused at its reset, before the run
        (["--task", "ipp_bench/Hotspots128Train-v2", "--warm-start", "oracle"],
         "--warm-start oracle on ipp_bench/Hotspots128Train-v2: planner 'oracle' cannot run on"),
    ]
    _refused_in_one_line(cases, tmp_path, capsys)


def _fake_obs(n_nodes: int, k: int, value: float) -> dict:
    import numpy as np

    return {"node_features": np.full((n_nodes, 6), value, np.float32), "current_node": np.array([0]),
            "neighbours": np.arange(k), "action_mask": np.ones(k, bool), "budget": np.array([0.5], np.float32),
            "pos_encoding": np.full((n_nodes, 4), float(n_nodes), np.float32)}


def test_warm_start_batches_hold_one_map_size_each_and_every_sample_once(tmp_path):
    """States of two roadmaps in one DAgger dataset: each minibatch stacks one roadmap's states, every
    sample comes exactly once per epoch; with one roadmap the batches are the plain shuffle's."""
    import numpy as np
    import torch

    from ipp_bench.policies.warmstart import BCDataset, _load_chunk, _save_chunk

    data = BCDataset()
    k = 3
    for e, n in enumerate([10, 25, 10, 25, 25]):
        obs = [_fake_obs(n, k, 100 * e + j) for j in range(7)]
        data.add_episode(obs, [0] * 7, [np.eye(k, dtype=np.float32)[0]] * 7, [1.0] * 7, 0.9)
    seen = []
    for obs, target, ret in data.batches(4, np.random.default_rng(0), torch.device("cpu")):
        nf = obs["node_features"]
        assert nf.shape[1] in (10, 25) and obs["pos_encoding"].shape[1] == nf.shape[1]
        assert torch.all(obs["pos_encoding"] == nf.shape[1])  # each state's own roadmap's encoding
        seen += nf[:, 0, 0].tolist()
    assert sorted(seen) == sorted(100 * e + j for e in range(5) for j in range(7))

    # a round's samples to disk and back (the resumable warm start), sizes kept
    _save_chunk(data, 7, tmp_path / "data_0.npz")
    back = BCDataset()
    _load_chunk(back, tmp_path / "data_0.npz")
    assert len(back) == len(data) - 7
    assert all(np.array_equal(a, b) for a, b in zip(back.nf, data.nf[7:]))
    assert [back.pes[i].shape[0] for i in back.pe_id] == [a.shape[0] for a in data.nf[7:]]

    one = BCDataset()
    one.add_episode([_fake_obs(10, k, j) for j in range(9)], [0] * 9, [np.eye(k, dtype=np.float32)[0]] * 9,
                    [1.0] * 9, 0.9)
    got = [b[0]["node_features"][:, 0, 0].tolist() for b in one.batches(4, np.random.default_rng(1), "cpu")]
    order = np.random.default_rng(1).permutation(9)
    assert got == [order[s:s + 4].astype(float).tolist() for s in range(0, 9, 4)]
