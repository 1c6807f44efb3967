"""The leaderboard: every planner on every benchmark task over the same episode seeds.

``run_leaderboard(make_plan(...), out_dir)`` runs the episodes that ``out_dir/results.csv`` does
not hold yet and then writes the report (``leaderboard.md`` and PNG plots, see
:mod:`ipp_bench.eval.report`). The folder holds:

``run.json``
    the fingerprint of the arguments that decide the numbers (tasks and their configs, planner
    specs, episode seeds, environment overrides). A rerun with other arguments is refused, naming
    what differs; the executor (backend, workers) is not part of it: results do not depend on it.
``results.csv``
    long format, one row per (task, planner, seed, report time) with :data:`COLUMNS`. An episode's
    rows are appended in one write, flushed and fsync'ed as soon as it finishes, so a killed run
    loses no finished episode. On resume a torn last line (the write a kill interrupted) and
    episodes with missing rows are dropped and run again. When every episode is in, the file is
    rewritten sorted (task, planner, seed, time), so its content does not depend on the order in
    which workers finished.

Episode seeds derive from ``seed`` alone (:func:`episode_seeds`): every planner meets the same
episodes (field, start, sensor noise), and the first ``n`` seeds stay the same when ``episodes``
grows.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import json
import os
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..envs import tagged, task_spec
from ..planners import make_config, make_planner, parse_spec, planner_names
from .executors import default_backend, make_executor
from .runner import REPORT_KEYS, run_episode

RESULTS_CSV = "results.csv"
RUN_JSON = "run.json"
LOCK_FILE = ".lock"
FORMAT_VERSION = 1
SEED_SCHEME = "SeedSequence(seed).spawn(episodes)[i] -> uint31"

KEY_COLUMNS = ("task", "planner", "seed")
TIMING_COLUMNS = ("decision_time_mean_s", "decision_time_max_s", "episode_wall_s")
COLUMNS = (*KEY_COLUMNS, "time_s", *REPORT_KEYS, "decisions", *TIMING_COLUMNS)
_INT_COLUMNS = ("seed", "decisions")
_FLOAT_COLUMNS = tuple(c for c in COLUMNS if c not in KEY_COLUMNS + _INT_COLUMNS or c == "time_s")

DEFAULT_EPISODES = 20
DEFAULT_TAG = "benchmark"
# --quick: few episodes and cheaper look-ahead (spec overrides, applied unless the spec sets the
# key itself). Sized so that all benchmark tasks x all planners fit 5 minutes on 2 busy cores:
# MCTS costs ~20 ms per simulation and ~90 decisions per 200 s episode, CMA-ES ~2.4 ms per
# evaluation and ~40 decisions (measured at load 5 on 2 cores).
QUICK_EPISODES = 3
QUICK_OVERRIDES: dict[str, dict[str, Any]] = {
    "mcts": {"simulations": 4},
    "cmaes": {"max_evals": 36},
}
# The default planner list's settings where they differ from the planner's own defaults: MCTS at
# the benchmark's operating point, about 1 s per decision on Grid30Eval-v1 on one of 2 cores (the
# paper: 3.94 s on a desktop). Its own default (100 simulations) made the v0 tables; name it
# (``--planners mcts``) to get it.
LEADERBOARD_DEFAULTS: dict[str, dict[str, Any]] = {
    "mcts": {"simulations": 24},
}
NAMESPACE = "ipp_bench/"


class ResultsMismatchError(ValueError):
    """``out_dir`` holds results made with other arguments."""


# --------------------------------------------------------------------------------------------------
# arguments
# --------------------------------------------------------------------------------------------------
def episode_seeds(seed: int, episodes: int) -> list[int]:
    """``episodes`` seeds derived from ``seed`` (prefix-stable: more episodes keep the first ones)."""
    if episodes < 1:
        raise ValueError(f"episodes = {episodes} is invalid: expected an integer >= 1")
    if seed < 0:
        raise ValueError(f"seed = {seed} is invalid: expected an integer >= 0")
    children = np.random.SeedSequence(int(seed)).spawn(int(episodes))
    return [int(c.generate_state(1, np.uint32)[0] >> 1) for c in children]


def resolve_task(name: str) -> str:
    """A registered task id; ``"Grid15Eval-v0"`` stands for ``"ipp_bench/Grid15Eval-v0"``."""
    name = name.strip()
    task_id = name if "/" in name else NAMESPACE + name
    task_spec(task_id)  # ValueError naming the valid ids
    return task_id


def canonical_spec(spec: str, extra: dict[str, Any] | None = None) -> str:
    """``"mcts:simulations=050"`` -> ``"mcts:simulations=50"``: name, then the overrides sorted, as
    the planner's config holds them. ``extra`` overrides apply where the spec does not set the key.

    Raises:
        ValueError: unknown planner or setting, or a value of the wrong type.
    """
    name, overrides = parse_spec(spec)
    overrides = {**{k: v for k, v in (extra or {}).items()}, **overrides}
    config = make_config(name, overrides)
    if not overrides:
        return name
    parts = [f"{k}={_format_value(getattr(config, k))}" for k in sorted(overrides)]
    return f"{name}:{','.join(parts)}"


def _format_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "none"
    return str(value)


def parse_env_overrides(items: Iterable[str]) -> dict[str, Any]:
    """``["budget_s=60", "report_times=[20,40,60]"]`` -> ``{"budget_s": 60, "report_times": [20, 40, 60]}``.

    Values are read as JSON where they parse (numbers, lists, true/false/null), else kept as text.
    """
    out: dict[str, Any] = {}
    for item in items:
        key, eq, raw = item.partition("=")
        key = key.strip()
        if not eq or not key:
            raise ValueError(f"environment override {item!r} is not key=value (e.g. budget_s=100)")
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw.strip()
        out[key] = value
    return out


def _task_config(task: str, env_overrides: dict[str, Any]):
    config = task_spec(task).config
    return config.replace(**env_overrides) if env_overrides else config


def report_times(task: str, env_overrides: dict[str, Any] | None = None) -> tuple[float, ...]:
    """The report times of ``task`` within its budget (the rows one episode gives)."""
    mission = _task_config(task, env_overrides or {}).mission
    return tuple(t for t in mission.report_times if t <= mission.budget_s + 1e-9)


def _config_digest(task: str, env_overrides: dict[str, Any]) -> str:
    blob = json.dumps(_task_config(task, env_overrides).to_dict(), sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def default_planners(log: Callable[[str], None] = print) -> list[str]:
    """Every registered planner that can be built here; the others are left out with a note.

    A planner whose module, extra (torch) or checkpoint is missing cannot run; that is fine for the
    default list (a printed note says why), never for a planner asked for by name.
    """
    names = []
    for name in planner_names():
        try:
            make_planner(name)
        except (ImportError, OSError, ValueError) as err:
            log(f"note: leaving planner {name!r} out of the default list: {type(err).__name__}: {err}")
            continue
        names.append(name)
    return names


@dataclass(frozen=True)
class Plan:
    """What a leaderboard run evaluates (resolved, validated arguments).

    Attributes:
        tasks: task ids, in table order.
        planners: canonical planner specs, in table order.
        seeds: episode seeds, the same for every (task, planner).
        env_overrides: IPPConfig fields set on every task (e.g. ``budget_s``), JSON values.
    """

    tasks: tuple[str, ...]
    planners: tuple[str, ...]
    episodes: int
    seed: int
    seeds: tuple[int, ...]
    env_overrides: dict[str, Any] = dataclasses.field(default_factory=dict)
    quick: bool = False

    def fingerprint(self) -> dict[str, Any]:
        """The arguments that decide the numbers (order-insensitive where order does not matter), as
        JSON would read them back (tuples become lists), so that a stored one compares equal."""
        return json.loads(json.dumps({
            "tasks": sorted(self.tasks),
            "planners": sorted(self.planners),
            "episodes": self.episodes,
            "seed": self.seed,
            "env_overrides": {k: self.env_overrides[k] for k in sorted(self.env_overrides)},
            "task_configs": {t: _config_digest(t, self.env_overrides) for t in sorted(self.tasks)},
            "seed_scheme": SEED_SCHEME,
        }, default=str))

    def jobs(self) -> list[EpisodeJob]:
        """Every episode, seed-major (an interrupted run has all planners on its first seeds)."""
        overrides = tuple((k, _freeze(v)) for k, v in sorted(self.env_overrides.items()))
        return [EpisodeJob(t, p, s, overrides) for s in self.seeds for t in self.tasks for p in self.planners]


def _freeze(value: Any) -> Any:
    """JSON lists as tuples (hashable; the configs hold tuples anyway)."""
    if isinstance(value, list):
        return tuple(_freeze(v) for v in value)
    return value


def make_plan(tasks: Sequence[str] | None = None, planners: Sequence[str] | None = None,
              episodes: int | None = None, seed: int = 0, quick: bool = False,
              env_overrides: dict[str, Any] | None = None,
              log: Callable[[str], None] = print) -> Plan:
    """Resolve and validate the leaderboard's arguments.

    Args:
        tasks: task ids (or names without the ``ipp_bench/`` prefix); default: tagged ``benchmark``.
        planners: planner specs (``"mcts:simulations=50"``); default: every registered planner that
            can be built here (see :func:`default_planners`).
        episodes: episodes per (task, planner); default :data:`DEFAULT_EPISODES`, or
            :data:`QUICK_EPISODES` with ``quick``.
        seed: base seed of the episode seeds.
        quick: few episodes and :data:`QUICK_OVERRIDES` on the planners (a spec's own keys win).
        env_overrides: IPPConfig fields set on every task.

    Raises:
        ValueError: unknown task, planner or setting; a planner that cannot be built (its message);
            bad episodes/seed; an override that leaves a task no report time within its budget.
        ImportError: a planner asked for by name whose extra is missing.
    """
    env_overrides = dict(env_overrides or {})
    task_ids = [resolve_task(t) for t in tasks] if tasks else tagged(DEFAULT_TAG)
    if not task_ids:
        raise ValueError(f"no task is tagged {DEFAULT_TAG!r}: pass --tasks")
    _no_duplicates("task", task_ids)
    for t in task_ids:
        if not report_times(t, env_overrides):
            mission = _task_config(t, env_overrides).mission
            raise ValueError(f"task {t}: no report time {mission.report_times} lies within the budget "
                             f"of {mission.budget_s} s; lower report_times or raise budget_s")
    explicit = bool(planners)
    specs = list(planners) if planners else default_planners(log)
    if not specs:
        raise ValueError("no planner can be built: pass --planners")
    resolved = []
    for spec in specs:
        name = parse_spec(spec)[0]
        extra = {} if explicit else dict(LEADERBOARD_DEFAULTS.get(name, {}))
        extra.update(QUICK_OVERRIDES.get(name, {}) if quick else {})
        canon = canonical_spec(spec, extra)
        if explicit:
            make_planner(canon)  # a planner asked for by name must build here, or fail now, loudly
        resolved.append(canon)
    _no_duplicates("planner", resolved)
    if episodes is None:
        episodes = QUICK_EPISODES if quick else DEFAULT_EPISODES
    seeds = episode_seeds(seed, episodes)
    return Plan(tuple(task_ids), tuple(resolved), int(episodes), int(seed), tuple(seeds), env_overrides, quick)


def _no_duplicates(kind: str, items: Sequence[str]) -> None:
    seen = set()
    for item in items:
        if item in seen:
            raise ValueError(f"{kind} {item!r} is given twice")
        seen.add(item)


def describe_quick() -> str:
    """What ``--quick`` changes, for the log."""
    overrides = ", ".join(f"{name}:" + ",".join(f"{k}={v}" for k, v in o.items())
                          for name, o in QUICK_OVERRIDES.items())
    return (f"quick mode: {QUICK_EPISODES} episodes per task and planner (instead of {DEFAULT_EPISODES}), "
            f"planner overrides {overrides} (unless a --planners spec sets them)")


# --------------------------------------------------------------------------------------------------
# one episode (runs in a worker)
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class EpisodeJob:
    task: str
    planner: str
    seed: int
    env_overrides: tuple[tuple[str, Any], ...] = ()

    @property
    def key(self) -> tuple[str, str, int]:
        return (self.task, self.planner, self.seed)


def run_job(job: EpisodeJob) -> list[dict[str, Any]]:
    """Fly one episode and return its results.csv rows (one per report time)."""
    result = run_episode(job.task, job.planner, job.seed, **dict(job.env_overrides))
    expected = report_times(job.task, dict(job.env_overrides))
    got = tuple(r["time_s"] for r in result.report)
    if got != expected:
        raise RuntimeError(f"{job.key}: the runner reported at {got}, expected {expected}")
    common = {
        "decisions": result.decisions,
        "decision_time_mean_s": result.decision_time_mean_s,
        "decision_time_max_s": result.decision_time_max_s,
        "episode_wall_s": result.episode_wall_s,
    }
    return [{"task": job.task, "planner": job.planner, "seed": job.seed, **r, **common} for r in result.report]


# --------------------------------------------------------------------------------------------------
# results.csv
# --------------------------------------------------------------------------------------------------
def _format_cell(value: Any) -> str:
    if isinstance(value, float):
        return repr(value)  # shortest round-trip form: the same number reads back bit for bit
    return str(value)


def format_rows(rows: Iterable[dict[str, Any]]) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    for row in rows:
        writer.writerow([_format_cell(row[c]) for c in COLUMNS])
    return buf.getvalue()


def _parse_row(fields: list[str]) -> dict[str, Any]:
    if len(fields) != len(COLUMNS):
        raise ValueError(f"{len(fields)} fields, expected {len(COLUMNS)}")
    row: dict[str, Any] = dict(zip(COLUMNS, fields))
    for c in _INT_COLUMNS:
        row[c] = int(row[c])
    for c in _FLOAT_COLUMNS:
        row[c] = float(row[c])
    return row


def read_results(path: str | Path) -> list[dict[str, Any]]:
    """The rows of a results.csv (typed); a torn last line is ignored."""
    text = Path(path).read_text()
    return _parse_text(text)[0]


def _parse_text(text: str) -> tuple[list[dict[str, Any]], list[str]]:
    """Rows of a results.csv text, and notes on what was dropped (torn or malformed lines)."""
    notes = []
    if text and not text.endswith("\n"):
        cut = text.rfind("\n") + 1
        notes.append(f"dropped a torn last line ({len(text) - cut} bytes, from an interrupted write)")
        text = text[:cut]
    lines = text.splitlines()
    if not lines:
        return [], notes
    header = next(csv.reader([lines[0]]))
    if tuple(header) != COLUMNS:
        raise ValueError(f"results.csv has columns {header}, expected {list(COLUMNS)}")
    rows = []
    for i, fields in enumerate(csv.reader(lines[1:]), start=2):
        try:
            rows.append(_parse_row(fields))
        except ValueError as err:
            notes.append(f"dropped malformed line {i} ({err})")
    return rows, notes


def _sort_key(plan: Plan):
    t_index = {t: i for i, t in enumerate(plan.tasks)}
    p_index = {p: i for i, p in enumerate(plan.planners)}
    s_index = {s: i for i, s in enumerate(plan.seeds)}
    return lambda r: (t_index.get(r["task"], 1 << 30), p_index.get(r["planner"], 1 << 30),
                      s_index.get(r["seed"], 1 << 30), r["time_s"])


class ResultsStore:
    """``out_dir`` of a leaderboard run: fingerprint check, lock, resumable results.csv.

    Use as a context manager; entering locks the folder against a second concurrent run.
    """

    def __init__(self, out_dir: str | Path, plan: Plan, command: str | None = None):
        self.dir = Path(out_dir)
        self.plan = plan
        self.command = command
        self.csv_path = self.dir / RESULTS_CSV
        self.run_json = self.dir / RUN_JSON
        self._lock_fd: int | None = None
        self.notes: list[str] = []
        self.done: dict[tuple[str, str, int], list[dict[str, Any]]] = {}

    # -- setup ----------------------------------------------------------------------------------------
    def __enter__(self) -> ResultsStore:
        self.dir.mkdir(parents=True, exist_ok=True)
        self._lock()
        try:
            self._check_fingerprint()
            self._load()
        except BaseException:
            self._unlock()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self._unlock()

    def _lock(self) -> None:
        try:
            import fcntl
        except ImportError:  # pragma: no cover (Windows): no lock
            return
        fd = os.open(self.dir / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise ResultsMismatchError(
                f"{self.dir} is in use by another leaderboard run (locked); wait for it or pass another --out") from None
        self._lock_fd = fd

    def _unlock(self) -> None:
        if self._lock_fd is not None:
            os.close(self._lock_fd)  # releases the flock
            self._lock_fd = None

    def _check_fingerprint(self) -> None:
        fingerprint = self.plan.fingerprint()
        if self.run_json.exists():
            try:
                stored = json.loads(self.run_json.read_text())["fingerprint"]
            except (ValueError, KeyError, TypeError) as err:
                raise ResultsMismatchError(
                    f"{self.run_json} is unreadable ({err}); pass a new --out DIR (or delete {self.dir})") from None
            differing = [k for k in sorted(set(stored) | set(fingerprint)) if stored.get(k) != fingerprint.get(k)]
            if differing:
                lines = [f"  {k}: there {_short(stored.get(k))}, now {_short(fingerprint.get(k))}" for k in differing]
                raise ResultsMismatchError(
                    f"{self.dir} holds results made with different arguments ({', '.join(differing)}):\n"
                    + "\n".join(lines)
                    + f"\nTo resume that run, repeat its arguments ({RUN_JSON} has them); for these arguments "
                    f"pass a new --out DIR (or delete {self.dir}). Results of different arguments are never mixed.")
            return
        if self.csv_path.exists() and self.csv_path.stat().st_size > 0:
            raise ResultsMismatchError(
                f"{self.csv_path} exists without {RUN_JSON}: its arguments are unknown, so it cannot be resumed; "
                f"pass a new --out DIR (or delete {self.dir})")
        meta = {
            "format": FORMAT_VERSION,
            "fingerprint": fingerprint,
            "quick": self.plan.quick,
            "tasks": list(self.plan.tasks),
            "planners": list(self.plan.planners),
            "seeds": list(self.plan.seeds),
            "ipp_bench_version": __version__,
            "command": self.command,
            "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }
        _atomic_write(self.run_json, json.dumps(meta, indent=2) + "\n")

    def _load(self) -> None:
        """Read finished episodes; drop torn lines and incomplete episodes (rewriting the file)."""
        if not self.csv_path.exists() or self.csv_path.stat().st_size == 0:
            _atomic_write(self.csv_path, format_header())
            return
        text = self.csv_path.read_text()
        try:
            rows, notes = _parse_text(text)
        except ValueError as err:  # another header: not a results file of this version
            raise ResultsMismatchError(f"{self.csv_path}: {err}; pass a new --out DIR (or delete {self.dir})") from None
        expected = {t: report_times(t, self.plan.env_overrides) for t in self.plan.tasks}
        wanted = {job.key for job in self.plan.jobs()}
        groups: dict[tuple[str, str, int], dict[float, dict[str, Any]]] = {}
        for row in rows:
            key = (row["task"], row["planner"], row["seed"])
            groups.setdefault(key, {}).setdefault(row["time_s"], row)  # a duplicate row: keep the first
        done = {}
        for key, by_time in groups.items():
            if key not in wanted:
                notes.append(f"dropped rows of {key}: not an episode of these arguments")
                continue
            if tuple(sorted(by_time)) != expected[key[0]]:
                notes.append(f"dropped the incomplete episode {key} ({len(by_time)} of {len(expected[key[0]])} rows); "
                             "it runs again")
                continue
            done[key] = [by_time[t] for t in expected[key[0]]]
        kept = sum(len(v) for v in done.values())
        if kept != len(rows) or not text.endswith("\n") or notes:
            self._rewrite([r for v in done.values() for r in v], sort=False)
        self.notes.extend(notes)
        self.done = done

    # -- writing --------------------------------------------------------------------------------------
    def append(self, rows: list[dict[str, Any]]) -> None:
        """Append one episode's rows: one write of whole lines, flushed and fsync'ed."""
        data = format_rows(rows).encode()
        fd = os.open(self.csv_path, os.O_WRONLY | os.O_APPEND)
        try:
            view = memoryview(data)
            while view:
                n = os.write(fd, view)
                view = view[n:]
            os.fsync(fd)
        finally:
            os.close(fd)
        key = (rows[0]["task"], rows[0]["planner"], rows[0]["seed"])
        self.done[key] = rows

    def _rewrite(self, rows: list[dict[str, Any]], sort: bool = True) -> None:
        if sort:
            rows = sorted(rows, key=_sort_key(self.plan))
        _atomic_write(self.csv_path, format_header() + format_rows(rows))

    def finalize(self) -> None:
        """Rewrite results.csv sorted by (task, planner, seed, time): independent of finishing order."""
        self._rewrite([r for v in self.done.values() for r in v], sort=True)


def format_header() -> str:
    return ",".join(COLUMNS) + "\n"


def _short(value: Any, limit: int = 200) -> str:
    text = json.dumps(value, sort_keys=True, default=str)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _atomic_write(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    with open(tmp, "w") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    try:  # make the rename itself durable
        dfd = os.open(path.parent, os.O_RDONLY)
    except OSError:  # pragma: no cover
        return
    try:
        os.fsync(dfd)
    except OSError:  # pragma: no cover (file systems that refuse fsync on a folder)
        pass
    finally:
        os.close(dfd)


# --------------------------------------------------------------------------------------------------
# the run
# --------------------------------------------------------------------------------------------------
@dataclass
class Summary:
    out_dir: Path
    total: int
    skipped: int
    ran: int
    wall_s: float
    files: list[Path]


class _Progress:
    """tqdm on a terminal, plain lines otherwise (CI logs)."""

    def __init__(self, total: int, enabled: bool | None, log: Callable[[str], None]):
        self.total = total
        self.count = 0
        self.log = log
        self.bar = None
        if enabled is None:
            enabled = sys.stderr.isatty()
        if enabled and total:
            try:
                from tqdm import tqdm
            except ImportError:  # plain lines are enough
                tqdm = None
            if tqdm is not None:
                self.bar = tqdm(total=total, unit="ep", dynamic_ncols=True, desc="leaderboard")

    def update(self, job: EpisodeJob, rows: list[dict[str, Any]]) -> None:
        self.count += 1
        last = rows[-1]
        text = (f"{job.task.removeprefix(NAMESPACE)} {job.planner} seed={job.seed}: "
                f"uncertainty -{last['uncertainty_reduction_pct']:.1f}% rmse -{last['rmse_reduction_pct']:.1f}% "
                f"at {last['time_s']:g} s, {last['decisions']} decisions, {last['episode_wall_s']:.1f} s")
        if self.bar is not None:
            self.bar.set_postfix_str(f"{job.task.removeprefix(NAMESPACE)} {job.planner}", refresh=False)
            self.bar.update(1)
        else:
            self.log(f"[{self.count}/{self.total}] {text}")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def run_leaderboard(plan: Plan, out_dir: str | Path, backend: str | None = None, workers: int | None = None,
                    address: str | None = None, progress: bool | None = None, command: str | None = None,
                    report: bool = True, log: Callable[[str], None] = print) -> Summary:
    """Run the episodes of ``plan`` that ``out_dir`` lacks, then write the report.

    Args:
        plan: from :func:`make_plan`.
        out_dir: output folder (created).
        backend: ``serial``, ``process`` or ``ray``; default ``process`` when more than one worker,
            else ``serial``.
        workers: processes / local Ray CPUs; default: the CPUs available.
        address: Ray cluster (``ray`` backend).
        progress: tqdm bar (True), plain lines (False), or tqdm only on a terminal (None).
        command: the command line, recorded in run.json and the report.
        report: write leaderboard.md and the plots at the end.

    Raises:
        ResultsMismatchError: ``out_dir`` holds results of other arguments, or is locked.
        ImportError: ray backend without Ray.
    """
    t0 = time.perf_counter()
    if backend is None:
        backend = default_backend(workers)
    with ResultsStore(out_dir, plan, command) as store:
        for note in store.notes:
            log(f"note: {note}")
        jobs = plan.jobs()
        todo = [j for j in jobs if j.key not in store.done]
        skipped = len(jobs) - len(todo)
        log(f"leaderboard: {len(plan.tasks)} tasks x {len(plan.planners)} planners x {plan.episodes} episodes "
            f"= {len(jobs)} episodes; {skipped} already in {store.csv_path}, {len(todo)} to run")
        if todo:
            executor = make_executor(backend, workers, address)
            log(f"running on {executor.describe()}")
            bar = _Progress(len(todo), progress, log)
            try:
                for job, rows in executor.imap_unordered(run_job, todo):
                    store.append(rows)
                    bar.update(job, rows)
            finally:
                bar.close()
                executor.close()
        store.finalize()
        files = [store.csv_path, store.run_json]
        if report:
            from .report import write_report

            files += write_report(store.csv_path, out_dir, tasks=plan.tasks, planners=plan.planners,
                                  command=command, quick=plan.quick)
    wall = time.perf_counter() - t0
    return Summary(Path(out_dir), len(jobs), skipped, len(todo), wall, files)


__all__ = [
    "COLUMNS",
    "DEFAULT_EPISODES",
    "QUICK_EPISODES",
    "QUICK_OVERRIDES",
    "TIMING_COLUMNS",
    "EpisodeJob",
    "Plan",
    "ResultsMismatchError",
    "ResultsStore",
    "Summary",
    "canonical_spec",
    "default_planners",
    "describe_quick",
    "episode_seeds",
    "make_plan",
    "parse_env_overrides",
    "read_results",
    "report_times",
    "resolve_task",
    "run_job",
    "run_leaderboard",
]
