"""``ipp-bench train``'s options: generated from TrainArgs, written back as the exact command."""

import argparse
import shlex

import pytest

from ipp_bench.train.args import TrainArgs, add_train_arguments, command_line


def _parse(argv: list[str]) -> TrainArgs:
    ns = add_train_arguments(argparse.ArgumentParser()).parse_args(argv)
    return TrainArgs(**{k: v for k, v in vars(ns).items() if k in TrainArgs.__dataclass_fields__ and v is not None})


@pytest.mark.parametrize("cfg", [
    TrainArgs(total_steps=1234, learning_rate=1e-5, progress=False, invariant=False, gain_feature=True),
    TrainArgs(warm_start="none", init="some/where.pt", mix=["ipp_bench/Hotspots15Train-v2"]),
    TrainArgs(total_steps=0, mix=["ipp_bench/Grid30Train-v1", "ipp_bench/Grid30Train-v1"],
              warm_start_for=["ipp_bench/Grid30Train-v1=mcts"], val_task=["ipp_bench/Grid20Train-v1"]),
], ids=["ppo-and-warm-start", "ppo-alone", "warm-start-alone"])
def test_command_line_round_trips_through_the_parser(cfg):
    assert _parse(shlex.split(command_line(cfg))[2:]) == cfg


def test_command_line_names_what_acts_on_the_run():
    both = command_line(TrainArgs(progress=False, invariant=False))
    assert "--no-progress" in both and "--no-invariant" in both and "--learning-rate" in both and "--bc-lr" in both
    alone = command_line(TrainArgs(total_steps=0))  # a warm start alone: no PPO option, but its fit's batch and gamma
    assert "--learning-rate" not in alone and "--n-envs" not in alone and "--eval-every" not in alone
    assert "--batch-size 128" in alone and "--gamma 0.99" in alone and "--bc-lr" in alone
    ppo = command_line(TrainArgs(warm_start="none", init="a.pt"))
    assert "--bc-lr" not in ppo and "--init a.pt" in ppo and "--warm-start none" in ppo
    assert "--out" not in ppo and "--out x" in command_line(TrainArgs(out="x"), where=True)
    assert "--device" not in command_line(TrainArgs(out="x"), where=True)  # the default is not spelled out


def test_val_task_is_repeatable_and_reads_earlier_run_folders():
    from ipp_bench.train.validation import val_tasks

    cfg = _parse(["--val-task", "ipp_bench/Grid15Train-v1", "--val-task", "ipp_bench/Grid30Train-v1"])
    assert [t for t, _ in val_tasks(cfg)] == ["ipp_bench/Grid15Train-v1", "ipp_bench/Grid30Train-v1"]
    assert command_line(cfg).count("--val-task") == 2
    # the recorded commands of earlier checkpoints (--val-task '') and their config.json ("val_task": "")
    assert _parse(["--val-task", ""]).val_task == []
    assert TrainArgs(val_task="").val_task == [] and TrainArgs(val_task="ipp_bench/Grid30Train-v1").val_task == [
        "ipp_bench/Grid30Train-v1"]
    # none given: the training tasks, each once
    mixed = TrainArgs(mix=["ipp_bench/Hotspots15Train-v2", "ipp_bench/Grid15Train-v1"], total_steps=0)
    assert [t for t, _ in val_tasks(mixed)] == ["ipp_bench/Grid15Train-v1", "ipp_bench/Hotspots15Train-v2"]


def test_options_are_generated_from_the_dataclass_and_the_defaults_are_the_recipes():
    parser = add_train_arguments(argparse.ArgumentParser())
    flags = {a.dest for a in parser._actions}
    assert set(TrainArgs.__dataclass_fields__) <= flags
    text = " ".join(parser.format_help().split())
    assert "(default 3e-05)" in text and "paper: 1e-5" in text  # the help shows the default and the paper's
    cfg = TrainArgs()
    assert (cfg.embed_dim, cfg.ff_dim, cfg.invariant, cfg.reward, cfg.gae_lambda, cfg.clip_range) == (
        64, 256, True, "metric", 0.95, 0.1)
    assert (cfg.n_envs, cfg.n_steps, cfg.n_epochs, cfg.warm_start) == (16, 64, 1, "greedy")
    assert cfg.net_config().node_dim == 6 and cfg.net_config().invariant


def test_warm_start_for_names_the_teacher_of_one_task():
    cfg = TrainArgs(task="ipp_bench/Grid15Train-v1", mix=["ipp_bench/Hotspots15Train-v2"], warm_start="greedy",
                    warm_start_for=["ipp_bench/Hotspots15Train-v2=mcts:simulations=4"])
    assert cfg.experts() == ["greedy", "mcts:simulations=4"]
    assert TrainArgs(warm_start="greedy").experts() == ["greedy"]
