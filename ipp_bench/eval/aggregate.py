"""Aggregate scores over the benchmark tasks, with the definitions of rliable (Agarwal et al. 2021,
*Deep RL at the edge of the statistical precipice*).

Scores, interval estimates and plots are kept apart, as rliable keeps them: this module computes
numbers from results.csv rows; :mod:`ipp_bench.eval.markdown_stats` and :mod:`ipp_bench.eval.plots`
write them as markdown and plots.

**Normalised score.** Per task and report time, an episode's uncertainty reduction is turned into
the share of the way from ``random`` to ``oracle``::

    score = (x - mean_random) / (mean_oracle - mean_random)

with the means over the board's episodes of that task and time (fixed anchors, as rliable's
Atari scores are normalised by fixed random and human scores). 0 is what flying without a plan
gets, 1 is what knowing where the region of interest lies gets with greedy's one-step rule (which a
planner that looks further ahead can exceed). Raw percentages do not pool: a small map saturates
near 100 % while a large map's best planner is far below it at the first report times, so a point
means something else on each. A board without ``random``
takes 0 % (the prior, no reduction) as the lower anchor, one without ``oracle`` 100 % (a perfect
belief over the ROI) as the upper one, and the report says so. A task and time whose span is below
:data:`MIN_SPAN` points is left out, with a note.

**rliable's terms here.** A *run* is an episode (one seed); a *task* is a (benchmark task, report
time) pair. With ``S`` the scores of every run and task of one planner:

- interquartile mean (IQM): ``scipy.stats.trim_mean(S, 0.25, axis=None)``, the mean of the middle
  50 % of every run's score on every task, flattened (:func:`iqm`);
- probability of improvement ``P(X > Y)``: per task ``m``, ``P(X_m > Y_m) + 0.5 P(X_m = Y_m)`` over
  every pair of an ``X`` run and a ``Y`` run (the Mann-Whitney U statistic over ``n_x n_y``),
  averaged over tasks (:func:`probability_of_improvement`);
- performance profile: the fraction of runs (every run of every task) with a score above ``tau``
  (:func:`performance_profile`, rliable's ``run_score_deviation``).

**Stratified bootstrap.** rliable resamples runs with replacement within each task. Here the
episodes of a benchmark task are the same seeds for every planner and every report time (one
episode gives every report time's row), so a resample draws episode indices per benchmark task
(the stratum) and takes those episodes for every planner and every report time together: the
intervals keep the pairing of the planners (rliable's independent resampling of ``X`` and ``Y`` for
the probability of improvement would ignore it and give wider intervals). With one report time per
task this is rliable's ``StratifiedBootstrap``. Percentile intervals, :data:`N_RESAMPLES` resamples,
a fixed seed: the same results.csv always gives the same numbers.

**A method over several networks** (:mod:`ipp_bench.eval.methods`): its intervals come from a two-level
resampling (:func:`two_level_indices`): the networks (training seeds) are drawn with replacement, then the
episodes within each drawn network; with one network it is the resampling above, exactly.

**Ties.** A planner's rank is 1 + the number of planners that beat it with a probability of
improvement whose interval lies above 0.5; planners with the same rank are tied (the data cannot
separate them). References that read the truth (the ``oracle``) are never ranked.

**One episode.** A task of fewer than :data:`MIN_EPISODES` episodes has no interval: resampling one
episode gives it back every time, a zero-width interval that would read as certainty. A board with
such a task gets point estimates alone, no interval, and every planner the same rank.

The rule for how many episodes a board needs is :mod:`ipp_bench.eval.power`.

One module on purpose (over 400 lines): the scores, the bootstrap and the estimators drawn from it
share one resampling of the episodes, which keeps the planners paired.
"""

from __future__ import annotations

import inspect
import math
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from ..planners import is_reference, parse_spec

N_RESAMPLES = 2000
LEVEL = 0.95
BOOTSTRAP_SEED = 0
BOOTSTRAP_METHOD = "percentile"
#: the metric the aggregate normalises and the power rule is stated in
SCORE_KEY = "uncertainty_reduction_pct"
LOWER_ANCHOR = "random"
UPPER_ANCHOR = "oracle"
#: the upper anchor of a team board, where the ``oracle`` reference is ``team-oracle`` (on one UAV the same)
TEAM_UPPER_ANCHOR = "team-oracle"
#: [points] the lower and upper anchors when the board has no ``random`` / no ``oracle`` rows
LOWER_DEFAULT, UPPER_DEFAULT = 0.0, 100.0
#: [points] a task and time whose random-to-oracle span is smaller is left out of the aggregate
MIN_SPAN = 1.0
#: episodes every task needs for the aggregate's intervals (and so for a rank or a bold probability)
MIN_EPISODES = 2
#: thresholds of the performance profile the report writes out (the plot draws every one)
PROFILE_MARKS = (0.0, 0.5, 0.75, 0.9, 1.0)
_BATCH = 250  # resamples per vectorised batch
_BATCH_VALUES = 4e6  # at most this many pooled scores per batch (bounds the memory of big boards)

# scipy >= 1.15 names the generator ``rng``, older releases ``random_state``
_RNG_ARG = "rng" if "rng" in inspect.signature(stats.bootstrap).parameters else "random_state"


def two_level_indices(rng: np.random.Generator, groups: Sequence[Any] | None, n: int,
                      n_resamples: int) -> np.ndarray:
    """``(n_resamples, n)`` indices of resampled episodes. Without ``groups`` (or one group): ``n`` episodes
    drawn with replacement, ``rng.integers(0, n, (n_resamples, n))``. With ``groups`` (per episode its network
    of a method: the two-level, hierarchical bootstrap over training seeds): per resample the G networks are
    drawn with replacement, and the j-th drawn network fills network j's places (as many episodes as network j
    flew) with its own episodes drawn with replacement."""
    if groups is None:
        return rng.integers(0, n, size=(n_resamples, n))
    keys = [g.item() if isinstance(g, np.generic) else g for g in groups]  # ints, or tuples of ints
    labels = sorted(set(keys))
    if len(keys) != n:
        raise ValueError(f"{len(keys)} groups for {n} episodes")
    where = {g: i for i, g in enumerate(labels)}
    slot = np.array([where[g] for g in keys])
    if len(labels) < 2:
        return rng.integers(0, n, size=(n_resamples, n))
    members = [np.flatnonzero(slot == g) for g in range(len(labels))]
    sizes = np.array([len(m) for m in members])
    table = np.zeros((len(labels), sizes.max()), dtype=np.int64)
    for g, m in enumerate(members):
        table[g, :len(m)] = m
    drawn = rng.integers(0, len(labels), size=(n_resamples, len(labels)))[:, slot]  # (R, n): each place's network
    return table[drawn, rng.integers(0, sizes[drawn])]


def bootstrap_ci(values: Sequence[float], n_resamples: int = N_RESAMPLES, level: float = LEVEL,
                 seed: int = BOOTSTRAP_SEED, groups: Sequence[Any] | None = None
                 ) -> tuple[float, float | None, float | None]:
    """Mean of ``values`` and its bootstrap interval ``(mean, low, high)`` (``scipy.stats.bootstrap``,
    :data:`BOOTSTRAP_METHOD`, seeded: reproducible).

    ``groups``: per value, the network of a method that flew it: then the interval is the two-level bootstrap's
    (:func:`two_level_indices`: networks, then episodes within each; percentile, the same resamples and seed).
    With one group (or None) it is the plain bootstrap above, exactly.

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
    if groups is not None and len(set(groups)) > 1:
        if len(groups) != x.size:
            raise ValueError(f"{len(groups)} groups for {x.size} values")
        rng = np.random.default_rng(seed)
        means = np.concatenate([x[two_level_indices(rng, groups, x.size, min(_BATCH, n_resamples - done))].mean(axis=1)
                                for done in range(0, n_resamples, _BATCH)])
        alpha = 100 * (1 - level) / 2
        low, high = np.percentile(means, [alpha, 100 - alpha])
        return mean, float(low), float(high)
    res = stats.bootstrap((x,), np.mean, confidence_level=level, n_resamples=n_resamples,
                          method=BOOTSTRAP_METHOD, **{_RNG_ARG: np.random.default_rng(seed)})
    return mean, float(res.confidence_interval.low), float(res.confidence_interval.high)


# --------------------------------------------------------------------------------------------------
# rliable's point estimates, on a (runs x tasks) matrix
# --------------------------------------------------------------------------------------------------
def iqm(scores: np.ndarray) -> float:
    """Interquartile mean of every entry (rliable's ``aggregate_iqm``)."""
    return float(stats.trim_mean(np.asarray(scores, dtype=np.float64), 0.25, axis=None))


def probability_of_improvement(x: np.ndarray, y: np.ndarray) -> float:
    """``P(X > Y)`` for (runs x tasks) matrices ``x`` and ``y`` (rliable's ``probability_of_improvement``):
    per task, the share of (x run, y run) pairs where x is higher, ties counting a half; averaged over tasks."""
    x, y = np.atleast_2d(np.asarray(x, dtype=np.float64)), np.atleast_2d(np.asarray(y, dtype=np.float64))
    if x.shape[1] != y.shape[1]:
        raise ValueError(f"x has {x.shape[1]} tasks, y {y.shape[1]}")
    per_task = [_pairwise_wins(x[:, m], y[:, m]).mean() for m in range(x.shape[1])]
    return float(np.mean(per_task))


def _pairwise_wins(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``C[i, j] = 1[x_i > y_j] + 0.5 * 1[x_i == y_j]``."""
    return (x[:, None] > y[None, :]) + 0.5 * (x[:, None] == y[None, :])


def _rank_positions(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``y``'s sorting order, and per ``x_i`` how many sorted ``y`` lie below it and up to it."""
    order = np.argsort(y, kind="stable")
    ys = y[order]
    return order, np.searchsorted(ys, x, side="left"), np.searchsorted(ys, x, side="right")


def performance_profile(scores: np.ndarray, taus: Sequence[float]) -> np.ndarray:
    """Fraction of every run's score on every task above each ``tau`` (rliable's score distribution)."""
    s = np.asarray(scores, dtype=np.float64).ravel()
    return np.array([float(np.mean(s > t)) for t in taus])


# --------------------------------------------------------------------------------------------------
# normalised scores of a board
# --------------------------------------------------------------------------------------------------
@dataclass
class Board:
    """The normalised scores of a board, per benchmark task: ``blocks[k][p, t, e]`` is planner
    ``planners[p]``'s score at report time ``times[k][t]`` in episode ``seeds[k][e]`` of ``tasks[k]``.

    Attributes:
        anchors: per (task, time), the (lower, upper) anchor in points.
        lower, upper: how the anchors were made (a planner spec, or the default's words).
        notes: what was left out and why.
    """

    planners: list[str]
    tasks: list[str]
    times: list[tuple[float, ...]]
    seeds: list[tuple[int, ...]]
    blocks: list[np.ndarray]
    anchors: dict[tuple[str, float], tuple[float, float]]
    lower: str
    upper: str
    key: str = SCORE_KEY
    notes: list[str] = field(default_factory=list)

    def matrix(self, planner: str) -> np.ndarray:
        """The planner's (runs x tasks) matrix as rliable takes it: one column per (task, time),
        one row per episode (needs the same episode count on every task)."""
        p = self.planners.index(planner)
        counts = {len(s) for s in self.seeds}
        if len(counts) != 1:
            raise ValueError(f"the tasks have {sorted(counts)} episodes: no rectangular matrix")
        return np.concatenate([b[p].T for b in self.blocks], axis=1)

    @property
    def all_times(self) -> list[float]:
        return sorted({t for ts in self.times for t in ts})


def _anchor(planners: Sequence[str], name: str) -> str | None:
    """The spec of planner ``name`` among ``planners``: the bare name, else its only spec."""
    if name in planners:
        return name
    named = [p for p in planners if parse_spec(p)[0] == name]
    return named[0] if len(named) == 1 else None


def normalised_board(rows: Iterable[dict[str, Any]], planners: Sequence[str] | None = None,
                     tasks: Sequence[str] | None = None, key: str = SCORE_KEY) -> Board:
    """Normalised scores (module docstring) of every planner that flew every task, on the
    episodes every planner flew.

    Args:
        rows: results.csv rows.
        planners, tasks: order (default: as they first appear in ``rows``).
        key: the metric (percentage points).
    """
    rows = list(rows)
    tasks = list(tasks) if tasks else list(dict.fromkeys(r["task"] for r in rows))
    planners = list(planners) if planners else list(dict.fromkeys(r["planner"] for r in rows))
    value: dict[tuple[str, str, float, int], float] = {}
    reported: dict[tuple[str, str, int], set[float]] = defaultdict(set)
    times: dict[str, set[float]] = defaultdict(set)
    for r in rows:
        value[(r["task"], r["planner"], float(r["time_s"]), int(r["seed"]))] = float(r[key])
        reported[(r["task"], r["planner"], int(r["seed"]))].add(float(r["time_s"]))
        times[r["task"]].add(float(r["time_s"]))
    flown: dict[tuple[str, str], set[int]] = defaultdict(set)  # episodes with a row at every report time
    for (task, planner, seed), ts in reported.items():
        if ts == times[task]:
            flown[(task, planner)].add(seed)
    notes = []
    tasks = [t for t in tasks if times.get(t)]
    # the largest (tasks x planners) block where every planner flew every task
    covered = {p: {t for t in tasks if flown.get((t, p))} for p in planners}
    best: tuple[int, list[str], list[str]] = (0, [], [])
    for candidate in [set(tasks), *covered.values()]:
        with_all = [p for p in planners if candidate <= covered[p]]
        if len(candidate) * len(with_all) > best[0]:
            best = (len(candidate) * len(with_all), [t for t in tasks if t in candidate], with_all)
    _, kept_tasks, kept = best
    if len(kept_tasks) < len(tasks):
        notes.append(f"left out of the aggregate (not every planner flew them): "
                     f"{', '.join(t for t in tasks if t not in kept_tasks)}")
    if len(kept) < len(planners):
        notes.append(f"left out of the aggregate (no rows on every task): "
                     f"{', '.join(p for p in planners if p not in kept)}")
    tasks, planners = kept_tasks, kept
    lower = _anchor(planners, LOWER_ANCHOR)
    upper = _anchor(planners, UPPER_ANCHOR) or _anchor(planners, TEAM_UPPER_ANCHOR)
    board = Board(planners, [], [], [], [], {}, lower or f"{LOWER_DEFAULT:g} % (no `{LOWER_ANCHOR}` rows)",
                  upper or f"{UPPER_DEFAULT:g} % (no `{UPPER_ANCHOR}` rows)", key, notes)
    if not planners:
        return board
    for task in tasks:
        seeds = sorted(set.intersection(*(flown[(task, p)] for p in planners)))
        every = set.union(*(flown[(task, p)] for p in planners))
        if len(seeds) < len(every):
            notes.append(f"{task}: {len(seeds)} episodes, the ones every planner flew to the end (of {len(every)})")
        kept_times = []
        block = []
        for t in sorted(times[task]):
            raw = np.array([[value[(task, p, t, s)] for s in seeds] for p in planners])
            lo = float(raw[planners.index(lower)].mean()) if lower else LOWER_DEFAULT
            hi = float(raw[planners.index(upper)].mean()) if upper else UPPER_DEFAULT
            if hi - lo < MIN_SPAN:
                notes.append(f"{task} at {t:g} s: left out (the anchors {lo:.1f} and {hi:.1f} % are less "
                             f"than {MIN_SPAN:g} point apart)")
                continue
            kept_times.append(t)
            block.append((raw - lo) / (hi - lo))
            board.anchors[(task, t)] = (lo, hi)
        if not kept_times or not seeds:
            continue
        board.tasks.append(task)
        board.times.append(tuple(kept_times))
        board.seeds.append(tuple(seeds))
        board.blocks.append(np.stack(block, axis=1))  # (planners, times, episodes)
    return board


# --------------------------------------------------------------------------------------------------
# interval estimates: the stratified bootstrap over episodes, joint for every planner
# --------------------------------------------------------------------------------------------------
Estimate = tuple[float, float | None, float | None]  # (point, low, high); no interval: (point, None, None)


@dataclass
class AggregateEstimates:
    """Point estimates and percentile intervals of a :class:`Board`.

    Attributes:
        iqm: per planner, over every task and report time.
        iqm_by_time: per report time, per planner, over the tasks reporting at that time.
        poi: per (x, y) planner pair (x != y), ``P(X > Y)``.
        taus, profile: the performance profile of each planner (point, low, high arrays over ``taus``;
            low and high None without intervals).
        ranks: per planner that is not a reference, 1 + the planners that beat it with a
            probability-of-improvement interval above 0.5.
        intervals: False where a task has fewer than :data:`MIN_EPISODES` episodes: every low and
            high is None, and every planner has rank 1.
    """

    planners: list[str]
    iqm: dict[str, Estimate]
    iqm_by_time: dict[float, dict[str, Estimate]]
    poi: dict[tuple[str, str], Estimate]
    taus: np.ndarray
    profile: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]
    ranks: dict[str, int]
    n_resamples: int
    level: float
    intervals: bool = True


def profile_taus(board: Board, n: int = 61) -> np.ndarray:
    """Thresholds from min(0, lowest score) to max(1, highest score), rounded out to tenths, with
    the :data:`PROFILE_MARKS` among them."""
    values = np.concatenate([b.ravel() for b in board.blocks]) if board.blocks else np.zeros(1)
    lo = min(0.0, math.floor(float(values.min()) * 10) / 10)
    hi = max(1.0, math.ceil(float(values.max()) * 10) / 10)
    return np.union1d(np.linspace(lo, hi, n), PROFILE_MARKS)


def estimate(board: Board, n_resamples: int = N_RESAMPLES, level: float = LEVEL, seed: int = BOOTSTRAP_SEED,
             taus: np.ndarray | None = None, networks: Mapping[str, Mapping[int, int]] | None = None
             ) -> AggregateEstimates:
    """IQM, probability of improvement and performance profile of every planner of ``board``, with
    stratified bootstrap intervals (episodes resampled per task, jointly for every planner and time).

    ``networks``: per method (a planner flown over several networks), each seed's network. Every estimate of
    a method (its IQMs and profile, a probability of improvement it is part of) then takes its interval from a
    second, two-level resampling (:func:`two_level_indices`, per task: networks, then episodes within each,
    jointly for every planner, the episodes grouped by the networks of every method); every other estimate
    keeps the plain one's, exactly."""
    if not board.blocks or not board.planners:
        raise ValueError("the board has no scores to aggregate")
    taus = profile_taus(board) if taus is None else np.asarray(taus, dtype=np.float64)
    P = len(board.planners)
    labels = np.concatenate([np.repeat(np.asarray(ts), len(s)) for ts, s in zip(board.times, board.seeds)])
    all_times = board.all_times
    pairs = [(a, b) for a in range(P) for b in range(a + 1, P)]
    # P(X > Y) in a resample with episode counts w: sum_i w_i (W(y < x_i) + 0.5 W(y = x_i)) / n^2, with
    # W the weight of b's episodes below / equal to x_i: cumulative weights in the order of b's values
    # (O(n) per resample instead of the n x n table of pairs)
    sorted_b = [[[_rank_positions(blk[a, t], blk[b, t]) for t in range(blk.shape[1])] for a, b in pairs]
                for blk in board.blocks]
    n_columns = sum(blk.shape[1] for blk in board.blocks)
    batch = max(1, min(_BATCH, int(_BATCH_VALUES // (P * len(labels)))))

    def statistics(indices: list[np.ndarray]):
        """IQM (all, per time), PoI per pair and profile for R resamples (``indices[k]``: R x n_k)."""
        r = indices[0].shape[0]
        pooled = np.concatenate(
            [blk[:, :, idx].transpose(0, 2, 1, 3).reshape(P, r, -1)  # (P, R, T_k * n_k)
             for blk, idx in zip(board.blocks, indices)], axis=2)
        ordered = np.sort(pooled, axis=2)
        cut = int(0.25 * ordered.shape[2])  # what scipy.stats.trim_mean(x, 0.25) cuts from each end
        out_iqm = ordered[:, :, cut:ordered.shape[2] - cut].mean(axis=2)  # (P, R)
        out_time = np.stack([stats.trim_mean(pooled[:, :, labels == t], 0.25, axis=2) for t in all_times])
        flat = ordered.reshape(P * r, -1)
        at_most = np.stack([np.searchsorted(row, taus, side="right") for row in flat])
        out_profile = (1.0 - at_most / flat.shape[1]).reshape(P, r, len(taus))  # (P, R, taus)
        out_poi = np.zeros((len(pairs), r))
        rows = np.arange(r)[:, None]
        for k, idx in enumerate(indices):
            n = idx.shape[1]
            w = np.zeros((r, n))
            np.add.at(w, (rows, idx), 1.0)
            for q in range(len(pairs)):
                for order, below, upto in sorted_b[k][q]:
                    cw = np.concatenate([np.zeros((r, 1)), np.cumsum(w[:, order], axis=1)], axis=1)
                    less, equal = cw[:, below], cw[:, upto] - cw[:, below]
                    out_poi[q] += (w * (less + 0.5 * equal)).sum(axis=1) / (n * n)
        return out_iqm, out_time, out_poi / n_columns, out_profile

    point = statistics([np.arange(len(s))[None, :] for s in board.seeds])
    names = board.planners
    ranked = [p for p in names if not is_reference(p)]
    if min(len(s) for s in board.seeds) < MIN_EPISODES:  # a resample of one episode is that episode: no interval
        poi = {}
        for q, (a, b) in enumerate(pairs):
            poi[(names[a], names[b])] = (float(point[2][q, 0]), None, None)
            poi[(names[b], names[a])] = (1 - float(point[2][q, 0]), None, None)
        return AggregateEstimates(
            list(names), {p: (float(point[0][i, 0]), None, None) for i, p in enumerate(names)},
            {t: {p: (float(point[1][j, i, 0]), None, None) for i, p in enumerate(names)}
             for j, t in enumerate(all_times)},
            poi, taus, {p: (point[3][i, 0], None, None) for i, p in enumerate(names)}, {p: 1 for p in ranked},
            n_resamples, level, intervals=False)
    def resampled(groups: list[Sequence[Any] | None]):
        rng = np.random.default_rng(seed)
        draws = [[], [], [], []]
        done = 0
        while done < n_resamples:
            r = min(batch, n_resamples - done)
            indices = [two_level_indices(rng, g, len(s), r) for g, s in zip(groups, board.seeds)]
            for acc, part in zip(draws, statistics(indices)):
                acc.append(part)
            done += r
        return [np.concatenate(d, axis=-2 if i == 3 else -1) for i, d in enumerate(draws)]

    boot_iqm, boot_time, boot_poi, boot_profile = resampled([None] * len(board.seeds))
    methods = [p for p in names if p in (networks or {}) and len(set(networks[p].values())) > 1]
    if methods:  # the method's estimates from the two-level resampling, every other one's kept
        groups = [[tuple(networks[p][s] for p in methods) for s in seeds] for seeds in board.seeds]
        two = resampled(groups)
        mine = np.array([p in methods for p in names])
        boot_iqm[mine], boot_time[:, mine], boot_profile[mine] = two[0][mine], two[1][:, mine], two[3][mine]
        for q, (a, b) in enumerate(pairs):
            if mine[a] or mine[b]:
                boot_poi[q] = two[2][q]
    alpha = 100 * (1 - level) / 2

    def interval(pt: float, samples: np.ndarray) -> Estimate:
        lo, hi = np.percentile(samples, [alpha, 100 - alpha])
        return float(pt), float(lo), float(hi)

    iqm_est = {p: interval(point[0][i, 0], boot_iqm[i]) for i, p in enumerate(names)}
    by_time = {}
    for j, t in enumerate(all_times):
        by_time[t] = {p: interval(point[1][j, i, 0], boot_time[j, i]) for i, p in enumerate(names)}
    poi = {}
    for q, (a, b) in enumerate(pairs):
        pt, lo, hi = interval(point[2][q, 0], boot_poi[q])
        poi[(names[a], names[b])] = (pt, lo, hi)
        poi[(names[b], names[a])] = (1 - pt, 1 - hi, 1 - lo)
    profile = {p: (point[3][i, 0], *np.percentile(boot_profile[i], [alpha, 100 - alpha], axis=0))
               for i, p in enumerate(names)}
    ranks = {p: 1 + sum(1 for o in ranked if o != p and poi[(o, p)][1] > 0.5) for p in ranked}
    return AggregateEstimates(list(names), iqm_est, by_time, poi, taus, profile, ranks, n_resamples, level)


__all__ = [
    "MIN_EPISODES",
    "N_RESAMPLES",
    "SCORE_KEY",
    "AggregateEstimates",
    "Board",
    "bootstrap_ci",
    "estimate",
    "two_level_indices",
    "iqm",
    "normalised_board",
    "performance_profile",
    "probability_of_improvement",
    "profile_taus",
]
