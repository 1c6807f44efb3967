"""Recipes: a checkpoint's whole training as data, run by ``ipp-bench train --recipe NAME --out DIR``.

A recipe (``recipes/<name>.toml`` in this package, or any ``.toml`` path) is a list of stages, each
one ``ipp-bench train`` run (rl-baselines3-zoo's habit: a published agent is rebuilt by naming it)::

    name = "mine"
    [settings]                      # every stage's settings (TrainArgs names) unless it sets its own
    seed = 0
    [[stage]]
    name = "warm"                   # its run folder: DIR/warm/
    kind = "warm_start"             # warm_start (DAgger, no PPO) or ppo
    tasks = ["ipp_bench/Grid15Train-v1"]
    teacher = "greedy"              # warm_start: the teacher of every task ...
    teachers = {"ipp_bench/Hotspots15Train-v2" = "attention:checkpoint={init},stall_legs=0"}  # ... or of one
    bc_episodes = 80
    [[stage]]
    name = "ppo"
    kind = "ppo"
    from = "warm"                   # starts from that stage's handed-on weights ...
    hand_on = "best"                # ... which are: bc (warm_start), last or best (ppo; best validated)
    tasks = ["ipp_bench/Grid15Train-v1"]
    total_steps = 200000

``{init}`` in a teacher stands for the weights the stage starts from. The runner skips finished
stages, resumes an interrupted one (``--resume`` of its run folder) and ends by writing
``DIR/attention.pt`` (the last stage's handed-on weights, its meta listing every stage's command).
A bad recipe is refused before any stage runs, with one line naming the key. ``--seed N`` runs every
stage with seed N instead of the recipe's (one training seed of the method the recipe is; a method is
judged over several, as rl-baselines3-zoo and rliable do).
"""

from __future__ import annotations

import argparse
import re
import shlex
import signal
import sys
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

from ipp_bench.train.args import NOT_IN_COMMAND, TrainArgs, check_args, command_line, explicit

RECIPE_DIR = Path(__file__).parent / "recipes"
KINDS = ("warm_start", "ppo")
HANDED_ON = {"bc": "warmstart/bc.pt", "last": "last.pt", "best": "export.pt"}
_KIND_HANDS_ON = {"warm_start": ("bc",), "ppo": ("last", "best")}
# TrainArgs fields a stage may not set: the tasks, teachers and start have their own keys, and where
# a run goes is the command's (ipp-bench train --recipe ... --device/--threads/--vec-env/--no-progress)
_NOT_IN_STAGE = {"task", "mix", "warm_start", "warm_start_for", "init", "total_steps", "progress",
                 *NOT_IN_COMMAND}
_SETTING_TYPES = {f.name: str(f.type) for f in fields(TrainArgs) if f.name not in _NOT_IN_STAGE}
_STAGE_KEYS = {"name": "str", "kind": "str", "what": "str", "from": "str", "hand_on": "str",
               "tasks": "list[str]", "teacher": "str", "teachers": "dict", "total_steps": "int"}
# the command-line options that may go with --recipe (all others are the recipe's)
_WITH_RECIPE = {"out", "device", "threads", "vec_env", "progress", "init", "seed"}


class RecipeError(ValueError):
    """A recipe that cannot be run (one line naming the recipe and the key)."""


@dataclass(frozen=True)
class Stage:
    """One stage: an ``ipp-bench train`` run in ``DIR/<name>/``."""

    name: str
    kind: str
    tasks: tuple[str, ...]
    settings: dict[str, Any]  # TrainArgs fields: the recipe's [settings], then the stage's own
    what: str = ""
    start: str = ""  # the earlier stage whose weights it starts from ('' = a fresh network)
    hand_on: str = "bc"
    teacher: str = "greedy"
    teachers: dict[str, str] = field(default_factory=dict)
    total_steps: int = 0

    def args(self, out: Path, init: str = "") -> TrainArgs:
        """The stage's run with ``init`` as its starting weights (``{init}`` in a teacher becomes it)."""
        ppo = self.kind == "ppo"
        return TrainArgs(**self.settings, task=self.tasks[0], mix=list(self.tasks[1:]), init=init,
                         total_steps=self.total_steps if ppo else 0, out=str(out / self.name),
                         warm_start="none" if ppo else self.teacher,
                         warm_start_for=[f"{t}={p.replace('{init}', init)}" for t, p in self.teachers.items()])

    def handed_on(self, out: Path) -> Path:
        return out / self.name / HANDED_ON[self.hand_on]


@dataclass(frozen=True)
class Recipe:
    name: str
    source: Path
    stages: tuple[Stage, ...]
    description: str = ""

    def stage(self, name: str) -> Stage:
        for s in self.stages:
            if s.name == name:
                return s
        raise RecipeError(f"--from-stage {name!r}: recipe {self.name} has no such stage; its stages: "
                          f"{', '.join(s.name for s in self.stages)}")


def known_recipes() -> list[str]:
    return sorted(p.stem for p in RECIPE_DIR.glob("*.toml"))


def load_recipe(name: str) -> Recipe:
    """A shipped recipe by name, or a recipe file (``.toml``) by path, checked (:class:`RecipeError`)."""
    path = Path(name) if name.endswith(".toml") else RECIPE_DIR / f"{name}.toml"
    if not path.is_file():
        if name.endswith(".toml"):
            raise RecipeError(f"--recipe {name}: no such file")
        raise RecipeError(f"--recipe {name!r} is unknown: the shipped recipes are {', '.join(known_recipes())} "
                          "(or give a .toml file)")
    try:
        data = tomllib.loads(path.read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
        raise RecipeError(f"recipe {path}: not readable TOML ({' '.join(str(err).split())})") from None
    return parse_recipe(data, path)


def _check_type(where: str, key: str, value: Any, kind: str) -> Any:
    ok = {"str": isinstance(value, str), "bool": isinstance(value, bool),
          "int": isinstance(value, int) and not isinstance(value, bool),
          "float": isinstance(value, (int, float)) and not isinstance(value, bool),
          "list[str]": isinstance(value, list) and all(isinstance(v, str) for v in value),
          "dict": isinstance(value, dict) and all(isinstance(v, str) for v in value.values())}[kind]
    if not ok:
        want = {"str": "a string", "bool": "true or false", "int": "an integer", "float": "a number",
                "list[str]": "a list of strings", "dict": "a table of strings"}[kind]
        raise RecipeError(f"{where}: {key} = {value!r} is invalid: expected {want}")
    return float(value) if kind == "float" else value


def _settings(where: str, table: dict[str, Any]) -> dict[str, Any]:
    return {k: _check_type(where, k, v, _SETTING_TYPES[k]) for k, v in table.items()}


def parse_recipe(data: dict[str, Any], path: Path) -> Recipe:
    """Check a recipe's TOML data: every key known, of its type, the stages in a runnable order."""
    where = f"recipe {path}"
    unknown = set(data) - {"name", "description", "settings", "stage"}
    if unknown:
        raise RecipeError(f"{where}: unknown key {min(unknown)!r}; expected name, description, settings, "
                          "[[stage]]")
    name = _check_type(where, "name", data.get("name", path.stem), "str")
    description = _check_type(where, "description", data.get("description", ""), "str")
    common = data.get("settings", {})
    if not isinstance(common, dict):
        raise RecipeError(f"{where}: settings must be a table of ipp-bench train settings")
    bad = sorted(set(common) - set(_SETTING_TYPES))
    if bad:
        raise RecipeError(f"{where}: [settings] has the unknown key {bad[0]!r}; expected one of "
                          f"{', '.join(sorted(_SETTING_TYPES))}")
    common = _settings(f"{where} [settings]", common)
    raw = data.get("stage", [])
    if not isinstance(raw, list) or not raw or not all(isinstance(s, dict) for s in raw):
        raise RecipeError(f"{where}: no [[stage]] tables; a recipe has at least one stage")
    stages: list[Stage] = []
    for i, table in enumerate(raw):
        stages.append(_parse_stage(f"{where} stage {i + 1}", table, common, [s.name for s in stages]))
    recipe = Recipe(name=name, source=path, stages=tuple(stages), description=description)
    for stage in recipe.stages:  # every setting in range, every task known (files are checked as it runs)
        cfg = stage.args(Path("out"), init="{init}" if stage.start else "")
        try:
            check_args(cfg, deep=False)
        except ValueError as err:
            raise RecipeError(f"{where} stage {stage.name!r}: {err}") from None
    return recipe


def _parse_stage(where: str, table: dict[str, Any], common: dict[str, Any], earlier: list[str]) -> Stage:
    for key in table:
        if key not in _STAGE_KEYS and key not in _SETTING_TYPES:
            raise RecipeError(f"{where}: unknown key {key!r}; expected {', '.join(_STAGE_KEYS)} or an ipp-bench "
                              "train setting")
    own = {k: _check_type(where, k, v, _STAGE_KEYS[k]) for k, v in table.items() if k in _STAGE_KEYS}
    for key in ("name", "kind", "tasks"):
        if key not in own:
            raise RecipeError(f"{where}: {key} is missing")
    name, kind = own["name"], own["kind"]
    where = f"{where} ({name!r})"
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", name) or name in earlier:
        raise RecipeError(f"{where}: name {name!r} is invalid: expected letters, digits, '_', '-', '.', "
                          "unique in the recipe (it names the stage's run folder)")
    if kind not in KINDS:
        raise RecipeError(f"{where}: kind {kind!r} is invalid: expected one of {', '.join(KINDS)}")
    if not own["tasks"]:
        raise RecipeError(f"{where}: tasks is empty: expected at least one training task")
    start = own.get("from", "")
    if start and start not in earlier:
        raise RecipeError(f"{where}: from {start!r} is not an earlier stage (earlier: {', '.join(earlier) or 'none'})")
    hand_on = own.get("hand_on", _KIND_HANDS_ON[kind][0])
    if hand_on not in _KIND_HANDS_ON[kind]:
        raise RecipeError(f"{where}: hand_on {hand_on!r} is invalid for a {kind} stage: expected one of "
                          f"{', '.join(_KIND_HANDS_ON[kind])}")
    if kind == "ppo":
        for key in ("teacher", "teachers"):
            if key in own:
                raise RecipeError(f"{where}: {key} is for a warm_start stage; a ppo stage has no teacher")
        if own.get("total_steps", 0) < 1:
            raise RecipeError(f"{where}: total_steps = {own.get('total_steps')} is invalid: a ppo stage needs an "
                              "integer >= 1")
    elif "total_steps" in own:
        raise RecipeError(f"{where}: total_steps is for a ppo stage; a warm_start stage runs no PPO")
    teachers = own.get("teachers", {})
    for task in teachers:
        if task not in own["tasks"]:
            raise RecipeError(f"{where}: teachers names {task!r}, not one of its tasks")
    if not start and any("{init}" in p for p in teachers.values()):
        raise RecipeError(f"{where}: a teacher is '{{init}}' (the starting weights) but the stage has no 'from'")
    settings = {**common, **_settings(where, {k: v for k, v in table.items() if k in _SETTING_TYPES})}
    return Stage(name=name, kind=kind, tasks=tuple(own["tasks"]), settings=settings, what=own.get("what", ""),
                 start=start, hand_on=hand_on, teacher=own.get("teacher", "greedy"), teachers=dict(teachers),
                 total_steps=own.get("total_steps", 0))


def plan(recipe: Recipe, out: Path, from_stage: str | None = None, init: str = "") -> list[tuple[Stage, TrainArgs]]:
    """The stages to run (from ``from_stage`` on, which starts from ``init``) with their settings."""
    first = recipe.stages.index(recipe.stage(from_stage)) if from_stage else 0
    by_name = {s.name: s for s in recipe.stages}
    runs = []
    for i, stage in enumerate(recipe.stages[first:], first):
        start = init if i == first and from_stage else (str(by_name[stage.start].handed_on(out)) if stage.start else "")
        runs.append((stage, stage.args(out, start)))
    return runs


def dry_run(recipe: Recipe, out: Path, from_stage: str | None, init: str, where: dict[str, Any]) -> str:
    lines = [f"recipe {recipe.name} ({recipe.source}): {len(recipe.stages)} stages into {out}/"]
    for stage, cfg in plan(recipe, out, from_stage, init):
        cfg = TrainArgs(**{**asdict(cfg), **where})
        kind = "warm start" if stage.kind == "warm_start" else f"PPO, {stage.total_steps} steps"
        start = f" from {cfg.init}" if cfg.init else " from a fresh network"
        lines.append(f"\n# {stage.name}: {kind}{start}; hands on {stage.handed_on(out)}"
                     + (f"\n# {stage.what}" if stage.what else ""))
        lines.append(command_line(cfg, where=True))
    lines.append(f"\n# then {out / 'attention.pt'} <- {recipe.stages[-1].handed_on(out)}")
    return "\n".join(lines)


def run_recipe_command(args: argparse.Namespace) -> int:
    """``ipp-bench train --recipe NAME [--out DIR] [--dry-run] [--from-stage S --init PT]``."""
    def error(msg: str) -> int:
        print(f"ipp-bench train: error: {msg}", file=sys.stderr)
        return 2

    given = explicit(args)
    extra = sorted(set(given) - _WITH_RECIPE) + [m for m in ("resume", "export", "validate") if getattr(args, m)]
    if extra:
        return error(f"--recipe takes its settings from the recipe: --{extra[0].replace('_', '-')} cannot go with "
                     "it (with it: --out, --seed, --dry-run, --from-stage with --init, --device, --threads, "
                     "--vec-env, --no-progress)")
    if bool(args.from_stage) != bool(given.get("init")):
        return error("--from-stage STAGE and --init PT go together: the stage to start at and its starting weights")
    try:
        recipe = load_recipe(args.recipe)
        if args.from_stage:
            recipe.stage(args.from_stage)
    except RecipeError as err:
        return error(str(err))
    out = Path(given.get("out") or "")
    # --seed: the recipe's seed in every stage (a training seed of the method); the rest: where it runs
    where = {k: given[k] for k in ("seed", "device", "threads", "vec_env", "progress") if k in given}
    if args.dry_run:
        print(dry_run(recipe, out if given.get("out") else Path("DIR"), args.from_stage, given.get("init", ""),
                      where))
        return 0
    if not given.get("out"):
        return error("--recipe needs --out DIR: the folder of its stages")
    seeded = ["--seed", str(given["seed"])] if "seed" in given else []
    again = shlex.join(["ipp-bench", "train", "--recipe", args.recipe, "--out", str(out), *seeded] + (
        ["--from-stage", args.from_stage, "--init", given["init"]] if args.from_stage else []))

    def on_term(signum, frame):  # SIGTERM between stages too: stop as Ctrl-C does
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, on_term)
    try:
        for stage, cfg in plan(recipe, out, args.from_stage, given.get("init", "")):
            code = _run_stage(stage, TrainArgs(**{**asdict(cfg), **where}), out, again)
            if code:
                return code
    except KeyboardInterrupt:
        print(f"interrupted; continue with: {again}", flush=True)
        return 130
    finally:
        signal.signal(signal.SIGTERM, old)
    final = write_result(recipe, out, args.from_stage, given.get("init", ""), given.get("seed"))
    print(f"wrote {final}")
    return 0


def _run_stage(stage: Stage, cfg: TrainArgs, out: Path, again: str) -> int:
    """Run one stage in ``out/<name>``: skipped when finished, resumed when started; the exit code."""
    from ipp_bench.train.run import execute, resolve_config

    run = out / stage.name
    if _finished(run, stage, out):
        print(f"stage {stage.name}: done, skipped ({stage.handed_on(out)})", flush=True)
        return 0
    resume = (run / "config.json").is_file()
    try:
        cfg, run = resolve_config(asdict(cfg), resume)
    except ValueError as err:
        print(f"ipp-bench train: error: stage {stage.name}: {err}", file=sys.stderr)
        return 2
    print(f"stage {stage.name}: {'resuming' if resume else 'starting'} in {run}", flush=True)
    return execute(cfg, run, again)


def _finished(run: Path, stage: Stage, out: Path) -> bool:
    from ipp_bench.train.run import RunState

    return (run / "config.json").is_file() and RunState.load(run).done and stage.handed_on(out).is_file()


def write_result(recipe: Recipe, out: Path, from_stage: str | None, init: str, seed: int | None = None) -> Path:
    """``DIR/attention.pt``: the last stage's handed-on weights, the meta listing every stage (``seed``: the
    ``--seed`` the stages ran with, where it was given)."""
    import json

    from ipp_bench.policies.checkpoint import load_checkpoint, save_checkpoint

    last = recipe.stages[-1]
    net, meta = load_checkpoint(last.handed_on(out))
    ran = {s.name: (cfg if seed is None else replace(cfg, seed=seed)) for s, cfg in plan(recipe, out, from_stage, init)}
    stages = []
    for i, stage in enumerate(recipe.stages, 1):
        cfg = ran.get(stage.name)
        row: dict[str, Any] = {"stage": i, "name": stage.name, "kind": stage.kind, "what": stage.what,
                               "hand_on": stage.hand_on, "from": stage.start}
        if cfg is None:
            row["not_run"] = f"started at stage {from_stage} from {init}"
        else:
            row["command"] = command_line(cfg)
            handed = json.loads(stage.handed_on(out).with_suffix(".json").read_text())["meta"]
            row.update({k: v for k, v in handed.items() if k.startswith("val/") or k in
                        ("ppo_steps", "ppo_wall_s", "warm_start_wall_s", "samples", "wall_s")})
        stages.append(row)
    meta = {k: v for k, v in meta.items() if k.startswith("val/") or k in ("versions", "seeds")}
    meta.update(recipe=recipe.name, command=f"ipp-bench train --recipe {recipe.name} --out {out}"
                + (f" --seed {seed}" if seed is not None else "")
                + (f" --from-stage {from_stage} --init {init}" if from_stage else ""), stages=stages,
                training_seed=ran[recipe.stages[-1].name].seed if recipe.stages[-1].name in ran else seed,
                ppo_steps_total=sum(r.get("ppo_steps", 0) or 0 for r in stages if r["kind"] == "ppo"))
    return save_checkpoint(net, out / "attention.pt", meta=meta)
