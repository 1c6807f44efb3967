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

How the gains are computed with ``search = "lowrank"`` (the default). A tree state's covariance is the
root's less the updates along its path, ``P = P0 - U U^T`` with ``U = [A_1 ... A_d]`` (n x r, r the
read-out rows flown since the root; ``A_j A_j^T`` one leg's Kalman update, :func:`~ipp_bench.core.belief.gain_factor`).
A state keeps only its edges' small terms (each leg's L^-1, with ``L L^T = S``, and ``Y = W U`` at the
state it leaves) and ``K = U^T D U`` (r x r; D: the ROI's diagonal mask), never P nor U: the search only
ever reads U and ``V = P0 D U`` on the q cells that the legs of the node being expanded see, and it
rebuilds those rows edge by edge from the root, ``A_j = C_j L_j^-T`` with ``C_j = P0 H_j^T - U Y_j^T``
and ``P0 D C_j = B0 H_j^T - V Y_j^T`` (``B0 = P0 D P0``, one product per decision), in O(q r^2) without
touching the rest of the map. On those cells ``P_cc = P0_cc - Uc Uc^T`` and ``(P D P)_cc = B0_cc -
Vc Uc^T - Uc Vc^T + Uc K Uc^T``, and a leg (rows W, noise R) reduces Tr(P) over the ROI by
``Tr(S^-1 G)`` with ``S = W P_cc W^T + R`` and ``G = W (P D P)_cc W^T``: the reference's ``sum_r (HP)_r^T
S^-1 (HP)_r`` (:func:`~ipp_bench.core.belief.trace_reductions`) regrouped. The root's terms cost O(q r^2 +
q^2 r); a state below it starts from its parent's (it keeps its rows of U and V and its P_cc and
(P D P)_cc): on the cells both nodes' legs see (about nine in ten) they are the parent's, the other
cells' rows are rebuilt from the root, and the edge's block A (m columns) updates them all, ``P_cc -=
A_c A_c^T`` and ``(P D P)_cc += A_c T_c^T + T_c A_c^T`` with ``T = A K_aa / 2 + U K_ua - P0 D A`` (K_aa,
K_ua: K's new corner and column block), in O(q^2 m + q r m) (:func:`~ipp_bench.planners._search_kernels.child_terms`;
a state keeps each of its legs' L^-1 and G, and its rows ``UV = [Uc^T | Vc^T]``).
Then b Cholesky factorisations of at most M x M (compiled, :mod:`~ipp_bench.planners._search_kernels`),
instead of the reference's O(b M q n) batched gain and its O(n^2 m) copy and downdate of the covariance
per edge; an edge adds K's new row and corner, ``U^T D A = (Z^T - K Y^T) L^-T`` (``Z = W V``) and
``A^T D A = L^-1 G L^-T``. A child's terms are built only when
its own gains are asked for (a rollout's last move, which crosses the horizon, never needs them).

The tree (selection, widening, backup) runs in Python; each rollout runs compiled, from the tree's new
state to its end (:func:`~ipp_bench.planners._search_kernels.rollout`): the same moves, drawn with the
planner's generator (one ``random()`` per move against the same cumulative softmax, NumPy's sums in their
order; ``exp`` is the C library's, which can differ from NumPy's in the last bit, so a draw within ~1e-16
of a boundary between two moves could go the other way), the same rewards and discounts. It stops to let
Python set a node's flight times the first time the search reaches it in an episode (the mission's clock,
as the reference reads it). The legs' layout (:func:`~ipp_bench.planners._search_kernels.node_legs`, every
node's, in one table) is static for a roadmap, camera and measurement spacing: it is built for every node
when a planner is first reset on a roadmap (0.2 s at 15 x 15, 0.8 s at 30 x 30) and kept for the process.

The quantities are the reference's in exact arithmetic and agree to round-off (~1e-15 of the largest gain);
the root's gains are computed exactly as the reference computes them, so that legs that tie exactly
there (mirror images, frequent at the start) are ordered alike. Deeper in the tree an exact tie can
still be broken the other way by rounding, and the two searches then grow different trees
(``tests/planners/test_search_fast.py`` compares them on real decision states;
``benchmarks/bench_search.py`` times them and counts identical moves). ``search = "reference"`` runs
the direct form (:mod:`ipp_bench.planners.mcts_reference`). A leg's read-outs come from the camera's
compiled rows, a footprint looked at twice on one leg folded into one row with both looks' precision (the
same posterior). The low-rank search needs numba (the ``eval`` extra); its kernels are compiled when the
planner is first reset, and numba caches them on disk (:mod:`~ipp_bench.planners._search_kernels`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ..core.belief import LegBatch, trace_reductions
from ..core.config import check_integer, check_number
from ..core.mission import TIME_TOL_S
from .base import GraphPlanner, stacked_leg

#: the most simulations per decision (a decision at 10^5 takes about half an hour)
MAX_SIMULATIONS = 100_000
#: how the gains are computed: the low-rank factor (the default) or the dense reference
SEARCHES = ("lowrank", "reference")


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
        search: ``"lowrank"`` (the gains from a low-rank factor of the covariance updates) or
            ``"reference"`` (a dense covariance copied and downdated per tree edge,
            :mod:`~ipp_bench.planners.mcts_reference`): the same search and gains, up to rounding.
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
    search: str = "lowrank"

    def __post_init__(self):
        check_integer("mcts.simulations", self.simulations, 1, MAX_SIMULATIONS)
        if self.time_limit_s is not None:
            check_number("mcts.time_limit_s", self.time_limit_s, 0.0, low_open=True, unit="s")
        # at or below the clock's tolerance the root counts as already at the horizon and no leg is scored
        check_number("mcts.horizon_s", self.horizon_s, TIME_TOL_S, low_open=True, unit="s")
        check_number("mcts.gamma", self.gamma, 0.0, 1.0, low_open=True)
        check_number("mcts.discount_period_s", self.discount_period_s, 0.0, low_open=True, unit="s")
        check_number("mcts.exploration", self.exploration, 0.0)
        check_number("mcts.pw_k", self.pw_k, 1.0)
        check_number("mcts.pw_alpha", self.pw_alpha, 0.0, 1.0)
        check_number("mcts.rollout_lambda", self.rollout_lambda, 0.0)
        if self.search not in SEARCHES:
            raise ValueError(f"mcts.search = {self.search!r} is invalid: expected one of {list(SEARCHES)}")


def _near_ties(rates: np.ndarray) -> bool:
    """Whether two of ``rates`` lie within rounding of each other (1e-9 of the largest), other than
    exact zeros (legs that see nothing score exactly 0 in both searches)."""
    r = np.sort(rates)
    close = np.diff(r) <= 1e-9 * np.abs(r).max(initial=0.0)
    return bool(np.any(close & ((r[1:] != 0.0) | (r[:-1] != 0.0))))


class _Legs:
    """A roadmap node's legs as the low-rank gains use them (static for an episode;
    :func:`~ipp_bench.planners._search_kernels.node_legs`): views of the node table's pools.

    Attributes:
        size: k, the node's legs; index (b,): those that see something; row: (k,) each leg's place among
            them (-1: the leg sees nothing).
        cells: (q,) the cells they see, ascending; m: (b,) each one's read-out rows; M: the most rows;
            var: (b, M) their noise variances (padding: 1).
        nz_cell, nz_w: the legs' nonzero weights (index in ``cells``, value), leg by leg and row by row; rptr
            (b, M + 1): where each leg's rows start among them.
        nz: per leg, (row, index in ``cells``, weight) of its nonzero weights, and (row, map cell) concatenated.
    """

    __slots__ = ("size", "index", "row", "cells", "m", "M", "var", "rptr", "nz_cell", "nz_w", "nz")

    def __init__(self, table, node: int, kernels):
        (b, self.M, self.row, self.index, self.cells, self.m, self.rptr, self.var, ptr, nz_row, nz_cell, nz_ints,
         nz_w) = kernels.node_view(table.ipool, table.fpool, table.table, node, table.k)
        self.size = table.k
        self.nz_cell, self.nz_w = nz_cell, nz_w
        self.nz = [(nz_row[ptr[j]:ptr[j + 1]], nz_cell[ptr[j]:ptr[j + 1]], nz_w[ptr[j]:ptr[j + 1]],
                    nz_ints[2 * ptr[j]:2 * ptr[j + 1]]) for j in range(b)]


#: the legs' layouts of the last roadmaps searched ((camera, spacing, neighbours, positions) -> (node table, the
#: legs' rows)), shared by the planners of a process: the layout is static for a roadmap
_LAYOUTS: dict[tuple, tuple] = {}
_MAX_LAYOUTS = 4


class _State:
    """A tree or rollout state. Its factor (the edges from the root, and ``K``) is set when its gains are first
    asked for."""

    __slots__ = ("node", "parent", "action", "header", "idata", "fdata", "r", "K", "remaining", "elapsed", "costs",
                 "order", "gains", "children", "visits", "Li", "G", "UV", "Pcc", "Bcc")

    def __init__(self, node: int, parent: _State | None, action: int, remaining: float, elapsed: float,
                 costs: np.ndarray):
        self.node = node
        self.parent = parent  # the state this one was reached from (None: the root)
        self.action = action  # the move from the parent
        # the edges from the root that saw something, as _search_kernels.state_terms reads them (None: not set)
        self.header: np.ndarray | None = None
        self.idata: np.ndarray | None = None
        self.fdata: np.ndarray | None = None
        self.r = 0  # columns of U: read-out rows flown since the root
        self.K: np.ndarray | None = None  # (r, r): U^T D U
        self.remaining = remaining  # [s] of budget
        self.elapsed = elapsed  # [s] flown since the root
        self.costs = costs  # (k,) [s] flight time to each neighbour, by the mission's clock
        self.order: np.ndarray | None = None  # playable actions, best one-step gain/s first
        self.gains: np.ndarray | None = None  # one-step reward per action
        self.children: dict[int, list] = {}  # action -> [child, reward, discount, visits, value sum]
        self.visits = 0
        # of the gains, for the edges out of this state: Li = L^-1 (L L^T = S = W P W^T + R) and G = W P D P W^T,
        # each (b, M, M) over the node's legs, and the rows UV = [Uc^T | Vc^T] (r, 2 q) of U and V on its cells
        self.Li = self.G = self.UV = None
        # P and P D P (q, q) on the node's cells (a child starts from them: _search_kernels.child_terms)
        self.Pcc = self.Bcc = None


class MCTSPlanner(GraphPlanner):
    """MCTS with progressive widening and cost-benefit rollouts (paper baseline (c))."""

    name = "mcts"
    Config = MCTSConfig

    def __init__(self, config: MCTSConfig | None = None):
        super().__init__(config or MCTSConfig())
        self._reference = None
        if self.settings.search == "lowrank":
            from ._search_kernels import require_numba

            require_numba("mcts:search=lowrank")

    def fingerprint(self) -> dict[str, str]:
        """The search, which can break a near-tie the other way: a results folder refuses the other's rows."""
        return {"search": self.settings.search}

    def reset(self, view, seed):
        view.require_dense_belief(self.name, "its search reads the full covariance of the belief (a window "
                                  "belief keeps only the cells near the UAV)")
        super().reset(view, seed)
        self._reference = None
        if self.settings.search == "reference":
            from .mcts_reference import ReferenceMCTSPlanner

            self._reference = ReferenceMCTSPlanner(self.settings)
            self._reference.reset(view, seed)
            self.rng = self._reference.rng
            return
        from . import _search_kernels

        _search_kernels.warm_up()  # compiled once per process, before the first decision's clock starts
        self._kernels = _search_kernels
        self._camera = _search_kernels.camera_args(view.sensor)
        self._roadmap = view.roadmap
        self._neighbours = np.array(view.roadmap.neighbours, dtype=np.int64)  # writable: the type the kernels take
        self._spacing = view.config.mission.measurement_spacing
        nodes, k = self._neighbours.shape
        # the legs' layout is static for a roadmap, camera and measurement spacing: kept across episodes
        key = (self._camera, float(self._spacing), self._neighbours.tobytes(),
               np.asarray(view.roadmap.positions, dtype=np.float64).tobytes())
        layout = _LAYOUTS.get(key)
        # the table of the nodes' legs, and each leg's read-out rows ((node, action) -> rows, None: sees nothing)
        if layout is None:
            while len(_LAYOUTS) >= _MAX_LAYOUTS:
                _LAYOUTS.pop(next(iter(_LAYOUTS)))
            self._table, self._legs = _search_kernels.NodeTable(nodes, k), {}
            for node in range(nodes):  # every node, once per roadmap and process (0.2 s at 15 x 15), in no decision
                self._lay_out(node)
            self._table.compact()
            layout = _LAYOUTS[key] = (self._table, self._legs)
        self._table, self._legs = layout
        self._batches: dict[int, LegBatch] = {}
        self._cost_rows = np.zeros((nodes, k))  # row i: flight times [s] from node i (the mission's clock), where
        self._known = np.zeros(nodes, dtype=np.bool_)  # known: set when the search first reaches node i
        self._B = None

    # -- the model: static per episode ---------------------------------------------------------
    def _leg(self, node: int, action: int):
        """The read-outs of the leg ``node -> action`` as the mission would take them, in sparse rows
        (:func:`~ipp_bench.planners._search_kernels.camera_rows`, repeated rows folded into one:
        :func:`~ipp_bench.planners._search_kernels.fold_repeated_rows`); None where the camera sees nothing."""
        key = (node, action)
        if key not in self._legs:
            rm = self._roadmap
            k = self._kernels
            points = k.leg_points(rm.positions[node], rm.positions[rm.neighbours[node, action]], self._spacing)
            rows = k.fold_repeated_rows(*k.camera_rows(points, *self._camera))  # a footprint seen twice: one row
            self._legs[key] = rows if rows[3].size else None
        return self._legs[key]

    def _lay_out(self, node: int) -> None:
        """Lay out node ``node``'s legs in the node table (once)."""
        if not self._table.built(node):
            self._table.add(node, [self._leg(node, a) for a in range(self._table.k)])

    def _legs_of(self, node: int) -> _Legs:
        self._lay_out(node)
        return _Legs(self._table, node, self._kernels)

    def _batch(self, node: int) -> LegBatch:
        """The legs of ``node`` as the reference scores them (dense, stacked; cached)."""
        batch = self._batches.get(node)
        if batch is None:
            batch = self._batches[node] = LegBatch([stacked_leg(self.view, node, a) for a in range(self._table.k)])
        return batch

    def _node_costs(self, node: int) -> np.ndarray:
        """(k,) flight times [s] from node ``node`` to its neighbours (the mission's clock; cached)."""
        if not self._known[node]:
            self._cost_rows[node] = self.view.neighbour_durations(node)
            self._known[node] = True
        return self._cost_rows[node]

    # -- the model: per decision ---------------------------------------------------------------
    def _begin(self, roi: np.ndarray) -> None:
        """The decision's root terms: P0 and B0 = P0 D P0 (D: the ROI's diagonal mask; one product: a search
        reaches most cells of the map)."""
        self._P = np.ascontiguousarray(self.view.belief.cov)
        self._B = self._kernels.roi_product(self._P, roi, self._B)

    @staticmethod
    def _terms(state: _State) -> tuple:
        """The terms of a scored state in the order the kernels take them (header to G)."""
        return (state.header, state.idata, state.fdata, state.r, state.K, state.UV, state.Pcc, state.Bcc, state.Li,
                state.G)

    @staticmethod
    def _set_terms(state: _State, Li, G, UV, Pcc, Bcc, header, idata, fdata, r, K) -> None:
        state.Li, state.G, state.UV, state.Pcc, state.Bcc = Li, G, UV, Pcc, Bcc
        state.header, state.idata, state.fdata, state.r, state.K = header, idata, fdata, r, K

    def _gains(self, state: _State) -> np.ndarray:
        """(k,) predicted reductions of Tr(P) over the decision's ROI, one per leg out of ``state`` (its
        parent scored), and its terms."""
        parent = state.parent
        if parent is not None:  # from the parent's terms and the edge that leads here (_search_kernels.step_terms)
            self._lay_out(state.node)
            out = self._kernels.step_terms(self._P, self._B, self._table.ipool, self._table.fpool, self._table.table,
                                           self._table.k, parent.node, state.action, state.node, *self._terms(parent))
            self._set_terms(state, *out[1:])
            return out[0]
        legs = self._legs_of(state.node)
        out = np.zeros(legs.size)
        state.header, state.K = np.zeros((0, 5), dtype=np.int64), np.zeros((0, 0))
        state.idata, state.fdata, state.r = np.zeros(0, dtype=np.int64), np.zeros(0), 0
        if not legs.index.size:
            state.Li = state.G = np.zeros((0, legs.M, legs.M))
            state.UV = state.Pcc = state.Bcc = np.zeros((0, 0))
            return out
        g, state.Li, state.G, state.UV, state.Pcc, state.Bcc = self._kernels.state_terms(
            self._P, self._B, state.header, state.idata, state.fdata, state.r, legs.cells, state.K, legs.m,
            legs.rptr, legs.nz_cell, legs.nz_w, legs.var, legs.M)
        out[legs.index] = g
        return out

    def _expand_info(self, state: _State) -> None:
        """Playable actions and their one-step rewards, best reward per second first."""
        costs = state.costs
        if state.elapsed >= self.settings.horizon_s - TIME_TOL_S:
            state.order = np.zeros(0, dtype=np.int64)
            return
        actions = np.flatnonzero(self.view.fits_budget(costs, state.remaining))
        gains = self._gains(state)
        if state.parent is None and _near_ties(gains[actions] / costs[actions]):
            # legs that tie at the root (mirror images, often at the start): their gains as the reference
            # computes them (the Kalman terms above stay for the edges), the same bits, so the same order
            gains = trace_reductions(self.view.belief.cov, self._batch(state.node), self._roi)
        state.gains = gains / self._unit
        rate = state.gains[actions] / costs[actions]
        state.order = actions[np.lexsort((actions, -rate))]

    def _transition(self, state: _State, action: int) -> tuple[_State, float, float]:
        """(next state, reward, discount): the move crossing the horizon counts pro rata."""
        rm = self._roadmap
        cost = float(state.costs[action])
        cfg = self.settings
        share = min(1.0, (cfg.horizon_s - state.elapsed) / cost)
        node = int(rm.neighbours[state.node, action])
        child = _State(node, state, action, state.remaining - cost, state.elapsed + cost, self._node_costs(node))
        discount = cfg.gamma ** (cost / cfg.discount_period_s)
        return child, share * float(state.gains[action]), discount

    # -- search -----------------------------------------------------------------------------
    def _rollout(self, state: _State) -> float:
        """The rollout's return from the tree's new state ``state`` (compiled: _search_kernels.rollout), which
        it expands on the way."""
        cfg = self.settings
        if state.elapsed >= cfg.horizon_s - TIME_TOL_S:
            state.order = np.zeros(0, dtype=np.int64)
            return 0.0
        self._lay_out(state.node)
        parent, table = state.parent, self._table
        args = tuple(map(float, (cfg.horizon_s, TIME_TOL_S, cfg.gamma, cfg.discount_period_s, cfg.rollout_lambda,
                                 self._unit)))  # the types the kernels were compiled for
        mode, go_on = 0, (parent.node, float(state.remaining), float(state.elapsed), parent.gains, state.action, 0.0,
                          1.0, *self._terms(parent))
        while True:
            (status, need, total, discount, gains, order, terms, node, remaining, elapsed, now_gains, action,
             now_terms) = self._kernels.rollout(self._P, self._B, table.ipool, table.fpool, table.table,
                                                self._neighbours, self._cost_rows, self._known, self.rng, *args, mode,
                                                *go_on)
            if mode == 0:
                state.gains, state.order = gains, order
                self._set_terms(state, *terms)
            if status == 0:
                return total
            # the move drawn leads to a node the search had not reached: its flight times, its legs, and on
            self._node_costs(need)
            if elapsed + self._cost_rows[node, action] < cfg.horizon_s - TIME_TOL_S:
                self._lay_out(need)
            Li, G, UV, Pcc, Bcc, header, idata, fdata, r, K = now_terms
            mode, go_on = 1, (node, remaining, elapsed, now_gains, action, total, discount, header, idata, fdata, r,
                              K, UV, Pcc, Bcc, Li, G)

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
        self._begin(self._roi)
        self._unit = 1.0
        # from where the robot is (on the graph tasks, exactly the node; in MuJoCo, near it)
        root = _State(node, None, -1, view.remaining_s, 0.0, view.neighbour_durations(node, view.position))
        self._expand_info(root)
        # the env's mask: the affordable legs and, in a team, not a node a teammate holds
        root.order = root.order[view.action_mask()[root.order]]
        if root.order.size == 0:
            raise ValueError(f"{self.name}: no affordable neighbour; the episode should have ended")
        return root

    def act(self, obs):
        if self._reference is not None:
            return self._reference.act(obs)
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
