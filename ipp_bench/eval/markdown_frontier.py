"""The report's section on quality against decision time, in markdown (numbers from :mod:`ipp_bench.eval.frontier`).

Per task with a sweep: the plot ``frontier_<task>.png`` (:func:`~ipp_bench.eval.plots.plot_frontier`), a table of
every planner (its setting where it is a sweep's point, its decision time, its mean uncertainty reduction at each
report time with the paired difference from the reference, the report times at which it is on the Pareto front),
the paper's question where an MCTS sweep and ``attention`` flew the task, and the share of the oracle's headroom
the best planner reaches where the ``oracle`` flew it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from ..envs import short_task_id
from .aggregate import BOOTSTRAP_METHOD, LEVEL
from .frontier import HEADROOM, MATCHED, SWEPT, Frontier, Headroom, Match, MatchAnswer
from .markdown import _milliseconds, method_label
from .tables import EpisodeTable

#: the mark of a point on the Pareto front, in the table
FRONT_MARK = "◆"


def _number(x: float) -> str:
    return f"{x:g}"


def _difference(e: tuple[float, float | None, float | None] | None) -> str:
    if e is None:
        return ""
    return f"{e[0]:+.1f}" + ("" if e[1] is None else f" [{e[1]:+.1f}, {e[2]:+.1f}]")


def _setting(frontier: Frontier, planner: str) -> str:
    return ", ".join(f"{s.key}={_number(s.value(planner))}" for s in frontier.sweeps if planner in s.specs) or "–"


def frontier_table(frontier: Frontier, published: frozenset[str] = frozenset()) -> str:
    """One row per planner: setting, decision time, mean [paired difference from the reference] per report time,
    and the report times at which it is on the Pareto front."""
    header = ["Method", "Setting", "Decision time [ms]", "Episode [s]", *(f"{t:g} s" for t in frontier.times),
              "Pareto front"]
    lines = ["| " + " | ".join(header) + " |", "|:--|:--|" + "--:|" * (len(frontier.times) + 2) + ":--|"]
    for p in sorted(frontier.points, key=lambda p: (p.reads_truth, p.decision_time_s)):
        cells = []
        for t in frontier.times:
            if t not in p.means:
                cells.append("–")
                continue
            versus = _difference(p.versus.get(t))
            mark = f" {FRONT_MARK}" if t in p.front else ""
            cells.append(f"{p.means[t]:.1f}%{mark}" + (f" ({versus})" if versus else ""))
        on = ", ".join(f"{t:g}" for t in frontier.times if t in p.front)
        lines.append("| " + " | ".join([method_label(p.planner, published), _setting(frontier, p.planner),
                                        _milliseconds(p.decision_time_s), _seconds(p.episode_wall_s), *cells,
                                        "–" if p.reads_truth else (f"{on} s" if on else "no")]) + " |")
    swept = {s for g in frontier.sweeps for s in g.specs}
    total = sum(p.wall_s for p in frontier.points if p.wall_s == p.wall_s)
    sweep = sum(p.wall_s for p in frontier.points if p.planner in swept and p.wall_s == p.wall_s)
    lines.append("\nEpisode: the mean wall time of one episode (its steps, belief updates and decisions; one "
                 f"process). This task's episodes took {total / 60:.1f} min of wall time in all, summed over "
                 f"episodes and planners, {sweep / 60:.1f} min of it the sweeps' points (with `--workers` W, about "
                 "1/W of it passes).")
    return "\n".join(lines) + "\n"


def _seconds(x: float) -> str:
    return "–" if x != x else (f"{x:.3g}" if x < 100 else f"{x:.0f}")


def _ratio(a: float, b: float) -> str:
    if b <= 0:
        return "–"
    return f"{a / b:.0f}x" if a / b >= 10 else f"{a / b:.2g}x"


def _match_line(m: Match, answer: MatchAnswer) -> str:
    return (f"`{m.planner}` ({answer.sweep.key}={_number(m.setting)}): {_difference(m.difference)} points; its "
            f"decision time {_milliseconds(m.decision_time_s)} ms against `{answer.matched}`'s "
            f"{_milliseconds(answer.matched_time_s)} ms, {_ratio(m.decision_time_s, answer.matched_time_s)}")


def question_lines(answers: Sequence[MatchAnswer]) -> list[str]:
    """The paper's question, one bullet per sweep and report time."""
    if not answers:
        return []
    a0 = answers[0]
    parts = [
        (f"**Which {SWEPT.upper()} setting is as good as `{a0.matched}`.** A setting is not below `{a0.matched}` at a "
         f"report time when the {LEVEL:.0%} paired {BOOTSTRAP_METHOD} bootstrap interval of {SWEPT.upper()} minus "
         f"`{a0.matched}` (uncertainty reduction, on the same episodes) is not wholly below 0: its upper end is at "
         "least 0. Given: the smallest such setting, its mean difference and interval in points, and its decision "
         f"time against `{a0.matched}`'s with their ratio; where none is, the setting with the highest mean "
         "difference (the largest gap closed)."),
        "",
    ]
    for a in answers:
        head = f"- at {a.time_s:g} s"
        if not a.intervals:
            means = "; ".join(f"{a.sweep.key}={_number(m.setting)}: {m.difference[0]:+.1f}" for m in a.rows)
            parts.append(f"{head}: one episode, no interval, so no setting is said to match; mean differences "
                         f"{SWEPT.upper()} minus `{a.matched}`: {means} points.")
        elif a.first is not None:
            parts.append(f"{head}: the smallest setting not below `{a.matched}` is {_match_line(a.first, a)}.")
        else:
            parts.append(f"{head}: no setting of `{a.sweep.name}:{a.sweep.key}` up to {_number(a.rows[-1].setting)} "
                         f"is as good as `{a.matched}` (every interval lies below 0); the largest gap closed is "
                         f"{_match_line(a.closest, a)}.")
    return parts + [""]


def headroom_lines(rows: Sequence[Headroom], reference: str | None) -> list[str]:
    """The share of the oracle's headroom over the reference the best planner reaches, per report time."""
    if not rows:
        return []
    lines = [
        (f"**How much of `{HEADROOM}`'s headroom a robot's planner reaches.** Per report time, the best mean "
         f"uncertainty reduction of a planner that does not read the truth, as a share of `{HEADROOM}`'s headroom "
         f"over `{reference}`: (best - `{reference}`) / (`{HEADROOM}` - `{reference}`), means over the episodes "
         "the three share."),
        "",
        f"| Time [s] | Best planner | Best | `{reference}` | `{HEADROOM}` | Share of the headroom |",
        "|--:|:--|--:|--:|--:|--:|",
    ]
    for h in rows:
        share = "– (no headroom)" if h.share is None else f"{h.share:.0%}"
        lines.append(f"| {h.time_s:g} | `{h.best}` | {h.best_mean:.1f}% | {h.reference_mean:.1f}% | "
                     f"{h.oracle_mean:.1f}% | {share} |")
    return lines + [""]


def frontier_section(table: EpisodeTable, frontiers: Sequence[Frontier], answers: Mapping[str, list[MatchAnswer]],
                     headrooms: Mapping[str, list[Headroom]], pngs: Mapping[str, str]) -> str:
    """The whole section, or "" without a frontier."""
    if not frontiers:
        return ""
    ref = next((f.reference for f in frontiers if f.reference), None)
    versus = (f" and, in brackets, its difference from `{ref}` on the same episodes with the {LEVEL:.0%} paired "
              f"{BOOTSTRAP_METHOD} bootstrap interval" if ref else "")
    parts = [
        "## Quality against decision time",
        "",
        ("Where the board holds two or more specs of one planner that differ in one numeric setting (a sweep, e.g. "
         f"`--sweep {SWEPT}:simulations=8,24,64`; a spec that does not name the setting has the planner's default), "
         "every planner of the task is a point: its decision time (the mean over episodes of each episode's mean "
         "decision time; log scale in the plot) against its mean uncertainty reduction at each report time"
         f"{versus}. A sweep's points are joined by a line. Pareto front ({FRONT_MARK}): no other planner has both a "
         "lower decision time and a mean at least as high at that report time; references that read the truth are "
         f"shown but are no part of it. `{MATCHED}` and `{HEADROOM}`, where they flew, answer the questions below "
         "the table."),
        "",
    ]
    if table.published:
        parts[-1:] = ["", ("A decision time is the one measured when its row was flown: a published row's on the "
                           "published board's machine and load, the others' on this run's. Compare them across the "
                           "two only as far as the machines and loads compare."), ""]
    for f in frontiers:
        parts += [f"### {short_task_id(f.task)}", ""]
        if f.task in pngs:
            parts += [f"![quality against decision time, {short_task_id(f.task)}]({pngs[f.task]})", ""]
        parts += [frontier_table(f, table.published)]
        parts += question_lines(answers.get(f.task, []))
        parts += headroom_lines(headrooms.get(f.task, []), f.reference)
    return "\n".join(parts)


__all__ = ["FRONT_MARK", "frontier_section", "frontier_table", "headroom_lines", "question_lines"]
