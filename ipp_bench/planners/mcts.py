"""Monte Carlo tree search with progressive widening and a cost-benefit rollout.

The search runs on the roadmap with the belief covariance alone (it does not depend on the
measured values), so it predicts information gain exactly under the GP model without touching the
real episode or the ground truth:

- state: (node, covariance after the planned measurements, remaining budget, time since the root);
- reward of a move: the reduction of Tr(P) over the belief ROI of the decision (fixed for the
  search), in units of the best one-step reduction at the root;
- moves last different times, so the look-ahead is a fixed flight time ``horizon_s`` (the move
  that crosses it counts pro rata) and the discount is ``gamma`` per ``discount_period_s`` of
  flight: short and long moves compete on gain per time, as the budget demands. (A horizon in
  moves instead favours long moves; that made an earlier version lose to greedy.)
- progressive widening (Sunberg & Kochenderfer 2018): a state has at most ``pw_k N^pw_alpha``
  children, added in decreasing order of one-step gain per second;
- UCT selection among the children; the most visited root child is flown;
- rollout (Choudhury et al. 2020): the next move is drawn with probability proportional to
  ``exp(lambda * (g / c) / max(g / c))`` (gain per second scaled by the best candidate, so that
  ``lambda`` does not depend on the map) until the horizon or the budget ends.

A search is limited by ``simulations`` per decision (deterministic; the default) or additionally
by ``time_limit_s`` of wall time per decision (then results depend on the machine).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ..belief import LegBatch, downdate_inplace, gain_factor, trace_reductions
from ..config import check_integer, check_number
from ..mission import TIME_TOL_S
from .base import GraphPlanner, softmax, stacked_leg

#: the most simulations per decision (a decision at 10^5 takes about half an hour)
MAX_SIMULATIONS = 100_000


@dataclass(frozen=True)
class MCTSConfig:
    """MCTS settings (defaults: about 1-2 s per decision on 2 cores at 15 x 15).

    Attributes:
        simulations: simulations per decision.
        time_limit_s: optional wall-clock limit per decision [s] (None: simulations only).
        horizon_s: flight time looked ahead, tree and rollout together [s].
        gamma: discount per ``discount_period_s`` of flight.
        discount_period_s: flight time over which ``gamma`` applies once [s].
        exploration: UCT constant c in Q + c sqrt(ln N / n) (rewards are in units of the best
            one-step gain at the root).
        pw_k, pw_alpha: progressive widening, children while |C| <= pw_k N^pw_alpha.
        rollout_lambda: sharpness of the cost-benefit rollout.
    """

    simulations: int = 100
    time_limit_s: float | None = None  # [s]
    horizon_s: float = 12.0  # [s]
    gamma: float = 0.95
    discount_period_s: float = 2.0  # [s]
    exploration: float = 0.5
    pw_k: float = 2.0
    pw_alpha: float = 0.5
    rollout_lambda: float = 8.0

    def __post_init__(self):
        check_integer("mcts.simulations", self.simulations, 1, MAX_SIMULATIONS)
        if self.time_limit_s is not None:
            check_number("mcts.time_limit_s", self.time_limit_s, 0.0, low_open=True, unit="s")
        check_number("mcts.horizon_s", self.horizon_s, 0.0, low_open=True, unit="s")
        check_number("mcts.gamma", self.gamma, 0.0, 1.0, low_open=True)
        check_number("mcts.discount_period_s", self.discount_period_s, 0.0, low_open=True, unit="s")
        check_number("mcts.exploration", self.exploration, 0.0)
        check_number("mcts.pw_k", self.pw_k, 1.0)
        check_number("mcts.pw_alpha", self.pw_alpha, 0.0, 1.0)
        check_number("mcts.rollout_lambda", self.rollout_lambda, 0.0)


class _State:
    __slots__ = ("node", "cov", "remaining", "elapsed", "costs", "order", "gains", "children", "visits")

    def __init__(self, node: int, cov: np.ndarray, remaining: float, elapsed: float, costs: np.ndarray):
        self.node = node
        self.cov = cov
        self.remaining = remaining  # [s] of budget
        self.elapsed = elapsed  # [s] flown since the root
        self.costs = costs  # (k,) [s] flight time to each neighbour, by the mission's clock
        self.order: np.ndarray | None = None  # playable actions, best one-step gain/s first
        self.gains: np.ndarray | None = None  # one-step reward per action
        self.children: dict[int, list] = {}  # action -> [child, reward, discount, visits, value sum]
        self.visits = 0


class MCTSPlanner(GraphPlanner):
    """MCTS with progressive widening and cost-benefit rollouts (paper baseline (c))."""

    name = "mcts"
    Config = MCTSConfig

    def __init__(self, config: MCTSConfig | None = None):
        super().__init__(config or MCTSConfig())

    def reset(self, view, seed):
        view.require_dense_belief(self.name, "its search copies and downdates the full covariance at every "
                                  "tree node (a window belief's copy is 120-190 ms at 128 x 128)")
        super().reset(view, seed)
        self._legs: dict[tuple[int, int], tuple | None] = {}
        self._batches: dict[int, LegBatch] = {}
        self._costs: dict[int, np.ndarray] = {}

    # -- the model --------------------------------------------------------------------------
    def _leg(self, node: int, action: int):
        key = (node, action)
        if key not in self._legs:
            self._legs[key] = stacked_leg(self.view, node, action)
        return self._legs[key]

    def _batch(self, node: int) -> LegBatch:
        batch = self._batches.get(node)
        if batch is None:
            batch = LegBatch([self._leg(node, a) for a in range(self.view.roadmap.k)])
            self._batches[node] = batch
        return batch

    def _node_costs(self, node: int) -> np.ndarray:
        """(k,) flight times [s] from node ``node`` to its neighbours (the mission's clock; cached)."""
        costs = self._costs.get(node)
        if costs is None:
            costs = self._costs[node] = self.view.neighbour_durations(node)
        return costs

    def _expand_info(self, state: _State) -> None:
        """Playable actions and their one-step rewards, best reward per second first."""
        costs = state.costs
        if state.elapsed >= self.settings.horizon_s - TIME_TOL_S:
            state.order = np.zeros(0, dtype=np.int64)
            return
        actions = np.flatnonzero(self.view.fits_budget(costs, state.remaining))
        state.gains = trace_reductions(state.cov, self._batch(state.node), self._roi) / self._unit
        rate = state.gains[actions] / costs[actions]
        state.order = actions[np.lexsort((actions, -rate))]

    def _transition(self, state: _State, action: int) -> tuple[_State, float, float]:
        """(next state, reward, discount): the move crossing the horizon counts pro rata."""
        rm = self.view.roadmap
        leg = self._leg(state.node, action)
        cov = state.cov
        if leg is not None:
            cov = cov.copy()
            downdate_inplace(cov, gain_factor(cov, *leg)[0])
        cost = float(state.costs[action])
        cfg = self.settings
        share = min(1.0, (cfg.horizon_s - state.elapsed) / cost)
        node = int(rm.neighbours[state.node, action])
        child = _State(node, cov, state.remaining - cost, state.elapsed + cost, self._node_costs(node))
        discount = cfg.gamma ** (cost / cfg.discount_period_s)
        return child, share * float(state.gains[action]), discount

    # -- search -----------------------------------------------------------------------------
    def _rollout(self, state: _State) -> float:
        cfg = self.settings
        total, discount = 0.0, 1.0
        while True:
            self._expand_info(state)
            acts = state.order
            if acts.size == 0:
                break
            rate = state.gains[acts] / state.costs[acts]
            top = rate.max()
            if top <= 0:
                break
            logits = cfg.rollout_lambda * rate / top
            a = int(self.rng.choice(acts, p=softmax(logits)))
            state, r, d = self._transition(state, a)
            total += discount * r
            discount *= d
        return total

    def _simulate(self, state: _State) -> float:
        cfg = self.settings
        if state.order is None:
            self._expand_info(state)
        if state.order.size == 0:
            return 0.0
        state.visits += 1
        if len(state.children) < min(state.order.size, cfg.pw_k * state.visits ** cfg.pw_alpha):
            a = int(next(x for x in state.order if x not in state.children))
            child, r, d = self._transition(state, a)
            edge = [child, r, d, 0, 0.0]
            state.children[a] = edge
            ret = r + d * self._rollout(child)
        else:
            log_n = math.log(state.visits)
            best, edge = -math.inf, None
            for e in state.children.values():
                score = e[4] / e[3] + cfg.exploration * math.sqrt(log_n / e[3]) if e[3] else math.inf
                if score > best:
                    best, edge = score, e
            ret = edge[1] + edge[2] * self._simulate(edge[0])
        edge[3] += 1
        edge[4] += ret
        return ret

    def _root(self, obs) -> _State:
        """The decision's root state, expanded, with the ROI fixed for the search (rewards in absolute units)."""
        view = self.view
        node = int(obs["current_node"][0])
        self._roi = view.belief_roi()
        self._unit = 1.0
        # from where the robot is (on the graph tasks, exactly the node; in MuJoCo, near it)
        root = _State(node, view.belief.cov, view.remaining_s, 0.0, view.neighbour_durations(node, view.position))
        self._expand_info(root)
        if root.order.size == 0:
            raise ValueError(f"{self.name}: no affordable neighbour; the episode should have ended")
        return root

    def act(self, obs):
        cfg = self.settings
        root = self._root(obs)
        best_gain = root.gains[root.order].max()
        self._unit = best_gain if best_gain > 0 else 1.0
        root.gains = root.gains / self._unit
        deadline = None if cfg.time_limit_s is None else time.perf_counter() + cfg.time_limit_s
        for _ in range(cfg.simulations):
            self._simulate(root)
            if deadline is not None and time.perf_counter() > deadline:
                break
        visits = {a: e[3] for a, e in root.children.items()}
        value = {a: e[4] / max(e[3], 1) for a, e in root.children.items()}
        return int(max(visits, key=lambda a: (visits[a], value[a], -a)))
