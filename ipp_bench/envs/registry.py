"""Benchmark tasks: one TOML file per task in ``tasks/``, registered with gymnasium.

A task file holds its id (``ipp_bench/<Name>-v<N>``), entry point, tags and the sections of an
:class:`~ipp_bench.config.IPPConfig`. Registration is idempotent; ``tagged("benchmark")`` is the
set the leaderboard runs (dm_control's habit of deriving benchmark sets from tags).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import gymnasium as gym

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
    return TaskSpec(data["id"], data["entry_point"], tuple(data.get("tags", ())),
                    data.get("description", "").strip(), config, str(path))


def _discover() -> dict[str, TaskSpec]:
    specs = {}
    for path in sorted(data_dir("tasks").glob("*.toml")):
        spec = _load(path)
        if spec.id in specs:
            raise ValueError(f"task id {spec.id} is defined twice: {specs[spec.id].source} and {path}")
        specs[spec.id] = spec
    return specs


TASKS: dict[str, TaskSpec] = _discover()


def register_all() -> None:
    """Register every task with gymnasium (idempotent)."""
    for spec in TASKS.values():
        if spec.id in gym.registry:
            continue
        gym.register(id=spec.id, entry_point=spec.entry_point,
                     kwargs={"config": spec.config, "task_id": spec.id},
                     disable_env_checker=True, order_enforce=False)


def tagged(tag: str) -> list[str]:
    """Ids of the tasks that carry ``tag`` (``"train"``, ``"benchmark"``, ``"deployment"``)."""
    return [t.id for t in TASKS.values() if tag in t.tags]


def task_spec(task_id: str) -> TaskSpec:
    try:
        return TASKS[task_id]
    except KeyError:
        raise ValueError(f"unknown task {task_id!r}: valid are {sorted(TASKS)}") from None
