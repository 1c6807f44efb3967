"""The leaderboard's report: the aggregate over the tasks, a markdown table in the layout of the
paper's Table I, paired comparisons, the power rule, and PNG plots.

Everything is computed from ``results.csv`` alone (:func:`write_report`; in a folder paired with a
published board, with that board's rows beside it), so a report can be made again from a results
file at any time. Every cell is the mean over episodes with a 95% percentile bootstrap interval
(:func:`bootstrap_ci`: ``scipy.stats.bootstrap``, 2000 resamples, fixed seed, so the same CSV
always gives the same report; with one episode there is no interval, and the report says so). The
best mean per task and column is in bold: the highest reduction, the lowest runtime per decision
(means equal at the printed precision are all bold).

The report opens with the aggregate over the tasks (:func:`aggregate_section`, numbers from
:mod:`ipp_bench.eval.aggregate`): each planner's interquartile mean of the normalised score (the
share of the way from ``random`` to ``oracle`` per task and report time) with its stratified
bootstrap interval and rank, ties shown; the performance profile; the probability of improvement
of each planner over each other. A quick board says there that its intervals are wide.

The paired comparison (:func:`paired_table`) sets each planner against a reference planner
(``--reference``, default ``greedy``) on the same episodes: per task and report time, the mean
difference of the reduction, its 95% paired bootstrap interval and the episodes won. Planners
flown against a published board are also set against each of its planners (:func:`versus_table`);
the published rows are marked. The power rule (:func:`power_section`) gives, per task and report
time, the sd of the paired differences, the half-width reached and the episodes a paired interval
within +-3 points (``--power``) needs.

Rows of the suite's reference planners that read the truth (:data:`~ipp_bench.planners.REFERENCE_PLANNERS`,
the ``oracle``) are shown apart, below a marker row, and never bold or ranked: they show the room
that knowing the true ROI opens, not a result a robot can reach. When one ran, a second paired
table gives every planner's distance to it.

Files written:

``leaderboard.md``
    the aggregate; rows = (task, planner), columns = uncertainty reduction and RMSE reduction at
    each report time and the runtime per decision (the mean of each episode's mean decision time);
    then the paired comparisons, the power rule, and the absolute values at the end of the mission.
``performance_profile.png``
    per planner, the fraction of episodes whose normalised score is above tau, with a 95% band.
``curves_<task>.png``
    ROI trace and ROI RMSE over mission time per planner: mean with a shaded 95% band.
``runtime_per_decision.png``
    runtime per decision per planner and task (log scale, 95% interval whiskers).

Plots use matplotlib's Agg canvas through :class:`matplotlib.figure.Figure` (no pyplot, no
display, no global backend switch). Without matplotlib (a core-only install) the report is the
markdown alone, with a note naming the extra that adds the plots.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.data import write_atomically
from ..core.mission import REPORT_KEYS
from ..envs import short_task_id
from ..planners import is_reference
from . import aggregate as agg_stats
from .aggregate import BOOTSTRAP_METHOD, BOOTSTRAP_SEED, LEVEL, N_RESAMPLES, POWER_HALF_WIDTH, bootstrap_ci
from .results import PUBLISHED_CSV, read_results

DEFAULT_REFERENCE = "greedy"
NO_INTERVAL = "no interval: 1 episode"
#: the marker row above the reference rows of the table
REFERENCE_MARKER = "*reference, knows the true ROI (not a planner a robot can run; never ranked):*"

REDUCTIONS = (("uncertainty_reduction_pct", "Uncertainty reduction"), ("rmse_reduction_pct", "RMSE reduction"))
CURVES = (("trace_roi", "ROI trace of the covariance"), ("rmse_roi", "ROI RMSE"))
PROFILE_PNG = "performance_profile.png"


short_task = short_task_id


class Aggregate:
    """Per-episode values grouped by (task, planner[, time]) from results.csv rows."""

    def __init__(self, rows: Sequence[dict[str, Any]], tasks: Sequence[str] | None = None,
                 planners: Sequence[str] | None = None, published: Sequence[str] = ()):
        self.rows = list(rows)
        #: planners whose rows were copied from a published board (``--against``), not flown here
        self.published = frozenset(published)
        self.tasks = list(tasks) if tasks else list(dict.fromkeys(r["task"] for r in rows))
        self.planners = list(planners) if planners else list(dict.fromkeys(r["planner"] for r in rows))
        self.values: dict[tuple[str, str, float, str], list[float]] = defaultdict(list)
        self.runtime: dict[tuple[str, str], dict[int, float]] = defaultdict(dict)
        self.times: dict[str, list[float]] = defaultdict(list)
        self.seeds: dict[tuple[str, str], set[int]] = defaultdict(set)
        self._by_seed: dict[tuple[str, str, float, str], dict[int, float]] = defaultdict(dict)
        for r in rows:
            task, planner, t = r["task"], r["planner"], float(r["time_s"])
            for key in REPORT_KEYS:
                self.values[(task, planner, t, key)].append(float(r[key]))
                self._by_seed[(task, planner, t, key)][int(r["seed"])] = float(r[key])
            self.runtime[(task, planner)][int(r["seed"])] = float(r["decision_time_mean_s"])
            self.seeds[(task, planner)].add(int(r["seed"]))
            if t not in self.times[task]:
                self.times[task].append(t)
        for task in self.times:
            self.times[task].sort()

    def stat(self, task: str, planner: str, time_s: float, key: str) -> tuple[float, float, float] | None:
        v = self.values.get((task, planner, time_s, key))
        return bootstrap_ci(v) if v else None

    def by_seed(self, task: str, planner: str, time_s: float, key: str) -> dict[int, float]:
        """Per-episode values keyed by seed (for pairing planners on the same episodes)."""
        return dict(self._by_seed.get((task, planner, time_s, key), {}))

    def runtime_stat(self, task: str, planner: str) -> tuple[float, float, float] | None:
        v = self.runtime.get((task, planner))
        return bootstrap_ci(list(v.values())) if v else None

    def all_times(self) -> list[float]:
        return sorted({t for task in self.tasks for t in self.times.get(task, [])})

    def episodes(self, task: str, planner: str) -> int:
        return len(self.seeds.get((task, planner), ()))


# --------------------------------------------------------------------------------------------------
# markdown
# --------------------------------------------------------------------------------------------------
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


def resolve_reference(reference: str, planners: Sequence[str]) -> str | None:
    """The planner spec among ``planners`` that ``reference`` names (a spec, or a name when exactly
    one spec of that planner ran), or None."""
    if reference in planners:
        return reference
    named = [p for p in planners if p.partition(":")[0] == reference]
    return named[0] if len(named) == 1 else None


def _label(planner: str, published: frozenset[str] | set[str] = frozenset()) -> str:
    """The method cell: the spec, marked when the planner is a reference that reads the truth, and
    when its rows are a published board's."""
    text = f"`{planner}` (reference)" if is_reference(planner) else f"`{planner}`"
    return f"{text} (published)" if planner in published else text


def ordered(planners: Sequence[str]) -> list[str]:
    """``planners`` with the references that read the truth moved to the end (order kept otherwise)."""
    return [p for p in planners if not is_reference(p)] + [p for p in planners if is_reference(p)]


def _paired_cell(agg: Aggregate, task: str, planner: str, other: str, t: float, key: str) -> str:
    """``planner`` minus ``other`` on the seeds both flew: mean [interval], episodes won / paired."""
    mine, theirs = agg.by_seed(task, planner, t, key), agg.by_seed(task, other, t, key)
    seeds = sorted(set(mine) & set(theirs))
    if not seeds:
        return "–"
    d = np.array([mine[s] - theirs[s] for s in seeds])
    mean, low, high = bootstrap_ci(d)
    won = int(np.sum(d > 0))
    interval = "" if low is None else f" [{low:+.1f}, {high:+.1f}]"
    return f"{mean:+.1f}{interval}, won {won}/{len(seeds)}"


def paired_table(agg: Aggregate, reference: str, key: str = "uncertainty_reduction_pct") -> str:
    """Each planner minus ``reference`` on the same episodes (seeds), per task and report time:
    mean difference [95% paired bootstrap interval], episodes won / episodes paired."""
    return _pairs_table(agg, [(p, reference) for p in ordered(agg.planners) if p != reference], key, 0)


def versus_table(agg: Aggregate, planner: str, key: str = "uncertainty_reduction_pct") -> str:
    """``planner`` minus each other planner on the same episodes, per task and report time (the
    Method column names the other planner)."""
    return _pairs_table(agg, [(planner, p) for p in ordered(agg.planners) if p != planner], key, 1)


def _pairs_table(agg: Aggregate, pairs: Sequence[tuple[str, str]], key: str, named: int) -> str:
    """Rows ``a - b`` for each pair, labelled by ``pair[named]``."""
    times = agg.all_times()
    header = ["Environment", "Method"] + [f"{t:g} s" for t in times]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join([":--", ":--"] + ["--:"] * len(times)) + "|"]
    for task in agg.tasks:
        first = True
        for a, b in pairs:
            if not agg.episodes(task, a) or not agg.episodes(task, b):
                continue
            row = [f"**{short_task(task)}**" if first else "", _label((a, b)[named], agg.published)]
            first = False
            row += [_paired_cell(agg, task, a, b, t, key) for t in times]
            lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def team_pairs(tasks: Sequence[str]) -> list[tuple[str, str, int]]:
    """(single-UAV task, team task, UAVs) for every team task among ``tasks`` whose single-UAV task (the
    same configuration: field family, prior, camera, roadmap, budget, report times, seeds) is there too."""
    from ..core.team import TeamConfig
    from ..envs.registry import TASKS

    out = []
    for team in tasks:
        spec = TASKS.get(team)
        if spec is None or not spec.is_team:
            continue
        for single in tasks:
            other = TASKS.get(single)
            if other is not None and not other.is_team and other.config == spec.config:
                out.append((single, team, TeamConfig.from_dict(spec.team).size))
    return out


def _cross_cell(agg: Aggregate, a: tuple[str, float], b: tuple[str, float], planner: str, key: str) -> str:
    """``planner`` on task a at time a minus on task b at time b, paired by seed: mean [interval], won."""
    mine, theirs = agg.by_seed(a[0], planner, a[1], key), agg.by_seed(b[0], planner, b[1], key)
    seeds = sorted(set(mine) & set(theirs))
    if not seeds:
        return "–"
    d = np.array([mine[s] - theirs[s] for s in seeds])
    mean, low, high = bootstrap_ci(d)
    interval = "" if low is None else f" [{low:+.1f}, {high:+.1f}]"
    return f"{mean:+.1f}{interval}, won {int(np.sum(d > 0))}/{len(seeds)}"


def team_section(agg: Aggregate, key: str = "uncertainty_reduction_pct") -> str:
    """What more UAVs buy: each planner's team rows minus its single-UAV rows on the same seeds, at equal
    flight time (n UAVs at t against one UAV at n t) and at equal mission time; empty without a pair."""
    parts = []
    for single, team, n in team_pairs(agg.tasks):
        times_team, times_single = agg.times.get(team, []), agg.times.get(single, [])
        flight = [t for t in times_team if any(abs(n * t - u) < 1e-9 for u in times_single)]
        same = [t for t in times_team if t in times_single]
        planners = [p for p in ordered(agg.planners) if agg.episodes(team, p) and agg.episodes(single, p)]
        if not planners or not (flight or same):
            continue
        header = (["Method"] + [f"{n} UAVs at {t:g} s - one at {n * t:g} s" for t in flight]
                  + [f"{n} UAVs - one, at {t:g} s" for t in same])
        lines = ["| " + " | ".join(header) + " |", "|:--" + "|--:" * (len(header) - 1) + "|"]
        for p in planners:
            cells = [_cross_cell(agg, (team, t), (single, n * t), p, key) for t in flight]
            cells += [_cross_cell(agg, (team, t), (single, t), p, key) for t in same]
            lines.append("| " + " | ".join([_label(p, agg.published)] + cells) + " |")
        parts += [
            f"## What {n} UAVs buy: `{short_task(team)}` minus `{short_task(single)}`, on the same episodes",
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


# --------------------------------------------------------------------------------------------------
# the aggregate over the benchmark tasks, and the power rule
# --------------------------------------------------------------------------------------------------
def _estimate_cell(e: tuple[float, float, float], digits: int = 2) -> str:
    return f"{e[0]:.{digits}f} [{e[1]:.{digits}f}, {e[2]:.{digits}f}]"


def aggregate_estimates(agg: Aggregate) -> tuple[agg_stats.Board, agg_stats.AggregateEstimates | None]:
    """The normalised board of ``agg``'s rows and its estimates (None: nothing to aggregate)."""
    board = agg_stats.normalised_board(agg.rows, planners=agg.planners, tasks=agg.tasks)
    if not board.blocks or not board.planners:
        return board, None
    return board, agg_stats.estimate(board)


def _anchor_text(anchor: str) -> str:
    """An anchor as the report names it: a planner spec in code style, the default's words as they are."""
    return anchor if " rows)" in anchor else f"`{anchor}`"


def aggregate_section(agg: Aggregate, board: agg_stats.Board, est: agg_stats.AggregateEstimates | None,
                      profile_png: str | None = None) -> str:
    """The report's opening section: IQM of the normalised score per planner with its interval and
    rank (ties shown), the performance profile, and the probability of improvement of each pair."""
    parts = ["## Aggregate over the benchmark tasks", ""]
    if est is None:
        parts += ["No aggregate: no planner flew every task." if not board.planners else
                  "No aggregate: no task and report time could be normalised.", ""]
        parts += [f"Note: {n}" for n in board.notes] + ([""] if board.notes else [])
        return "\n".join(parts)
    tasks = ", ".join(short_task(t) for t in board.tasks)
    episodes = sorted({len(s) for s in board.seeds})
    n_text = str(episodes[0]) if len(episodes) == 1 else f"{episodes[0]} to {episodes[-1]}"
    names = [p for p in ordered(board.planners)]
    ranked = sorted((p for p in names if p in est.ranks), key=lambda p: (est.ranks[p], -est.iqm[p][0]))
    refs = [p for p in names if p not in est.ranks]
    counts = defaultdict(int)
    for p in ranked:
        counts[est.ranks[p]] += 1
    times = board.all_times
    header = ["Rank", "Method", "IQM, all report times"] + [f"IQM {t:g} s" if i == 0 else f"{t:g} s"
                                                           for i, t in enumerate(times)]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["--:", ":--"] + ["--:"] * (len(header) - 2)) + "|"]
    for p in ranked + refs:
        if p in est.ranks:
            rank = f"{est.ranks[p]}{'=' if counts[est.ranks[p]] > 1 else ''}"
        else:
            rank = "–"
        row = [rank, _label(p, agg.published), _estimate_cell(est.iqm[p])]
        row += [_estimate_cell(est.iqm_by_time[t][p]) for t in times]
        lines.append("| " + " | ".join(row) + " |")
    parts += ["\n".join(lines), ""]
    if profile_png:
        parts += [f"![performance profile]({profile_png})", ""]
    parts += [
        (f"Score: per task and report time, an episode's uncertainty reduction as the share of the way from "
        f"{_anchor_text(board.lower)} (0) to {_anchor_text(board.upper)} (1), both anchors the means over this "
        "board's episodes of that task and time (the anchors of a published board stay fixed when a planner is "
        "compared against it). "
        "Raw percentages do not pool: a 15 x 15 map saturates near 97 % while the best planner on a 30 x 30 map "
        "is below 50 % at 100 s; the normalised score puts every task and time on the scale of the room between "
        f"flying without a plan and knowing where the region of interest lies. Over {len(board.tasks)} tasks "
        f"({tasks}) and their report times, {n_text} episodes each."),
        "",
        (f"IQM: the interquartile mean (the mean of the middle 50 %) of the scores of every episode at every task "
        f"and report time; in brackets its {est.level:.0%} stratified bootstrap interval (percentile, "
        f"{est.n_resamples} resamples, seed {BOOTSTRAP_SEED}): episodes are resampled with replacement within each "
        "task, the same episodes for every planner and report time (every planner flew the same seeds). Rank: 1 + "
        "the number of planners whose probability of improvement over this one has an interval above 0.5; planners "
        "with the same rank are tied (marked =): the data cannot separate them. Definitions as rliable's "
        "(Agarwal et al. 2021; `ipp_bench.eval.aggregate`)."),
        "",
    ]
    taus = est.taus
    shown = [t for t in agg_stats.PROFILE_MARKS if np.any(np.isclose(taus, t))]
    at = {t: int(np.argmin(np.abs(taus - t))) for t in shown}
    prof = {p: {t: tuple(float(v[at[t]]) for v in est.profile[p]) for t in shown} for p in names}
    parts += [
        "Performance profile: the fraction of episodes (over every task and report time) whose score is above "
        f"tau, with its {est.level:.0%} stratified bootstrap interval"
        + (f" (the plot `{profile_png}` draws every tau)." if profile_png else "."),
        "",
        "| Method | " + " | ".join(f"score > {t:g}" for t in shown) + " |",
        "|:--|" + "|".join(["--:"] * len(shown)) + "|",
    ]
    parts += ["| " + " | ".join([_label(p, agg.published)] + [_estimate_cell(prof[p][t]) for t in shown]) + " |"
              for p in ranked + refs]
    parts += [
        "",
        ("Probability of improvement P(row > column): per task and report time, the chance that an episode of the "
        "row planner scores higher than an episode of the column planner (ties count a half; every pair of "
        "episodes, as rliable's Mann-Whitney estimate), averaged over tasks and report times; in brackets its "
        f"{est.level:.0%} stratified bootstrap interval. Bold: the interval lies above 0.5 (the row planner is "
        "ahead); an interval that holds 0.5 leaves the pair tied."),
        "",
    ]
    order = ranked + refs
    header = ["P(row > column)"] + [f"`{p}`" for p in order]
    lines = ["| " + " | ".join(header) + " |", "|:--|" + "|".join(["--:"] * len(order)) + "|"]
    for x in order:
        row = [_label(x, agg.published)]
        for y in order:
            if x == y:
                row.append("–")
                continue
            e = est.poi[(x, y)]
            cell = _estimate_cell(e)
            row.append(f"**{cell}**" if e[1] > 0.5 else cell)
        lines.append("| " + " | ".join(row) + " |")
    parts += ["\n".join(lines), ""]
    parts += [f"Note: {n}" for n in board.notes] + ([""] if board.notes else [])
    return "\n".join(parts)


def power_section(agg: Aggregate, reference: str, half_width: float = POWER_HALF_WIDTH) -> str:
    """The power rule's table: per task and report time, the largest sd of a paired difference
    (planner minus ``reference``), the episodes, the largest half-width reached and the episodes
    the rule asks for; then the count per task."""
    cells = agg_stats.power_rule(agg.rows, reference, half_width)
    if not cells:
        return ""
    by_time: dict[tuple[str, float], list[agg_stats.PowerCell]] = defaultdict(list)
    for c in cells:
        by_time[(c.task, c.time_s)].append(c)
    parts = [
        f"## Episodes for a ±{half_width:g}-point paired interval (the power rule)",
        "",
        (f"For every planner minus `{reference}` ({REDUCTIONS[0][1].lower()}), a task needs "
        f"n = ceil((1.96 sd / {half_width:g})^2) episodes for a paired {LEVEL:.0%} interval of half-width at "
        f"most {half_width:g} points, sd the standard deviation of the paired difference over this board's "
        "episodes; the task's count is the largest over planners and report times. Half-width reached: of the "
        "paired bootstrap interval above (the larger side). The sd is itself estimated, roughly from few "
        "episodes: apply the rule again on the bigger board (`ipp-bench power DIR`) and extend it while a "
        "half-width is above the target (seeds are prefix-stable: only the new episodes fly). The percentile "
        "bootstrap interval is about sqrt((n - 1) / n) times the normal one, so it reaches the target at n "
        "episodes or a little before."),
        "",
        ("| Environment | Time [s] | Episodes | Largest sd of a paired difference | Largest half-width reached "
        "| Episodes needed |"),
        "|:--|--:|--:|--:|--:|--:|",
    ]
    last = None
    for (task, t), cs in by_time.items():
        sd = max(cs, key=lambda c: c.sd if math.isfinite(c.sd) else -1.0)
        hw = [c for c in cs if c.half_width is not None]
        widest = max(hw, key=lambda c: c.half_width) if hw else None
        need = max(cs, key=lambda c: c.needed)
        parts.append("| " + " | ".join([
            f"**{short_task(task)}**" if task != last else "", f"{t:g}", str(max(c.episodes for c in cs)),
            f"{sd.sd:.1f} (`{sd.planner}`)" if math.isfinite(sd.sd) else "–",
            f"{widest.half_width:.1f} (`{widest.planner}`)" if widest else "–",
            f"{need.needed}"]) + " |")
        last = task
    parts += ["", ("| Environment | Episodes flown | Episodes needed | Set by | Every half-width within "
              f"±{half_width:g} |"), "|:--|--:|--:|:--|:--|"]
    for task, c in agg_stats.needed_per_task(cells).items():
        flown = max(x.episodes for x in cells if x.task == task)
        within = all(x.half_width is not None and x.half_width <= half_width for x in cells if x.task == task)
        parts.append(f"| **{short_task(task)}** | {flown} | {c.needed} | `{c.planner}` at {c.time_s:g} s | "
                     f"{'yes' if within else 'no'} |")
    return "\n".join(parts) + "\n"


def markdown_table(agg: Aggregate) -> str:
    """Table I layout: one row per (task, planner); reductions at each report time; runtime."""
    times = agg.all_times()
    header = ["Environment", "Method"]
    for _, label in REDUCTIONS:
        header += [f"{label} {t:g} s" if i == 0 else f"{t:g} s" for i, t in enumerate(times)]
    header.append("Runtime per decision [ms]")
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join([":--", ":--"] + ["--:"] * (len(header) - 2)) + "|"]
    for task in agg.tasks:
        planners = [p for p in ordered(agg.planners) if agg.episodes(task, p)]
        ranked = [p for p in planners if not is_reference(p)]  # references are never "best"
        best: dict[tuple[str, float], set[str]] = {}
        for key, _ in REDUCTIONS:
            for t in times:
                means = {p: s[0] for p in ranked if (s := agg.stat(task, p, t, key))}
                best[(key, t)] = _best(means, _pct, lowest=False)
        runtime_means = {p: s[0] for p in ranked if (s := agg.runtime_stat(task, p))}
        best_runtime = _best(runtime_means, _milliseconds, lowest=True)
        for i, planner in enumerate(planners):
            if is_reference(planner) and (i == 0 or not is_reference(planners[i - 1])):
                lines.append("| " + " | ".join(["", REFERENCE_MARKER] + [""] * (len(header) - 2)) + " |")
            row = [f"**{short_task(task)}**" if i == 0 else "", _label(planner, agg.published)]
            for key, _ in REDUCTIONS:
                for t in times:
                    row.append(_cell(agg.stat(task, planner, t, key), _pct, "%", planner in best[(key, t)]))
            row.append(_cell(agg.runtime_stat(task, planner), _milliseconds, "", planner in best_runtime))
            lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def final_table(agg: Aggregate) -> str:
    """ROI trace and RMSE (absolute) at each task's last report time, and decisions per episode."""
    lines = ["| Environment | Method | Time [s] | ROI trace | ROI RMSE | Episodes |",
             "|:--|:--|--:|--:|--:|--:|"]
    for task in agg.tasks:
        if not agg.times.get(task):
            continue
        t = agg.times[task][-1]
        for i, planner in enumerate(p for p in ordered(agg.planners) if agg.episodes(task, p)):
            trace = agg.stat(task, planner, t, "trace_roi")
            rmse = agg.stat(task, planner, t, "rmse_roi")
            lines.append("| " + " | ".join([
                f"**{short_task(task)}**" if i == 0 else "", _label(planner, agg.published), f"{t:g}",
                _cell(trace, lambda x: f"{x:.3g}", "", False), _cell(rmse, lambda x: f"{x:.3f}", "", False),
                str(agg.episodes(task, planner))]) + " |")
    return "\n".join(lines) + "\n"


QUICK_NOTE = (
    "**Quick board**: {n} episodes per task and planner and cheaper look-ahead settings: its intervals are wide, "
    "and a bootstrap over so few episodes understates even those; it checks a set-up, not a ranking. For numbers "
    "to quote use the powered boards in "
    "`baselines/` (`baselines/README.md` lists them), or extend this folder with the episodes the power rule "
    "below asks for (`--episodes N` with the same command; the first seeds stay the same).")


def markdown_report(agg: Aggregate, command: str | None = None, quick: bool = False,
                    plots: Sequence[str] = (), reference: str | None = DEFAULT_REFERENCE,
                    notes: Sequence[str] = (), published_from: str | None = None,
                    power: float | None = POWER_HALF_WIDTH, profile_png: str | None = None,
                    estimates: tuple[agg_stats.Board, agg_stats.AggregateEstimates | None] | None = None,
                    made_on: Sequence[str] = ()) -> str:
    """The whole leaderboard.md.

    Args:
        published_from: the published board whose rows (``agg.published``) were copied in.
        power: the power rule's half-width target in points (None: no power section).
        profile_png: the performance-profile plot's file name, shown beside the aggregate.
        estimates: :func:`aggregate_estimates` of ``agg`` (computed when None).
        made_on: where the rows were made, one line per machine (run.json's ``machine``).
    """
    counts = sorted({agg.episodes(t, p) for t in agg.tasks for p in agg.planners if agg.episodes(t, p)})
    n_text = (" to ".join(str(c) for c in (counts[0], counts[-1])) if len(counts) > 1
              else str(counts[0] if counts else 0))
    parts = ["# ipp-bench leaderboard", ""]
    if command:
        parts += [f"Made with `{command}`" + (" (quick mode: few episodes, cheaper look-ahead)." if quick else "."), ""]
    if made_on:
        parts += [f"Made on {made_on[0]}" + (f"; rows also made on {len(made_on) - 1} other machine"
                                             f"{'s' if len(made_on) > 2 else ''} (run.json)." if len(made_on) > 1
                                             else "."), ""]
    if quick:
        parts += [QUICK_NOTE.format(n=n_text), ""]
    if counts and counts[0] == 1:
        parts += [(f"Every cell shows the mean alone ({NO_INTERVAL} per task and planner)." if len(counts) == 1
                   else f"A cell of one episode shows the mean alone ({NO_INTERVAL})."), ""]
    if agg.published:
        new = [p for p in agg.planners if p not in agg.published]
        parts += [
            f"Rows marked (published) are copied from the published board `{published_from or '?'}` "
            f"(its `results.csv`, kept here as `{PUBLISHED_CSV}`), not flown again; "
            + (", ".join(f"`{p}`" for p in new) or "no planner")
            + " flew its tasks, task configurations and episode seeds, so every row pairs with every published "
            "row episode by episode.", ""]
    if estimates is None:
        estimates = aggregate_estimates(agg)
    parts += [aggregate_section(agg, *estimates, profile_png=profile_png)]
    parts += ["## Per task", ""]
    legend = (
        f"Mean over {n_text} episodes per task and planner (every planner meets the same episode seeds), "
        f"with the {LEVEL:.0%} {BOOTSTRAP_METHOD} bootstrap interval of the mean in brackets "
        f"(scipy.stats.bootstrap, {N_RESAMPLES} resamples, seed {BOOTSTRAP_SEED}; one episode has no interval). "
        "Reductions are relative to the prior, over the region of interest. Bold: the best per task and column "
        "(highest reduction, lowest runtime). Runtime per decision: wall time of the planner's decision, "
        "mean over each episode's decisions, then over episodes.")
    truth_refs = [p for p in agg.planners if is_reference(p)]
    if truth_refs:
        legend += (
            " Rows marked (reference), below the marker row, read the ground truth's region of interest "
            "(`oracle`: greedy's rule scored on the true ROI); they are never bold and never ranked. They "
            "indicate the room that knowing where the ROI lies opens above the planners that cannot; they "
            "are no upper bound (a planner that looks further ahead can beat them).")
    parts += [legend, "", markdown_table(agg)]
    ref = resolve_reference(reference, agg.planners) if reference else None
    if ref is not None and len(agg.planners) > 1:
        for key, label in REDUCTIONS:
            parts += [
                f"## {label}: each planner minus `{ref}`, on the same episodes",
                "",
                (f"Mean difference in percentage points [{LEVEL:.0%} paired {BOOTSTRAP_METHOD} bootstrap interval], "
                f"and the episodes where the planner's reduction is higher than `{ref}`'s."),
                "",
                paired_table(agg, ref, key),
            ]
    elif reference:
        parts += [(f"No paired comparison: the reference planner `{reference}` is not among the planners "
                  "(pass --reference SPEC)."), ""]
    for oracle in truth_refs:
        if oracle == ref or len(agg.planners) < 2:
            continue
        for key, label in REDUCTIONS:
            parts += [
                f"## {label}: each planner minus `{oracle}` (the headroom reference), on the same episodes",
                "",
                (f"How far each planner is from `{oracle}`, which knows the true ROI: mean difference in percentage "
                f"points [{LEVEL:.0%} paired {BOOTSTRAP_METHOD} bootstrap interval], and the episodes where the "
                f"planner's reduction is higher than `{oracle}`'s."),
                "",
                paired_table(agg, oracle, key),
            ]
    for planner in (p for p in agg.planners if agg.published and p not in agg.published):
        for key, label in REDUCTIONS:
            parts += [
                f"## {label}: `{planner}` minus each other planner, on the same episodes",
                "",
                (f"Mean difference in percentage points [{LEVEL:.0%} paired {BOOTSTRAP_METHOD} bootstrap interval], "
                f"and the episodes where `{planner}`'s reduction is higher than the named planner's."),
                "",
                versus_table(agg, planner, key),
            ]
    teams = team_section(agg)
    if teams:
        parts += [teams]
    if ref is not None and power is not None:
        section = power_section(agg, ref, power)
        if section:
            parts += [section]
    parts += ["## Absolute values at the end of the mission", "", final_table(agg)]
    if notes:
        parts += [f"Note: {n}" for n in notes] + [""]
    if plots:
        parts += ["## Plots", ""] + [f"![{Path(p).stem}]({Path(p).name})" for p in plots] + [""]
    return "\n".join(parts)


# --------------------------------------------------------------------------------------------------
# plots
# --------------------------------------------------------------------------------------------------
def _figure(**kwargs):
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise ImportError('the leaderboard plots need matplotlib: pip install "ipp-bench[eval]"') from None
    return Figure(**kwargs)


def _colours(planners: Sequence[str]) -> dict[str, Any]:
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return {p: cmap(i % 10) for i, p in enumerate(planners)}


def plot_curves(agg: Aggregate, task: str, path: str | Path) -> Path:
    """ROI trace and RMSE over mission time for ``task``: mean per planner with a 95% band."""
    colours = _colours(agg.planners)
    fig = _figure(figsize=(10, 4), layout="constrained")
    axes = fig.subplots(1, len(CURVES))
    times = agg.times.get(task, [])
    for ax, (key, label) in zip(axes, CURVES):
        for planner in agg.planners:
            stats = [agg.stat(task, planner, t, key) for t in times]
            if not stats or any(s is None for s in stats):
                continue
            stats = [(m, m if lo is None else lo, m if hi is None else hi) for m, lo, hi in stats]  # 1 episode
            mean, low, high = (np.array(v) for v in zip(*stats))
            dashed = is_reference(planner)
            ax.plot(times, mean, marker="o", color=colours[planner], linestyle="--" if dashed else "-",
                    label=f"{planner} (reference, knows the true ROI)" if dashed else planner)
            ax.fill_between(times, low, high, color=colours[planner], alpha=0.2, linewidth=0)
        ax.set_xlabel("mission time [s]")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside right center", fontsize="small")  # not over data
    fig.suptitle(f"{short_task(task)}: mean and {LEVEL:.0%} bootstrap band over episodes")
    path = Path(path)
    write_atomically(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    return path


def plot_runtime(agg: Aggregate, path: str | Path) -> Path:
    """Runtime per decision per planner (bars per task, log scale, 95% interval whiskers)."""
    fig = _figure(figsize=(max(7.0, 0.8 * len(agg.planners) * max(1, len(agg.tasks))), 4),
                  layout="constrained")
    ax = fig.subplots()
    width = 0.8 / max(1, len(agg.tasks))
    x = np.arange(len(agg.planners))
    for j, task in enumerate(agg.tasks):
        stats = [agg.runtime_stat(task, p) for p in agg.planners]
        mean = np.array([s[0] if s else np.nan for s in stats])
        low = np.array([(s[0] if s[1] is None else s[1]) if s else np.nan for s in stats], dtype=float)
        high = np.array([(s[0] if s[2] is None else s[2]) if s else np.nan for s in stats], dtype=float)
        mean, low, high = 1000 * mean, 1000 * low, 1000 * high  # [ms]
        floor = 1e-4  # a log axis cannot show 0
        mean_c = np.maximum(mean, floor)
        err = np.vstack([mean_c - np.maximum(low, floor), np.maximum(high, floor) - mean_c])
        ax.bar(x + (j - (len(agg.tasks) - 1) / 2) * width, mean_c, width, yerr=err, capsize=3,
               label=short_task(task))
    ax.set_xticks(x, agg.planners, rotation=20, ha="right")
    ax.set_yscale("log")
    ax.set_ylabel("runtime per decision [ms]")
    ax.grid(axis="y", alpha=0.3)
    fig.legend(loc="outside right center", fontsize="small")  # beside the bars, never over them
    ax.set_title("Runtime per decision: mean over episodes, 95% bootstrap interval", fontsize="medium")
    path = Path(path)
    write_atomically(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    return path


def plot_profile(agg: Aggregate, est: agg_stats.AggregateEstimates, path: str | Path,
                 lower: str = agg_stats.LOWER_ANCHOR, upper: str = agg_stats.UPPER_ANCHOR) -> Path:
    """The performance profile: per planner, the fraction of episodes (every task and report time)
    whose normalised score is above tau, with its stratified bootstrap band (``lower``, ``upper``:
    the anchors, as the x label names them)."""
    colours = _colours(agg.planners)
    fig = _figure(figsize=(8, 4.5), layout="constrained")
    ax = fig.subplots()
    for planner in ordered(est.planners):
        point, low, high = est.profile[planner]
        dashed = is_reference(planner)
        label = planner + (" (reference, knows the true ROI)" if dashed else "") \
            + (" (published)" if planner in agg.published else "")
        ax.plot(est.taus, point, color=colours[planner], linestyle="--" if dashed else "-", label=label)
        ax.fill_between(est.taus, low, high, color=colours[planner], alpha=0.2, linewidth=0)
    ax.set_xlabel(f"normalised score tau (0: {lower}, 1: {upper}, per task and report time)")
    ax.set_ylabel("fraction of episodes with score > tau")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    fig.legend(*ax.get_legend_handles_labels(), loc="outside right center", fontsize="small")
    fig.suptitle(f"Performance profile over every task and report time, {est.level:.0%} stratified bootstrap band",
                 fontsize="medium")
    path = Path(path)
    write_atomically(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    return path


def write_report(results_csv: str | Path, out_dir: str | Path, tasks: Sequence[str] | None = None,
                 planners: Sequence[str] | None = None, command: str | None = None,
                 quick: bool = False, reference: str | None = DEFAULT_REFERENCE,
                 log: Callable[[str], None] | None = None, published_csv: str | Path | None = None,
                 published_from: str | None = None, power: float | None = POWER_HALF_WIDTH,
                 made_on: Sequence[str] = ()) -> list[Path]:
    """Write ``leaderboard.md``, ``performance_profile.png``, ``curves_<task>.png`` and
    ``runtime_per_decision.png`` from a results.csv.

    Without matplotlib the plots are left out, with a note in the report (and through ``log``).

    Args:
        published_csv: a published board's results.csv whose rows join the report, marked
            (published), before this run's planners (``--against``).
        published_from: the published board's folder, as the report names it.
        power: the power rule's half-width target in points (None: no power section).
        made_on: where the rows were made (one line per machine), said in one line at the top.

    Returns:
        The paths written.
    """
    out_dir = Path(out_dir)
    rows = read_results(results_csv)
    published: list[str] = []
    if published_csv is not None:
        theirs = read_results(published_csv)
        published = list(dict.fromkeys(r["planner"] for r in theirs))
        rows = theirs + rows
        if planners is not None:
            planners = published + [p for p in planners if p not in published]
    agg = Aggregate(rows, tasks, planners, published=published)
    estimates = aggregate_estimates(agg)
    written: list[Path] = []
    notes: list[str] = []
    profile_png = None
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        notes.append('the plots need matplotlib, which is not installed: pip install "ipp-bench[eval]"')
    else:
        if estimates[1] is not None:
            board = estimates[0]
            written.append(plot_profile(agg, estimates[1], out_dir / PROFILE_PNG, board.lower, board.upper))
            profile_png = PROFILE_PNG
        for task in agg.tasks:
            if agg.times.get(task):
                written.append(plot_curves(agg, task, out_dir / f"curves_{short_task(task).replace('/', '_')}.png"))
        if agg.runtime:
            written.append(plot_runtime(agg, out_dir / "runtime_per_decision.png"))
    if log is not None:
        for note in notes:
            log(f"note: {note}")
    md = out_dir / "leaderboard.md"
    text = markdown_report(agg, command, quick, [p.name for p in written if p.name != PROFILE_PNG], reference,
                           notes, published_from, power, profile_png, estimates, made_on)
    write_atomically(md, lambda tmp: tmp.write_text(text))
    return [md, *written]


__all__ = [
    "DEFAULT_REFERENCE",
    "Aggregate",
    "aggregate_estimates",
    "aggregate_section",
    "bootstrap_ci",
    "markdown_report",
    "markdown_table",
    "paired_table",
    "plot_curves",
    "plot_profile",
    "plot_runtime",
    "power_section",
    "versus_table",
    "write_report",
]
