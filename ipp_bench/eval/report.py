"""The leaderboard's report: ``leaderboard.md`` and its plots, a pure function of ``results.csv``.

:func:`write_report` reads a results.csv (in a folder paired with a published board, with that
board's rows beside it), groups its rows (:class:`~ipp_bench.eval.tables.EpisodeTable`) and writes
the report, so a report can be made again from a results file at any time: the same CSV always
gives the same bytes (every bootstrap is seeded). :func:`markdown_report` puts ``leaderboard.md``
together:

- the aggregate over the tasks (:func:`~ipp_bench.eval.markdown_stats.aggregate_section`); a quick
  board says there that its intervals are wide;
- per task, the layout of the paper's Table I (:func:`~ipp_bench.eval.markdown.markdown_table`):
  rows = (task, planner), columns = uncertainty reduction and RMSE reduction at each report time
  and the runtime per decision (the mean of each episode's mean decision time);
- the paired comparison (:func:`~ipp_bench.eval.markdown.paired_table`) of each planner against a
  reference planner (``--reference``, default ``greedy``) on the same episodes; planners flown
  against a published board also against each of its planners
  (:func:`~ipp_bench.eval.markdown.versus_table`; the published rows are marked); when a reference
  that reads the truth (the ``oracle``) ran, every planner's distance to it;
- quality against decision time, where the board holds a sweep of a planner's setting
  (:func:`~ipp_bench.eval.markdown_frontier.frontier_section`, numbers from :mod:`ipp_bench.eval.frontier`);
- what more UAVs buy, where a team task and its single-UAV task are both on the board;
- the power rule (:func:`~ipp_bench.eval.markdown_stats.power_section`);
- the absolute values at the end of the mission, notes, and the plots
  (:mod:`ipp_bench.eval.plots`).

Without matplotlib (a core-only install) the report is the markdown alone, with a note naming the
extra that adds the plots.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from ..core.data import write_atomically
from ..planners import is_reference
from . import aggregate as agg_stats
from .aggregate import BOOTSTRAP_METHOD, BOOTSTRAP_SEED, LEVEL, N_RESAMPLES
from .frontier import Frontier, headroom, infer_sweeps, match_answers, task_frontier
from .markdown import NO_INTERVAL, REDUCTIONS, final_table, markdown_table, paired_table, team_section, versus_table
from .markdown_frontier import frontier_section
from .markdown_methods import methods_section
from .markdown_stats import aggregate_estimates, aggregate_section, power_section
from .plots import (
    PROFILE_PNG,
    RUNTIME_PNG,
    curves_png,
    frontier_png,
    plot_curves,
    plot_frontier,
    plot_profile,
    plot_runtime,
)
from .power import POWER_HALF_WIDTH
from .results import PUBLISHED_CSV
from .results_csv import read_results
from .tables import DEFAULT_REFERENCE, EpisodeTable, resolve_reference

QUICK_NOTE = (
    "**Quick board**: {n} episodes per task and planner and cheaper look-ahead settings: its intervals are wide, "
    "and a bootstrap over so few episodes understates even those; it checks a set-up, not a ranking. For numbers "
    "to quote use the powered boards in "
    "`baselines/` (`baselines/README.md` lists them), or extend this folder with the episodes the power rule "
    "below asks for (`--episodes N` with the same command; the first seeds stay the same).")


def markdown_report(table: EpisodeTable, command: str | None = None, quick: bool = False,
                    plots: Sequence[str] = (), reference: str | None = DEFAULT_REFERENCE,
                    notes: Sequence[str] = (), published_from: str | None = None,
                    power: float | None = POWER_HALF_WIDTH, profile_png: str | None = None,
                    estimates: tuple[agg_stats.Board, agg_stats.AggregateEstimates | None] | None = None,
                    made_on: Sequence[str] = (), published_unverified: bool = False,
                    isolated: Sequence[str] = (), frontiers: Sequence[Frontier] | None = None,
                    frontier_pngs: Mapping[str, str] | None = None) -> str:
    """The whole leaderboard.md.

    Args:
        published_from: the published board whose rows (``table.published``) were copied in.
        power: the power rule's half-width target in points (None: no power section).
        profile_png: the performance-profile plot's file name, shown beside the aggregate.
        estimates: :func:`aggregate_estimates` of ``table`` (computed when None).
        made_on: where the rows were made, one line per machine (run.json's ``machine``).
        published_unverified: the published board records no row digests and was used with
            ``--trust-unverified``: said beside the published rows.
        isolated: the planners whose rows (some of them, in a resumed folder) flew in a process of their own
            (run.json's ``isolated_planners``; a published board's as it recorded them): said under the
            per-task tables. None isolated: nothing is said.
        frontiers: :func:`frontiers_of` ``table`` (computed when None); ``frontier_pngs``: their plots' file
            names per task.
    """
    counts = sorted({table.episodes(t, p) for t in table.tasks for p in table.planners if table.episodes(t, p)})
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
    if table.published:
        new = [p for p in table.planners if p not in table.published]
        parts += [
            f"Rows marked (published) are copied from the published board `{published_from or '?'}` "
            f"(its `results.csv`, kept here as `{PUBLISHED_CSV}`), not flown again; "
            + (", ".join(f"`{p}`" for p in new) or "no planner")
            + " flew its tasks, task configurations and episode seeds, so every row pairs with every published "
            "row episode by episode.", ""]
        if published_unverified:
            parts += [
                f"**The published rows are unverified**: `{published_from or '?'}`'s `run.json` records no row "
                "digests, so a row changed since it was made cannot be told; they were used as "
                "`--trust-unverified` asks (their episodes, report times and completeness were checked).", ""]
    if estimates is None:
        estimates = aggregate_estimates(table)
    parts += [aggregate_section(table, *estimates, profile_png=profile_png)]
    parts += ["## Per task", ""]
    legend = (
        f"Mean over {n_text} episodes per task and planner (every planner meets the same episode seeds), "
        f"with the {LEVEL:.0%} {BOOTSTRAP_METHOD} bootstrap interval of the mean in brackets "
        f"(scipy.stats.bootstrap, {N_RESAMPLES} resamples, seed {BOOTSTRAP_SEED}; one episode has no interval). "
        "Reductions are relative to the prior, over the region of interest. Bold: the best per task and column "
        "(highest reduction, lowest runtime). Runtime per decision: wall time of the planner's decision, "
        "mean over each episode's decisions, then over episodes.")
    truth_refs = [p for p in table.planners if is_reference(p)]
    if truth_refs:
        legend += (
            " Rows marked (reference), below the marker row, read the ground truth's region of interest "
            "(`oracle`: greedy's rule scored on the true ROI); they are never bold and never ranked. They "
            "indicate the room that knowing where the ROI lies opens above the planners that cannot; they "
            "are no upper bound (a planner that looks further ahead can beat them).")
    parts += [legend, "", markdown_table(table)]
    if table.networks:
        parts += [methods_section(table)]
    flown = [p for p in table.planners if p in set(isolated)]
    if flown:
        parts += [isolated_note(flown, table.published), ""]
    ref = resolve_reference(reference, table.planners) if reference else None
    if ref is not None and len(table.planners) > 1:
        for key, label in REDUCTIONS:
            parts += [
                f"## {label}: each planner minus `{ref}`, on the same episodes",
                "",
                (f"Mean difference in percentage points [{LEVEL:.0%} paired {BOOTSTRAP_METHOD} bootstrap interval], "
                f"and the episodes where the planner's reduction is higher than `{ref}`'s."),
                "",
                paired_table(table, ref, key),
            ]
    elif reference:
        parts += [(f"No paired comparison: the reference planner `{reference}` is not among the planners "
                  "(pass --reference SPEC)."), ""]
    for oracle in truth_refs:
        if oracle == ref or len(table.planners) < 2:
            continue
        for key, label in REDUCTIONS:
            parts += [
                f"## {label}: each planner minus `{oracle}` (the headroom reference), on the same episodes",
                "",
                (f"How far each planner is from `{oracle}`, which knows the true ROI: mean difference in percentage "
                f"points [{LEVEL:.0%} paired {BOOTSTRAP_METHOD} bootstrap interval], and the episodes where the "
                f"planner's reduction is higher than `{oracle}`'s."),
                "",
                paired_table(table, oracle, key),
            ]
    for planner in (p for p in table.planners if table.published and p not in table.published):
        for key, label in REDUCTIONS:
            parts += [
                f"## {label}: `{planner}` minus each other planner, on the same episodes",
                "",
                (f"Mean difference in percentage points [{LEVEL:.0%} paired {BOOTSTRAP_METHOD} bootstrap interval], "
                f"and the episodes where `{planner}`'s reduction is higher than the named planner's."),
                "",
                versus_table(table, planner, key),
            ]
    if frontiers is None:
        frontiers = frontiers_of(table, reference)
    section = frontier_section(table, frontiers, {f.task: match_answers(table, f) for f in frontiers},
                               {f.task: headroom(table, f) for f in frontiers}, frontier_pngs or {})
    if section:
        parts += [section]
    teams = team_section(table)
    if teams:
        parts += [teams]
    if ref is not None and power is not None:
        section = power_section(table, ref, power)
        if section:
            parts += [section]
    parts += ["## Absolute values at the end of the mission", "", final_table(table)]
    if notes:
        parts += [f"Note: {n}" for n in notes] + [""]
    if plots:
        parts += ["## Plots", ""] + [f"![{Path(p).stem}]({Path(p).name})" for p in plots] + [""]
    return "\n".join(parts)


def frontiers_of(table: EpisodeTable, reference: str | None) -> list[Frontier]:
    """Quality against decision time on every task where a sweep (:func:`~ipp_bench.eval.frontier.infer_sweeps`)
    flew, paired with ``reference``."""
    sweeps = infer_sweeps(table.planners)
    ref = resolve_reference(reference, table.planners) if reference else None
    return [f for t in table.tasks if (f := task_frontier(table, t, ref, sweeps)) is not None] if sweeps else []


def isolated_note(planners: Sequence[str], published: Sequence[str] = ()) -> str:
    """The line under the per-task tables naming the planners flown isolated."""
    names = ", ".join(f"`{p}`" + (" (published)" if p in published else "") for p in planners)
    return (f"Flown isolated: {names}: each in a process of its own that receives only what the robot measures, "
            "never the ground truth (`--isolate`; on by default for plugins' planners and `--against` submissions; "
            "the same numbers as in-process). run.json's `isolated_planners` names a planner when any of its "
            "episodes here flew so.")


def write_report(results_csv: str | Path, out_dir: str | Path, tasks: Sequence[str] | None = None,
                 planners: Sequence[str] | None = None, command: str | None = None,
                 quick: bool = False, reference: str | None = DEFAULT_REFERENCE,
                 log: Callable[[str], None] | None = None, published_csv: str | Path | None = None,
                 published_from: str | None = None, power: float | None = POWER_HALF_WIDTH,
                 made_on: Sequence[str] = (), published_unverified: bool = False,
                 isolated: Sequence[str] = (), methods: Mapping[str, Mapping] | None = None,
                 seeds: Sequence[int] = ()) -> list[Path]:
    """Write ``leaderboard.md``, ``performance_profile.png``, ``curves_<task>.png``,
    ``runtime_per_decision.png`` and, where the board holds a sweep, ``frontier_<task>.png`` from a results.csv.

    Without matplotlib the plots are left out, with a note in the report (and through ``log``).

    Args:
        published_csv: a published board's results.csv whose rows join the report, marked
            (published), before this run's planners (``--against``).
        published_from: the published board's folder, as the report names it.
        power: the power rule's half-width target in points (None: no power section).
        made_on: where the rows were made (one line per machine), said in one line at the top.
        published_unverified: the published rows were used unverified (``--trust-unverified``).
        isolated: the planners (this run's or the published board's) whose rows flew isolated.
        methods, seeds: run.json's record of the planners flown over several networks and the board's seed
            list (:mod:`ipp_bench.eval.methods`): each row's network, for the two-level intervals and the
            per-network section.

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
    table = EpisodeTable(rows, tasks, planners, published=published, methods=methods, seeds=seeds)
    estimates = aggregate_estimates(table)
    frontiers = frontiers_of(table, reference)
    pngs: dict[str, str] = {}
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
            written.append(plot_profile(table, estimates[1], out_dir / PROFILE_PNG, board.lower, board.upper))
            profile_png = PROFILE_PNG
        for task in table.tasks:
            if table.times.get(task):
                written.append(plot_curves(table, task, out_dir / curves_png(task)))
        if table.runtime:
            written.append(plot_runtime(table, out_dir / RUNTIME_PNG))
        for f in frontiers:
            written.append(plot_frontier(f, out_dir / frontier_png(f.task)))
            pngs[f.task] = written[-1].name
    if log is not None:
        for note in notes:
            log(f"note: {note}")
    md = out_dir / "leaderboard.md"
    shown_apart = {PROFILE_PNG, *pngs.values()}
    text = markdown_report(table, command, quick, [p.name for p in written if p.name not in shown_apart], reference,
                           notes, published_from, power, profile_png, estimates, made_on, published_unverified,
                           isolated, frontiers, pngs)
    write_atomically(md, lambda tmp: tmp.write_text(text))
    return [md, *written]


__all__ = ["frontiers_of", "isolated_note", "markdown_report", "write_report"]
