"""The leaderboard's report: a markdown table in the layout of the paper's Table I, and PNG plots.

Everything is computed from ``results.csv`` alone (:func:`write_report`), so a report can be made
again from a results file at any time. Every cell is the mean over episodes with a 95% percentile
bootstrap interval (:func:`bootstrap_ci`: ``scipy.stats.bootstrap``, 2000 resamples, fixed seed,
so the same CSV always gives the same report; with one episode there is no interval, and the
report says so). The best mean per task and column is in bold: the highest reduction, the lowest
runtime per decision (means equal at the printed precision are all bold).

The paired comparison (:func:`paired_table`) sets each planner against a reference planner
(``--reference``, default ``greedy``) on the same episodes: per task and report time, the mean
difference of the reduction, its 95% paired bootstrap interval and the episodes won.

Rows of the suite's reference planners that read the truth (:data:`~ipp_bench.planners.REFERENCE_PLANNERS`,
the ``oracle``) are shown apart, below a marker row, and never bold: they show the room that
knowing the true ROI opens, not a result a robot can reach. When one ran, a second paired table
gives every planner's distance to it.

Files written:

``leaderboard.md``
    rows = (task, planner), columns = uncertainty reduction and RMSE reduction at each report time
    and the runtime per decision (the mean of each episode's mean decision time); then the paired
    comparison with the reference planner, and the absolute values at the end of the mission.
``curves_<task>.png``
    ROI trace and ROI RMSE over mission time per planner: mean with a shaded 95% band.
``runtime_per_decision.png``
    runtime per decision per planner and task (log scale, 95% interval whiskers).

Plots use matplotlib's Agg canvas through :class:`matplotlib.figure.Figure` (no pyplot, no
display, no global backend switch). Without matplotlib (a core-only install) the report is the
markdown alone, with a note naming the extra that adds the plots.
"""

from __future__ import annotations

import inspect
import math
from collections import defaultdict
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from ..data import write_atomically
from ..envs import short_task_id
from ..mission import REPORT_KEYS
from ..planners import is_reference
from .results import read_results

N_RESAMPLES = 2000
LEVEL = 0.95
BOOTSTRAP_SEED = 0
BOOTSTRAP_METHOD = "percentile"
DEFAULT_REFERENCE = "greedy"
NO_INTERVAL = "no interval: 1 episode"
#: the marker row above the reference rows of the table
REFERENCE_MARKER = "*reference, knows the true ROI (not a planner a robot can run; never ranked):*"

REDUCTIONS = (("uncertainty_reduction_pct", "Uncertainty reduction"), ("rmse_reduction_pct", "RMSE reduction"))
CURVES = (("trace_roi", "ROI trace of the covariance"), ("rmse_roi", "ROI RMSE"))


# scipy >= 1.15 names the generator ``rng``, older releases ``random_state``
_RNG_ARG = "rng" if "rng" in inspect.signature(stats.bootstrap).parameters else "random_state"


def bootstrap_ci(values: Sequence[float], n_resamples: int = N_RESAMPLES, level: float = LEVEL,
                 seed: int = BOOTSTRAP_SEED) -> tuple[float, float | None, float | None]:
    """Mean of ``values`` and its bootstrap interval ``(mean, low, high)`` (``scipy.stats.bootstrap``,
    :data:`BOOTSTRAP_METHOD`, seeded: reproducible).

    One value has no interval: ``(v, None, None)``. Equal values give ``(v, v, v)``.
    """
    x = np.asarray(values, dtype=np.float64)
    if x.size == 0:
        raise ValueError("bootstrap_ci needs at least one value")
    mean = float(x.mean())
    if x.size == 1:
        return mean, None, None
    if np.all(x == x[0]):
        return mean, mean, mean
    res = stats.bootstrap((x,), np.mean, confidence_level=level, n_resamples=n_resamples,
                          method=BOOTSTRAP_METHOD, **{_RNG_ARG: np.random.default_rng(seed)})
    return mean, float(res.confidence_interval.low), float(res.confidence_interval.high)


short_task = short_task_id


class Aggregate:
    """Per-episode values grouped by (task, planner[, time]) from results.csv rows."""

    def __init__(self, rows: Sequence[dict[str, Any]], tasks: Sequence[str] | None = None,
                 planners: Sequence[str] | None = None):
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
    if low is None:
        return f"{head} ({NO_INTERVAL})"
    return f"{head} [{fmt(low)}, {fmt(high)}]"


def resolve_reference(reference: str, planners: Sequence[str]) -> str | None:
    """The planner spec among ``planners`` that ``reference`` names (a spec, or a name when exactly
    one spec of that planner ran), or None."""
    if reference in planners:
        return reference
    named = [p for p in planners if p.partition(":")[0] == reference]
    return named[0] if len(named) == 1 else None


def _label(planner: str) -> str:
    """The method cell: the spec, marked when the planner is a reference that reads the truth."""
    return f"`{planner}` (reference)" if is_reference(planner) else f"`{planner}`"


def ordered(planners: Sequence[str]) -> list[str]:
    """``planners`` with the references that read the truth moved to the end (order kept otherwise)."""
    return [p for p in planners if not is_reference(p)] + [p for p in planners if is_reference(p)]


def paired_table(agg: Aggregate, reference: str, key: str = "uncertainty_reduction_pct") -> str:
    """Each planner minus ``reference`` on the same episodes (seeds), per task and report time:
    mean difference [95% paired bootstrap interval], episodes won / episodes paired."""
    times = agg.all_times()
    header = ["Environment", "Method"] + [f"{t:g} s" for t in times]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join([":--", ":--"] + ["--:"] * len(times)) + "|"]
    for task in agg.tasks:
        first = True
        for planner in ordered(agg.planners):
            if planner == reference or not agg.episodes(task, planner):
                continue
            row = [f"**{short_task(task)}**" if first else "", _label(planner)]
            first = False
            for t in times:
                mine, ref = agg.by_seed(task, planner, t, key), agg.by_seed(task, reference, t, key)
                seeds = sorted(set(mine) & set(ref))
                if not seeds:
                    row.append("–")
                    continue
                d = np.array([mine[s] - ref[s] for s in seeds])
                mean, low, high = bootstrap_ci(d)
                won = int(np.sum(d > 0))
                interval = f"({NO_INTERVAL})" if low is None else f"[{low:+.1f}, {high:+.1f}]"
                row.append(f"{mean:+.1f} {interval}, won {won}/{len(seeds)}")
            lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


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
            row = [f"**{short_task(task)}**" if i == 0 else "", _label(planner)]
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
                f"**{short_task(task)}**" if i == 0 else "", _label(planner), f"{t:g}",
                _cell(trace, lambda x: f"{x:.3g}", "", False), _cell(rmse, lambda x: f"{x:.3f}", "", False),
                str(agg.episodes(task, planner))]) + " |")
    return "\n".join(lines) + "\n"


def markdown_report(agg: Aggregate, command: str | None = None, quick: bool = False,
                    plots: Sequence[str] = (), reference: str | None = DEFAULT_REFERENCE,
                    notes: Sequence[str] = ()) -> str:
    counts = sorted({agg.episodes(t, p) for t in agg.tasks for p in agg.planners if agg.episodes(t, p)})
    n_text = " to ".join(str(c) for c in (counts[0], counts[-1])) if len(counts) > 1 else str(counts[0] if counts else 0)
    parts = ["# ipp-bench leaderboard", ""]
    if command:
        parts += [f"Made with `{command}`" + (" (quick mode: few episodes, cheaper look-ahead)." if quick else "."), ""]
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
                f"Mean difference in percentage points [{LEVEL:.0%} paired {BOOTSTRAP_METHOD} bootstrap interval], "
                f"and the episodes where the planner's reduction is higher than `{ref}`'s.",
                "",
                paired_table(agg, ref, key),
            ]
    elif reference:
        parts += [f"No paired comparison: the reference planner `{reference}` is not among the planners "
                  "(pass --reference SPEC).", ""]
    for oracle in truth_refs:
        if oracle == ref or len(agg.planners) < 2:
            continue
        for key, label in REDUCTIONS:
            parts += [
                f"## {label}: each planner minus `{oracle}` (the headroom reference), on the same episodes",
                "",
                f"How far each planner is from `{oracle}`, which knows the true ROI: mean difference in percentage "
                f"points [{LEVEL:.0%} paired {BOOTSTRAP_METHOD} bootstrap interval], and the episodes where the "
                f"planner's reduction is higher than `{oracle}`'s.",
                "",
                paired_table(agg, oracle, key),
            ]
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


def write_report(results_csv: str | Path, out_dir: str | Path, tasks: Sequence[str] | None = None,
                 planners: Sequence[str] | None = None, command: str | None = None,
                 quick: bool = False, reference: str | None = DEFAULT_REFERENCE,
                 log: Callable[[str], None] | None = None) -> list[Path]:
    """Write ``leaderboard.md``, ``curves_<task>.png`` and ``runtime_per_decision.png`` from a results.csv.

    Without matplotlib the plots are left out, with a note in the report (and through ``log``).

    Returns:
        The paths written.
    """
    out_dir = Path(out_dir)
    agg = Aggregate(read_results(results_csv), tasks, planners)
    written: list[Path] = []
    notes: list[str] = []
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        notes.append('the plots need matplotlib, which is not installed: pip install "ipp-bench[eval]"')
    else:
        for task in agg.tasks:
            if agg.times.get(task):
                written.append(plot_curves(agg, task, out_dir / f"curves_{short_task(task).replace('/', '_')}.png"))
        if agg.runtime:
            written.append(plot_runtime(agg, out_dir / "runtime_per_decision.png"))
    if log is not None:
        for note in notes:
            log(f"note: {note}")
    md = out_dir / "leaderboard.md"
    text = markdown_report(agg, command, quick, [p.name for p in written], reference, notes)
    write_atomically(md, lambda tmp: tmp.write_text(text))
    return [md, *written]


__all__ = [
    "Aggregate",
    "DEFAULT_REFERENCE",
    "bootstrap_ci",
    "paired_table",
    "markdown_report",
    "markdown_table",
    "plot_curves",
    "plot_runtime",
    "write_report",
]
