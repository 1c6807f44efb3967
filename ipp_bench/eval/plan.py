"""Planning a leaderboard run: resolved, validated arguments and the episodes they make.

:func:`make_plan` turns the command line's arguments (tasks, planner specs, episodes, seed,
``--quick``, ``--env`` overrides) into a :class:`Plan`: canonical planner specs, the episode
seeds, and the fingerprint of everything that decides the numbers (:mod:`ipp_bench.eval.fingerprint`;
the results folder compares it on a rerun, see :mod:`ipp_bench.eval.run_json`).

Episode seeds derive from ``seed`` alone (:func:`episode_seeds`): every planner meets the same
episodes (field, start, sensor noise), and the first ``n`` seeds stay the same when ``episodes``
grows, so a rerun with more episodes extends a results folder.

:func:`ipp_bench.eval.against.against_plan` plans new planners on a published board (``--against FOLDER``): its tasks,
task configurations, environment overrides and seeds, read from its run.json; a configuration or
seed set that today's suite gives otherwise is refused, naming what differs.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np

from ..envs import tagged, task_config, task_spec
from ..envs.registry import is_team_task, resolve_task
from ..planners import make_config, make_planner, parse_spec, planner_names
from ..planners.isolation import describe_planner, isolated_by_default
from .fingerprint import normalised_overrides, planner_fingerprint, task_config_record
from .methods import METHODS_KEY, methods_record, network_index, planner_members
from .plan_checks import check_distinct_episodes, check_episode_starts, check_isolation

SEED_SCHEME = "SeedSequence(seed).spawn(episodes)[i] -> uint31"
DEFAULT_EPISODES = 20
#: the most episodes per (task, planner): a 95% interval is already ~1/100 of the spread at 10^4
MAX_EPISODES = 10_000
DEFAULT_TAG = "benchmark"
# A planner's defaults are its Config's, on every board. --quick: few episodes and cheaper look-ahead, flown
# as explicit specs (``mcts:simulations=4``, so named in the results) unless a spec sets the key itself;
# sized so that every benchmark task x every planner fits a few minutes on 2 busy cores (the planners'
# times per decision: benchmarks/RESULTS.md).
QUICK_EPISODES = 3
QUICK_OVERRIDES: dict[str, dict[str, Any]] = {
    "mcts": {"simulations": 4},
    "cmaes": {"max_evals": 36},
}
#: settings a canonical spec names at their default too, so that one label is one planner on every board:
#: the v0 boards' ``mcts`` rows flew 100 simulations, and the default (24) is ``mcts:simulations=24``
SPELLED_SETTINGS: dict[str, tuple[str, ...]] = {"mcts": ("simulations",)}
#: planners whose episodes take longest, most expensive first (only the order of a run's jobs uses it)
SLOW_PLANNERS: dict[str, int] = {"mcts": 2, "cmaes": 1}


def episode_seeds(seed: int, episodes: int) -> list[int]:
    """``episodes`` seeds derived from ``seed`` (prefix-stable: more episodes keep the first ones)."""
    _check_episodes(episodes)
    if seed < 0:
        raise ValueError(f"seed = {seed} is invalid: expected an integer >= 0")
    children = np.random.SeedSequence(int(seed)).spawn(int(episodes))
    return [int(c.generate_state(1, np.uint32)[0] >> 1) for c in children]


def _check_episodes(episodes: Any) -> None:
    if (isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer))
            or not 1 <= episodes <= MAX_EPISODES):
        raise ValueError(f"episodes = {episodes!r} is invalid: expected an integer in [1, {MAX_EPISODES}]")


def canonical_spec(spec: str, extra: dict[str, Any] | None = None, *, isolated: bool = False) -> str:
    """``"mcts:simulations=050"`` -> ``"mcts:simulations=50"``: name, then the overrides and the planner's
    :data:`SPELLED_SETTINGS` sorted, as the planner's config holds them (``"mcts"`` -> ``"mcts:simulations=24"``).
    ``extra`` overrides apply where the spec does not set the key. ``isolated``: the config is read from the
    planner's own process (:func:`~ipp_bench.planners.isolation.describe_planner`), so that this process never
    imports the planner's code.

    Raises:
        ValueError: unknown planner or setting, or a value of the wrong type.
    """
    name, overrides = parse_spec(spec)
    overrides = {**(extra or {}), **overrides}
    if isolated:
        asked = ",".join(f"{k}={_format_value(v)}" for k, v in overrides.items())
        settings = describe_planner(f"{name}:{asked}" if asked else name)["settings"]
        config = SimpleNamespace(**{k: tuple(v) if isinstance(v, list) else v for k, v in settings.items()})
    else:
        config = make_config(name, overrides)
    keys = sorted(set(overrides) | {k for k in SPELLED_SETTINGS.get(name, ()) if hasattr(config, k)})
    if not keys:
        return name
    parts = [f"{k}={_format_value(getattr(config, k))}" for k in keys]
    return f"{name}:{','.join(parts)}"


def planner_settings(spec: str) -> dict[str, Any]:
    """Every setting of planner ``spec`` (its config's fields, defaults included); a planner the leaderboard
    isolates by default (an installed plugin's) is described by its own process, never built in this one.

    Raises:
        ValueError: unknown planner or setting, or a value of the wrong type (a plugin's: one line).
    """
    if isolated_by_default(spec):
        return dict(describe_planner(spec)["settings"])
    name, overrides = parse_spec(spec)
    return dataclasses.asdict(make_config(name, overrides))


def _format_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "none"
    return str(value)


def report_times(task: str, env_overrides: dict[str, Any] | None = None) -> tuple[float, ...]:
    """The report times of ``task`` within its budget (the rows one episode gives)."""
    return task_config(task, env_overrides).mission.report_times_in_budget


def default_planners(log: Callable[[str], None] = print, team: bool = False) -> list[str]:
    """Every registered planner that can be built here; the others are left out with a note. The
    team-aware planners (``team-greedy``, ...) only where ``team`` (a team task among the tasks): any
    other planner flies each UAV of a team on its own, and on one UAV they fly as their single-UAV
    counterparts.

    A planner whose module, extra (torch, pycma) or checkpoint is missing, or a plugin that fails
    to build (no ``Config``, an exception in its constructor), cannot run; that is fine for the
    default list (a printed note says why), never for a planner asked for by name.
    """
    names = []
    for name in planner_names():
        try:  # a plugin's planner is built in its own process only (never beside the truth)
            team_planner = (describe_planner(name)["team"] if isolated_by_default(name)
                            else getattr(make_planner(name), "team", False))
        except Exception as err:  # any broken planner (a plugin's bug too) is left out, with its reason
            log(f"note: leaving planner {name!r} out of the default list: {type(err).__name__}: {err}")
            continue
        if team_planner and not team:
            continue
        names.append(name)
    return names


@dataclass(frozen=True)
class EpisodeJob:
    """One episode to run: (task, planner spec, seed) and the env overrides of the run."""

    task: str
    planner: str
    seed: int
    env_overrides: tuple[tuple[str, Any], ...] = ()
    task_file: str | None = None  # a user's task file (not of the suite): a worker loads it first
    isolate: bool = False  # fly the planner in a process of its own (:mod:`ipp_bench.planners.isolation`)
    #: a method's episode: the spec of the one network that flies it (:mod:`ipp_bench.eval.methods`); rows
    #: carry ``planner``, the method's spec
    flies: str | None = None
    network: int | None = None  # that network's place (0-based) in the method's list

    @property
    def key(self) -> tuple[str, str, int]:
        return (self.task, self.planner, self.seed)


@dataclass(frozen=True)
class Plan:
    """What a leaderboard run evaluates (resolved, validated arguments).

    Attributes:
        tasks: task ids, in table order.
        planners: canonical planner specs, in table order.
        seeds: episode seeds, the same for every (task, planner).
        env_overrides: IPPConfig fields set on every task (e.g. ``budget_s``), JSON values.
        quick: ``--quick`` changed something (fewer episodes or cheaper settings); a ``--quick``
            that changed nothing is no quick run.
        planner_fingerprints: per planner spec, what its decisions depend on beyond the spec
            (:func:`~ipp_bench.eval.fingerprint.planner_fingerprint`).
        against: the published board these planners are paired with (:func:`ipp_bench.eval.against.against_plan`):
            its ``folder``, ``planners``, ``episodes`` and ``results_sha256``; None for a board of its own.
        isolated: the planners flown in a process of their own (:mod:`ipp_bench.planners.isolation`), in table
            order. Not part of the fingerprint: isolation changes no number.
        members: per method (a planner spec naming several networks, :mod:`ipp_bench.eval.methods`), its
            networks in order: (name, the spec that flies it alone); episode i flies network i mod k.
    """

    tasks: tuple[str, ...]
    planners: tuple[str, ...]
    episodes: int
    seed: int
    seeds: tuple[int, ...]
    env_overrides: dict[str, Any] = dataclasses.field(default_factory=dict)
    quick: bool = False
    planner_fingerprints: dict[str, dict[str, str]] = dataclasses.field(default_factory=dict)
    against: dict[str, Any] | None = None
    isolated: tuple[str, ...] = ()
    members: dict[str, tuple[tuple[str, str], ...]] = dataclasses.field(default_factory=dict)

    def fingerprint(self) -> dict[str, Any]:
        """The arguments that decide the numbers (order-insensitive where order does not matter), as
        JSON would read them back (tuples become lists), so that a stored one compares equal.

        The number of episodes is not part of it: seeds are prefix-stable, so more episodes extend
        a folder (:class:`~ipp_bench.eval.results.ResultsStore` checks that none are dropped).
        """
        record = {
            "tasks": sorted(self.tasks),
            "planners": sorted(self.planners),
            "seed": self.seed,
            "env_overrides": normalised_overrides(self.tasks, self.env_overrides),
            "task_configs": {t: task_config_record(t, self.env_overrides) for t in sorted(self.tasks)},
            "planner_fingerprints": {p: self.planner_fingerprints[p] for p in sorted(self.planner_fingerprints)},
            "seed_scheme": SEED_SCHEME,
        }
        if self.members:  # only on a board that flies a method: older folders' fingerprints stay as they are
            record[METHODS_KEY] = methods_record(self.members)
        if self.against is not None:  # the published rows the report pairs with (where they lie aside)
            record["against"] = {k: v for k, v in self.against.items() if k != "folder"}
        return json.loads(json.dumps(record, default=str))

    def jobs(self) -> list[EpisodeJob]:
        """Every episode, seed-major (an interrupted run has all planners on its first seeds).

        Within a seed the likely longest episodes come first (larger maps, then the look-ahead
        planners, :data:`SLOW_PLANNERS`), so that a pool's workers finish together instead of one
        flying a 30 x 30 MCTS episode alone at the end. The order changes no result.
        """
        overrides = tuple((k, _freeze(v)) for k, v in sorted(self.env_overrides.items()))
        files = {t: (None if task_spec(t).builtin else task_spec(t).source) for t in self.tasks}
        cells = {t: task_config(t, self.env_overrides).grid.n_cells for t in self.tasks}
        pairs = sorted(((t, p) for t in self.tasks for p in self.planners),
                       key=lambda tp: (-cells[tp[0]], -SLOW_PLANNERS.get(parse_spec(tp[1])[0], 0)))
        jobs = []
        for i, s in enumerate(self.seeds):
            for t, p in pairs:
                job = EpisodeJob(t, p, s, overrides, files[t], p in self.isolated)
                if p in self.members:  # a method: this episode's network flies it (methods.SPLIT_RULE)
                    n = network_index(i, len(self.members[p]))
                    job = dataclasses.replace(job, flies=self.members[p][n][1], network=n)
                jobs.append(job)
        return jobs


def _freeze(value: Any) -> Any:
    """JSON lists as tuples (hashable; the configs hold tuples anyway)."""
    if isinstance(value, list):
        return tuple(_freeze(v) for v in value)
    return value


def make_plan(tasks: Sequence[str] | None = None, planners: Sequence[str] | None = None,
              episodes: int | None = None, seed: int = 0, quick: bool = False,
              env_overrides: dict[str, Any] | None = None,
              log: Callable[[str], None] = print, check_start: bool = True, isolate: bool = False,
              isolate_why: str = "--isolate", sweeps: Sequence[str] = ()) -> Plan:
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
        check_start: start the first episode of every task with every planner (reset, no
            decision; :func:`check_episode_starts`), so that what an episode's start refuses is
            refused here, before a results folder is written.
        isolate: fly every planner in a process of its own (``--isolate``); without it, only the
            planners of installed plugins' entry points
            (:func:`~ipp_bench.planners.isolation.isolated_by_default`). ``isolate_why``: what asked
            for it, as a refusal names it.
        sweeps: planner specs of ``--sweep`` points (:func:`ipp_bench.eval.sweep.sweep_specs`), flown after
            ``planners`` (or the default list); a point that is one of those planners flies once.

    Raises:
        ValueError: unknown task, planner or setting; a planner that cannot be built (its message);
            bad episodes/seed; an override that leaves a task no report time within its budget;
            a planner to isolate on a task that cannot be flown isolated (a team or MuJoCo task).
        ImportError: a planner asked for by name whose extra is missing.
    """
    env_overrides = dict(env_overrides or {})
    task_ids = [resolve_task(t) for t in tasks] if tasks else tagged(DEFAULT_TAG)
    if not task_ids:
        raise ValueError(f"no task is tagged {DEFAULT_TAG!r}: pass --tasks")
    _no_duplicates("task", task_ids)
    for t in task_ids:
        if not report_times(t, env_overrides):
            mission = task_config(t, env_overrides).mission
            raise ValueError(f"task {t}: no report time {mission.report_times} lies within the budget "
                             f"of {mission.budget_s} s; lower report_times or raise budget_s")
    if episodes is not None:
        _check_episodes(episodes)
    if planners is not None and not [p for p in planners if str(p).strip(" ,")] and not sweeps:
        raise ValueError(f"the planner list {list(planners)!r} names no planner: pass planner specs "
                         "(e.g. --planners random greedy), or leave --planners out for every planner")
    specs = list(planners) if planners is not None else default_planners(
        log, team=any(is_team_task(t) for t in task_ids))
    given = len(specs)
    specs = [*specs, *sweeps]
    if not specs:
        raise ValueError("no planner can be built: pass --planners")
    resolved, fingerprints, quick_changed, built, members = [], {}, quick and episodes is None, {}, {}
    for i, spec in enumerate(specs):
        name = parse_spec(spec)[0]
        apart = isolate or isolated_by_default(spec)  # built in its own process only, never in this one
        without_quick = canonical_spec(spec, isolated=apart)
        canon = canonical_spec(spec, QUICK_OVERRIDES.get(name) if quick else None, isolated=apart)
        if i >= given and canon in resolved:  # a sweep's point that is one of the planners already
            continue
        quick_changed = quick_changed or canon != without_quick
        # a planner must build here, or fail now, loudly (the default list holds buildable ones)
        built[canon] = None if apart else make_planner(canon)
        fingerprint = describe_planner(canon)["fingerprint"] if apart else planner_fingerprint(built[canon])
        if fingerprint:
            fingerprints[canon] = fingerprint
        resolved.append(canon)
        members[canon] = planner_members(canon)
        if members[canon]:  # a method: each network starts on every task in the check below, never the method
            del built[canon]
            built.update({alone: None if apart else make_planner(alone) for _, alone in members[canon]})
    _no_duplicates("planner", resolved)
    isolated = tuple(resolved) if isolate else tuple(p for p in resolved if isolated_by_default(p))
    check_isolation(task_ids, isolated, isolate_why if isolate else
                    "a planner from an installed plugin's entry point is isolated by default")
    if episodes is None:
        episodes = QUICK_EPISODES if quick else DEFAULT_EPISODES
    seeds = episode_seeds(seed, episodes)
    for t in task_ids:
        check_distinct_episodes(t, seeds, env_overrides)
    if check_start:
        check_episode_starts(task_ids, built, seeds[0], env_overrides)
    return Plan(tuple(task_ids), tuple(resolved), int(episodes), int(seed), tuple(seeds), env_overrides,
                quick_changed, fingerprints, isolated=isolated, members={p: m for p, m in members.items() if m})


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


__all__ = ["DEFAULT_EPISODES", "MAX_EPISODES", "QUICK_EPISODES", "QUICK_OVERRIDES", "SPELLED_SETTINGS",
           "EpisodeJob", "Plan", "canonical_spec", "check_isolation", "default_planners", "check_episode_starts",
           "describe_quick", "episode_seeds", "make_plan", "planner_settings", "report_times", "resolve_task"]
