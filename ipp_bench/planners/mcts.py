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
A state keeps ``U``, ``V = P0 D U`` (D: the ROI's diagonal mask) and ``K = U^T D U`` (r x r), never P.
With the root terms of a leg (rows W on its cells, noise R) ``S0 = W P0 W^T + R`` and
``G0 = W (P0 D P0) W^T``, its predicted reduction of Tr(P) over the ROI is ``Tr(S^-1 G)`` with

    Y = W U,  Z = W V,  S = S0 - Y Y^T,  G = G0 - Z Y^T - Y Z^T + Y K Y^T,

the reference's ``sum_r (HP)_r^T S^-1 (HP)_r`` (:func:`~ipp_bench.belief.trace_reductions`) regrouped.
An expanded state with b legs of at most M rows over q cells costs O(q r^2 + nnz(W) r + b M^2 r) and
one batch of b (M, M) inverses, instead of the reference's O(b M q n) batched gain; an edge appends the
leg's block in O(n r m) instead of copying and downdating the n x n covariance (O(n^2 m)):
``C = P H^T = P0 H^T - U Y^T``, ``A = C L^-T`` (``L L^T = S``), the matching block of V from
``P0 D C = B0 H^T - V Y^T`` (``B0 = P0 D P0``, its rows computed once per decision as the search
reaches them), and K's new row and corner from ``U^T D C = Z^T - K Y^T`` and ``C^T D C = G``. A child's
factor is built only when its own gains are asked for (a rollout's last move, which crosses the
horizon, never needs it). The quantities are the reference's in exact arithmetic and agree to
round-off (~1e-15 of the largest gain); the root's gains are computed exactly as the reference computes
them, so that legs that tie exactly there (mirror images, frequent at the start) are ordered alike.
Deeper in the tree an exact tie can still be broken the other way by rounding, and the two searches
then grow different trees (``tests/planners/test_search_fast.py`` compares them on real decision
states; ``benchmarks/bench_search.py`` times them and counts identical moves). ``search =
"reference"`` runs the direct form (:mod:`ipp_bench.planners.mcts_reference`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from ..belief import LegBatch, trace_reductions
from ..config import check_integer, check_number
from ..mission import TIME_TOL_S
from .base import GraphPlanner, softmax, stacked_leg

#: the most simulations per decision (a decision at 10^5 takes about half an hour)
MAX_SIMULATIONS = 100_000
#: how the gains are computed: the low-rank factor (default) or the dense reference
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


class _Legs:
    """A roadmap node's legs as the low-rank gains use them (static for an episode).

    Attributes:
        batch: the legs padded to M rows (:class:`~ipp_bench.belief.LegBatch`; b of them see something).
        row: (k,) the batch row of each action (-1: the leg sees nothing).
        m: (b,) read-out rows of each leg (the rest of its M are padding: W = 0, unit variance).
        Wq: (b M, q) sparse, the stacked rows W over the batch's cells; Wt: (b, q, M) dense, each leg's W^T.
        cols: (2q,) the batch's cells, then the same offset by n: the rows of [U; V] on them.
    """

    __slots__ = ("batch", "row", "m", "Wq", "Wt", "b", "M", "cols")

    def __init__(self, batch: LegBatch, legs: list, n: int):
        self.batch = batch
        self.b = b = int(batch.index.size)
        self.row = np.full(batch.size, -1, dtype=np.int64)
        self.row[batch.index] = np.arange(b)
        if not b:
            return
        self.M = M = batch.W.shape[1]
        self.m = np.array([legs[i][1].shape[0] for i in batch.index])
        q = batch.cells.size
        flat = batch.W.reshape(b * M, q)
        r, c = np.nonzero(flat)
        w = flat[r, c]
        self.Wq = sparse.csr_array((w, (r, c)), shape=(b * M, q))
        self.Wt = np.ascontiguousarray(batch.W.transpose(0, 2, 1))
        self.cols = np.concatenate([batch.cells, batch.cells + n])


class _Factor:
    """Rows of [U | V]^T, shared by a chain of states: a child appends its rows in place when no other
    state has appended after its parent's (a rollout), else it copies (a second child in the tree)."""

    __slots__ = ("rows", "used")

    def __init__(self, capacity: int, width: int):
        self.rows = np.empty((capacity, width))
        self.used = 0


class _State:
    """A tree or rollout state. Its factor (``buf``: [U | V]^T, and ``K``) is built when its gains are first
    asked for."""

    __slots__ = ("node", "parent", "action", "buf", "r", "K", "remaining", "elapsed", "costs", "order", "gains",
                 "children", "visits", "Y", "T", "Q", "S", "Sinv")

    def __init__(self, node: int, parent: _State | None, action: int, remaining: float, elapsed: float,
                 costs: np.ndarray):
        self.node = node
        self.parent = parent  # the state this one was reached from (None: the root)
        self.action = action  # the move from the parent
        self.buf: _Factor | None = None  # its rows [:r] are [U | V]^T (r, 2n): U the factor, V = P0 D U
        self.r = 0
        self.K: np.ndarray | None = None  # (r, r): U^T D U
        self.remaining = remaining  # [s] of budget
        self.elapsed = elapsed  # [s] flown since the root
        self.costs = costs  # (k,) [s] flight time to each neighbour, by the mission's clock
        self.order: np.ndarray | None = None  # playable actions, best one-step gain/s first
        self.gains: np.ndarray | None = None  # one-step reward per action
        self.children: dict[int, list] = {}  # action -> [child, reward, discount, visits, value sum]
        self.visits = 0
        # of the gains, for the edges out of this state: Y = W U, T = (1/2) Y K - W V, Q = T Y^T + G0 / 2
        # (G = Q + Q^T), S and S^-1, each (b, M, .) over the node's legs
        self.Y = self.T = self.Q = self.S = self.Sinv = None


class MCTSPlanner(GraphPlanner):
    """MCTS with progressive widening and cost-benefit rollouts (paper baseline (c))."""

    name = "mcts"
    Config = MCTSConfig

    def __init__(self, config: MCTSConfig | None = None):
        super().__init__(config or MCTSConfig())
        self._reference = None

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
        self._legs: dict[tuple[int, int], tuple | None] = {}
        self._node_legs: dict[int, _Legs] = {}
        self._costs: dict[int, np.ndarray] = {}
        self._PB = None

    # -- the model: static per episode ---------------------------------------------------------
    def _leg(self, node: int, action: int):
        key = (node, action)
        if key not in self._legs:
            self._legs[key] = stacked_leg(self.view, node, action)
        return self._legs[key]

    def _legs_of(self, node: int) -> _Legs:
        legs = self._node_legs.get(node)
        if legs is None:
            raw = [self._leg(node, a) for a in range(self.view.roadmap.k)]
            legs = self._node_legs[node] = _Legs(LegBatch(raw), raw, self._n)
        return legs

    def _node_costs(self, node: int) -> np.ndarray:
        """(k,) flight times [s] from node ``node`` to its neighbours (the mission's clock; cached)."""
        costs = self._costs.get(node)
        if costs is None:
            costs = self._costs[node] = self.view.neighbour_durations(node)
        return costs

    # -- the model: per decision ---------------------------------------------------------------
    def _begin(self, roi: np.ndarray) -> None:
        """The decision's root terms: P0 and the rows of B0 = P0 D P0 (filled as the search reaches them)."""
        cov = self.view.belief.cov
        n = self._n = cov.shape[0]
        if getattr(self, "_PB", None) is None or self._PB.shape != (n, 2 * n):
            self._PB = np.empty((n, 2 * n))  # [P0 | B0]: B0's row c is filled (and read) once cell c is reached
        self._PB[:, :n] = cov
        self._D = roi.astype(np.float64)  # the ROI's diagonal mask
        self._filled = np.zeros(n, dtype=bool)
        self._root_terms: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._edge_terms: dict[tuple[int, int], np.ndarray] = {}

    def _fill_B0(self, cells: np.ndarray) -> None:
        new = cells[~self._filled[cells]]
        if new.size:
            P0 = self._PB[:, :self._n]
            self._PB[new, self._n:] = (P0[new] * self._D) @ P0  # B0[c, :] = (P0 D P0)[c, :]
            self._filled[new] = True

    def _node_terms(self, node: int, legs: _Legs) -> tuple[np.ndarray, np.ndarray]:
        """(S0, G0), each (b, M, M): W P0 W^T + R and W B0 W^T per leg of ``node`` at the root."""
        terms = self._root_terms.get(node)
        if terms is None:
            batch, b, M = legs.batch, legs.b, legs.M
            self._fill_B0(batch.cells)
            q = batch.cells.size
            block = self._PB[np.ix_(batch.cells, legs.cols)]  # (q, 2q): [P0 | B0] on the cells
            X = (legs.Wq @ block).reshape(b, M, 2, q)  # W P0 and W B0 on the cells, per leg
            S0, G0 = X[:, :, 0] @ legs.Wt, X[:, :, 1] @ legs.Wt
            idx = np.arange(M)
            S0[:, idx, idx] += batch.var
            terms = self._root_terms[node] = (S0, G0)
        return terms

    def _edge_term(self, node: int, action: int) -> np.ndarray:
        """(m, 2n): [H P0 | H B0] of the leg ``node -> action`` (C^T and (P0 D C)^T at the root)."""
        key = (node, action)
        term = self._edge_terms.get(key)
        if term is None:
            cells, W, _ = self._leg(node, action)
            term = self._edge_terms[key] = W @ self._PB[cells]
        return term

    def _materialise(self, state: _State) -> None:
        """The factor of ``state``: its parent's with the block of the leg that led to it appended."""
        parent, a = state.parent, state.action
        legs = self._legs_of(parent.node)
        j = int(legs.row[a])
        if j < 0:  # the leg sees nothing: the same posterior
            state.buf, state.r, state.K = parent.buf, parent.r, parent.K
            return
        m = int(legs.m[j])
        Sinv = parent.Sinv[j, :m, :m]
        L = np.linalg.cholesky(parent.S[j, :m, :m])
        Lit = Sinv @ L  # L^-T (= S^-1 L)
        CT = self._edge_term(parent.node, a)  # (m, 2n): [C | P0 D C]^T at the root
        r, buf = parent.r, parent.buf
        if r:
            Y, K = parent.Y[j, :m], parent.K  # (m, r): W U
            CT = CT - Y @ buf.rows[:r]  # C = P0 H^T - U Y^T, P0 D C = B0 H^T - V Y^T
            Q = parent.Q[j, :m, :m]
            G = Q + Q.T
            Z = 0.5 * (Y @ K) - parent.T[j, :m]  # W V
            X = (Z.T - K @ Y.T) @ Lit  # U^T D A
        else:
            G = self._root_terms[parent.node][1][j, :m, :m]
        AT = Lit.T @ CT  # (m, 2n): [A | P0 D A]^T
        corner = Lit.T @ G @ Lit  # A^T D A
        if buf.used != r or r + m > buf.rows.shape[0]:
            old, buf = buf, _Factor(max(2 * (r + m), 64), CT.shape[1])
            buf.rows[:r] = old.rows[:r]
        buf.rows[r:r + m] = AT
        buf.used = r + m
        state.buf, state.r = buf, r + m
        if r:
            state.K = Kn = np.empty((r + m, r + m))
            Kn[:r, :r], Kn[:r, r:], Kn[r:, :r], Kn[r:, r:] = K, X, X.T, corner
        else:
            state.K = corner

    def _gains(self, state: _State) -> np.ndarray:
        """(k,) predicted reductions of Tr(P) over the decision's ROI, one per leg out of ``state``."""
        if state.buf is None:
            self._materialise(state)
        legs = self._legs_of(state.node)
        out = np.zeros(legs.batch.size)
        if not legs.b:
            return out
        S0, G0 = self._node_terms(state.node, legs)
        b, M = legs.b, legs.M
        r = state.r
        if r:
            q = legs.batch.cells.size
            Fb = np.take(state.buf.rows[:r], legs.cols, axis=1)  # (r, 2q): [U | V]^T on the batch's cells
            Ub = Fb[:, :q].T
            UT = np.empty((q, 2 * r))
            UT[:, :r] = Ub
            UT[:, r:] = 0.5 * (Ub @ state.K) - Fb[:, q:].T  # (1/2) U K - V
            X = legs.Wq @ UT  # (b M, 2r): [Y | T], Y = W U, T = (1/2) Y K - Z, Z = W V
            Y, T = X[:, :r].reshape(b, M, r), X[:, r:].reshape(b, M, r)
            Yt = Y.transpose(0, 2, 1)
            S = S0 - Y @ Yt
            Q = T @ Yt  # G = G0 - Z Y^T - Y Z^T + Y K Y^T = G0 + Q + Q^T
            Sinv = np.linalg.inv(S)
            Q += 0.5 * G0
            g = 2.0 * np.einsum("bij,bij->b", Sinv, Q)  # Tr(S^-1 G), S^-1 symmetric
            state.Y, state.T, state.Q = Y, T, Q
        else:
            S = S0
            Sinv = np.linalg.inv(S)
            g = np.einsum("bij,bij->b", Sinv, G0)
        state.S, state.Sinv = S, Sinv
        out[legs.batch.index] = g
        return out

    def _expand_info(self, state: _State) -> None:
        """Playable actions and their one-step rewards, best reward per second first."""
        costs = state.costs
        if state.elapsed >= self.settings.horizon_s - TIME_TOL_S:
            state.order = np.zeros(0, dtype=np.int64)
            return
        actions = np.flatnonzero(self.view.fits_budget(costs, state.remaining))
        gains = self._gains(state)
        if state.parent is None:
            # the root's gains as the reference computes them (its Kalman terms stay for the edges): the
            # same bits, so the same order where legs tie exactly (mirror images, often at the start)
            gains = trace_reductions(self.view.belief.cov, self._legs_of(state.node).batch, self._roi)
        state.gains = gains / self._unit
        rate = state.gains[actions] / costs[actions]
        state.order = actions[np.lexsort((actions, -rate))]

    def _transition(self, state: _State, action: int) -> tuple[_State, float, float]:
        """(next state, reward, discount): the move crossing the horizon counts pro rata."""
        rm = self.view.roadmap
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
        self._begin(self._roi)
        self._unit = 1.0
        # from where the robot is (on the graph tasks, exactly the node; in MuJoCo, near it)
        root = _State(node, None, -1, view.remaining_s, 0.0, view.neighbour_durations(node, view.position))
        root.buf, root.K = _Factor(64, 2 * self._n), np.zeros((0, 0))
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
