"""The report's section on methods flown over several trained networks (:mod:`ipp_bench.eval.methods`).

Per method: how many networks, how the episodes were split among them, and per task and network the mean
uncertainty reduction at each report time, so that a reader sees the spread from one training seed to the next
beside the method's intervals (which resample the networks as well as the episodes).
"""

from __future__ import annotations

from ..envs import short_task_id
from .aggregate import BOOTSTRAP_SEED, LEVEL, N_RESAMPLES
from .markdown import REDUCTIONS, method_label
from .tables import EpisodeTable


def methods_section(table: EpisodeTable) -> str:
    """Per method of ``table`` (``table.networks``): its networks, the split, and each network's means."""
    key, label = REDUCTIONS[0]
    times = table.all_times()
    parts = [
        "## Methods over several trained networks",
        "",
        ("A method is one planner flown with several trained networks (training seeds): episode i of the board's "
         "seed list is flown by network i mod k, the k networks in the order its spec names them, whatever the "
         "backend and workers. Every interval of a method in this report (per task, paired, the aggregate and the "
         f"power rule) is a two-level {LEVEL:.0%} bootstrap: each resample draws k networks with replacement, "
         "then for each drawn network as many of its episodes as that place holds, with replacement (percentile, "
         f"{N_RESAMPLES} resamples, seed {BOOTSTRAP_SEED}), so it counts the spread between training seeds as "
         "well as between episodes. Below, per network, its mean "
         f"{label.lower()} over the episodes it flew."),
        "",
    ]
    for planner in (p for p in table.planners if p in table.networks):
        names = table.methods[planner]["networks"]
        k = len(names)
        header = ["Environment", "Network", "Episodes"] + [f"{label} {t:g} s" if i == 0 else f"{t:g} s"
                                                           for i, t in enumerate(times)]
        lines = [f"{method_label(planner, table.published)}: {k} networks, "
                 + ", ".join(f"{i + 1} `{n}`" for i, n in enumerate(names)) + ".", "",
                 "| " + " | ".join(header) + " |", "|" + "|".join([":--", ":--", "--:"] + ["--:"] * len(times)) + "|"]
        for task in table.tasks:
            if not table.episodes(task, planner):
                continue
            for n in range(k):
                cells = []
                for t in times:
                    values = [v for s, v in table.by_seed(task, planner, t, key).items()
                              if table.networks[planner].get(s) == n]
                    cells.append(f"{sum(values) / len(values):.1f}" if values else "–")
                flown = sum(1 for s in table.seeds[(task, planner)] if table.networks[planner].get(s) == n)
                lines.append("| " + " | ".join([f"**{short_task_id(task)}**" if n == 0 else "", f"{n + 1} `{names[n]}`",
                                                str(flown)] + cells) + " |")
        parts += lines + [""]
    return "\n".join(parts)


__all__ = ["methods_section"]
