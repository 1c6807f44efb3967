"""The report's sections of statistics over the board, in markdown: the aggregate over the
benchmark tasks and the power rule.

The aggregate (:func:`aggregate_section`, numbers from :mod:`ipp_bench.eval.aggregate`): each
planner's interquartile mean of the normalised score (the share of the way from ``random`` to
``oracle`` per task and report time) with its stratified bootstrap interval and rank, ties shown;
the performance profile; the probability of improvement of each planner over each other.

The power rule (:func:`power_section`, numbers from :mod:`ipp_bench.eval.power`): per task and report
time, the sd of the paired differences, the half-width reached and the episodes a paired interval
within +-3 points (``--power``) needs.
"""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np

from ..envs import short_task_id
from . import aggregate as agg_stats
from . import power
from .aggregate import BOOTSTRAP_SEED, LEVEL
from .markdown import REDUCTIONS, method_label
from .power import POWER_HALF_WIDTH
from .tables import EpisodeTable, ordered


def _estimate_cell(e: tuple[float, float | None, float | None], digits: int = 2) -> str:
    if e[1] is None:  # no interval (a task of one episode): the point alone
        return f"{e[0]:.{digits}f}"
    return f"{e[0]:.{digits}f} [{e[1]:.{digits}f}, {e[2]:.{digits}f}]"


def aggregate_estimates(table: EpisodeTable) -> tuple[agg_stats.Board, agg_stats.AggregateEstimates | None]:
    """The normalised board of ``table``'s rows and its estimates (None: nothing to aggregate)."""
    board = agg_stats.normalised_board(table.rows, planners=table.planners, tasks=table.tasks)
    if not board.blocks or not board.planners:
        return board, None
    return board, agg_stats.estimate(board, networks=table.networks)


def _anchor_text(anchor: str, score: int) -> str:
    """An anchor and its ``score`` as the report names them: a planner spec in code style, ```random` (0)``;
    a default (``0 % (no `random` rows)``) in words, ``a 0 % reduction (score 0; the board has no `random` rows)``."""
    if " rows)" not in anchor:
        return f"`{anchor}` ({score})"
    value, _, why = anchor.partition(" (")
    return f"a {value} reduction (score {score}; the board has {why.removesuffix(')')})"


def aggregate_section(table: EpisodeTable, board: agg_stats.Board, est: agg_stats.AggregateEstimates | None,
                      profile_png: str | None = None) -> str:
    """The report's opening section: IQM of the normalised score per planner with its interval and
    rank (ties shown), the performance profile, and the probability of improvement of each pair."""
    parts = ["## Aggregate over the benchmark tasks", ""]
    if est is None:
        parts += ["No aggregate: no planner flew every task." if not board.planners else
                  "No aggregate: no task and report time could be normalised.", ""]
        parts += [f"Note: {n}" for n in board.notes] + ([""] if board.notes else [])
        return "\n".join(parts)
    tasks = ", ".join(short_task_id(t) for t in board.tasks)
    episodes = sorted({len(s) for s in board.seeds})
    n_text = (f"{episodes[0]} episode{'s' if episodes[0] != 1 else ''}" if len(episodes) == 1
              else f"{episodes[0]} to {episodes[-1]} episodes")
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
        row = [rank, method_label(p, table.published), _estimate_cell(est.iqm[p])]
        row += [_estimate_cell(est.iqm_by_time[t][p]) for t in times]
        lines.append("| " + " | ".join(row) + " |")
    parts += ["\n".join(lines), ""]
    if profile_png:
        parts += [f"![performance profile]({profile_png})", ""]
    parts += [
        (f"Score: per task and report time, an episode's uncertainty reduction as the share of the way from "
        f"{_anchor_text(board.lower, 0)} to {_anchor_text(board.upper, 1)}, both anchors the means over this "
        "board's episodes of that task and time (the anchors of a published board stay fixed when a planner is "
        "compared against it). "
        "Raw percentages do not pool: a 15 x 15 map saturates near 97 % while the best planner on a 30 x 30 map "
        "is below 50 % at 100 s; the normalised score puts every task and time on the scale of the room between "
        f"flying without a plan and knowing where the region of interest lies. Over {len(board.tasks)} tasks "
        f"({tasks}) and their report times, {n_text} each."),
        "",
    ]
    if not est.intervals:
        one = [short_task_id(t) for t, s in zip(board.tasks, board.seeds) if len(s) < agg_stats.MIN_EPISODES]
        parts += [
            (f"No intervals, and no planner ranked or bold above another: {', '.join(one)} "
             f"{'has' if len(one) == 1 else 'have'} one "
             "episode, and a bootstrap of one episode draws it every time, a zero-width interval that would read as "
             "certainty. Every figure below is the point estimate alone, and every planner has rank 1 (tied): one "
             "episode cannot separate them. IQM: the interquartile mean (the mean of the middle 50 %) of the scores "
             "of every episode at every task and report time. Definitions as rliable's (Agarwal et al. 2021; "
             "`ipp_bench.eval.aggregate`)."),
            "",
        ]
    else:
        parts += [
            (f"IQM: the interquartile mean (the mean of the middle 50 %) of the scores of every episode at every task "
             f"and report time; in brackets its {est.level:.0%} stratified bootstrap interval (percentile, "
             f"{est.n_resamples} resamples, seed {BOOTSTRAP_SEED}): episodes are resampled with replacement within "
             "each task, the same episodes for every planner and report time (every planner flew the same seeds). "
             "Rank: 1 + the number of planners whose probability of improvement over this one has an interval above "
             "0.5; planners with the same rank are tied (marked =): the data cannot separate them. Definitions as "
             "rliable's (Agarwal et al. 2021; `ipp_bench.eval.aggregate`)."),
            "",
        ]
    with_interval = f", with its {est.level:.0%} stratified bootstrap interval" if est.intervals else ""
    taus = est.taus
    shown = [t for t in agg_stats.PROFILE_MARKS if np.any(np.isclose(taus, t))]
    at = {t: int(np.argmin(np.abs(taus - t))) for t in shown}
    prof = {p: {t: tuple(None if v is None else float(v[at[t]]) for v in est.profile[p]) for t in shown}
            for p in names}
    parts += [
        "Performance profile: the fraction of episodes (over every task and report time) whose score is above "
        f"tau{with_interval}" + (f" (the plot `{profile_png}` draws every tau)." if profile_png else "."),
        "",
        "| Method | " + " | ".join(f"score > {t:g}" for t in shown) + " |",
        "|:--|" + "|".join(["--:"] * len(shown)) + "|",
    ]
    parts += ["| " + " | ".join([method_label(p, table.published)] + [_estimate_cell(prof[p][t]) for t in shown]) + " |"
              for p in ranked + refs]
    parts += [
        "",
        ("Probability of improvement P(row > column): per task and report time, the chance that an episode of the "
        "row planner scores higher than an episode of the column planner (ties count a half; every pair of "
        "episodes, as rliable's Mann-Whitney estimate), averaged over tasks and report times"
        + (f"; in brackets its {est.level:.0%} stratified bootstrap interval. Bold: the interval lies above 0.5 (the "
           "row planner is ahead); an interval that holds 0.5 leaves the pair tied." if est.intervals else
           ". Without an interval nothing is bold: no pair is separated.")),
        "",
    ]
    order = ranked + refs
    header = ["P(row > column)"] + [f"`{p}`" for p in order]
    lines = ["| " + " | ".join(header) + " |", "|:--|" + "|".join(["--:"] * len(order)) + "|"]
    for x in order:
        row = [method_label(x, table.published)]
        for y in order:
            if x == y:
                row.append("–")
                continue
            e = est.poi[(x, y)]
            cell = _estimate_cell(e)
            row.append(f"**{cell}**" if e[1] is not None and e[1] > 0.5 else cell)
        lines.append("| " + " | ".join(row) + " |")
    parts += ["\n".join(lines), ""]
    parts += [f"Note: {n}" for n in board.notes] + ([""] if board.notes else [])
    return "\n".join(parts)


def power_section(table: EpisodeTable, reference: str, half_width: float = POWER_HALF_WIDTH) -> str:
    """The power rule's table: per task and report time, the largest sd of a paired difference
    (planner minus ``reference``), the episodes, the largest half-width reached and the episodes
    the rule asks for; then the count per task."""
    cells = power.power_rule(table.rows, reference, half_width, networks=table.networks)
    if not cells:
        return ""
    by_time: dict[tuple[str, float], list[power.PowerCell]] = defaultdict(list)
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
            f"**{short_task_id(task)}**" if task != last else "", f"{t:g}", str(max(c.episodes for c in cs)),
            f"{sd.sd:.1f} (`{sd.planner}`)" if math.isfinite(sd.sd) else "–",
            f"{widest.half_width:.1f} (`{widest.planner}`)" if widest else "–",
            f"{need.needed}"]) + " |")
        last = task
    parts += ["", ("| Environment | Episodes flown | Episodes needed | Set by | Every half-width within "
              f"±{half_width:g} |"), "|:--|--:|--:|:--|:--|"]
    for task, c in power.needed_per_task(cells).items():
        flown = max(x.episodes for x in cells if x.task == task)
        within = all(x.half_width is not None and x.half_width <= half_width for x in cells if x.task == task)
        parts.append(f"| **{short_task_id(task)}** | {flown} | {c.needed} | `{c.planner}` at {c.time_s:g} s | "
                     f"{'yes' if within else 'no'} |")
    undecided = power.undecided_below_count(cells)
    if undecided:
        parts += ["", (f"Below the rule's count this board cannot decide these comparisons with `{reference}`: their "
                       f"paired {LEVEL:.0%} interval holds 0 at the report times named (with one episode there is "
                       "none), so which of the two is ahead is open until the task has the episodes above. A "
                       "comparison not named is decided: its interval excludes 0.")]
        parts.append("")
        needed = power.needed_per_task(cells)
        for task, planners in undecided.items():
            flown = max(x.episodes for x in cells if x.task == task)
            named = "; ".join(f"`{p}` at {', '.join(f'{t:g}' for t in sorted(planners[p]))} s"
                              for p in ordered(list(dict.fromkeys([*table.planners, *planners]))) if p in planners)
            parts.append(f"- **{short_task_id(task)}** ({flown} of {needed[task].needed} episodes): {named}")
    return "\n".join(parts) + "\n"


__all__ = ["aggregate_estimates", "aggregate_section", "power_section"]
