"""Benchmark tasks: one TOML file per task in ``tasks/``, registered with gymnasium.

A task file holds its id (``ipp_bench/<Name>-v<N>``), entry point, tags and the sections of an
:class:`~ipp_bench.config.IPPConfig`; a deployment task also its ``[sim]`` table (read here, passed
to the env as ``sim_section``, validated by ``ipp_bench.sim``, which this module never imports).
Registration is idempotent; ``tagged("benchmark")`` is the set the leaderboard runs (dm_control's
habit of deriving benchmark sets from tags).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
from gymnasium.envs.registration import load_env_creator

from ..config import IPPConfig
from ..data import data_dir

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

NAMESPACE = "ipp_bench"


@dataclass(frozen=True)
class TaskSpec:
    """A benchmark task as read from its file."""

    id: str
    entry_point: str
    tags: tuple[str, ...]
    description: str
    config: IPPConfig
    source: str
    #: the task's ``[sim]`` table as read (deployment tasks; the sim package validates it)
    sim: dict | None = None


def _load(path) -> TaskSpec:
    with open(path, "rb") as fh:
        data = tomllib.load(fh)
    missing = {"id", "entry_point", "config"} - set(data)
    if missing:
        raise ValueError(f"task file {path} lacks {sorted(missing)}")
    if not data["id"].startswith(NAMESPACE + "/"):
        raise ValueError(f"task file {path}: id {data['id']!r} must start with '{NAMESPACE}/'")
    try:
        config = IPPConfig.from_dict(data["config"])
    except ValueError as err:
        raise ValueError(f"task file {path}: {err}") from None
    sim = data.get("sim")
    if sim is not None and not isinstance(sim, dict):
        raise ValueError(f"task file {path}: [sim] must be a table, got {sim!r}")
    return TaskSpec(data["id"], data["entry_point"], tuple(data.get("tags", ())),
                    data.get("description", "").strip(), config, str(path), sim)


def _discover() -> dict[str, TaskSpec]:
    specs = {}
    for path in sorted(data_dir("tasks").glob("*.toml")):
        spec = _load(path)
        if spec.id in specs:
            raise ValueError(f"task id {spec.id} is defined twice: {specs[spec.id].source} and {path}")
        specs[spec.id] = spec
    return specs


TASKS: dict[str, TaskSpec] = _discover()


def make_task_env(*, env_class: str, render_mode: str | None = None, **kwargs):
    """gym.make's entry point of every task: builds ``env_class`` ("module:Class").

    It refuses a render mode the class does not have, naming the ones it has. (Given the class
    itself, gymnasium would wrap an ``rgb_array`` env asked for ``"human"`` in its HumanRendering
    window, which asks for pygame instead.)
    """
    cls = load_env_creator(env_class)
    modes = list(cls.metadata.get("render_modes", []))
    if render_mode is not None and render_mode not in modes:
        raise ValueError(f"render_mode={render_mode!r} is invalid: valid are {modes} or None "
                         "(there is no window: render 'rgb_array' frames and show or save them)")
    return cls(render_mode=render_mode, **kwargs)


def register_all() -> None:
    """Register every task with gymnasium (idempotent)."""
    for spec in TASKS.values():
        if spec.id in gym.registry:
            continue
        kwargs = {"env_class": spec.entry_point, "config": spec.config, "task_id": spec.id}
        if spec.sim is not None:
            kwargs["sim_section"] = spec.sim
        gym.register(id=spec.id, entry_point=f"{__name__}:make_task_env",
                     kwargs=kwargs,
                     disable_env_checker=True, order_enforce=False)


def tagged(tag: str) -> list[str]:
    """Ids of the tasks that carry ``tag`` (``"train"``, ``"benchmark"``, ``"deployment"``)."""
    return [t.id for t in TASKS.values() if tag in t.tags]


def task_spec(task_id: str) -> TaskSpec:
    """The task ``task_id`` (``"Grid15Eval-v0"`` stands for ``"ipp_bench/Grid15Eval-v0"``)."""
    try:
        return TASKS[resolve_task(task_id)]
    except KeyError:
        raise ValueError(f"unknown task {task_id!r}: valid are {sorted(TASKS)}") from None


def resolve_task(name: str) -> str:
    """The full task id of ``name``: the namespace prefix is optional. Does not check it exists."""
    name = name.strip()
    return name if "/" in name else f"{NAMESPACE}/{name}"


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
    if not overrides:
        return config
    sim = sim_fields(spec)
    try:
        return config.replace(**{k: v for k, v in overrides.items() if k not in sim})
    except ValueError as err:
        if sim and str(err).startswith("unknown config field"):
            raise ValueError(f"{err}; or a [sim] field of {spec.id}: {sorted(sim)}") from None
        raise


def sim_fields(spec: TaskSpec) -> set[str]:
    """The field names of a task's ``[sim]`` table (its own keys and its sub-tables' keys): the
    simulation settings ``--env`` may override; the env validates their values."""
    names: set[str] = set()
    for key, value in (spec.sim or {}).items():
        names.update(value) if isinstance(value, dict) else names.add(key)
    return names


def parse_overrides(items: Iterable[str]) -> dict[str, Any]:
    """``["budget_s=60", "report_times=[20,40,60]"]`` -> ``{"budget_s": 60, "report_times": [20, 40, 60]}``.

    The ``--env KEY=VALUE`` options of the command line. Values are read as JSON where they parse
    (numbers, lists, true/false/null), else kept as text (which a numeric field then refuses,
    naming itself).

    Raises:
        ValueError: an item that is not ``key=value``.
    """
    out: dict[str, Any] = {}
    for item in items:
        key, eq, raw = item.partition("=")
        key = key.strip()
        if not eq or not key:
            raise ValueError(f"--env {item!r} is not KEY=VALUE (e.g. --env budget_s=100)")
        try:
            out[key] = json.loads(raw)
        except json.JSONDecodeError:
            out[key] = raw.strip()
    return out
