"""The reference MCTS search: every tree state holds its own dense covariance.

The search of :mod:`ipp_bench.planners.mcts` (same tree, widening, UCT, rollout and rewards) in its
direct form: every edge copies the parent's n x n covariance and downdates it with the leg's Kalman
update (:func:`~ipp_bench.core.belief.gain_factor`, :func:`~ipp_bench.core.belief.downdate_inplace`), and every
expanded state scores its legs with :func:`~ipp_bench.core.belief.trace_reductions` on that copy. It costs
O(n^2) memory and time per edge; ``mcts`` computes the same gains from a low-rank factor and is what
the leaderboard runs. This one stays as the reference the tests and ``benchmarks/bench_search.py``
compare it with, and runs as ``mcts:search=reference``.
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING

import numpy as np

from ..core.belief import LegBatch, downdate_inplace, gain_factor, trace_reductions
from ..core.mission import TIME_TOL_S
from .base import GraphPlanner, softmax, stacked_leg

if TYPE_CHECKING:
    from .mcts import MCTSConfig


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


class ReferenceMCTSPlanner(GraphPlanner):
    """The reference MCTS: a dense covariance per tree state, copied and downdated on every edge."""

    name = "mcts"

    def __init__(self, config: MCTSConfig):
        super().__init__(config)

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
        # the env's mask: the affordable legs and, in a team, not a node a teammate holds
        root.order = root.order[view.action_mask()[root.order]]
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
