"""The leaderboard's plots, as PNG files beside ``leaderboard.md``.

``performance_profile.png`` (:func:`plot_profile`)
    per planner, the fraction of episodes whose normalised score is above tau, with a 95% band.
``curves_<task>.png`` (:func:`plot_curves`)
    ROI trace and ROI RMSE over mission time per planner: mean with a shaded 95% band.
``runtime_per_decision.png`` (:func:`plot_runtime`)
    runtime per decision per planner and task (log scale, 95% interval whiskers).
``frontier_<task>.png`` (:func:`plot_frontier`)
    where the board holds a sweep: mean uncertainty reduction against mean decision time (log scale), one
    panel per report time, sweeps joined and labelled by their setting, paired 95% whiskers from the
    reference, the Pareto front as a step line.

Plots use matplotlib's Agg canvas through :class:`matplotlib.figure.Figure` (no pyplot, no
display, no global backend switch). Reference planners that read the truth are drawn dashed.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.data import write_atomically
from ..envs import short_task_id
from ..planners import is_reference
from . import aggregate as agg_stats
from .aggregate import LEVEL
from .frontier import Frontier
from .tables import EpisodeTable, ordered

CURVES = (("trace_roi", "ROI trace of the covariance"), ("rmse_roi", "ROI RMSE"))
PROFILE_PNG = "performance_profile.png"
RUNTIME_PNG = "runtime_per_decision.png"


def curves_png(task: str) -> str:
    """The file name of ``task``'s curves."""
    return f"curves_{short_task_id(task).replace('/', '_')}.png"


def frontier_png(task: str) -> str:
    """The file name of ``task``'s quality against decision time."""
    return f"frontier_{short_task_id(task).replace('/', '_')}.png"


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


def plot_curves(table: EpisodeTable, task: str, path: str | Path) -> Path:
    """ROI trace and RMSE over mission time for ``task``: mean per planner with a 95% band."""
    colours = _colours(table.planners)
    fig = _figure(figsize=(10, 4), layout="constrained")
    axes = fig.subplots(1, len(CURVES))
    times = table.times.get(task, [])
    for ax, (key, label) in zip(axes, CURVES):
        for planner in table.planners:
            stats = [table.stat(task, planner, t, key) for t in times]
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
    fig.suptitle(f"{short_task_id(task)}: mean and {LEVEL:.0%} bootstrap band over episodes")
    path = Path(path)
    write_atomically(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    return path


def plot_runtime(table: EpisodeTable, path: str | Path) -> Path:
    """Runtime per decision per planner (bars per task, log scale, 95% interval whiskers)."""
    fig = _figure(figsize=(max(7.0, 0.8 * len(table.planners) * max(1, len(table.tasks))), 4),
                  layout="constrained")
    ax = fig.subplots()
    width = 0.8 / max(1, len(table.tasks))
    x = np.arange(len(table.planners))
    for j, task in enumerate(table.tasks):
        stats = [table.runtime_stat(task, p) for p in table.planners]
        mean = np.array([s[0] if s else np.nan for s in stats])
        low = np.array([(s[0] if s[1] is None else s[1]) if s else np.nan for s in stats], dtype=float)
        high = np.array([(s[0] if s[2] is None else s[2]) if s else np.nan for s in stats], dtype=float)
        mean, low, high = 1000 * mean, 1000 * low, 1000 * high  # [ms]
        floor = 1e-4  # a log axis cannot show 0
        mean_c = np.maximum(mean, floor)
        err = np.vstack([mean_c - np.maximum(low, floor), np.maximum(high, floor) - mean_c])
        ax.bar(x + (j - (len(table.tasks) - 1) / 2) * width, mean_c, width, yerr=err, capsize=3,
               label=short_task_id(task))
    ax.set_xticks(x, table.planners, rotation=20, ha="right")
    ax.set_yscale("log")
    ax.set_ylabel("runtime per decision [ms]")
    ax.grid(axis="y", alpha=0.3)
    fig.legend(loc="outside right center", fontsize="small")  # beside the bars, never over them
    ax.set_title("Runtime per decision: mean over episodes, 95% bootstrap interval", fontsize="medium")
    path = Path(path)
    write_atomically(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    return path


def plot_profile(table: EpisodeTable, est: agg_stats.AggregateEstimates, path: str | Path,
                 lower: str = agg_stats.LOWER_ANCHOR, upper: str = agg_stats.UPPER_ANCHOR) -> Path:
    """The performance profile: per planner, the fraction of episodes (every task and report time)
    whose normalised score is above tau, with its stratified bootstrap band (``lower``, ``upper``:
    the anchors, as the x label names them)."""
    colours = _colours(table.planners)
    fig = _figure(figsize=(8, 4.5), layout="constrained")
    ax = fig.subplots()
    for planner in ordered(est.planners):
        point, low, high = est.profile[planner]
        dashed = is_reference(planner)
        label = planner + (" (reference, knows the true ROI)" if dashed else "") \
            + (" (published)" if planner in table.published else "")
        ax.plot(est.taus, point, color=colours[planner], linestyle="--" if dashed else "-", label=label)
        if low is not None:  # no band where a task has one episode
            ax.fill_between(est.taus, low, high, color=colours[planner], alpha=0.2, linewidth=0)
    ax.set_xlabel(f"normalised score tau (0: {lower}, 1: {upper}, per task and report time)")
    ax.set_ylabel("fraction of episodes with score > tau")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    fig.legend(*ax.get_legend_handles_labels(), loc="outside right center", fontsize="small")
    band = f", {est.level:.0%} stratified bootstrap band" if est.intervals else " (one episode: no band)"
    fig.suptitle(f"Performance profile over every task and report time{band}", fontsize="medium")
    path = Path(path)
    write_atomically(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    return path


def plot_frontier(frontier: Frontier, path: str | Path) -> Path:
    """Quality against decision time on one task: a panel per report time, x the mean decision time (log),
    y the mean uncertainty reduction; whiskers: the paired 95% interval from the reference, around the point."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    names = [p.planner for p in frontier.points]
    colours = _colours(names)
    n = len(frontier.times)
    cols = min(2, n)
    rows = -(-n // cols)
    fig = _figure(figsize=(6.0 * cols + 2.5, 4.0 * rows), layout="constrained")
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False).ravel())
    for ax in axes[n:]:
        ax.set_visible(False)
    for ax, t in zip(axes, frontier.times):
        for p in (q for q in frontier.points if t in q.means):
            x, y, d = 1000 * max(p.decision_time_s, 1e-7), p.means[t], p.versus.get(t)
            err = None if d is None or d[1] is None else [[max(0.0, d[0] - d[1])], [max(0.0, d[2] - d[0])]]
            label = p.planner + (" (reference, knows the true ROI)" if p.reads_truth else "")
            ax.errorbar([x], [y], yerr=err, fmt="o", mfc="none" if p.reads_truth else colours[p.planner],
                        color=colours[p.planner], capsize=3, label=label, zorder=3)
            if p.planner == frontier.reference:
                ax.axhline(y, color=colours[p.planner], linestyle=":", linewidth=1)
        for sweep in frontier.sweeps:
            pts = [(1000 * max(frontier.point(s).decision_time_s, 1e-7), frontier.point(s).means[t], v)
                   for v, s in sweep.points if t in frontier.point(s).means]
            ax.plot([q[0] for q in pts], [q[1] for q in pts], color="0.4", linewidth=1, zorder=2)
            for x, y, v in pts:
                ax.annotate(f"{sweep.key}={v:g}", (x, y), textcoords="offset points", xytext=(4, 4), fontsize="x-small")
        front = sorted((1000 * max(p.decision_time_s, 1e-7), p.means[t]) for p in frontier.points if t in p.front)
        if front:
            ax.step([q[0] for q in front], [q[1] for q in front], where="post", color="k", alpha=0.3, linewidth=3,
                    marker="o", markersize=13, mfc="none", label="Pareto front", zorder=1)
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))  # 0.01, 0.1, 1, 10, ... ms
        ax.xaxis.set_minor_formatter(NullFormatter())  # decades only: the minor ticks' labels would overlap
        ax.set_xlabel("mean decision time [ms] (log)")
        ax.set_ylabel("uncertainty reduction [%]")
        ax.set_title(f"at {t:g} s", fontsize="medium")
        ax.grid(alpha=0.3, which="both")
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside right center", fontsize="small")
    versus = f"; whiskers: {LEVEL:.0%} paired interval from {frontier.reference}" if frontier.reference else ""
    fig.suptitle(f"{short_task_id(frontier.task)}: quality against decision time{versus}", fontsize="medium")
    path = Path(path)
    write_atomically(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    return path


__all__ = ["PROFILE_PNG", "RUNTIME_PNG", "curves_png", "frontier_png", "plot_curves", "plot_frontier", "plot_profile",
           "plot_runtime"]
