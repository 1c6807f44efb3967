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

How the gains are computed with ``search = "lowrank"`` (opt in: the default, ``"reference"``, keeps the
rows of the published boards until they are flown again). A tree state's covariance is the
root's less the updates along its path, ``P = P0 - U U^T`` with ``U = [A_1 ... A_d]`` (n x r, r the
read-out rows flown since the root; ``A_j A_j^T`` one leg's Kalman update, :func:`~ipp_bench.belief.gain_factor`).
A state keeps only its edges' small terms (each leg's L^-1, with ``L L^T = S``, and ``Y = W U`` at the
state it leaves) and ``K = U^T D U`` (r x r; D: the ROI's diagonal mask), never P nor U: the search only
ever reads U and ``V = P0 D U`` on the q cells that the legs of the node being expanded see, and it
rebuilds those rows edge by edge from the root, ``A_j = C_j L_j^-T`` with ``C_j = P0 H_j^T - U Y_j^T``
and ``P0 D C_j = B0 H_j^T - V Y_j^T`` (``B0 = P0 D P0``, one product per decision), in O(q r^2) without
touching the rest of the map. On those cells ``P_cc = P0_cc - Uc Uc^T`` and ``(P D P)_cc = B0_cc -
Vc Uc^T - Uc Vc^T + Uc K Uc^T``, and a leg (rows W, noise R) reduces Tr(P) over the ROI by
``Tr(S^-1 G)`` with ``S = W P_cc W^T + R`` and ``G = W (P D P)_cc W^T``: the reference's ``sum_r (HP)_r^T
S^-1 (HP)_r`` (:func:`~ipp_bench.belief.trace_reductions`) regrouped. The root's terms cost O(q r^2 +
q^2 r); a state below it starts from its parent's (it keeps its rows of U and V and its P_cc and
(P D P)_cc): on the cells both nodes' legs see (about nine in ten) they are the parent's, the other
cells' rows are rebuilt from the root, and the edge's block A (m columns) updates them all, ``P_cc -=
A_c A_c^T`` and ``(P D P)_cc += A_c T_c^T + T_c A_c^T`` with ``T = A K_aa / 2 + U K_ua - P0 D A`` (K_aa,
K_ua: K's new corner and column block), in O(q^2 m + q r m) (:func:`~ipp_bench.planners._search_kernels.child_terms`).
Then b Cholesky factorisations of at most M x M (compiled, :mod:`~ipp_bench.planners._search_kernels`),
instead of the reference's O(b M q n) batched gain and its O(n^2 m) copy and downdate of the covariance
per edge; an edge adds K's new row and corner, ``U^T D A = (Z^T - K Y^T) L^-T`` (``Z = W V``) and
``A^T D A = L^-1 G L^-T``. A child's terms are built only when
its own gains are asked for (a rollout's last move, which crosses the horizon, never needs them). The
quantities are the reference's in exact arithmetic and agree to round-off (~1e-15 of the largest gain);
the root's gains are computed exactly as the reference computes them, so that legs that tie exactly
there (mirror images, frequent at the start) are ordered alike. Deeper in the tree an exact tie can
still be broken the other way by rounding, and the two searches then grow different trees
(``tests/planners/test_search_fast.py`` compares them on real decision states;
``benchmarks/bench_search.py`` times them and counts identical moves). ``search = "reference"`` runs
the direct form (:mod:`ipp_bench.planners.mcts_reference`). A leg's read-outs come from the camera's
compiled rows, a footprint looked at twice on one leg folded into one row with both looks' precision (the
same posterior). The low-rank search needs numba (the ``eval`` extra); its kernels are compiled once per
process, when the planner is first reset.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ..belief import LegBatch, trace_reductions
from ..config import check_integer, check_number
from ..mission import TIME_TOL_S
from .base import GraphPlanner, softmax, stacked_leg

#: the most simulations per decision (a decision at 10^5 takes about half an hour)
MAX_SIMULATIONS = 100_000
#: how the gains are computed: the low-rank factor or the dense reference (the default)
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
    search: str = "reference"

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
    :func:`~ipp_bench.planners._search_kernels.node_legs`).

    Attributes:
        size: k, the node's legs; index (b,): those that see something; row: (k,) each leg's place among
            them (-1: the leg sees nothing).
        cells: (q,) the cells they see, ascending; m: (b,) each one's read-out rows; M: the most rows;
            var: (b, M) their noise variances (padding: 1).
        pair_ptr, pair_cell, pair_w: for each leg j and pair of its rows (a, c), c <= a, the products
            ``w_a[x] w_c[y]`` of their weights and the flat index ``x q + y`` of their cells in the q x q block.
        nz: per leg, (row, index in ``cells``, weight) of its nonzero weights, and (row, map cell) concatenated.
        batch: the legs as the reference scores them (:class:`~ipp_bench.belief.LegBatch`), built when first
            asked for.
    """

    __slots__ = ("size", "index", "row", "cells", "m", "M", "var", "pair_ptr", "pair_cell", "pair_w", "nz", "batch")

    def __init__(self, legs: list, kernels):
        self.size = len(legs)
        self.batch = None
        rows = [(0, 0) if leg is None else (leg[0].size - 1, leg[1].size) for leg in legs]
        leg_rows = np.concatenate([[0], np.cumsum([r for r, _ in rows])]).astype(np.int64)
        present = [leg for leg in legs if leg is not None]
        if present:
            offsets = np.cumsum([0] + [nnz for _, nnz in rows if nnz])[:-1]
            row_ptr = np.concatenate([[0]] + [leg[0][1:] + o for leg, o in zip(present, offsets)]).astype(np.int64)
            cells, weights, var = (np.concatenate([leg[i] for leg in present]) for i in (1, 2, 3))
        else:
            row_ptr, cells, weights, var = np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0), \
                np.zeros(0)
        (self.index, self.cells, self.m, self.var, self.pair_ptr, self.pair_cell, self.pair_w, ptr, nz_row, nz_cell,
         nz_w) = kernels.node_legs(leg_rows, row_ptr, cells.astype(np.int64), weights, var)
        self.M = self.var.shape[1]
        self.row = np.full(self.size, -1, dtype=np.int64)
        self.row[self.index] = np.arange(self.index.size)
        self.nz = []
        for j in range(self.index.size):
            a, x = nz_row[ptr[j]:ptr[j + 1]], nz_cell[ptr[j]:ptr[j + 1]]
            self.nz.append((a, x, nz_w[ptr[j]:ptr[j + 1]], np.concatenate([a, self.cells[x]])))


#: the edge arguments of ``_search_kernels.child_terms`` for a leg that sees nothing
_NO_EDGE = (np.zeros((0, 0)), np.zeros((0, 0)), 0, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64),
            np.zeros(0), np.zeros(0, dtype=np.int64))


class _State:
    """A tree or rollout state. Its factor (the edges from the root, and ``K``) is set when its gains are first
    asked for."""

    __slots__ = ("node", "parent", "action", "header", "idata", "fdata", "r", "K", "remaining", "elapsed", "costs",
                 "order", "gains", "children", "visits", "S", "G", "Ut", "Vt", "Pcc", "Bcc")

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
        # of the gains, for the edges out of this state: S = W P W^T + R and G = W P D P W^T, each (b, M, M)
        # over the node's legs, and the rows Ut = Uc^T, Vt = Vc^T (r, q) of U and V on the node's cells
        self.S = self.G = self.Ut = self.Vt = None
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
        self._legs: dict[tuple[int, int], tuple | None] = {}
        self._node_legs: dict[int, _Legs] = {}
        self._camera = _search_kernels.camera_args(view.sensor)
        self._roadmap = view.roadmap
        self._spacing = view.config.mission.measurement_spacing
        self._costs: dict[int, np.ndarray] = {}
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

    def _legs_of(self, node: int) -> _Legs:
        legs = self._node_legs.get(node)
        if legs is None:
            legs = self._node_legs[node] = _Legs([self._leg(node, a) for a in range(self._roadmap.k)], self._kernels)
        return legs

    def _batch(self, node: int) -> LegBatch:
        """The legs of ``node`` as the reference scores them (dense, stacked; cached)."""
        legs = self._legs_of(node)
        if legs.batch is None:
            legs.batch = LegBatch([stacked_leg(self.view, node, a) for a in range(legs.size)])
        return legs.batch

    def _node_costs(self, node: int) -> np.ndarray:
        """(k,) flight times [s] from node ``node`` to its neighbours (the mission's clock; cached)."""
        costs = self._costs.get(node)
        if costs is None:
            costs = self._costs[node] = self.view.neighbour_durations(node)
        return costs

    # -- the model: per decision ---------------------------------------------------------------
    def _begin(self, roi: np.ndarray) -> None:
        """The decision's root terms: P0 and B0 = P0 D P0 (D: the ROI's diagonal mask; one product: a search
        reaches most cells of the map)."""
        self._P = np.ascontiguousarray(self.view.belief.cov)
        self._B = self._kernels.roi_product(self._P, roi, self._B)

    def _materialise(self, state: _State) -> None:
        """The factor of ``state``: its parent's with the edge that led to it appended (its L^-1 and Y = W U
        from :func:`~ipp_bench.planners._search_kernels.edge_terms`)."""
        parent, a = state.parent, state.action
        legs = self._legs_of(parent.node)
        j = int(legs.row[a])
        if j < 0:  # the leg sees nothing: the same posterior
            state.header, state.idata, state.fdata = parent.header, parent.idata, parent.fdata
            state.r, state.K = parent.r, parent.K
            return
        m = int(legs.m[j])
        rows, cells, w, ints = legs.nz[j]
        Linv, Y, state.K = self._kernels.edge_terms(parent.S[j], parent.G[j], m, rows, cells, w, parent.Ut, parent.Vt,
                                                    parent.K)
        r = parent.r
        head = np.array([[m, r, w.size, parent.fdata.size, parent.idata.size]], dtype=np.int64)
        state.header = np.concatenate([parent.header, head])
        state.idata = np.concatenate([parent.idata, ints])
        state.fdata = np.concatenate([parent.fdata, w, Linv.ravel(), Y.ravel()])
        state.r = r + m

    def _gains(self, state: _State) -> np.ndarray:
        """(k,) predicted reductions of Tr(P) over the decision's ROI, one per leg out of ``state``."""
        legs = self._legs_of(state.node)
        parent = state.parent
        if parent is None or parent.Pcc is None or not legs.index.size:
            if state.header is None:
                self._materialise(state)
            out = np.zeros(legs.size)
            if not legs.index.size:
                return out
            g, state.S, state.G, state.Ut, state.Vt, state.Pcc, state.Bcc = self._kernels.state_terms(
                self._P, self._B, state.header, state.idata, state.fdata, state.r, legs.cells, state.K, legs.m,
                legs.pair_ptr, legs.pair_cell, legs.pair_w, legs.var, legs.M)
            out[legs.index] = g
            return out
        # from the parent's terms, with the edge that leads here (the cells both nodes see keep their rows)
        plegs = self._legs_of(parent.node)
        j = int(plegs.row[state.action])
        edge = (parent.S[j], parent.G[j], int(plegs.m[j]), *plegs.nz[j]) if j >= 0 else _NO_EDGE
        (g, state.S, state.G, state.Ut, state.Vt, state.Pcc, state.Bcc, header, idata, fdata,
         K) = self._kernels.child_terms(self._P, self._B, parent.header, parent.idata, parent.fdata, parent.r,
                                        legs.cells, parent.K, legs.m, legs.pair_ptr, legs.pair_cell, legs.pair_w,
                                        legs.var, legs.M, plegs.cells, parent.Ut, parent.Vt, parent.Pcc, parent.Bcc,
                                        *edge)
        if j >= 0:
            state.header, state.idata, state.fdata, state.K = header, idata, fdata, K
            state.r = parent.r + edge[2]
        else:  # the leg sees nothing: the same posterior
            state.header, state.idata, state.fdata = parent.header, parent.idata, parent.fdata
            state.r, state.K = parent.r, parent.K
        out = np.zeros(legs.size)
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
            cdf = np.cumsum(softmax(cfg.rollout_lambda * rate / top))
            cdf /= cdf[-1]  # the draw of rng.choice(acts, p=...), without its checks: the same number, the same move
            a = int(acts[np.searchsorted(cdf, self.rng.random(), side="right")])
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
        self._begin(self._roi)
        self._unit = 1.0
        # from where the robot is (on the graph tasks, exactly the node; in MuJoCo, near it)
        root = _State(node, None, -1, view.remaining_s, 0.0, view.neighbour_durations(node, view.position))
        root.header, root.K = np.zeros((0, 5), dtype=np.int64), np.zeros((0, 0))
        root.idata, root.fdata = np.zeros(0, dtype=np.int64), np.zeros(0)
        self._expand_info(root)
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
