"""Benchmark tasks registered with gymnasium, and the one way the package makes a task's env.

The tasks are the files of ``tasks/`` (:mod:`ipp_bench.envs.taskfile`: reading and checking them);
each is registered under its id with :func:`make_task_env` as entry point, which builds the class the
file names. A file with a ``[team]`` table is a team task: a PettingZoo env (:func:`make_env`,
:mod:`ipp_bench.envs.team`), registered only so that ``gym.make`` says so in one line. Registration
is idempotent; ``tagged("benchmark")`` is the set the leaderboard runs (dm_control's habit of
deriving benchmark sets from tags).
"""

from __future__ import annotations

import json
import multiprocessing as mp
import re
import sys
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import gymnasium as gym
from gymnasium.envs.registration import load_env_creator

from ..core.config import IPPConfig
from .taskfile import (
    NAMESPACE,
    TASK_FILE_ERRORS,
    TASKS,
    TaskFileError,
    TaskFileWarning,
    TaskSpec,
    discover,
    entry_point_problem,
    line_of,
    load_task_file,
    sim_fields,
    task_path,
)

#: what ``gym.make_vec`` of a MuJoCo task passes to its vector env (the spec's ``vector_kwargs``)
VECTOR_KWARGS = {"context": "forkserver"}
#: the line a worker process adds when the user's script, imported anew in it, starts processes of its own
BOOTSTRAP_HINT = ("ipp-bench: a vector env's worker process imports your script anew ('forkserver' or 'spawn'), and "
                  "your script starts processes at its top level: put the code that makes environments under "
                  "`if __name__ == \"__main__\":`")


def _name_the_main_guard() -> None:
    """In a worker process that is importing the user's script (multiprocessing's bootstrapping), make the
    RuntimeError of a vector env made at the script's top level end with the fix, in one line (the parent only
    sees its worker gone, a ConnectionResetError)."""
    if not getattr(mp.current_process(), "_inheriting", False):
        return
    previous = sys.excepthook

    def hook(cls, err, tb):
        previous(cls, err, tb)
        if issubclass(cls, RuntimeError) and "bootstrapping phase" in str(err):
            print(BOOTSTRAP_HINT, file=sys.stderr)

    sys.excepthook = hook


_name_the_main_guard()


def load_task(path) -> str:
    """Load a task file from anywhere, register it with gymnasium and return its id.

    The file has the layout of the suite's ``tasks/*.toml`` and the same checks. Loading the same
    file again is a no-op; another file with the id of a registered task is refused.

    Raises:
        TaskFileError: the file cannot be read or is invalid (file, line, what).
    """
    spec = load_task_file(task_path(path, "load_task(path)"))
    held = TASKS.get(spec.id)
    if held is not None:
        if Path(held.source).resolve() == Path(spec.source).resolve():
            return spec.id
        raise TaskFileError(path, f"id {spec.id!r} is already registered (from {held.source}): give your task "
                                  "another name", line_of(Path(path).read_text(), "id"))
    TASKS[spec.id] = spec
    _register(spec)
    return spec.id


def make_task_env(*, env_class: str, render_mode: str | None = None, **kwargs):
    """gym.make's entry point of every task: builds ``env_class`` ("module:Class").

    It refuses a render mode the class does not have, naming the ones it has. (Given the class
    itself, gymnasium would wrap an ``rgb_array`` env asked for ``"human"`` in its HumanRendering
    window, which asks for pygame instead.)
    """
    kwargs.pop("vector_kwargs", None)  # the spec's, for gym.make_vec only (_register)
    spec = TASKS.get(kwargs.get("task_id", ""))
    if spec is not None and spec.is_team:  # registered so that gym.make says what it is, in one line
        task = spec.id
        raise ValueError(f"{task} is a team task: a PettingZoo AEC environment, not a gymnasium one; make it with "
                         f"ipp_bench.envs.make_env({task!r})")
    problem = entry_point_problem(env_class)
    if problem is not None:  # never import what a task file names unless it is the suite's
        raise ValueError(problem)
    cls = _env_class(env_class, spec)
    if _is_team_class(cls):
        raise ValueError(f"{kwargs.get('task_id', env_class)}: entry_point = {env_class!r} is a team environment: "
                         "a team task needs a [team] table (size, starts)")
    modes = list(cls.metadata.get("render_modes", []))
    if render_mode is not None and render_mode not in modes:
        raise ValueError(f"render_mode={render_mode!r} is invalid: valid are {modes} or None "
                         "(there is no window: render 'rgb_array' frames and show or save them)")
    return cls(render_mode=render_mode, **kwargs)


def _is_team_class(cls: type) -> bool:
    """Whether ``cls`` is a team's environment (PettingZoo's AEC API: it names its agents)."""
    return hasattr(cls, "possible_agents") or getattr(cls, "metadata", {}).get("name", "").startswith("ipp_bench_team")


def _env_class(env_class: str, spec: TaskSpec | None) -> type:
    """The class a task file names, imported (a missing extra named in the error)."""
    try:
        return load_env_creator(env_class)
    except ImportError as err:
        extra = "sim" if spec is not None and "deployment" in spec.tags else None  # the MuJoCo tasks
        hint = f'pip install "ipp-bench[{extra}]"' if extra else "install the package that provides it"
        if "pip install" in str(err):  # the import's own message already names what to install
            raise ImportError(f"the environment {env_class} cannot be imported: {err}") from None
        raise ImportError(f"the environment {env_class} cannot be imported ({err}): {hint}") from None


def register_all() -> None:
    """Register every task with gymnasium (idempotent)."""
    for spec in TASKS.values():
        _register(spec)


def _register(spec: TaskSpec) -> None:
    if spec.id in gym.registry:
        return
    kwargs = {"env_class": spec.entry_point, "config": spec.config, "task_id": spec.id}
    if spec.sim:  # a deployment task's [sim] table, validated by ipp_bench.sim (never imported here)
        kwargs["sim_section"] = spec.sim
    if "deployment" in spec.tags:
        # gym.make_vec(..., vectorization_mode="async") starts its workers with forkserver: a worker
        # forked from a process that has rendered would hang on its first frame (Mesa's GL threads do
        # not survive fork). gymnasium reads these vector_kwargs from the spec; gym.make drops them.
        kwargs["vector_kwargs"] = dict(VECTOR_KWARGS)
    # gymnasium's defaults: gym.make wraps the env in OrderEnforcing (no step or render before reset)
    # and the PassiveEnvChecker (the spaces at make, the first reset's and step's results). Its checks
    # run once per env, not per step; the suite's spaces pass them without a warning (tests/envs).
    gym.register(id=spec.id, entry_point=f"{__name__}:make_task_env", kwargs=kwargs)


def tagged(tag: str) -> list[str]:
    """Ids of the tasks that carry ``tag`` (``"train"``, ``"benchmark"``, ``"deployment"``)."""
    return [t.id for t in TASKS.values() if tag in t.tags]


def task_spec(task_id: str) -> TaskSpec:
    """The task ``task_id`` (``"Grid15Eval-v0"`` stands for ``"ipp_bench/Grid15Eval-v0"``)."""
    if str(task_id).endswith(".toml"):  # a user's task file
        return TASKS[load_task(task_id)]
    try:
        return TASKS[_full_id(task_id)]
    except KeyError:
        skipped = f"; skipped task files: {'; '.join(TASK_FILE_ERRORS)}" if TASK_FILE_ERRORS else ""
        raise ValueError(f"unknown task {task_id!r}: valid are {sorted(TASKS)} or a task file path "
                         f"(path/to/mine.toml){skipped}") from None


def _full_id(name: str) -> str:
    """``"Grid15Eval-v1"`` -> ``"ipp_bench/Grid15Eval-v1"`` (the namespace prefix is optional)."""
    name = str(name).strip()
    return name if "/" in name else f"{NAMESPACE}/{name}"


def resolve_task(name: str) -> str:
    """The registered task id that ``name`` stands for: an id, an id without the ``ipp_bench/``
    prefix, or a task file path (``path/to/mine.toml``, loaded and registered, :func:`load_task`).

    Raises:
        ValueError: no such task (naming the valid ones), or an invalid task file.
    """
    return task_spec(name).id


def make_env(task: str, *, render: bool = False, **overrides: Any):
    """The environment of a task: the one way the package makes one (the leaderboard, ``ipp-bench
    evaluate``, training, the demo, the dm_control view and the calibration all call it).

    It returns the bare env, not what ``gym.make`` returns: ``gym.make(task)`` wraps it in
    ``OrderEnforcing`` and ``PassiveEnvChecker`` (made here, so the checker has seen its spaces), and
    gymnasium 1.x wrappers forward no attributes, while every caller reads the env's own: ``mission``,
    ``roadmap``, ``action_masks()`` (the planners' views, the episode loop, sb3-contrib's masks),
    ``world`` (the MuJoCo tasks). The bare env enforces the order itself (``step`` before ``reset``
    raises RuntimeError) and refuses an invalid action naming the valid ones. A team task's env is
    PettingZoo's bare AEC env (:func:`ipp_bench.envs.team.raw_env`; :func:`ipp_bench.envs.team.env`
    wraps it in PettingZoo's wrappers).

    Args:
        task: a task id, an id without the ``ipp_bench/`` prefix, or a task file path
            (:func:`resolve_task`).
        render: ``render_mode="rgb_array"`` (the MuJoCo tasks' camera frames).
        **overrides: config fields by name, as ``gym.make(task, **overrides)``.

    Raises:
        ValueError: unknown task, or an override that names no field or has a bad value.
    """
    task_id = resolve_task(task)
    spec = TASKS.get(task_id)
    if spec is not None and spec.is_team:
        return make_team_env(spec, render=render, **overrides)
    with warnings.catch_warnings():  # gymnasium's own notice (in colour, once per process and task): ours instead
        warnings.filterwarnings("ignore", message=r".* is out of date\. You should consider upgrading",
                                category=DeprecationWarning)
        env = gym.make(task_id, render_mode="rgb_array" if render else None, **overrides)
    warn_if_outdated(task_id)
    return env.unwrapped


def make_team_env(spec: TaskSpec, *, render: bool = False, **overrides: Any):
    """A team task's :class:`~ipp_bench.envs.team.TeamGraphEnv` (or, deployed in MuJoCo,
    :class:`~ipp_bench.sim.team.MuJoCoTeamEnv`); ``overrides``: config fields by name, ``team={...}``
    for fields of its ``[team]`` table, and a MuJoCo team's ``[sim]`` fields by name."""
    team = dict(spec.team)
    overrides = dict(overrides)
    extra = overrides.pop("team", None)
    if extra is not None:
        if not isinstance(extra, dict):
            raise ValueError(f"team = {extra!r} is invalid: expected a dict of [team] fields, e.g. "
                             "team={\"size\": 4}")
        team.update(extra)
    config = task_config(spec.id, overrides)
    render_mode = "rgb_array" if render else None
    problem = entry_point_problem(spec.entry_point)
    if problem is not None:
        raise ValueError(problem)
    cls = _env_class(spec.entry_point, spec)
    if not _is_team_class(cls):
        raise ValueError(f"{spec.id}: a [team] table needs a team environment as its entry_point (e.g. "
                         f"'ipp_bench.envs.team:TeamGraphEnv'); {spec.entry_point!r} flies one UAV")
    sim = {k: v for k, v in overrides.items() if k in sim_fields(spec)}
    extra = {"sim_section": spec.sim, **sim} if spec.sim else {}
    return cls(config, team=team, render_mode=render_mode, task_id=spec.id, **extra)


def is_team_task(task: str) -> bool:
    """Whether ``task`` (an id or a task file) is a team task (several UAVs, one belief)."""
    spec = TASKS.get(resolve_task(task))
    return spec is not None and spec.is_team


class OutdatedTaskWarning(FutureWarning):
    """A task whose name has a newer version (``Grid15Eval-v0`` beside ``-v1``): said once per process
    and task, in plain text, pointing at the task file. Leaderboard workers do not repeat it."""


_WARNED_OUTDATED: set[str] = set()


def newer_version(task_id: str) -> str | None:
    """The id of the newest version of ``task_id``'s name when it is newer than ``task_id``, else None."""
    match = re.match(r"^(.*)-v(\d+)$", task_id)
    if match is None:
        return None
    name, version = match.group(1), int(match.group(2))
    newer = [(int(m.group(1)), t) for t in TASKS if (m := re.match(rf"^{re.escape(name)}-v(\d+)$", t))]
    best = max(newer, default=(version, task_id))
    return best[1] if best[0] > version else None


def warn_if_outdated(task_id: str) -> None:
    """Warn (:class:`OutdatedTaskWarning`, once per process) that a newer version of the task exists."""
    newer = newer_version(task_id)
    if newer is None or task_id in _WARNED_OUTDATED:
        return
    _WARNED_OUTDATED.add(task_id)
    spec = TASKS[task_id]
    source = spec.source
    line = line_of(Path(source).read_text(), "id") if Path(source).is_file() else None
    warnings.warn_explicit(f"{task_id} is out of date: the current version of the task is {newer}",
                           OutdatedTaskWarning, filename=source, lineno=line or 0)


def short_task_id(task_id: str) -> str:
    """``"ipp_bench/Grid15Eval-v0"`` -> ``"Grid15Eval-v0"`` (tables, file names)."""
    return task_id.removeprefix(NAMESPACE + "/")


def task_config(task_id: str, overrides: dict[str, Any] | None = None) -> IPPConfig:
    """The configuration of task ``task_id`` with ``overrides`` (fields by name) applied.

    Raises:
        ValueError: unknown task, or an override that names no field or has a bad value.
    """
    spec = task_spec(task_id)
    config = spec.config
    if overrides and spec.is_team and "team" in overrides:  # the [team] table's own
        overrides = {k: v for k, v in overrides.items() if k != "team"}
    if not overrides:
        return config
    sim = sim_fields(spec)
    try:
        return config.replace(**{k: v for k, v in overrides.items() if k not in sim})
    except ValueError as err:
        if sim and str(err).startswith("unknown config field"):
            raise ValueError(f"{err}; or a [sim] field of {spec.id}: {sorted(sim)}") from None
        raise


def parse_overrides(items: Iterable[str]) -> dict[str, Any]:
    """``["budget_s=60", "report_times=[20,40,60]"]`` -> ``{"budget_s": 60, "report_times": [20, 40, 60]}``.

    The ``--env KEY=VALUE`` options of the command line. Values are read as JSON where they parse
    (numbers, lists, true/false/null), else kept as text (which a numeric field then refuses,
    naming itself).

    Raises:
        ValueError: an item that is not ``key=value``, or a key given twice.
    """
    out: dict[str, Any] = {}
    given: dict[str, str] = {}
    for item in items:
        key, eq, raw = item.partition("=")
        key = key.strip()
        if not eq or not key:
            raise ValueError(f"--env {item!r} is not KEY=VALUE (e.g. --env budget_s=100)")
        if key in given:  # which of the two was meant is not ours to guess
            raise ValueError(f"--env {key} is given twice ({key}={given[key].strip()} and {key}={raw.strip()}): "
                             "give each setting once")
        given[key] = raw
        try:
            out[key] = json.loads(raw)
        except json.JSONDecodeError:
            out[key] = raw.strip()
    return out


__all__ = ["NAMESPACE", "TASKS", "TASK_FILE_ERRORS", "VECTOR_KWARGS", "OutdatedTaskWarning", "TaskFileError",
           "TaskFileWarning", "TaskSpec", "discover", "is_team_task", "load_task", "load_task_file", "make_env",
           "make_task_env", "make_team_env", "newer_version", "parse_overrides", "register_all", "resolve_task",
           "short_task_id", "tagged", "task_config", "task_spec", "warn_if_outdated"]
