"""The power rule: how many episodes a board needs for a paired interval of a given half-width.

For a paired 95 % interval of "planner minus reference" of
half-width at most ``h`` points at every report time, a task needs ``n = ceil((1.96 sd / h)^2)``
episodes, ``sd`` the standard deviation of the paired difference over the board's episodes (the
largest over planners and report times). Caveats: ``sd`` is itself estimated (a 3-episode board
gives a rough one: apply the rule again on the bigger board and extend it while a half-width is
still above ``h``; seeds are prefix-stable, so extending flies only the new episodes); the
report's percentile bootstrap interval is about ``sqrt((n - 1) / n)`` times the normal one, so it
reaches ``h`` at ``n`` episodes or a little before.

The report's section on it is :func:`ipp_bench.eval.markdown_stats.power_section`;
``ipp-bench power DIR`` applies it to a finished folder.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .aggregate import SCORE_KEY, bootstrap_ci

#: the normal quantile of a two-sided 95 % interval, as the power rule states it
Z95 = 1.96
#: [points] the default half-width target of the power rule
POWER_HALF_WIDTH = 3.0


@dataclass(frozen=True)
class PowerCell:
    """One planner minus the reference at one task and report time."""

    task: str
    time_s: float
    planner: str
    episodes: int
    sd: float  # [points] of the paired difference (ddof 1)
    half_width: float | None  # [points] of the bootstrap interval reached; None with one episode
    needed: int  # episodes the rule asks for
    low: float | None = None  # [points] the paired bootstrap interval of the mean difference; None with one episode
    high: float | None = None

    @property
    def decided(self) -> bool:
        """Whether the paired interval excludes 0: the board tells which of the two is ahead."""
        return self.low is not None and (self.low > 0 or self.high < 0)


def episodes_needed(sd: float, half_width: float) -> int:
    """``ceil((1.96 sd / h)^2)``, at least 2 (one episode has no interval)."""
    if not half_width > 0:
        raise ValueError(f"half-width = {half_width!r} is invalid: expected a number of points > 0")
    return max(2, math.ceil((Z95 * sd / half_width) ** 2 - 1e-9))


def paired_differences(rows: Iterable[dict[str, Any]], reference: str, key: str = SCORE_KEY
                       ) -> dict[tuple[str, float, str], np.ndarray]:
    """Per (task, time, planner), the planner's value minus ``reference``'s on each seed both flew."""
    by: dict[tuple[str, str, float], dict[int, float]] = defaultdict(dict)
    order: dict[tuple[str, float], list[str]] = defaultdict(list)
    for r in rows:
        cell = (r["task"], float(r["time_s"]))
        by[(r["task"], r["planner"], cell[1])][int(r["seed"])] = float(r[key])
        if r["planner"] not in order[cell]:
            order[cell].append(r["planner"])
    out = {}
    for (task, t), planners in order.items():
        ref = by.get((task, reference, t))
        if not ref:
            continue
        for p in planners:
            if p == reference:
                continue
            mine = by[(task, p, t)]
            seeds = sorted(set(mine) & set(ref))
            if seeds:
                out[(task, t, p)] = np.array([mine[s] - ref[s] for s in seeds])
    return out


def power_rule(rows: Iterable[dict[str, Any]], reference: str, half_width: float = POWER_HALF_WIDTH,
               key: str = SCORE_KEY, networks: Mapping[str, Mapping[int, int]] | None = None) -> list[PowerCell]:
    """The power rule (module docstring) for every planner minus ``reference``, task and report time.
    ``networks``: per method, each seed's network: its paired interval is the two-level bootstrap's."""
    rows = list(rows)
    networks = networks or {}
    flown: dict[tuple[str, float, str], list[int]] = defaultdict(list)
    for r in rows:
        flown[(r["task"], float(r["time_s"]), r["planner"])].append(int(r["seed"]))
    cells = []
    for (task, t, p), d in paired_differences(rows, reference, key).items():
        sd = float(np.std(d, ddof=1)) if d.size > 1 else float("nan")
        groups = None
        methods = [m for m in (p, reference) if m in networks]
        if methods:  # the seeds paired_differences pairs, in its order
            seeds = sorted(set(flown[(task, t, p)]) & set(flown[(task, t, reference)]))
            groups = [tuple(networks[m][s] for m in methods) for s in seeds]
        _, lo, hi = bootstrap_ci(d, groups=groups)
        reached = None if lo is None else float(max(d.mean() - lo, hi - d.mean()))
        needed = episodes_needed(sd, half_width) if math.isfinite(sd) else 2
        cells.append(PowerCell(task, t, p, int(d.size), sd, reached, needed, lo, hi))
    return cells


def undecided_below_count(cells: Iterable[PowerCell]) -> dict[str, dict[str, list[float]]]:
    """Per task flown with fewer episodes than the rule asks for, the planners whose paired interval
    with the reference holds 0 (or that have none), with those report times: the comparisons the board
    cannot decide. A comparison decided (its interval excludes 0) is decided however few the episodes."""
    cells = list(cells)
    short = {task for task, c in needed_per_task(cells).items()
             if max(x.episodes for x in cells if x.task == task) < c.needed}
    out: dict[str, dict[str, list[float]]] = {}
    for c in cells:
        if c.task in short and not c.decided:
            out.setdefault(c.task, {}).setdefault(c.planner, []).append(c.time_s)
    return out


def needed_per_task(cells: Iterable[PowerCell]) -> dict[str, PowerCell]:
    """Per task, the cell that asks for the most episodes (the task's count)."""
    out: dict[str, PowerCell] = {}
    for c in cells:
        if c.task not in out or c.needed > out[c.task].needed:
            out[c.task] = c
    return out


__all__ = ["POWER_HALF_WIDTH", "PowerCell", "episodes_needed", "needed_per_task", "paired_differences", "power_rule",
           "undecided_below_count"]
