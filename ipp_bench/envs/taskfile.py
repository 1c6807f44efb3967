"""Benchmark tasks as data: one TOML file per task in ``tasks/``, read and checked.

A task file holds its id (``ipp_bench/<Name>-v<N>``), entry point, tags and the sections of an
:class:`~ipp_bench.core.config.IPPConfig`; a ``[sim]`` table (a MuJoCo deployment's settings) and a
``[team]`` table (a team task's UAVs) where the task has them. The entry point names a class of this
package (``ipp_bench.<module>:<Class>``) as a string: this module imports nothing a file names, and
the MuJoCo tasks' classes live in :mod:`ipp_bench.sim`, a layer above, named by their files (data),
never by this module. A broken file is reported, naming its line, and skipped: the others load.
Registration with gymnasium and making the envs are :mod:`ipp_bench.envs.registry`.
"""

from __future__ import annotations

import re
import stat
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

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
        builtin: one of the suite's ``tasks/`` files (False: a user's file, :func:`~ipp_bench.envs.registry.load_task`).
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


def line_of(text: str, key: str) -> int | None:
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

    path = task_path(path, "load_task_file(path)")
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
                            line_of(text, deep))
    unknown = sorted(set(data) - set(TASK_FILE_KEYS))
    if unknown:
        raise TaskFileError(path, f"unknown key {unknown[0]!r}: valid top-level keys are {list(TASK_FILE_KEYS)}",
                            line_of(text, unknown[0]))
    missing = [k for k in ("id", "entry_point", "config") if k not in data]
    if missing:
        raise TaskFileError(path, f"lacks {missing} (a task file needs id, entry_point and [config.*] tables)")
    task_id = data["id"]
    if not isinstance(task_id, str) or not _ID.match(task_id):
        raise TaskFileError(path, f"id = {task_id!r} is invalid: expected a string '{NAMESPACE}/<Name>-v<N>', "
                                  f"e.g. '{NAMESPACE}/MyGrid-v0'", line_of(text, "id"))
    entry = data["entry_point"]
    problem = entry_point_problem(entry)
    if problem is not None:
        raise TaskFileError(path, problem, line_of(text, "entry_point"))
    tags = data.get("tags", [])
    if not isinstance(tags, list) or not all(isinstance(t, str) for t in tags):
        raise TaskFileError(path, f"tags = {tags!r} is invalid: expected a list of strings",
                            line_of(text, "tags"))
    description = data.get("description", "")
    if not isinstance(description, str):
        raise TaskFileError(path, f"description = {description!r} is invalid: expected a string",
                            line_of(text, "description"))
    sim = data.get("sim", {})
    if not isinstance(sim, dict):
        raise TaskFileError(path, f"sim = {sim!r} is invalid: expected a [sim] table", line_of(text, "sim"))
    if not isinstance(data["config"], dict):
        raise TaskFileError(path, "config is invalid: expected [config.grid], [config.mission], ... tables",
                            line_of(text, "config"))
    try:
        config = IPPConfig.from_dict(data["config"])
        check_sizes(config)
    except ValueError as err:
        m = re.match(r"(\w+)\.(\w+) = ", str(err)) or re.search(r"unknown fields \['(\w+)'", str(err))
        line = line_of(text, m.group(m.lastindex)) if m else None
        raise TaskFileError(path, str(err), line) from None
    team = data.get("team", {})
    if "team" in data:  # a team task: its [team] table says so (its class is checked when it is made)
        if not isinstance(team, dict) or not team:
            raise TaskFileError(path, "team is invalid: expected a [team] table with at least size = N",
                                line_of(text, "team"))
        try:
            TeamConfig.from_dict(team).check(config)
        except ValueError as err:
            raise TaskFileError(path, str(err), line_of(text, "team")) from None
    return TaskSpec(task_id, entry, tuple(tags), description.strip(), config, str(path), builtin, dict(sim),
                    dict(team))


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


def task_path(path, what: str) -> Path:
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
                                    line_of(path.read_text(), "id"))
        except TaskFileError as err:
            errors.append(str(err))
            warnings.warn_explicit(f"{err.what}; this task file is skipped (the other tasks work)",
                                   TaskFileWarning, filename=err.path, lineno=err.line or 0)
            continue
        specs[spec.id] = spec
    return specs, errors


#: the suite's tasks by id, and its task files that could not be read ("FILE:LINE: what", skipped)
TASKS, TASK_FILE_ERRORS = discover(data_dir("tasks"), builtin=True)


def sim_fields(spec: TaskSpec) -> set[str]:
    """The field names of a task's ``[sim]`` table (its own keys and its sub-tables' keys): the
    simulation settings ``--env`` may override; the env validates their values."""
    names: set[str] = set()
    for key, value in spec.sim.items():
        names.update(value) if isinstance(value, dict) else names.add(key)
    return names


__all__ = ["MAX_TASK_FILE_BYTES", "MAX_TASK_FILE_DEPTH", "NAMESPACE", "TASKS", "TASK_FILE_ERRORS", "TASK_FILE_KEYS",
           "TaskFileError", "TaskFileWarning", "TaskSpec", "discover", "entry_point_problem", "line_of",
           "load_task_file", "sim_fields", "task_path"]
