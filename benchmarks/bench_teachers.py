"""Is greedy beatable on benchmark v1? Non-myopic probe planners against greedy, paired per episode.

The attention policy is meant to beat greedy (issue 11). Imitation of greedy can at best tie it, and
reinforcement learning needs room above greedy to find. This script measures that room with
planners that look further than one leg, on held-out seeds of a task, paired with greedy on the
same episodes:

- ``rollout``: one-step policy improvement of greedy (Bertsekas' rollout): for each of the ``top``
  best neighbours by greedy's score, fly it in the belief model and then follow greedy there until
  ``horizon_s`` seconds of flight (the leg crossing it counts pro rata); fly the neighbour with the
  largest predicted ROI trace reduction over the horizon. With ``horizon_s`` down to one leg it is
  greedy on gain rather than gain per second.
- ``global`` (``benchmarks/bench_saturation.py``): the node anywhere with the best one-look gain per
  second of shortest-path flight, reached hop by hop.
- ``far``: greedy plus far targets, the ``oracle`` reference's move set scored on the belief's ROI
  (no truth): besides the neighbours' legs, one look at any roadmap node, scored by its exact ROI
  trace reduction per second of the quickest roadmap flight to it; when the best target beats every
  leg, fly the first leg towards it. ``far:top=16`` computes the exact look gain only for the 16
  targets the look-gain feature ranks best per second: the attention policy's skip teacher
  (``ipp_bench.planners.far.far_scores``); ``top=0`` for every node (12x the cost on 30 x 30).
- ``farcheap``: per neighbour, the best look-gain feature (the marginal-variance approximation) per
  second of flight through it, against greedy's exact leg score (``exact_near=false``: the feature
  for the neighbours too); cheaper, and measured worse than greedy (RESULTS, "Attention policy at
  the frontier").

Probes of the 20 x 20 wall at 150 s (issue 17, eighth session: can a planner on the belief be at
greedy's level early and at the lawnmower's when its low sweep ends?):

- ``lateroll``: greedy until ``switch_s`` seconds are flown, then ``rollout``.
- ``roibeta``: greedy on the ROI ``mean + beta sigma >= mu_th`` with its own ``beta``.
- ``knob``: greedy's gain over ``duration ** power``; ``low_after_s``: only the lowest level after that.
- ``graphcover``: the ``coverage`` lawnmower's lanes snapped to the roadmap (how near a roadmap
  planner comes to the continuous lawnmower).
- ``sweeproi``: greedy until ``switch_s``, then the lawnmower's lanes cut to the belief-ROI cells
  whose variance is still above ``var_frac`` of the prior's.
- ``latesample`` (ninth session): the ``attention`` planner's argmax until ``switch_s``, then its
  trajectory sampling (``samples``, ``plan_s``).
- ``greedysample`` (tenth session): ``greedy`` until ``switch_s``, then the same sampling; a teacher
  for ``benchmarks/joint_warm_start.py --teacher-for``.
- ``tieroll`` (fourteenth session): the greedy ``rollout`` among greedy's near-ties only (legs within
  ``eps`` of the best gain per second), over ``horizon_s`` or up to the mission time ``until_s``.
- ``softroi`` (fourteenth session): greedy on the expected ROI trace reduction, each cell's variance
  reduction weighted by ``Phi((mu - mu_th) / sigma) ** power`` (at least ``floor``) instead of the 0/1
  belief ROI.

``--env KEY=VALUE`` flies every planner on the task with a config field overridden, as ``ipp-bench
leaderboard --env`` (fourteenth session: ``--env altitudes=[8,10,14] --env k=21``, a third flight level
at the camera's last full-resolution altitude).

Those that score predict with the belief covariance alone (the ROI of the decision held fixed), as
greedy and MCTS do; none touches the truth.

    python benchmarks/bench_teachers.py --task ipp_bench/Grid30Train-v1 --episodes 20 --workers 16 \
        --planners greedy rollout:horizon_s=30 rollout:horizon_s=60
    python benchmarks/bench_teachers.py --task ipp_bench/Hotspots30Train-v2 --episodes 8 --workers 2 \
        --planners greedy far far:top=16
    python benchmarks/bench_teachers.py --task ipp_bench/Grid20Train-v1 --episodes 16 --workers 2 \
        --planners greedy coverage graphcover knob:low_after_s=50 sweeproi

Seeds are 10,000,000 + i (``--leaderboard-seeds``: the leaderboard's, ``ipp-bench leaderboard --seed 0``).
Prints the mean ROI uncertainty reduction at the report times, the paired difference to greedy with a
95% bootstrap interval, and the wall time per decision.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass

import numpy as np

from ipp_bench.envs import make_env, parse_overrides
from ipp_bench.eval.plan import episode_seeds
from ipp_bench.eval.runner import run_episode
from ipp_bench.planners import register
from ipp_bench.planners.far import FarTargets, duration_graph, far_move, far_scores
from ipp_bench.planners.base import first_best
from ipp_bench.planners.greedy import GreedyPlanner, greedy_scores, leg_batch
from ipp_bench.planners.mcts import MCTSConfig, MCTSPlanner, _State
from ipp_bench.policies.features import LookGain
from ipp_bench.policies.planner import AttentionConfig, AttentionPlanner

SEED0 = 10_000_000


@dataclass(frozen=True)
class RolloutConfig(MCTSConfig):
    horizon_s: float = 40.0  # [s] flight time looked ahead: the first leg, then greedy
    gamma: float = 1.0
    top: int = 20  # [-] first legs tried, best greedy scores first


class RolloutGreedy(MCTSPlanner):
    """Greedy rollout: the first leg whose greedy continuation gains most within ``horizon_s``."""

    name = "rollout"
    Config = RolloutConfig

    def _greedy_value(self, state: _State) -> float:
        total = 0.0
        while True:
            self._expand_info(state)
            acts = state.order
            if acts.size == 0:
                return total
            a = int(acts[0])  # best gain per second (ties: lowest index), as greedy
            if state.gains[a] <= 0:
                return total
            state, r, _ = self._transition(state, a)
            total += r

    def act(self, obs):
        root = self._root(obs)
        best, best_value = int(root.order[0]), -np.inf
        for a in root.order[: self.settings.top]:
            child, r, _ = self._transition(root, int(a))
            value = r + self._greedy_value(child)
            if value > best_value + 1e-12:
                best, best_value = int(a), value
        return best


@dataclass(frozen=True)
class LateRolloutConfig(RolloutConfig):
    switch_s: float = 75.0  # [s] of flight after which the rollout replaces greedy


class LateRollout(RolloutGreedy):
    """Greedy until ``switch_s`` seconds of the mission are flown, then the greedy rollout."""

    name = "lateroll"
    Config = LateRolloutConfig

    def act(self, obs):
        if self.view.time_s < self.settings.switch_s:
            scores = greedy_scores(self.view, int(obs["current_node"][0]))
            return first_best(np.where(obs["action_mask"].astype(bool), scores, -np.inf))
        return super().act(obs)


@dataclass(frozen=True)
class TieRolloutConfig(RolloutConfig):
    eps: float = 0.1  # [-] only first legs whose gain per second is within eps of the best are rolled out
    until_s: float = 0.0  # [s] if > 0: the rollout's horizon ends at this mission time (horizon_s at least)


class TieRollout(RolloutGreedy):
    """The greedy rollout among greedy's near-ties only: legs within ``eps`` of the best gain per second,
    each followed by greedy up to ``horizon_s`` (or to the mission time ``until_s``); the best total flies."""

    name = "tieroll"
    Config = TieRolloutConfig

    def act(self, obs):
        cfg = self.settings
        horizon = max(cfg.horizon_s, cfg.until_s - self.view.time_s) if cfg.until_s > 0 else cfg.horizon_s
        base = cfg
        self.settings = dataclasses.replace(cfg, horizon_s=horizon)
        try:
            root = self._root(obs)
            rate = root.gains[root.order] / root.costs[root.order]
            near = root.order[rate >= (1.0 - cfg.eps) * rate[0]][: cfg.top]
            best, best_value = int(root.order[0]), -np.inf
            if near.size > 1:
                for a in near:
                    child, r, _ = self._transition(root, int(a))
                    value = r + self._greedy_value(child)
                    if value > best_value + 1e-12:
                        best, best_value = int(a), value
            return best
        finally:
            self.settings = base


@dataclass(frozen=True)
class RoiBetaConfig:
    beta: float = 1.0  # [-] the ROI the score is computed on: mean + beta sigma >= mu_th


class RoiBetaGreedy(GreedyPlanner):
    """Greedy on a wider (or narrower) belief ROI than the task's ``beta``: more of the map counts."""

    name = "roibeta"
    Config = RoiBetaConfig

    def roi(self) -> np.ndarray:
        b, m = self.view.belief, self.view.config.mission
        return b.mean + self.settings.beta * np.sqrt(np.maximum(b.variance, 0.0)) >= m.mu_th


@dataclass(frozen=True)
class SoftRoiConfig:
    power: float = 1.0  # [-] cell weight = P(cell in the ROI) ** power under the belief's marginal
    floor: float = 0.0  # [-] the least weight of a cell


def soft_trace_reductions(cov: np.ndarray, batch, w: np.ndarray) -> np.ndarray:
    """For every leg of ``batch``: sum_i w_i (P - P+)_ii, the weighted form of ``trace_reductions``."""
    out = np.zeros(batch.size)
    if batch.index.size == 0:
        return out
    HP = batch.W @ cov[batch.cells, :]
    S = HP[:, :, batch.cells] @ batch.W.transpose(0, 2, 1)
    idx = np.arange(S.shape[1])
    S[:, idx, idx] += batch.var
    out[batch.index] = np.einsum("bmr,bmr,r->b", np.linalg.solve(S, HP), HP, w)
    return out


class SoftRoiGreedy(GreedyPlanner):
    """Greedy on the expected ROI trace reduction: each cell's variance reduction weighted by the belief's
    probability that the cell is in the ROI, Phi((mu - mu_th) / sigma) (greedy: the 0/1 mask mu + sigma >= mu_th)."""

    name = "softroi"
    Config = SoftRoiConfig

    def scores(self, obs) -> np.ndarray:
        from scipy.special import ndtr

        view = self.view
        node = int(obs["current_node"][0])
        b = view.belief
        sd = np.sqrt(np.maximum(b.variance, 1e-12))
        w = np.maximum(ndtr((b.mean - view.config.mission.mu_th) / sd) ** self.settings.power, self.settings.floor)
        gains = soft_trace_reductions(b.cov, leg_batch(view, node), w)
        s = gains / view.neighbour_durations(node, view.position)
        return np.where(obs["action_mask"].astype(bool), s, -np.inf)


def _lawn_ends(view, seed: int, overlap: float = 0.0) -> np.ndarray:
    """The ``coverage`` lawnmower's lane ends [m], its pattern and the reverse, from the view's start."""
    from ipp_bench.planners.simple import CoverageConfig, CoveragePlanner

    lawn = CoveragePlanner(CoverageConfig(overlap=overlap))
    lawn.reset(view, seed)
    return np.array([lawn._target, *(next(lawn._targets) for _ in range(4 * view.config.grid.rows - 1))])


def _snap(positions: np.ndarray, pts) -> np.ndarray:
    """Each point moved to its nearest roadmap node, repeats in a row dropped."""
    snapped = [positions[np.argmin(np.linalg.norm(positions - np.asarray(p), axis=1))] for p in pts]
    return np.array([q for i, q in enumerate(snapped) if i == 0 or not np.allclose(q, snapped[i - 1])])


def _toward(view, obs, target: np.ndarray) -> int:
    """The valid neighbour nearest ``target`` (ties: the lowest index)."""
    nb = view.roadmap.neighbours[int(obs["current_node"][0])]
    d = np.linalg.norm(view.roadmap.positions[nb] - target, axis=1)
    return first_best(np.where(obs["action_mask"].astype(bool), -d, -np.inf))


@dataclass(frozen=True)
class GraphCoverConfig:
    overlap: float = 0.0  # [-] share of the footprint neighbouring lanes overlap


class GraphCover(GreedyPlanner):
    """The lawnmower on the roadmap: the lowest level's nodes lane by lane, one footprint apart, each
    leg the neighbour nearest the next lane end (how near a roadmap planner can come to ``coverage``)."""

    name = "graphcover"
    Config = GraphCoverConfig

    def reset(self, view, seed: int) -> None:
        super().reset(view, seed)
        # lane ends snapped to the nearest roadmap nodes (the lowest level: the lawnmower's altitude)
        self._pts, self._i = _snap(view.roadmap.positions, _lawn_ends(view, seed, self.settings.overlap)), 0

    def act(self, obs):
        view = self.view
        node = int(obs["current_node"][0])
        pos = view.roadmap.positions
        while np.linalg.norm(pos[node] - self._pts[self._i % len(self._pts)]) < 1e-6:
            self._i += 1
        return _toward(view, obs, self._pts[self._i % len(self._pts)])


@dataclass(frozen=True)
class SweepRoiConfig:
    switch_s: float = 50.0  # [s] of greedy flight before the sweep
    var_frac: float = 0.3  # [-] ROI cells count while their variance is above this share of the prior's


class SweepRoi(GraphCover):
    """Greedy for ``switch_s`` seconds, then the lawnmower's lanes at the lowest level, cut to the
    stretch of each lane whose footprint holds belief-ROI cells still above ``var_frac`` of the prior
    variance, nearest lane end first; re-planned when the plan is flown, greedy when no lane is left."""

    name = "sweeproi"
    Config = SweepRoiConfig

    def reset(self, view, seed: int) -> None:
        GreedyPlanner.reset(self, view, seed)
        from ipp_bench.belief import cell_centres

        pts = _lawn_ends(view, seed)
        self._lanes = np.unique(pts[:, 1])
        self._x = (pts[:, 0].min(), pts[:, 0].max())
        self._alt = view.config.graph.altitudes[0]
        self._half = view.sensor.footprint_side(self._alt) / 2
        g = view.config.grid
        self._xy = cell_centres((g.rows, g.cols), g.resolution)
        self._v0 = view.belief.variance.copy()
        self._pts, self._i = np.zeros((0, 3)), 0

    def _plan(self) -> None:
        view = self.view
        hot = view.belief_roi() & (view.belief.variance > self.settings.var_frac * self._v0)
        segs = []
        for y in self._lanes:
            cells = self._xy[hot & (np.abs(self._xy[:, 1] - y) <= self._half)]
            if cells.size:
                lo, hi = np.clip([cells[:, 0].min(), cells[:, 0].max()], *self._x)
                segs.append(((lo, y, self._alt), (hi, y, self._alt)))
        here, pts = np.asarray(view.position, float), []
        while segs:
            d = [min(np.linalg.norm(np.subtract(a, here)), np.linalg.norm(np.subtract(b, here))) for a, b in segs]
            a, b = segs.pop(int(np.argmin(d)))
            if np.linalg.norm(np.subtract(b, here)) < np.linalg.norm(np.subtract(a, here)):
                a, b = b, a
            pts += [a, b]
            here = np.asarray(b, float)
        self._pts, self._i = (_snap(view.roadmap.positions, pts) if pts else np.zeros((0, 3))), 0

    def act(self, obs):
        view = self.view
        if view.time_s >= self.settings.switch_s:
            node = int(obs["current_node"][0])
            pos = view.roadmap.positions
            while self._i < len(self._pts) and np.linalg.norm(pos[node] - self._pts[self._i]) < 1e-6:
                self._i += 1
            if self._i >= len(self._pts):
                self._plan()
                while self._i < len(self._pts) and np.linalg.norm(pos[node] - self._pts[self._i]) < 1e-6:
                    self._i += 1
            if self._i < len(self._pts):
                return _toward(view, obs, self._pts[self._i])
        return first_best(self.scores(obs))


@dataclass(frozen=True)
class KnobConfig:
    power: float = 1.0  # [-] score = gain / duration ** power (1: greedy's gain per second)
    low_after_s: float = float("inf")  # [s] of flight after which only the lowest level's nodes are flown to


class KnobGreedy(GreedyPlanner):
    """Greedy with two knobs: how much a leg's flight time costs, and low flight only after a time."""

    name = "knob"
    Config = KnobConfig

    def scores(self, obs) -> np.ndarray:
        view = self.view
        node = int(obs["current_node"][0])
        dur = view.neighbour_durations(node, view.position)
        s = greedy_scores(view, node) * dur ** (1.0 - self.settings.power)
        mask = obs["action_mask"].astype(bool)
        if view.time_s >= self.settings.low_after_s:
            low = np.isclose(view.roadmap.positions[view.roadmap.neighbours[node], 2], view.config.graph.altitudes[0])
            mask = mask & low if (mask & low).any() else mask
        return np.where(mask, s, -np.inf)


@dataclass(frozen=True)
class LookRateConfig:
    """No settings: score = look-gain feature of the neighbour / flight time to it."""


class LookRate(GreedyPlanner):
    """Greedy on the attention policy's look-gain feature: what the network is told, per second."""

    name = "lookrate"
    Config = LookRateConfig

    def scores(self, obs) -> np.ndarray:
        view = self.view
        node = int(obs["current_node"][0])
        gain = LookGain.of(view)(view.belief.variance, view.belief_roi())
        nb = view.roadmap.neighbours[node]
        s = gain[nb] / view.neighbour_durations(node, view.position)
        return np.where(obs["action_mask"].astype(bool), s, -np.inf)


@dataclass(frozen=True)
class FarConfig:
    """The oracle's rule (neighbour legs and far one-look targets) on the belief's ROI."""

    top: int = 0  # [-] exact look gains only for the best ``top`` targets by the look-gain feature (0: all)


class FarGreedy(GreedyPlanner):
    """Greedy plus far targets: the oracle's move set, scored on the belief ROI (no truth)."""

    name = "far"
    Config = FarConfig

    def reset(self, view, seed: int) -> None:
        super().reset(view, seed)
        if not self.settings.top:
            ft = FarTargets.of(view)  # a look at every node, exact
            self._targets, self._looks = ft.targets, ft.looks

    def act(self, obs):
        if self.settings.top:  # the attention policy's skip teacher
            return int(np.argmax(far_scores(self.view, obs, self.settings.top)))
        return far_move(self.view, obs, self.scores(obs), self._targets,
                        lambda: self._looks.trace_reductions(self.view.belief.cov, self.view.belief_roi()))


@dataclass(frozen=True)
class FarCheapConfig:
    exact_near: bool = True  # greedy's exact leg scores for the neighbours (else the look gain as well)


class FarCheap(GreedyPlanner):
    """Per neighbour nb: max(leg score, max_j g_j / (t(cur -> nb) + D[nb, j])), g the look-gain feature
    (marginal variances), D all-pairs quickest roadmap flight times (built once per roadmap)."""

    name = "farcheap"
    Config = FarCheapConfig

    def reset(self, view, seed: int) -> None:
        super().reset(view, seed)
        from scipy.sparse.csgraph import shortest_path

        self._D = shortest_path(duration_graph(view), method="D", directed=True)

    def act(self, obs):
        view = self.view
        cur = int(obs["current_node"][0])
        nb = view.roadmap.neighbours[cur]
        dur = view.neighbour_durations(cur, view.position)
        g = LookGain.of(view)(view.belief.variance, view.belief_roi())
        t = dur[:, None] + self._D[nb]  # (k, n)
        far = np.where(view.fits_budget(t, view.remaining_s), g[None, :] / t, 0.0).max(axis=1)
        near = greedy_scores(view, cur) if self.settings.exact_near else g[nb] / dur
        s = np.maximum(near, far)
        return int(np.argmax(np.where(obs["action_mask"].astype(bool), s, -np.inf)))


@dataclass(frozen=True)
class LateSampleConfig(AttentionConfig):
    switch_s: float = 50.0  # [s] the network's argmax until this much of the mission is flown
    samples: int = 8


class LateSample(AttentionPlanner):
    """``attention`` (argmax) until ``switch_s`` seconds are flown, then its trajectory sampling."""

    name = "latesample"
    Config = LateSampleConfig

    def act(self, obs):
        if self.view.time_s < self.settings.switch_s:
            guard = self._stall_guard(obs)
            if guard >= 0:
                self.guard_decisions += 1
                return guard
            return int(np.argmax(self._logits(obs)))
        return super().act(obs)


class GreedySample(LateSample):
    """``greedy`` until ``switch_s`` seconds are flown, then the ``attention`` planner's trajectory sampling
    (a teacher for expert iteration that keeps greedy's labels early, as the shipped warm starts had)."""

    name = "greedysample"

    def act(self, obs):
        if self.view.time_s < self.settings.switch_s:
            scores = greedy_scores(self.view, int(obs["current_node"][0]))
            return first_best(np.where(obs["action_mask"].astype(bool), scores, -np.inf))
        return AttentionPlanner.act(self, obs)


def register_probes() -> None:
    """Put the probes in the planner registry (``rollout``, ``latesample``, ...), in this process."""
    register("rollout", f"{__name__}:RolloutGreedy")
    register("global", "bench_saturation:GlobalGreedy")
    register("lateroll", f"{__name__}:LateRollout")
    register("tieroll", f"{__name__}:TieRollout")
    register("roibeta", f"{__name__}:RoiBetaGreedy")
    register("softroi", f"{__name__}:SoftRoiGreedy")
    register("graphcover", f"{__name__}:GraphCover")
    register("sweeproi", f"{__name__}:SweepRoi")
    register("knob", f"{__name__}:KnobGreedy")
    register("lookrate", f"{__name__}:LookRate")
    register("far", f"{__name__}:FarGreedy")
    register("farcheap", f"{__name__}:FarCheap")
    register("latesample", f"{__name__}:LateSample")
    register("greedysample", f"{__name__}:GreedySample")


def _episode(job):
    task, spec, seed, env = job
    register_probes()
    res = run_episode(task, spec, seed, env=make_env(task, **env))
    return spec, seed, [r["uncertainty_reduction_pct"] for r in res.report], res.decision_time_mean_s


def _interval(d: np.ndarray, rng: np.random.Generator) -> tuple[float, float]:
    if d.size < 2:
        return float("nan"), float("nan")
    boot = rng.choice(d, size=(10_000, d.size)).mean(axis=1)
    return float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="ipp_bench/Grid30Train-v1")
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--workers", type=int, default=os.cpu_count())
    parser.add_argument("--planners", nargs="+", default=["greedy", "rollout:horizon_s=30", "rollout:horizon_s=60"])
    parser.add_argument("--leaderboard-seeds", action="store_true",
                        help="the leaderboard's episode seeds (ipp-bench leaderboard --seed 0) instead of the held-out "
                             f"validation seeds {SEED0}..")
    parser.add_argument("--env", action="append", default=[], metavar="KEY=VALUE",
                        help="override a task config field, as ipp-bench leaderboard --env (e.g. "
                             "--env altitudes=[8,10,14] --env k=21: a third flight level)")
    parser.add_argument("--log", default="", help="append each finished episode to this JSON-lines file")
    parser.add_argument("--from-log", default="", help="only print the table of a --log file")
    args = parser.parse_args(argv)
    if args.from_log:
        with open(args.from_log) as f:
            done = [tuple(json.loads(line)) for line in f if line.strip()]
        specs = list(dict.fromkeys(["greedy", *(d[0] for d in done)]))
        _table(args.task, specs, done, f"from {args.from_log}")
        return
    specs = list(dict.fromkeys(["greedy", *args.planners]))
    try:
        env = parse_overrides(args.env)
        make_env(args.task, **env)  # refuses an unknown task or a bad override before any episode
    except ValueError as e:
        parser.error(str(e))
    seeds = episode_seeds(0, args.episodes) if args.leaderboard_seeds else [SEED0 + i for i in range(args.episodes)]
    jobs = [(args.task, s, seed, env) for seed in seeds for s in specs]
    t0 = time.perf_counter()
    done = []
    with ProcessPoolExecutor(args.workers) as pool:
        for fut in as_completed([pool.submit(_episode, job) for job in jobs]):
            done.append(fut.result())
            if args.log:
                with open(args.log, "a") as f:
                    f.write(json.dumps(done[-1]) + "\n")
    _table(args.task, specs, done, f"{time.perf_counter() - t0:.0f} s wall on {args.workers} workers"
           + (f", env overrides {env}" if env else ""))


def _table(task: str, specs: list[str], done: list, how: str) -> None:
    rows = {s: {} for s in specs}
    dts = {s: [] for s in specs}
    for spec, seed, rep, dt in done:
        rows[spec][seed] = rep
        dts[spec].append(dt)
    times = make_env(task).config.mission.report_times
    seeds = sorted(set.intersection(*(set(rows[s]) for s in specs)))
    ref = np.array([rows["greedy"][s] for s in seeds])
    rng = np.random.default_rng(0)
    which = f"seeds {SEED0}.." if SEED0 in seeds else "the leaderboard's seeds"
    print(f"{task}: ROI uncertainty reduction [%], {len(seeds)} episodes ({which}), {how}")
    print("| planner | " + " | ".join(f"{t:g} s" for t in times) + " | minus greedy [95% CI] | ms per decision |")
    print("|---|" + "---|" * (len(times) + 2))
    for spec in specs:
        x = np.array([rows[spec][s] for s in seeds])
        diffs = []
        for j in range(len(times)):
            lo, hi = _interval(x[:, j] - ref[:, j], rng)
            diffs.append(f"{(x[:, j] - ref[:, j]).mean():+.1f} [{lo:+.1f}, {hi:+.1f}]")
        print(f"| {spec} | " + " | ".join(f"{m:.1f}" for m in x.mean(axis=0)) + " | " + "; ".join(diffs)
              + f" | {1000 * np.mean(dts[spec]):.0f} |", flush=True)


if __name__ == "__main__":
    main()
