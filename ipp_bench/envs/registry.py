"""Benchmark tasks: one TOML file per task in ``tasks/``, registered with gymnasium.

A task file holds its id (``ipp_bench/<Name>-v<N>``), entry point, tags and the sections of an
:class:`~ipp_bench.core.config.IPPConfig`. The entry point names a class of this package
(``ipp_bench.<module>:<Class>``); nothing else is ever imported, and the class only when an env is
made, after the whole file was checked. The MuJoCo tasks are such files too: their class lives in
:mod:`ipp_bench.sim`, a layer above this one, named by the task file (data), never by this module.
A file with a ``[team]`` table is a team task (a PettingZoo env, :func:`make_env`). Registration is
idempotent; ``tagged("benchmark")`` is the set the leaderboard runs (dm_control's habit of deriving
benchmark sets from tags).
"""

from __future__ import annotations

import json
import re
import stat
import sys
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
from gymnasium.envs.registration import load_env_creator

from ..core.config import IPPConfig, quoted
from ..core.data import data_dir
from ..core.team import TeamConfig

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

NAMESPACE = "ipp_bench"


@dataclass(frozen=True)
class TaskSpec:
    """A benchmark task as read from its file.

    Attributes:
        builtin: one of the suite's ``tasks/`` files (False: a user's file, :func:`load_task`).
        sim: the file's ``[sim]`` table (the MuJoCo deployment's settings), as read.
        team: the file's ``[team]`` table (a team task's UAVs, :class:`~ipp_bench.core.team.TeamConfig`),
            validated; empty for a single-UAV task.
    """

    id: str
    entry_point: str
    tags: tuple[str, ...]
    description: str
    config: IPPConfig
    source: str
    builtin: bool = True
    sim: dict[str, Any] = field(default_factory=dict)
    team: dict[str, Any] = field(default_factory=dict)

    @property
    def is_team(self) -> bool:
        """Whether the task flies a team (its file has a ``[team]`` table)."""
        return bool(self.team)


class TaskFileError(ValueError):
    """A task file that cannot be read: ``"FILE:LINE: what is wrong"`` (the line where known)."""

    def __init__(self, path, what: str, line: int | None = None):
        where = f"{path}:{line}" if line else f"{path}"
        super().__init__(f"{where}: {what}")
        self.path, self.line, self.what = str(path), line, what


class TaskFileWarning(UserWarning):
    """A task file of the suite's ``tasks/`` folder was skipped (the others are registered)."""


#: the keys a task file may have at its top level
TASK_FILE_KEYS = ("id", "entry_point", "tags", "description", "config", "sim", "team")
_ID = re.compile(rf"^{NAMESPACE}/[A-Za-z][A-Za-z0-9_]*-v[0-9]+$")


def _line_of(text: str, key: str) -> int | None:
    """The first line (1-based) that sets ``key`` (``key = ...``) or opens the table ``[key]``."""
    name = re.escape(key.rsplit(".", 1)[-1])
    pattern = re.compile(rf"^\s*(?:{name}\s*=|\[[^\]]*\b{name}\])")
    for i, line in enumerate(text.splitlines(), start=1):
        if pattern.match(line):
            return i
    return None


def load_task_file(path, builtin: bool = False) -> TaskSpec:
    """Read and validate one task file (the checks of ``--env`` on its config, and the size limits).

    Raises:
        TaskFileError: naming the file, the line where known, and what is wrong.
    """
    from ..core.limits import check_sizes

    path = _task_path(path, "load_task_file(path)")
    raw = _read_regular_file(path)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise TaskFileError(path, f"is not a UTF-8 text file (byte {err.start} is {raw[err.start]:#04x}); "
                                  "a task file is TOML") from None
    try:
        data = tomllib.loads(text)
    except RecursionError:
        raise TaskFileError(path, f"nests its tables or arrays too deeply to read (a task file nests at most "
                                  f"{MAX_TASK_FILE_DEPTH} deep)") from None
    except tomllib.TOMLDecodeError as err:
        m = re.search(r"\(at line (\d+), column \d+\)", str(err))
        what = re.sub(r"\s*\(at (line \d+, column \d+|end of document)\)", "", str(err)).strip()
        line = int(m.group(1)) if m else (max(text.count("\n"), 1) if "end of document" in str(err) else None)
        raise TaskFileError(path, f"TOML syntax error: {what}", line) from None
    deep = _too_deep(data, MAX_TASK_FILE_DEPTH)
    if deep is not None:
        raise TaskFileError(path, f"{deep} nests more than {MAX_TASK_FILE_DEPTH} tables or arrays deep: a task "
                                  "file holds [config.*] tables of numbers, strings and short lists",
                            _line_of(text, deep))
    unknown = sorted(set(data) - set(TASK_FILE_KEYS))
    if unknown:
        raise TaskFileError(path, f"unknown key {unknown[0]!r}: valid top-level keys are {list(TASK_FILE_KEYS)}",
                            _line_of(text, unknown[0]))
    missing = [k for k in ("id", "entry_point", "config") if k not in data]
    if missing:
        raise TaskFileError(path, f"lacks {missing} (a task file needs id, entry_point and [config.*] tables)")
    task_id = data["id"]
    if not isinstance(task_id, str) or not _ID.match(task_id):
        raise TaskFileError(path, f"id = {task_id!r} is invalid: expected a string '{NAMESPACE}/<Name>-v<N>', "
                                  f"e.g. '{NAMESPACE}/MyGrid-v0'", _line_of(text, "id"))
    entry = data["entry_point"]
    problem = entry_point_problem(entry)
    if problem is not None:
        raise TaskFileError(path, problem, _line_of(text, "entry_point"))
    tags = data.get("tags", [])
    if not isinstance(tags, list) or not all(isinstance(t, str) for t in tags):
        raise TaskFileError(path, f"tags = {tags!r} is invalid: expected a list of strings",
                            _line_of(text, "tags"))
    description = data.get("description", "")
    if not isinstance(description, str):
        raise TaskFileError(path, f"description = {description!r} is invalid: expected a string",
                            _line_of(text, "description"))
    sim = data.get("sim", {})
    if not isinstance(sim, dict):
        raise TaskFileError(path, f"sim = {sim!r} is invalid: expected a [sim] table", _line_of(text, "sim"))
    if not isinstance(data["config"], dict):
        raise TaskFileError(path, "config is invalid: expected [config.grid], [config.mission], ... tables",
                            _line_of(text, "config"))
    try:
        config = IPPConfig.from_dict(data["config"])
        check_sizes(config)
    except ValueError as err:
        m = re.match(r"(\w+)\.(\w+) = ", str(err)) or re.search(r"unknown fields \['(\w+)'", str(err))
        line = _line_of(text, m.group(m.lastindex)) if m else None
        raise TaskFileError(path, str(err), line) from None
    team = data.get("team", {})
    if "team" in data:  # a team task: its [team] table says so (its class is checked when it is made)
        if not isinstance(team, dict) or not team:
            raise TaskFileError(path, "team is invalid: expected a [team] table with at least size = N",
                                _line_of(text, "team"))
        try:
            TeamConfig.from_dict(team).check(config)
        except ValueError as err:
            raise TaskFileError(path, str(err), _line_of(text, "team")) from None
    return TaskSpec(task_id, entry, tuple(tags), description.strip(), config, str(path), builtin, dict(sim),
                    dict(team))


#: what ``gym.make_vec`` of a MuJoCo task passes to its vector env (the spec's ``vector_kwargs``)
VECTOR_KWARGS = {"context": "forkserver"}
_ENTRY_POINT = re.compile(r"^ipp_bench(\.[A-Za-z_][A-Za-z0-9_]*)+:[A-Za-z_][A-Za-z0-9_]*$")


def entry_point_problem(entry: Any) -> str | None:
    """Why ``entry`` cannot be a task's entry point, or None. Only a class of this package
    (``ipp_bench.<module>:<Class>``) is allowed: a task file is data, and importing a module it
    names runs that module's code (any installed module, before anything else is checked)."""
    if isinstance(entry, str) and _ENTRY_POINT.match(entry):
        return None
    classes = sorted({spec.entry_point for spec in globals().get("TASKS", {}).values() if spec.builtin})
    return (f"entry_point = {quoted(entry)} is invalid: expected a class of this package, "
            f"'ipp_bench.<module>:<Class>', one of {classes} (a task file imports nothing else)")


#: [bytes] the largest task file read (the suite's are about 2 KB)
MAX_TASK_FILE_BYTES = 1 << 20
#: tables and arrays a task file may nest (``config`` > ``sim`` > a sub-table > a list of lists: 4)
MAX_TASK_FILE_DEPTH = 6


def _task_path(path, what: str) -> Path:
    """``path`` as a Path, or a ValueError naming ``what`` (the argument) and what it takes."""
    if isinstance(path, bytes):
        path = path.decode(errors="replace")
    if not isinstance(path, (str, Path)) or not str(path).strip():
        raise ValueError(f"{what} = {quoted(path)} is invalid: expected the path of a task file "
                         "(e.g. 'path/to/mine.toml')")
    return Path(path)


def _read_regular_file(path: Path) -> bytes:
    """The bytes of the regular file ``path`` (at most :data:`MAX_TASK_FILE_BYTES`); a FIFO, a device or
    a folder is refused before it is opened (reading a FIFO would wait for a writer for ever)."""
    try:
        st = path.stat()
    except OSError as err:
        raise TaskFileError(path, f"cannot be read ({err.strerror or err})") from None
    if not stat.S_ISREG(st.st_mode):
        kind = ("a folder" if stat.S_ISDIR(st.st_mode) else "a FIFO (named pipe)" if stat.S_ISFIFO(st.st_mode)
                else "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode)
                else "a socket" if stat.S_ISSOCK(st.st_mode) else "not a regular file")
        raise TaskFileError(path, f"cannot be read: it is {kind}, not a regular file (a task file is a .toml file)")
    if st.st_size > MAX_TASK_FILE_BYTES:
        raise TaskFileError(path, f"is {st.st_size} bytes: a task file has at most {MAX_TASK_FILE_BYTES} bytes "
                                  "(the suite's have about 2 KB)")
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_TASK_FILE_BYTES + 1)  # a file that grows while it is read is cut here
    except OSError as err:
        raise TaskFileError(path, f"cannot be read ({err.strerror or err})") from None
    if len(raw) > MAX_TASK_FILE_BYTES:
        raise TaskFileError(path, f"has more than {MAX_TASK_FILE_BYTES} bytes: a task file has at most that many")
    return raw


def _too_deep(value: Any, limit: int, where: str = "") -> str | None:
    """The key path of the first value of ``value`` nested more than ``limit`` tables or arrays deep, or None."""
    if not isinstance(value, (dict, list)):
        return None
    if limit < 0:
        return where or "the file"
    items = value.items() if isinstance(value, dict) else enumerate(value)
    for key, item in items:
        name = where if isinstance(value, list) else f"{where}.{key}" if where else str(key)  # keys, not indices
        found = _too_deep(item, limit - 1, name)
        if found is not None:
            return found
    return None


def discover(folder, builtin: bool = False) -> tuple[dict[str, TaskSpec], list[str]]:
    """The valid task files of ``folder`` by id, and one ``"FILE:LINE: what"`` per invalid one
    (each also a :class:`TaskFileWarning`, pointing at the file's line); a bad file never stops
    the others."""
    specs: dict[str, TaskSpec] = {}
    errors: list[str] = []
    for path in sorted(Path(folder).glob("*.toml")):
        try:
            spec = load_task_file(path, builtin)
            if spec.id in specs:
                raise TaskFileError(path, f"id {spec.id!r} is already defined by {specs[spec.id].source}",
                                    _line_of(path.read_text(), "id"))
        except TaskFileError as err:
            errors.append(str(err))
            warnings.warn_explicit(f"{err.what}; this task file is skipped (the other tasks work)",
                                   TaskFileWarning, filename=err.path, lineno=err.line or 0)
            continue
        specs[spec.id] = spec
    return specs, errors


#: the suite's tasks by id, and its task files that could not be read ("FILE:LINE: what", skipped)
TASKS, TASK_FILE_ERRORS = discover(data_dir("tasks"), builtin=True)
_load = load_task_file  # the name older callers import


def load_task(path) -> str:
    """Load a task file from anywhere, register it with gymnasium and return its id.

    The file has the layout of the suite's ``tasks/*.toml`` and the same checks. Loading the same
    file again is a no-op; another file with the id of a registered task is refused.

    Raises:
        TaskFileError: the file cannot be read or is invalid (file, line, what).
    """
    spec = load_task_file(_task_path(path, "load_task(path)"))
    held = TASKS.get(spec.id)
    if held is not None:
        if Path(held.source).resolve() == Path(spec.source).resolve():
            return spec.id
        raise TaskFileError(path, f"id {spec.id!r} is already registered (from {held.source}): give your task "
                                  "another name", _line_of(Path(path).read_text(), "id"))
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
    gym.register(id=spec.id, entry_point=f"{__name__}:make_task_env", kwargs=kwargs,
                 disable_env_checker=True, order_enforce=False)


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
    return env.unwrapped  # the tasks are registered without gymnasium's checker and wrappers


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
    line = _line_of(Path(source).read_text(), "id") if Path(source).is_file() else None
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


def sim_fields(spec: TaskSpec) -> set[str]:
    """The field names of a task's ``[sim]`` table (its own keys and its sub-tables' keys): the
    simulation settings ``--env`` may override; the env validates their values."""
    names: set[str] = set()
    for key, value in spec.sim.items():
        names.update(value) if isinstance(value, dict) else names.add(key)
    return names


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
