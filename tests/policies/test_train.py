"""A tiny run of the real `ipp-bench train` command, its resume, and the export it writes."""

import json
import subprocess
import sys

import pytest

pytest.importorskip("sb3_contrib")

from ipp_bench.policies.checkpoint import load_checkpoint
from ipp_bench.policies.train import TrainArgs, add_train_arguments, command_line, soft_target

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


def test_tiny_training_run_then_resume(tmp_path):
    run = tmp_path / "run"
    _train(*TINY, "--total-steps", "64", "--out", str(run))
    state = json.loads((run / "state.json").read_text())
    assert state["bc_done"] and state["ppo_steps"] == 64
    for name in ("config.json", "progress.csv", "warmstart/bc.pt", "checkpoints/latest.zip",
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
    proc = _train("--out", str(run), "--resume", "--total-steps", "128", "--no-progress")
    assert "resuming PPO" in proc.stdout and "at step 64" in proc.stdout
    state = json.loads((run / "state.json").read_text())
    assert state["ppo_steps"] == 128
    steps_after = _logged_steps(run)
    assert steps_after[: len(steps_before)] == steps_before and max(steps_after) == 128


def _logged_steps(run):
    import csv

    with open(run / "progress.csv") as fh:
        return [int(float(r["time/total_timesteps"])) for r in csv.DictReader(fh) if r["time/total_timesteps"]]


def test_command_line_round_trips_through_the_parser():
    import argparse
    import shlex

    cfg = TrainArgs(total_steps=1234, warm_start="greedy", learning_rate=3e-5, progress=False)
    argv = shlex.split(command_line(cfg))[2:]
    ns = add_train_arguments(argparse.ArgumentParser()).parse_args(argv)
    parsed = {k: v for k, v in vars(ns).items() if k in TrainArgs.__dataclass_fields__ and v is not None}
    again = TrainArgs(**parsed)
    assert again == cfg


def test_soft_targets():
    import numpy as np

    s = np.array([1.0, 0.95, 0.5, -np.inf])
    t = soft_target(0, s, 4, 0.1)
    assert t[3] == 0 and t.argmax() == 0 and t[1] > t[2] > 0 and abs(t.sum() - 1) < 1e-6
    assert soft_target(2, None, 4, 0.1).tolist() == [0, 0, 1, 0]
    assert soft_target(1, s, 4, 0.0).tolist() == [0, 1, 0, 0]
