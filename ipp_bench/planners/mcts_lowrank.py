"""The MCTS's low-rank gains model (``mcts:search=lowrank``, the default): the reference's gains from a low-rank
factor of the tree's covariance updates, compiled.

A tree state's covariance is the root's less the updates along its path, ``P = P0 - U U^T``; a state keeps only
its edges' small terms, and the search rebuilds, edge by edge from the root, the rows of U it needs on the cells
the legs of the node being expanded see. Each rollout runs compiled
(:func:`~ipp_bench.planners.kernels.lowrank.rollout`) with the planner's generator, the reference's moves. The
quantities are the reference's in exact arithmetic and agree to round-off; where two legs' gains per second lie
within rounding of each other at the root, the root's gains are the reference's own, so the same order. The
derivation, term by term: ``docs/mcts-lowrank.md``. Needs numba (the ``eval`` extra); the kernels are compiled
when the planner is first reset and cached on disk (:mod:`~ipp_bench.planners.kernels`).
"""

from __future__ import annotations

import numpy as np

from ..core.mission import TIME_TOL_S
from .base import RobotView
from .mcts_reference import ReferenceGains

#: the legs' layouts of the last roadmaps searched ((camera, spacing, neighbours, positions) -> (node table, the
#: legs' rows)), shared by the planners of a process: the layout is static for a roadmap
_LAYOUTS: dict[tuple, tuple] = {}
_MAX_LAYOUTS = 4


def _near_ties(rates: np.ndarray) -> bool:
    """Whether two of ``rates`` lie within rounding of each other (1e-9 of the largest), other than
    exact zeros (legs that see nothing score exactly 0 in both searches)."""
    r = np.sort(rates)
    close = np.diff(r) <= 1e-9 * np.abs(r).max(initial=0.0)
    return bool(np.any(close & ((r[1:] != 0.0) | (r[:-1] != 0.0))))


class _Legs:
    """A roadmap node's legs as the low-rank gains use them (static for an episode;
    :func:`~ipp_bench.planners.kernels.node_table.node_legs`): views of the node table's pools.

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

    def __init__(self, table, node: int):
        from .kernels.lowrank import node_view

        (b, self.M, self.row, self.index, self.cells, self.m, self.rptr, self.var, ptr, nz_row, nz_cell, nz_ints,
         nz_w) = node_view(table.ipool, table.fpool, table.table, node, table.k)
        self.size = table.k
        self.nz_cell, self.nz_w = nz_cell, nz_w
        self.nz = [(nz_row[ptr[j]:ptr[j + 1]], nz_cell[ptr[j]:ptr[j + 1]], nz_w[ptr[j]:ptr[j + 1]],
                    nz_ints[2 * ptr[j]:2 * ptr[j + 1]]) for j in range(b)]


class LowRankGains:
    """The low-rank gains model of :class:`~ipp_bench.planners.mcts.MCTSPlanner` for one episode (``view``).

    A state's terms (``header`` to ``K``: its factor; ``Li`` to ``Bcc``: what its edges reuse) are set when its
    gains are first asked for, from its parent's.
    """

    def __init__(self, view: RobotView):
        from . import kernels
        from .kernels import lowrank, node_table, readouts

        kernels.warm_up()  # compiled once per process, before the first decision's clock starts
        self._lowrank, self._readouts = lowrank, readouts
        self.view = view
        self._reference = ReferenceGains(view)  # the root's gains where legs tie within rounding
        self._camera = readouts.camera_args(view.sensor)
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
            self._table, self._legs = node_table.NodeTable(nodes, k), {}
            for node in range(nodes):  # every node, once per roadmap and process, in no decision
                self._lay_out(node)
            self._table.compact()
            layout = _LAYOUTS[key] = (self._table, self._legs)
        self._table, self._legs = layout
        self._P = self._B = None

    @staticmethod
    def check_installed() -> None:
        """Raise, naming the extra to install, when numba is missing."""
        from .kernels.jit import require_numba

        require_numba("mcts:search=lowrank")

    # -- the legs: static per roadmap -----------------------------------------------------------
    def _leg(self, node: int, action: int):
        """The read-outs of the leg ``node -> action`` as the mission would take them, in sparse rows
        (:func:`~ipp_bench.planners.kernels.readouts.camera_rows`, repeated rows folded into one:
        :func:`~ipp_bench.planners.kernels.readouts.fold_repeated_rows`); None where the camera sees nothing."""
        key = (node, action)
        if key not in self._legs:
            rm = self.view.roadmap
            k = self._readouts
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
        return _Legs(self._table, node)

    # -- per decision ---------------------------------------------------------------------------
    def begin(self, roi: np.ndarray) -> None:
        """A decision's search starts: its root terms, P0 and B0 = P0 D P0 (D: the ROI's diagonal mask; one
        product: a search reaches most cells of the map)."""
        self._reference.begin(roi)
        self._P = np.ascontiguousarray(self.view.belief.cov)
        self._B = self._readouts.roi_product(self._P, roi, self._B)

    def enter(self, state) -> None:
        """A new state: its terms wait until its gains are asked for."""

    @staticmethod
    def _terms(state) -> tuple:
        """The terms of a scored state in the order the kernels take them (header to G)."""
        return (state.header, state.idata, state.fdata, state.r, state.K, state.UV, state.Pcc, state.Bcc, state.Li,
                state.G)

    @staticmethod
    def _set_terms(state, Li, G, UV, Pcc, Bcc, header, idata, fdata, r, K) -> None:
        state.Li, state.G, state.UV, state.Pcc, state.Bcc = Li, G, UV, Pcc, Bcc
        state.header, state.idata, state.fdata, state.r, state.K = header, idata, fdata, r, K

    def _factor_gains(self, state) -> np.ndarray:
        """(k,) predicted reductions of Tr(P) over the decision's ROI, one per leg out of ``state`` (its
        parent scored), and its terms."""
        parent = state.parent
        if parent is not None:  # from the parent's terms and the edge that leads here (kernels.lowrank.step_terms)
            self._lay_out(state.node)
            t = self._table
            out = self._lowrank.step_terms(self._P, self._B, t.ipool, t.fpool, t.table, t.k, parent.node, state.action,
                                           state.node, *self._terms(parent))
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
        g, state.Li, state.G, state.UV, state.Pcc, state.Bcc = self._lowrank.state_terms(
            self._P, self._B, state.header, state.idata, state.fdata, state.r, legs.cells, state.K, legs.m,
            legs.rptr, legs.nz_cell, legs.nz_w, legs.var, legs.M)
        out[legs.index] = g
        return out

    def gains(self, state, actions: np.ndarray) -> np.ndarray:
        """(k,) predicted reductions of Tr(P) over the decision's ROI, one per leg out of ``state`` (``actions``:
        its playable legs)."""
        gains = self._factor_gains(state)
        if state.parent is None and _near_ties(gains[actions] / state.costs[actions]):
            # legs that tie at the root (mirror images, often at the start): their gains as the reference
            # computes them (the Kalman terms above stay for the edges), the same bits, so the same order
            gains = self._reference.leg_gains(self.view.belief.cov, state.node)
        return gains

    def rollout(self, tree, state) -> float:
        """The rollout's return from the tree's new state ``state`` (compiled: kernels.lowrank.rollout), which it
        expands on the way (``tree``: the planner, whose settings, generator and flight times it uses)."""
        cfg = tree.settings
        if state.elapsed >= cfg.horizon_s - TIME_TOL_S:
            state.order = np.zeros(0, dtype=np.int64)
            return 0.0
        self._lay_out(state.node)
        parent, table = state.parent, self._table
        args = tuple(map(float, (cfg.horizon_s, TIME_TOL_S, cfg.gamma, cfg.discount_period_s, cfg.rollout_lambda,
                                 tree._unit)))  # the types the kernels were compiled for
        mode, go_on = 0, (parent.node, float(state.remaining), float(state.elapsed), parent.gains, state.action, 0.0,
                          1.0, *self._terms(parent))
        while True:
            (status, need, total, discount, gains, order, terms, node, remaining, elapsed, now_gains, action,
             now_terms) = self._lowrank.rollout(self._P, self._B, table.ipool, table.fpool, table.table,
                                                self._neighbours, tree._cost_rows, tree._known, tree.rng, *args, mode,
                                                *go_on)
            if mode == 0:
                state.gains, state.order = gains, order
                self._set_terms(state, *terms)
            if status == 0:
                return total
            # the move drawn leads to a node the search had not reached: its flight times, its legs, and on
            tree._node_costs(need)
            if elapsed + tree._cost_rows[node, action] < cfg.horizon_s - TIME_TOL_S:
                self._lay_out(need)
            Li, G, UV, Pcc, Bcc, header, idata, fdata, r, K = now_terms
            mode, go_on = 1, (node, remaining, elapsed, now_gains, action, total, discount, header, idata, fdata, r,
                              K, UV, Pcc, Bcc, Li, G)
