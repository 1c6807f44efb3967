"""The rows of results.csv grouped the way the report reads them: per (task, planner, report time).

:class:`EpisodeTable` holds every episode's value of every report metric, keyed by task, planner,
report time and seed, and the per-episode runtime per decision; every cell of the markdown
(:mod:`ipp_bench.eval.markdown`, :mod:`ipp_bench.eval.markdown_stats`) and every plot
(:mod:`ipp_bench.eval.plots`) is computed from it. The scores over tasks are
:mod:`ipp_bench.eval.aggregate`'s.

Also here: which planner is the paired comparisons' reference (:func:`resolve_reference`), the
order planners are shown in (:func:`ordered`), and which tasks pair a team with its single UAV
(:func:`team_pairs`).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping, Sequence
from typing import Any

from ..core.mission import REPORT_KEYS
from ..planners import is_reference
from .aggregate import bootstrap_ci
from .methods import networks_by_seed

#: the planner every other is paired with when ``--reference`` is not given
DEFAULT_REFERENCE = "greedy"


class EpisodeTable:
    """Per-episode values grouped by (task, planner[, report time]) from results.csv rows.

    Args:
        rows: results.csv rows (:func:`ipp_bench.eval.results_csv.read_results`).
        tasks, planners: the order of the report (default: as they first appear in ``rows``).
        published: planners whose rows were copied from a published board (``--against``), not
            flown here.
        methods: run.json's record of the methods (planners flown over several networks,
            :mod:`ipp_bench.eval.methods`) and ``seeds`` the board's seed list, from which each row's network
            follows: a method's intervals resample its networks, then the episodes within each.
    """

    def __init__(self, rows: Sequence[dict[str, Any]], tasks: Sequence[str] | None = None,
                 planners: Sequence[str] | None = None, published: Sequence[str] = (),
                 methods: Mapping[str, Mapping[str, Any]] | None = None, seeds: Sequence[int] = ()):
        self.rows = list(rows)
        self.methods = {p: dict(m) for p, m in (methods or {}).items()}
        #: per method, each seed's network (0-based)
        self.networks = networks_by_seed(self.methods, seeds)
        self.published = frozenset(published)
        self.tasks = list(tasks) if tasks else list(dict.fromkeys(r["task"] for r in rows))
        self.planners = list(planners) if planners else list(dict.fromkeys(r["planner"] for r in rows))
        self.values: dict[tuple[str, str, float, str], list[float]] = defaultdict(list)
        self.runtime: dict[tuple[str, str], dict[int, float]] = defaultdict(dict)
        #: each episode's wall time [s] (the step, the belief updates and the decisions)
        self.wall: dict[tuple[str, str], dict[int, float]] = defaultdict(dict)
        self.times: dict[str, list[float]] = defaultdict(list)
        self.seeds: dict[tuple[str, str], set[int]] = defaultdict(set)
        self._by_seed: dict[tuple[str, str, float, str], dict[int, float]] = defaultdict(dict)
        for r in rows:
            task, planner, t = r["task"], r["planner"], float(r["time_s"])
            for key in REPORT_KEYS:
                self.values[(task, planner, t, key)].append(float(r[key]))
                self._by_seed[(task, planner, t, key)][int(r["seed"])] = float(r[key])
            self.runtime[(task, planner)][int(r["seed"])] = float(r["decision_time_mean_s"])
            self.wall[(task, planner)][int(r["seed"])] = float(r.get("episode_wall_s", "nan") or "nan")
            self.seeds[(task, planner)].add(int(r["seed"]))
            if t not in self.times[task]:
                self.times[task].append(t)
        for task in self.times:
            self.times[task].sort()

    def stat(self, task: str, planner: str, time_s: float, key: str) -> tuple[float, float, float] | None:
        """Mean and bootstrap interval of ``key`` over the episodes (None: no episode); a method's two-level."""
        v = self.values.get((task, planner, time_s, key))
        if not v:
            return None
        if planner not in self.networks:
            return bootstrap_ci(v)
        by_seed = self._by_seed[(task, planner, time_s, key)]
        seeds = sorted(by_seed)
        return bootstrap_ci([by_seed[s] for s in seeds], groups=self.groups(planner, seeds))

    def groups(self, planner: str, seeds: Sequence[int], other: str | None = None) -> list[tuple[int, ...]] | None:
        """Per seed, the network of ``planner`` (and of ``other``) that flew it where either is a method: the
        groups of a two-level bootstrap (None: neither is)."""
        methods = [p for p in (planner, other) if p in self.networks]
        if not methods:
            return None
        return [tuple(self.networks[p][s] for p in methods) for s in seeds]

    def by_seed(self, task: str, planner: str, time_s: float, key: str) -> dict[int, float]:
        """Per-episode values keyed by seed (for pairing planners on the same episodes)."""
        return dict(self._by_seed.get((task, planner, time_s, key), {}))

    def runtime_stat(self, task: str, planner: str) -> tuple[float, float, float] | None:
        """Mean and bootstrap interval of the runtime per decision over the episodes (None: no episode)."""
        v = self.runtime.get((task, planner))
        if not v:
            return None
        if planner not in self.networks:
            return bootstrap_ci(list(v.values()))
        seeds = sorted(v)
        return bootstrap_ci([v[s] for s in seeds], groups=self.groups(planner, seeds))

    def all_times(self) -> list[float]:
        """Every report time of every task, sorted."""
        return sorted({t for task in self.tasks for t in self.times.get(task, [])})

    def episodes(self, task: str, planner: str) -> int:
        return len(self.seeds.get((task, planner), ()))


def resolve_reference(reference: str, planners: Sequence[str]) -> str | None:
    """The planner spec among ``planners`` that ``reference`` names (a spec, or a name when exactly
    one spec of that planner ran), or None."""
    if reference in planners:
        return reference
    named = [p for p in planners if p.partition(":")[0] == reference]
    return named[0] if len(named) == 1 else None


def ordered(planners: Sequence[str]) -> list[str]:
    """``planners`` with the references that read the truth moved to the end (order kept otherwise)."""
    return [p for p in planners if not is_reference(p)] + [p for p in planners if is_reference(p)]


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


__all__ = ["DEFAULT_REFERENCE", "EpisodeTable", "ordered", "resolve_reference", "team_pairs"]
