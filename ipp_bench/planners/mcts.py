"""Monte Carlo tree search with progressive widening and a cost-benefit rollout.

The search runs on the roadmap with the belief covariance alone (it does not depend on the
measured values), so it predicts information gain exactly under the GP model without touching the
real episode or the ground truth:

- state: (node, covariance after the planned measurements, remaining budget, time since the root);
- reward of a move: the reduction of Tr(P) over the belief ROI of the decision (fixed for the
  search), in units of the best one-step reduction at the root;
- moves last different times, so the look-ahead is a fixed flight time ``horizon_s`` (the move
  that crosses it counts pro rata) and the discount is ``gamma`` per ``discount_period_s`` of
  flight: short and long moves compete on gain per time, as the budget demands (a horizon in
  moves would favour long moves);
- progressive widening (Sunberg & Kochenderfer 2018): a state has at most ``pw_k N^pw_alpha``
  children, added in decreasing order of one-step gain per second;
- UCT selection among the children; the most visited root child is flown;
- rollout (Choudhury et al. 2020): the next move is drawn with probability proportional to
  ``exp(lambda * (g / c) / max(g / c))`` (gain per second scaled by the best candidate, so that
  ``lambda`` does not depend on the map) until the horizon or the budget ends.

A search is limited by ``simulations`` per decision (deterministic; the default) or additionally
by ``time_limit_s`` of wall time per decision (then results depend on the machine).

One tree (:class:`MCTSPlanner`: selection, widening, transitions, backup), parameterised by its gains
model, ``search``: what a state keeps of its covariance, how it scores its legs, and how it runs a rollout.

- ``search = "lowrank"`` (the default, :class:`~ipp_bench.planners.mcts_lowrank.LowRankGains`): a state keeps
  the small terms of a low-rank factor of the updates since the root and scores its legs on the cells they see
  (compiled; the rollout runs compiled from the tree's new state to its end);
- ``search = "reference"`` (:class:`~ipp_bench.planners.mcts_reference.ReferenceGains`): every state holds its
  own dense covariance, copied and downdated on every edge; the rollout runs in Python.

Both compute the same gains in exact arithmetic and agree to round-off; the root's gains are computed alike,
so legs that tie exactly there (mirror images, frequent at the start) are ordered alike. Deeper in the tree an
exact tie can still be broken the other way by rounding, and the two searches then grow different trees
(``tests/planners/test_search_fast.py`` compares them on real decision states; ``benchmarks/bench_search.py``
times them and counts identical moves).
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..core.mission import TIME_TOL_S
from .base import GraphPlanner
from .mcts_config import MCTSConfig
from .mcts_lowrank import LowRankGains
from .mcts_reference import ReferenceGains

#: search -> its gains model
GAINS_MODELS = {"lowrank": LowRankGains, "reference": ReferenceGains}


class _State:
    """A tree or rollout state: the tree's fields, then the gains model's terms (set by the model; None where
    that model does not use them or has not set them yet)."""

    __slots__ = ("node", "parent", "action", "remaining", "elapsed", "costs", "order", "gains", "children", "visits",
                 "cov", "header", "idata", "fdata", "r", "K", "Li", "G", "UV", "Pcc", "Bcc")

    def __init__(self, node: int, parent: _State | None, action: int, remaining: float, elapsed: float,
                 costs: np.ndarray):
        self.node = node
        self.parent = parent  # the state this one was reached from (None: the root)
        self.action = action  # the move from the parent
        self.remaining = remaining  # [s] of budget
        self.elapsed = elapsed  # [s] flown since the root
        self.costs = costs  # (k,) [s] flight time to each neighbour, by the mission's clock
        self.order: np.ndarray | None = None  # playable actions, best one-step gain/s first
        self.gains: np.ndarray | None = None  # one-step reward per action
        self.children: dict[int, list] = {}  # action -> [child, reward, discount, visits, value sum]
        self.visits = 0
        # search=reference: the state's covariance (n, n)
        self.cov: np.ndarray | None = None
        # search=lowrank: the edges from the root that saw something, as kernels.lowrank.state_terms reads them,
        # r (the columns of U: read-out rows flown since the root) and K = U^T D U (r, r) (None: not set)
        self.header = self.idata = self.fdata = self.K = None
        self.r = 0
        # search=lowrank, of the gains, for the edges out of this state: Li = L^-1 (L L^T = S = W P W^T + R) and
        # G = W P D P W^T, each (b, M, M) over the node's legs, the rows UV = [Uc^T | Vc^T] (r, 2 q) of U and V
        # on its cells, and P and P D P (q, q) there (a child starts from them: kernels.lowrank.child_terms)
        self.Li = self.G = self.UV = self.Pcc = self.Bcc = None


class MCTSPlanner(GraphPlanner):
    """MCTS with progressive widening and cost-benefit rollouts (paper baseline (c))."""

    name = "mcts"
    Config = MCTSConfig

    def __init__(self, config: MCTSConfig | None = None):
        super().__init__(config or MCTSConfig())
        self._model = None
        GAINS_MODELS[self.settings.search].check_installed()

    def fingerprint(self) -> dict[str, str]:
        """The search, which can break a near-tie the other way: a results folder refuses the other's rows."""
        return {"search": self.settings.search}

    def reset(self, view, seed):
        view.require_dense_belief(self.name, "its search reads the full covariance of the belief (a window "
                                  "belief keeps only the cells near the UAV)")
        super().reset(view, seed)
        self._model = GAINS_MODELS[self.settings.search](view)
        self._neighbours = view.roadmap.neighbours
        nodes, k = self._neighbours.shape
        self._cost_rows = np.zeros((nodes, k))  # row i: flight times [s] from node i (the mission's clock), where
        self._known = np.zeros(nodes, dtype=np.bool_)  # known: set when the search first reaches node i

    def _node_costs(self, node: int) -> np.ndarray:
        """(k,) flight times [s] from node ``node`` to its neighbours (the mission's clock; cached)."""
        if not self._known[node]:
            self._cost_rows[node] = self.view.neighbour_durations(node)
            self._known[node] = True
        return self._cost_rows[node]

    # -- the tree -------------------------------------------------------------------------------
    def _expand_info(self, state: _State) -> None:
        """Playable actions and their one-step rewards, best reward per second first."""
        costs = state.costs
        if state.elapsed >= self.settings.horizon_s - TIME_TOL_S:
            state.order = np.zeros(0, dtype=np.int64)
            return
        actions = np.flatnonzero(self.view.fits_budget(costs, state.remaining))
        state.gains = self._model.gains(state, actions) / self._unit
        rate = state.gains[actions] / costs[actions]
        state.order = actions[np.lexsort((actions, -rate))]

    def _transition(self, state: _State, action: int) -> tuple[_State, float, float]:
        """(next state, reward, discount): the move crossing the horizon counts pro rata."""
        cost = float(state.costs[action])
        cfg = self.settings
        share = min(1.0, (cfg.horizon_s - state.elapsed) / cost)
        node = int(self._neighbours[state.node, action])
        child = _State(node, state, action, state.remaining - cost, state.elapsed + cost, self._node_costs(node))
        self._model.enter(child)
        discount = cfg.gamma ** (cost / cfg.discount_period_s)
        return child, share * float(state.gains[action]), discount

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
            ret = r + d * self._model.rollout(self, child)
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
        self._model.begin(self._roi)
        self._unit = 1.0
        # from where the robot is (on the graph tasks, exactly the node; in MuJoCo, near it)
        root = _State(node, None, -1, view.remaining_s, 0.0, view.neighbour_durations(node, view.position))
        self._model.enter(root)
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


__all__ = ["GAINS_MODELS", "MCTSConfig", "MCTSPlanner"]
