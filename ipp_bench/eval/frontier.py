"""Quality against decision time: the sweeps among a board's planners, the Pareto front, and the paper's questions.

A **sweep** is two or more specs of one planner that differ in exactly one numeric setting, found from the
planner specs alone (:func:`infer_sweeps`), whatever flew them (``--sweep``, ``--planners``, a published board's
rows): ``mcts:simulations=8``, ``mcts:simulations=24`` and ``mcts:simulations=64`` are one. A spec that does not
spell the setting has the planner's default (its ``Config``'s, :func:`settings_of`), so plain ``cmaes`` joins a
sweep over ``cmaes:max_evals`` at 72.

Per task (:func:`task_frontier`), every planner is a point: x the mean over episodes of each episode's mean
decision time (``decision_time_mean_s``), y its mean uncertainty reduction at each report time, with the paired
difference from the reference planner and its 95 % paired bootstrap interval
(:func:`~ipp_bench.eval.aggregate.bootstrap_ci` of the per-episode differences, as every paired table of the
report). The **Pareto front** at a report time (:func:`pareto_front`) holds every point for which no other point
has both a lower decision time and a mean at least as high; references that read the truth are no points of it.

The paper's question (:func:`match_answers`): per report time, the smallest setting of an MCTS sweep whose quality
is not below ``attention``'s, i.e. whose paired 95 % interval of MCTS minus ``attention`` is not wholly below 0
(its upper end >= 0); where none is, the setting with the highest mean difference (the largest gap closed). And
how much of the oracle's headroom over the reference the best planner that does not read the truth reaches
(:func:`headroom`): (best - reference) / (oracle - reference). With one episode there is no interval, and no
setting is said to match.
"""

from __future__ import annotations

import numbers
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..planners import is_reference, parse_spec
from .aggregate import SCORE_KEY, Estimate, bootstrap_ci
from .plan import planner_settings
from .tables import EpisodeTable, ordered, resolve_reference

#: the report times [s] the paper's question is answered at (those a task has; else its last report time)
QUESTION_TIMES = (100.0, 200.0)
#: the planner swept, and the planner it is matched with, in the paper's question
SWEPT, MATCHED = "mcts", "attention"
#: the reference that reads the truth whose headroom over the reference planner is shared out
HEADROOM = "oracle"


def settings_of(spec: str) -> dict[str, Any]:
    """The settings of planner ``spec``: its config's every field (defaults included) where the planner can be
    built here, else the settings the spec spells (a number where one parses)."""
    try:  # a plugin's planner is described by its own process, never built in this one
        return planner_settings(spec)
    except (ValueError, ImportError, TypeError):  # a planner not installed here (a published row): what it spells
        return {k: _number(v) for k, v in parse_spec(spec)[1].items()}


def _number(text: str) -> Any:
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def _is_number(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


@dataclass(frozen=True)
class SweepGroup:
    """Planner ``name`` over setting ``key``: ``points`` are (setting, spec), the setting ascending."""

    name: str
    key: str
    points: tuple[tuple[float, str], ...]

    @property
    def specs(self) -> tuple[str, ...]:
        return tuple(s for _, s in self.points)

    def value(self, spec: str) -> float:
        return next(v for v, s in self.points if s == spec)


def infer_sweeps(planners: Sequence[str]) -> list[SweepGroup]:
    """Every sweep among ``planners`` (module docstring): per planner name and numeric setting, the specs equal
    in every other setting, where they hold two or more values of it. References that read the truth are none."""
    by_name: dict[str, list[str]] = defaultdict(list)
    for p in planners:
        if not is_reference(p):
            by_name[parse_spec(p)[0]].append(p)
    sweeps = []
    for name, specs in by_name.items():
        if len(specs) < 2:
            continue
        settings = {s: settings_of(s) for s in specs}
        for key in sorted({k for v in settings.values() for k in v}):
            groups: dict[str, list[tuple[float, str]]] = defaultdict(list)
            for s in specs:
                if _is_number(settings[s].get(key)):
                    rest = repr(sorted((k, repr(v)) for k, v in settings[s].items() if k != key))
                    groups[rest].append((settings[s][key], s))
            for points in groups.values():
                if len({v for v, _ in points}) >= 2:
                    sweeps.append(SweepGroup(name, key, tuple(sorted(points))))
    return sweeps


def pareto_front(times: Sequence[float], means: Sequence[float]) -> list[bool]:
    """Per point, whether it is on the front: no other point has both a lower time and a mean at least as high."""
    t, m = np.asarray(times, dtype=float), np.asarray(means, dtype=float)
    return [not bool(np.any((t < t[i]) & (m >= m[i]))) for i in range(len(t))]


def paired(table: EpisodeTable, task: str, a: str, b: str, time_s: float, key: str = SCORE_KEY) -> Estimate | None:
    """``a`` minus ``b`` on the episodes both flew: mean and paired bootstrap interval (None: no common episode;
    one episode: no interval)."""
    mine, theirs = table.by_seed(task, a, time_s, key), table.by_seed(task, b, time_s, key)
    seeds = sorted(set(mine) & set(theirs))
    return bootstrap_ci([mine[s] - theirs[s] for s in seeds]) if seeds else None


def decision_time(table: EpisodeTable, task: str, planner: str) -> float:
    """[s] the mean over ``planner``'s episodes of each episode's mean decision time."""
    return float(np.mean(list(table.runtime[(task, planner)].values())))


@dataclass(frozen=True)
class Point:
    """One planner on one task: ``means`` and ``versus`` (the paired difference from the reference; None for the
    reference itself) per report time, and the report times at which it is on the Pareto front."""

    planner: str
    decision_time_s: float
    means: dict[float, float]
    versus: dict[float, Estimate | None]
    front: frozenset[float]
    reads_truth: bool
    #: the mean and the sum over its episodes of an episode's wall time [s] (the step, the updates, the decisions)
    episode_wall_s: float = float("nan")
    wall_s: float = float("nan")


@dataclass(frozen=True)
class Frontier:
    """Quality against decision time on ``task``: every planner's :class:`Point` and the sweeps flown there."""

    task: str
    times: tuple[float, ...]
    reference: str | None
    points: tuple[Point, ...]
    sweeps: tuple[SweepGroup, ...]

    def point(self, planner: str) -> Point:
        return next(p for p in self.points if p.planner == planner)


def task_frontier(table: EpisodeTable, task: str, reference: str | None, sweeps: Sequence[SweepGroup],
                  key: str = SCORE_KEY) -> Frontier | None:
    """The frontier of ``task`` (None where no sweep has two points flown on it)."""
    planners = [p for p in ordered(table.planners) if table.episodes(task, p)]
    flown = [SweepGroup(s.name, s.key, tuple((v, p) for v, p in s.points if p in planners)) for s in sweeps]
    flown = [s for s in flown if len(s.points) >= 2]
    if not flown:
        return None
    times = tuple(table.times.get(task, ()))
    ref = reference if reference in planners else None
    dt = {p: decision_time(table, task, p) for p in planners}
    means = {p: {t: float(np.mean(table.values[(task, p, t, key)])) for t in times
                 if table.values.get((task, p, t, key))} for p in planners}
    front: dict[str, set[float]] = defaultdict(set)
    for t in times:
        ranked = [p for p in planners if not is_reference(p) and t in means[p]]
        for p, on in zip(ranked, pareto_front([dt[p] for p in ranked], [means[p][t] for p in ranked])):
            if on:
                front[p].add(t)
    walls = {p: list(table.wall.get((task, p), {}).values()) for p in planners}
    points = tuple(Point(p, dt[p], means[p],
                         {t: (paired(table, task, p, ref, t, key) if ref and p != ref else None) for t in times},
                         frozenset(front[p]), is_reference(p),
                         float(np.mean(walls[p])) if walls[p] else float("nan"), float(np.sum(walls[p])))
                   for p in planners)
    return Frontier(task, times, ref, points, tuple(flown))


def question_times(times: Sequence[float]) -> list[float]:
    """The report times the paper's question is answered at: :data:`QUESTION_TIMES` where the task has them,
    else its last report time."""
    return [t for t in QUESTION_TIMES if t in times] or list(times[-1:])


@dataclass(frozen=True)
class Match:
    """One setting of the sweep against the matched planner at one report time (paired, MCTS minus it)."""

    planner: str
    setting: float
    difference: Estimate
    decision_time_s: float


@dataclass(frozen=True)
class MatchAnswer:
    """The paper's question at ``time_s``: ``first``, the smallest setting whose paired interval is not wholly
    below 0 (None: none, or no intervals); ``closest``, the setting with the highest mean difference."""

    time_s: float
    sweep: SweepGroup
    matched: str
    matched_time_s: float
    rows: tuple[Match, ...]
    intervals: bool
    first: Match | None
    closest: Match | None


def match_answers(table: EpisodeTable, frontier: Frontier, key: str = SCORE_KEY) -> list[MatchAnswer]:
    """The paper's question (module docstring) on ``frontier``'s task, per :data:`SWEPT` sweep and question time;
    empty without such a sweep or a :data:`MATCHED` planner there."""
    matched = resolve_reference(MATCHED, [p.planner for p in frontier.points])
    if matched is None:
        return []
    out = []
    for sweep in (s for s in frontier.sweeps if s.name == SWEPT):
        for t in question_times(frontier.times):
            rows = []
            for value, spec in sweep.points:
                d = paired(table, frontier.task, spec, matched, t, key)
                if d is not None:
                    rows.append(Match(spec, value, d, frontier.point(spec).decision_time_s))
            if not rows:
                continue
            intervals = all(r.difference[1] is not None for r in rows)
            first = next((r for r in rows if r.difference[2] >= 0), None) if intervals else None
            closest = max(rows, key=lambda r: r.difference[0])
            out.append(MatchAnswer(t, sweep, matched, frontier.point(matched).decision_time_s, tuple(rows),
                                   intervals, first, closest))
    return out


@dataclass(frozen=True)
class Headroom:
    """At ``time_s``: the best planner that does not read the truth and its share of the oracle's headroom over the
    reference, (best - reference) / (oracle - reference), means over the episodes the three share (None: the oracle
    is not above the reference)."""

    time_s: float
    best: str
    best_mean: float
    reference_mean: float
    oracle_mean: float
    share: float | None


def headroom(table: EpisodeTable, frontier: Frontier, key: str = SCORE_KEY) -> list[Headroom]:
    """Per report time, the share of :data:`HEADROOM`'s headroom over the reference that the best planner reaches;
    empty without a reference or an oracle on the task."""
    names = [p.planner for p in frontier.points]
    oracle, ref = resolve_reference(HEADROOM, names), frontier.reference
    if oracle is None or ref is None:
        return []
    out = []
    for t in frontier.times:
        base = set(table.by_seed(frontier.task, ref, t, key)) & set(table.by_seed(frontier.task, oracle, t, key))
        best = None
        for p in (n for n in names if not is_reference(n)):
            mine = table.by_seed(frontier.task, p, t, key)
            seeds = sorted(base & set(mine))
            if not seeds:
                continue
            means = [float(np.mean([table.by_seed(frontier.task, q, t, key)[s] for s in seeds]))
                     for q in (p, ref, oracle)]
            if best is None or means[0] - means[1] > best[1][0] - best[1][1]:
                best = (p, means)
        if best is None:
            continue
        p, (mine, theirs, top) = best
        share = (mine - theirs) / (top - theirs) if top - theirs > 1e-9 else None
        out.append(Headroom(t, p, mine, theirs, top, share))
    return out


__all__ = ["HEADROOM", "MATCHED", "QUESTION_TIMES", "SWEPT", "Frontier", "Headroom", "Match", "MatchAnswer", "Point",
           "SweepGroup", "headroom", "infer_sweeps", "match_answers", "pareto_front", "question_times",
           "settings_of", "task_frontier"]
