"""The report's per-task tables in markdown: cells, the layout of the paper's Table I, the paired
comparisons, what more UAVs buy, and the absolute values at the end of the mission.

Every cell is the mean over episodes with a 95% percentile bootstrap interval
(:func:`~ipp_bench.eval.aggregate.bootstrap_ci`; with one episode there is no interval, and the
report says so). The best mean per task and column is in bold: the highest reduction, the lowest
runtime per decision (means equal at the printed precision are all bold). Rows of the reference
planners that read the truth (:data:`~ipp_bench.planners.REFERENCE_PLANNERS`, the ``oracle``) are
shown apart, below a marker row, and never bold.

A paired cell is one planner minus another on the episodes (seeds) both flew: the mean difference,
its 95% paired bootstrap interval and the episodes won.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..envs import short_task_id
from ..planners import is_reference
from .aggregate import BOOTSTRAP_METHOD, LEVEL, bootstrap_ci
from .tables import EpisodeTable, ordered, team_pairs

NO_INTERVAL = "no interval: 1 episode"
#: the marker row above the reference rows of the table
REFERENCE_MARKER = "*reference, knows the true ROI (not a planner a robot can run; never ranked):*"
REDUCTIONS = (("uncertainty_reduction_pct", "Uncertainty reduction"), ("rmse_reduction_pct", "RMSE reduction"))


def _pct(x: float) -> str:
    return f"{x:.1f}"


def _milliseconds(x: float) -> str:
    """A time in seconds written in ms, three significant digits without exponent: 3940, 12.3, 0.0210."""
    x = 1000.0 * x
    if x <= 0 or not math.isfinite(x):
        return f"{x:g}"
    digits = max(0, 2 - math.floor(math.log10(x)))
    return f"{x:.{digits}f}"


def _best(means: dict[str, float], fmt, lowest: bool) -> set[str]:
    means = {p: m for p, m in means.items() if math.isfinite(m)}  # a mean that is not a number is never best
    if not means:
        return set()
    target = min(means.values()) if lowest else max(means.values())
    return {p for p, m in means.items() if fmt(m) == fmt(target)}


def _cell(stat: tuple[float, float | None, float | None] | None, fmt, unit: str, bold: bool) -> str:
    if stat is None:
        return "–"
    mean, low, high = stat
    head = f"{fmt(mean)}{unit}"
    if bold:
        head = f"**{head}**"
    if low is None:  # one episode: the report says once that such cells have no interval
        return head
    return f"{head} [{fmt(low)}, {fmt(high)}]"


def method_label(planner: str, published: frozenset[str] | set[str] = frozenset()) -> str:
    """The method cell: the spec, marked when the planner is a reference that reads the truth, and
    when its rows are a published board's."""
    text = f"`{planner}` (reference)" if is_reference(planner) else f"`{planner}`"
    return f"{text} (published)" if planner in published else text


def _difference_cell(mine: dict[int, float], theirs: dict[int, float], groups=None) -> str:
    """``mine`` minus ``theirs`` on the seeds both have: mean [paired interval], episodes won / paired.
    ``groups(seeds)``: the networks of a method among the two per seed (its interval is then two-level)."""
    seeds = sorted(set(mine) & set(theirs))
    if not seeds:
        return "–"
    d = np.array([mine[s] - theirs[s] for s in seeds])
    mean, low, high = bootstrap_ci(d, groups=groups(seeds) if groups else None)
    interval = "" if low is None else f" [{low:+.1f}, {high:+.1f}]"
    return f"{mean:+.1f}{interval}, won {int(np.sum(d > 0))}/{len(seeds)}"


def paired_table(table: EpisodeTable, reference: str, key: str = "uncertainty_reduction_pct") -> str:
    """Each planner minus ``reference`` on the same episodes (seeds), per task and report time:
    mean difference [95% paired bootstrap interval], episodes won / episodes paired."""
    return _pairs_table(table, [(p, reference) for p in ordered(table.planners) if p != reference], key, 0)


def versus_table(table: EpisodeTable, planner: str, key: str = "uncertainty_reduction_pct") -> str:
    """``planner`` minus each other planner on the same episodes, per task and report time (the
    Method column names the other planner)."""
    return _pairs_table(table, [(planner, p) for p in ordered(table.planners) if p != planner], key, 1)


def _pairs_table(table: EpisodeTable, pairs: Sequence[tuple[str, str]], key: str, named: int) -> str:
    """Rows ``a - b`` for each pair, labelled by ``pair[named]``."""
    times = table.all_times()
    header = ["Environment", "Method"] + [f"{t:g} s" for t in times]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join([":--", ":--"] + ["--:"] * len(times)) + "|"]
    for task in table.tasks:
        first = True
        for a, b in pairs:
            if not table.episodes(task, a) or not table.episodes(task, b):
                continue
            row = [f"**{short_task_id(task)}**" if first else "", method_label((a, b)[named], table.published)]
            first = False
            row += [_difference_cell(table.by_seed(task, a, t, key), table.by_seed(task, b, t, key),
                                     lambda seeds, a=a, b=b: table.groups(a, seeds, b)) for t in times]
            lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def team_section(table: EpisodeTable, key: str = "uncertainty_reduction_pct") -> str:
    """What more UAVs buy: each planner's team rows minus its single-UAV rows on the same seeds, at equal
    flight time (n UAVs at t against one UAV at n t) and at equal mission time; empty without a pair."""
    parts = []
    for single, team, n in team_pairs(table.tasks):
        times_team, times_single = table.times.get(team, []), table.times.get(single, [])
        flight = [t for t in times_team if any(abs(n * t - u) < 1e-9 for u in times_single)]
        same = [t for t in times_team if t in times_single]
        planners = [p for p in ordered(table.planners) if table.episodes(team, p) and table.episodes(single, p)]
        if not planners or not (flight or same):
            continue
        header = (["Method"] + [f"{n} UAVs at {t:g} s - one at {n * t:g} s" for t in flight]
                  + [f"{n} UAVs - one, at {t:g} s" for t in same])
        lines = ["| " + " | ".join(header) + " |", "|:--" + "|--:" * (len(header) - 1) + "|"]
        for p in planners:
            groups = lambda seeds, p=p: table.groups(p, seeds)  # noqa: E731
            cells = [_difference_cell(table.by_seed(team, p, t, key), table.by_seed(single, p, n * t, key), groups)
                     for t in flight]
            cells += [_difference_cell(table.by_seed(team, p, t, key), table.by_seed(single, p, t, key), groups)
                      for t in same]
            lines.append("| " + " | ".join([method_label(p, table.published)] + cells) + " |")
        parts += [
            f"## What {n} UAVs buy: `{short_task_id(team)}` minus `{short_task_id(single)}`, on the same episodes",
            "",
            (f"Each planner's uncertainty reduction with {n} UAVs minus its own with one UAV, paired by seed (a seed "
             f"plays the same field, the same first start and camera noise on both tasks): mean in percentage "
             f"points [{LEVEL:.0%} paired {BOOTSTRAP_METHOD} bootstrap interval], episodes the team did better. "
             f"Equal flight time: by t the {n} UAVs have flown {n} t seconds, what one UAV flies by {n} t. A "
             "team-aware planner's single-UAV rows are its single-UAV counterpart's."),
            "",
            "\n".join(lines) + "\n",
        ]
    return "\n".join(parts)


def markdown_table(table: EpisodeTable) -> str:
    """Table I layout: one row per (task, planner); reductions at each report time; runtime."""
    times = table.all_times()
    header = ["Environment", "Method"]
    for _, label in REDUCTIONS:
        header += [f"{label} {t:g} s" if i == 0 else f"{t:g} s" for i, t in enumerate(times)]
    header.append("Runtime per decision [ms]")
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join([":--", ":--"] + ["--:"] * (len(header) - 2)) + "|"]
    for task in table.tasks:
        planners = [p for p in ordered(table.planners) if table.episodes(task, p)]
        ranked = [p for p in planners if not is_reference(p)]  # references are never "best"
        best: dict[tuple[str, float], set[str]] = {}
        for key, _ in REDUCTIONS:
            for t in times:
                means = {p: s[0] for p in ranked if (s := table.stat(task, p, t, key))}
                best[(key, t)] = _best(means, _pct, lowest=False)
        runtime_means = {p: s[0] for p in ranked if (s := table.runtime_stat(task, p))}
        best_runtime = _best(runtime_means, _milliseconds, lowest=True)
        for i, planner in enumerate(planners):
            if is_reference(planner) and (i == 0 or not is_reference(planners[i - 1])):
                lines.append("| " + " | ".join(["", REFERENCE_MARKER] + [""] * (len(header) - 2)) + " |")
            row = [f"**{short_task_id(task)}**" if i == 0 else "", method_label(planner, table.published)]
            for key, _ in REDUCTIONS:
                for t in times:
                    row.append(_cell(table.stat(task, planner, t, key), _pct, "%", planner in best[(key, t)]))
            row.append(_cell(table.runtime_stat(task, planner), _milliseconds, "", planner in best_runtime))
            lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def final_table(table: EpisodeTable) -> str:
    """ROI trace and RMSE (absolute) at each task's last report time, and decisions per episode."""
    lines = ["| Environment | Method | Time [s] | ROI trace | ROI RMSE | Episodes |",
             "|:--|:--|--:|--:|--:|--:|"]
    for task in table.tasks:
        if not table.times.get(task):
            continue
        t = table.times[task][-1]
        for i, planner in enumerate(p for p in ordered(table.planners) if table.episodes(task, p)):
            trace = table.stat(task, planner, t, "trace_roi")
            rmse = table.stat(task, planner, t, "rmse_roi")
            lines.append("| " + " | ".join([
                f"**{short_task_id(task)}**" if i == 0 else "", method_label(planner, table.published), f"{t:g}",
                _cell(trace, lambda x: f"{x:.3g}", "", False), _cell(rmse, lambda x: f"{x:.3f}", "", False),
                str(table.episodes(task, planner))]) + " |")
    return "\n".join(lines) + "\n"


__all__ = ["NO_INTERVAL", "REDUCTIONS", "REFERENCE_MARKER", "final_table", "markdown_table", "method_label",
           "paired_table", "team_section", "versus_table"]
