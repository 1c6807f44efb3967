"""Recipes: the shipped checkpoint's stages as data, refused in one line when wrong, printed by
``--dry-run``, and a tiny recipe of every stage kind run end to end, interrupted, resumed, skipped."""

import json
import shlex
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest

from ipp_bench.train.args import TrainArgs, command_line
from ipp_bench.train.command import main
from ipp_bench.train.recipe import RecipeError, known_recipes, load_recipe, plan

SHIPPED = Path(__file__).resolve().parents[2] / "ipp_bench" / "policies" / "checkpoints"

TINY_RECIPE = """
name = "tiny"
[settings]
embed_dim = 16
n_heads = 2
ff_dim = 32
env = ["budget_s=60"]
eval_episodes = 1
n_envs = 2
n_steps = 32
batch_size = 32
bc_episodes = 2
bc_rounds = 1
bc_round_episodes = 1
bc_epochs = 1

[[stage]]
name = "warm"
kind = "warm_start"
tasks = ["ipp_bench/Grid15-v0"]

[[stage]]
name = "ppo"
kind = "ppo"
from = "warm"
hand_on = "best"
tasks = ["ipp_bench/Grid15-v0"]
total_steps = 128
eval_every = 64
checkpoint_every = 64

[[stage]]
name = "joint"
kind = "warm_start"
from = "ppo"
tasks = ["ipp_bench/Grid15-v0", "ipp_bench/Grid20Train-v1", "ipp_bench/Grid15-v0"]
teachers = {"ipp_bench/Grid20Train-v1" = "attention:checkpoint={init},stall_legs=0"}
bc_episodes = 3
"""


def _write(tmp_path, text, name="r.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_the_shipped_recipe_has_every_stage_of_the_shipped_checkpoint():
    import math

    assert "attention_v6" in known_recipes()
    recipe = load_recipe("attention_v6")
    assert [s.name for s in recipe.stages] == ["warm15", "ppo15", "ppo30", "ppo15b", "dagger30", "ppo30b", "joint"]
    assert [s.kind for s in recipe.stages] == ["warm_start", "ppo", "ppo", "ppo", "warm_start", "ppo", "warm_start"]
    assert [s.hand_on for s in recipe.stages] == ["bc", "last", "best", "last", "bc", "last", "bc"]
    # the PPO steps of the shipped checkpoint's lineage: every stage's, the 30 x 30 one to its best step
    shipped = json.loads((SHIPPED / "attention_v6.json").read_text())["meta"]
    assert sum(s.total_steps for s in recipe.stages) >= shipped["ppo_steps_total"] == 2_751_488
    runs = dict((s.name, cfg) for s, cfg in plan(recipe, Path("out")))
    joint = runs["joint"]
    assert joint.init == "out/ppo30b/last.pt" and joint.total_steps == 0 and joint.tasks.count(
        "ipp_bench/Grid20Train-v1") == 2 and joint.tasks.count("ipp_bench/Grid30Train-v1") == 2
    assert joint.experts().count("attention:checkpoint=out/ppo30b/last.pt,stall_legs=0") == 2
    assert (joint.bc_episodes, joint.bc_round_episodes, joint.bc_epochs, joint.bc_lr, joint.bc_temperature) == (
        140, 70, 4, 1e-4, 0.05)
    # every PPO stage's settings are those recorded in the shipped checkpoint's meta
    for stage_meta, (stage, cfg) in zip(shipped["stages"], plan(recipe, Path("out")), strict=True):
        if stage.kind != "ppo":
            continue
        recorded = shlex.split(stage_meta["command"])
        for opt in ("--total-steps", "--learning-rate", "--gae-lambda", "--clip-range", "--n-envs", "--n-steps",
                    "--eval-every", "--checkpoint-every", "--embed-dim", "--ff-dim"):
            value = recorded[recorded.index(opt) + 1]
            assert math.isclose(float(getattr(cfg, opt[2:].replace("-", "_"))), float(value)), (stage.name, opt)
        assert cfg.reward == "metric" and cfg.invariant and cfg.warm_start == "none"


def test_the_method_recipe_has_three_stages_that_build_on_each_other_and_is_what_the_seeds_ran():
    """attention_v7: at most three stages, each from the one before, one set of settings (no stage sets its own
    PPO or network settings), every training task in the warm start; each shipped seed's recorded commands
    are the recipe's with --seed S, and the method ships three training seeds, 0, 1 and 2."""
    recipe = load_recipe("attention_v7")
    assert len(recipe.stages) <= 3
    assert [s.start for s in recipe.stages] == ["", *(s.name for s in recipe.stages[:-1])]
    runs = [cfg for _, cfg in plan(recipe, Path("out"))]
    shared = ("learning_rate", "clip_range", "n_envs", "n_steps", "batch_size", "n_epochs", "embed_dim", "ff_dim",
              "n_heads", "gae_lambda", "ent_coef", "vf_coef", "reward", "invariant", "seed", "val_task")
    assert all(getattr(cfg, k) == getattr(runs[0], k) for cfg in runs for k in shared)
    assert set(runs[0].tasks) == {f"ipp_bench/{t}" for t in ("Grid15Train-v1", "Grid20Train-v1", "Grid30Train-v1",
                                                               "Hotspots15Train-v2", "Hotspots30Train-v2")}
    assert sorted(p.name for p in SHIPPED.glob("attention_v7_seed*.pt")) == [
        f"attention_v7_seed{s}.pt" for s in (0, 1, 2)]
    for seed in (0, 1, 2):
        shipped = json.loads((SHIPPED / f"attention_v7_seed{seed}.json").read_text())["meta"]
        assert shipped["recipe"] == "attention_v7" and shipped["training_seed"] == seed
        out = Path(f"runs/v7/seed{seed}")
        for stage_meta, (stage, cfg) in zip(shipped["stages"], plan(recipe, out), strict=True):
            assert stage_meta["name"] == stage.name
            assert shlex.split(stage_meta["command"]) == shlex.split(command_line(replace(cfg, seed=seed))), (
                seed, stage.name)


def test_a_recipe_runs_with_another_seed_in_every_stage(capsys):
    assert main(["--recipe", "attention_v7", "--dry-run", "--seed", "2", "--out", "runs/v7_2"]) == 0
    commands = [shlex.split(line) for line in capsys.readouterr().out.splitlines() if line.startswith("ipp-bench")]
    assert len(commands) == 3 and all(c[c.index("--seed") + 1] == "2" for c in commands)


def test_dry_run_prints_every_stage_as_its_command(capsys):
    assert main(["--recipe", "attention_v6", "--dry-run", "--out", "runs/v6", "--threads", "1"]) == 0
    out = capsys.readouterr().out
    commands = [line for line in out.splitlines() if line.startswith("ipp-bench train")]
    assert len(commands) == 7 and "runs/v6/attention.pt <- runs/v6/joint/warmstart/bc.pt" in out
    recipe = load_recipe("attention_v6")
    for line, (stage, cfg) in zip(commands, plan(recipe, Path("runs/v6")), strict=True):
        assert f"--out runs/v6/{stage.name}" in line and "--threads 1" in line
        assert line == command_line(TrainArgs(**{**cfg.__dict__, "threads": 1}), where=True)
    assert "--init runs/v6/warm15/warmstart/bc.pt" in commands[1] and "--init runs/v6/ppo30/export.pt" in commands[3]
    assert main(["--recipe", "attention_v6", "--dry-run", "--from-stage", "joint", "--init", "v3.pt"]) == 0
    out = capsys.readouterr().out
    assert out.count("ipp-bench train --task") == 1 and "--init v3.pt" in out and "checkpoint=v3.pt" in out


@pytest.mark.parametrize("text, why", [
    ('name = "x"\nbogus = 1\n[[stage]]\nname="a"\nkind="ppo"\ntasks=["ipp_bench/Grid15-v0"]\ntotal_steps=1',
     "unknown key 'bogus'"),
    ('[settings]\nlr = 1\n[[stage]]\nname="a"\nkind="ppo"\ntasks=["ipp_bench/Grid15-v0"]\ntotal_steps=1',
     "[settings] has the unknown key 'lr'"),
    ('[settings]\nlearning_rate = "fast"\n[[stage]]\nname="a"\nkind="ppo"\ntasks=["ipp_bench/Grid15-v0"]\n'
     'total_steps=1', "learning_rate = 'fast' is invalid: expected a number"),
    ('[[stage]]\nname="a"\nkind="ppo"\ntasks=["ipp_bench/Grid15-v0"]\ntotal_steps=1\nsteps=3', "unknown key 'steps'"),
    ('[[stage]]\nname="a"\nkind="ppo"\ntasks="ipp_bench/Grid15-v0"\ntotal_steps=1',
     "tasks = 'ipp_bench/Grid15-v0' is invalid: expected a list of strings"),
    ('[[stage]]\nname="a"\nkind="ppo"\ntasks=["ipp_bench/Grid15-v0"]\ntotal_steps=true',
     "total_steps = True is invalid: expected an integer"),
    ('[[stage]]\nname="a"\nkind="dagger"\ntasks=["ipp_bench/Grid15-v0"]', "kind 'dagger' is invalid"),
    ('[[stage]]\nname="a"\nkind="ppo"\ntasks=["ipp_bench/Grid15-v0"]', "a ppo stage needs an integer >= 1"),
    ('[[stage]]\nname="a"\nkind="warm_start"\ntasks=["ipp_bench/Grid15-v0"]\ntotal_steps=5',
     "total_steps is for a ppo stage"),
    ('[[stage]]\nname="a"\nkind="warm_start"\ntasks=["ipp_bench/Grid15-v0"]\nhand_on="last"',
     "hand_on 'last' is invalid for a warm_start stage"),
    ('[[stage]]\nname="a"\nkind="ppo"\nfrom="b"\ntasks=["ipp_bench/Grid15-v0"]\ntotal_steps=1',
     "from 'b' is not an earlier stage"),
    ('[[stage]]\nname="a"\nkind="warm_start"\ntasks=["ipp_bench/Grid15-v0"]\n'
     'teachers={"ipp_bench/Grid20Train-v1"="greedy"}', "teachers names 'ipp_bench/Grid20Train-v1', not one of"),
    ('[[stage]]\nname="a"\nkind="warm_start"\ntasks=["ipp_bench/Grid15-v0"]\n'
     'teachers={"ipp_bench/Grid15-v0"="attention:checkpoint={init}"}', "the stage has no 'from'"),
    ('[[stage]]\nname="a"\nkind="warm_start"\ntasks=["ipp_bench/Nope-v1"]', "stage 'a': --task 'ipp_bench/Nope-v1'"),
    ('[[stage]]\nname="a"\nkind="warm_start"\ntasks=["ipp_bench/Grid15-v0"]\nbc_lr=0',
     "stage 'a': --bc-lr = 0.0 is invalid"),
    ('[[stage]]\nname="a/b"\nkind="warm_start"\ntasks=["ipp_bench/Grid15-v0"]', "name 'a/b' is invalid"),
    ('[[stage]]\nname="a"\nkind="warm_start"\ntasks=["ipp_bench/Grid15-v0"]\nout="x"', "unknown key 'out'"),
    ('name = "x"', "no [[stage]] tables"),
    ('[[stage]\nname="a"', "not readable TOML"),
], ids=["top-key", "settings-key", "setting-type", "stage-key", "tasks-type", "steps-type", "kind", "ppo-steps",
        "warm-steps", "hand-on", "from", "teachers", "init-without-from", "task", "range", "name", "where-key",
        "no-stage", "toml"])
def test_a_bad_recipe_is_one_line_naming_the_key(tmp_path, capsys, text, why):
    path = _write(tmp_path, text)
    with pytest.raises(RecipeError):
        load_recipe(str(path))
    assert main(["--recipe", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert why in err and err.count("\n") == 1 and "Traceback" not in err, err
    assert not (tmp_path / "out").exists()


def test_an_unknown_recipe_and_wrong_companions_are_one_line(tmp_path, capsys):
    cases = [
        (["--recipe", "nope"], "--recipe 'nope' is unknown: the shipped recipes are attention_v6"),
        (["--recipe", str(tmp_path / "missing.toml")], "missing.toml: no such file"),
        (["--recipe", "attention_v6", "--learning-rate", "0.1"], "--learning-rate cannot go with it"),
        (["--recipe", "attention_v6", "--resume"], "--resume cannot go with it"),
        (["--recipe", "attention_v6"], "--recipe needs --out DIR"),
        (["--recipe", "attention_v6", "--from-stage", "joint"], "--from-stage STAGE and --init PT go together"),
        (["--recipe", "attention_v6", "--from-stage", "nope", "--init", "x.pt"], "no such stage; its stages: warm15"),
        (["--dry-run"], "--dry-run needs --recipe NAME"),
    ]
    for argv, why in cases:
        assert main([*argv, "--out", str(tmp_path / "out")] if "--out" not in argv and "needs --out" not in why
                    else argv) == 2
        err = capsys.readouterr().err
        assert why in err and err.count("\n") == 1, (argv, err)
    assert not (tmp_path / "out").exists()


def _recipe(*args):
    return subprocess.Popen([sys.executable, "-m", "ipp_bench.cli", "train", "--recipe", *args, "--threads", "1",
                             "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.slow  # three tiny stages in subprocesses, twice: about a minute on 2 cores
def test_a_tiny_recipe_runs_every_stage_kind_resumes_and_skips_done_stages(tmp_path):
    import torch

    from ipp_bench.policies.checkpoint import load_checkpoint

    path = _write(tmp_path, TINY_RECIPE)
    out = tmp_path / "out"
    proc = _recipe(str(path), "--out", str(out))
    deadline = time.time() + 600
    while time.time() < deadline and proc.poll() is None:  # interrupt once PPO has saved an update
        if (out / "ppo" / "checkpoints" / "latest.zip").is_file():
            proc.send_signal(signal.SIGTERM)
            break
        time.sleep(0.05)
    stdout, stderr = proc.communicate(timeout=600)
    assert proc.returncode == 130, stderr
    assert f"continue with: ipp-bench train --recipe {path} --out {out}" in stdout
    assert not (out / "attention.pt").exists()

    proc = _recipe(str(path), "--out", str(out))
    stdout, stderr = proc.communicate(timeout=600)
    assert proc.returncode == 0, stderr
    assert "stage warm: done, skipped" in stdout and "stage ppo: resuming" in stdout
    assert "stage joint: starting" in stdout and "resuming PPO from" in stdout
    net, meta = load_checkpoint(out / "attention.pt")
    handed, _ = load_checkpoint(out / "joint" / "warmstart" / "bc.pt")
    assert all(torch.equal(a, b) for a, b in zip(net.state_dict().values(), handed.state_dict().values()))
    assert meta["recipe"] == "tiny" and [s["name"] for s in meta["stages"]] == ["warm", "ppo", "joint"]
    assert meta["stages"][1]["command"].startswith("ipp-bench train --task ipp_bench/Grid15-v0")
    assert meta["ppo_steps_total"] == json.loads((out / "ppo" / "export.json").read_text())["meta"]["ppo_steps"]
    assert json.loads((out / "ppo" / "state.json").read_text())["ppo_steps"] == 128
    # the joint stage: its teacher is the PPO stage's best weights, on a roadmap of another size
    joint = json.loads((out / "joint" / "config.json").read_text())["args"]
    assert joint["init"] == str(out / "ppo" / "export.pt")
    assert joint["warm_start_for"] == [f"ipp_bench/Grid20Train-v1=attention:checkpoint={out / 'ppo' / 'export.pt'},"
                                       "stall_legs=0"]

    proc = _recipe(str(path), "--out", str(out))  # everything done: every stage skipped, the result rewritten
    stdout, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0 and stdout.count("done, skipped") == 3
