"""Every roadmap node's legs laid out for the compiled MCTS search, once per roadmap: :func:`node_legs` lays out
one node's legs and :class:`NodeTable` holds every node's in two flat pools, which the search reads
(:func:`~ipp_bench.planners.kernels.lowrank.node_view`; the table's columns: ``T_*``)."""

from __future__ import annotations

import numpy as np

from .jit import kernel
from .lowrank import (
    T_B,
    T_BUILT,
    T_CELLS,
    T_INDEX,
    T_LEGM,
    T_M,
    T_NZ_CELL,
    T_NZ_INTS,
    T_NZ_PTR,
    T_NZ_ROW,
    T_NZ_W,
    T_Q,
    T_ROW,
    T_RPTR,
    T_VAR,
    TABLE_WIDTH,
)


@kernel
def node_legs(leg_rows, row_ptr, cells, weights, var):
    """A roadmap node's legs laid out for :func:`~ipp_bench.planners.kernels.lowrank.state_terms`, from their
    read-outs in sparse rows.

    Leg i has rows ``leg_rows[i]`` to ``leg_rows[i + 1]`` of (``row_ptr``, ``cells``, ``weights``, ``var``)
    (as :func:`~ipp_bench.planners.kernels.readouts.camera_rows` gives them; none: the leg sees nothing). The b
    legs that see something are padded to M rows (padding: no weights, unit variance) over the union of their
    q cells.

    Returns:
        index (b,) the legs that see something; union (q,) their cells, ascending; m (b,) their rows;
        var (b, M); nz_ptr, nz_row, nz_cell, nz_w: leg j's weights (row, index in ``union``, value) between
        ``nz_ptr[j]`` and ``nz_ptr[j + 1]``, row by row; rptr (b, M + 1): where each of leg j's rows starts
        among them (row a: ``rptr[j, a]`` to ``rptr[j, a + 1]``; padding rows are empty).
    """
    k = leg_rows.size - 1
    b = 0
    M = 1
    for i in range(k):
        rows = leg_rows[i + 1] - leg_rows[i]
        if rows > 0:
            b += 1
            M = max(M, rows)
    index = np.empty(b, dtype=np.int64)
    m = np.empty(b, dtype=np.int64)
    j = 0
    for i in range(k):
        rows = leg_rows[i + 1] - leg_rows[i]
        if rows > 0:
            index[j] = i
            m[j] = rows
            j += 1
    union = np.unique(cells)
    local = np.empty(cells.size, dtype=np.int64)
    for p in range(cells.size):
        local[p] = np.searchsorted(union, cells[p])
    var_pad = np.ones((b, M))
    nz_ptr = np.zeros(b + 1, dtype=np.int64)
    for j in range(b):
        r0 = leg_rows[index[j]]
        nz_ptr[j + 1] = nz_ptr[j] + row_ptr[r0 + m[j]] - row_ptr[r0]
    nz_row = np.empty(nz_ptr[b], dtype=np.int64)
    nz_cell = np.empty(nz_ptr[b], dtype=np.int64)
    nz_w = np.empty(nz_ptr[b])
    rptr = np.empty((b, M + 1), dtype=np.int64)
    for j in range(b):
        r0 = leg_rows[index[j]]
        t = nz_ptr[j]
        for a in range(M + 1):
            rptr[j, a] = nz_ptr[j + 1]
        for a in range(m[j]):
            var_pad[j, a] = var[r0 + a]
            rptr[j, a] = t
            for p in range(row_ptr[r0 + a], row_ptr[r0 + a + 1]):
                nz_row[t] = a
                nz_cell[t] = local[p]
                nz_w[t] = weights[p]
                t += 1
    return index, union, m, var_pad, nz_ptr, nz_row, nz_cell, nz_w, rptr


class NodeTable:
    """Every roadmap node's legs laid out for the compiled search, a node when the search first reaches it, in
    two flat pools (the layout of :func:`node_legs`; the table's columns: ``T_*``), which the compiled search
    reads (:func:`~ipp_bench.planners.kernels.lowrank.node_view`)."""

    def __init__(self, nodes: int, k: int):
        self.k = k
        self.table = np.zeros((nodes, TABLE_WIDTH), dtype=np.int64)
        self.ipool = np.zeros(1 << 16, dtype=np.int64)
        self.fpool = np.zeros(1 << 16)
        self._ni = self._nf = 0

    def built(self, node: int) -> bool:
        return bool(self.table[node, T_BUILT])

    def add(self, node: int, legs: list) -> None:
        """Lay out node ``node``'s legs (``legs[a]``: the sparse rows of leg a, None where it sees nothing)."""
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
        index, union, m, var_pad, nz_ptr, nz_row, nz_cell, nz_w, rptr = node_legs(leg_rows, row_ptr,
                                                                                   cells.astype(np.int64), weights, var)
        row = np.full(self.k, -1, dtype=np.int64)
        row[index] = np.arange(index.size)
        nz_ints = np.concatenate([np.zeros(0, dtype=np.int64)] + [
            np.concatenate([nz_row[nz_ptr[j]:nz_ptr[j + 1]], union[nz_cell[nz_ptr[j]:nz_ptr[j + 1]]]])
            for j in range(index.size)])
        ints = (row, index, union, m, rptr.ravel(), nz_ptr, nz_row, nz_cell, nz_ints)
        floats = (var_pad.ravel(), nz_w)
        i0 = self._ni
        f0 = self._nf
        self.ipool = self._grown(self.ipool, i0, sum(a.size for a in ints))
        self.fpool = self._grown(self.fpool, f0, sum(a.size for a in floats))
        entry = self.table[node]
        entry[T_B], entry[T_M], entry[T_Q] = index.size, var_pad.shape[1], union.size
        for col, a in zip((T_ROW, T_INDEX, T_CELLS, T_LEGM, T_RPTR, T_NZ_PTR, T_NZ_ROW, T_NZ_CELL, T_NZ_INTS), ints):
            self.ipool[i0:i0 + a.size] = a
            entry[col] = i0
            i0 += a.size
        for col, a in zip((T_VAR, T_NZ_W), floats):
            self.fpool[f0:f0 + a.size] = a
            entry[col] = f0
            f0 += a.size
        self._ni, self._nf = i0, f0
        entry[T_BUILT] = 1

    def compact(self) -> None:
        """Drop the pools' room past what they hold."""
        self.ipool = self.ipool[:self._ni].copy()
        self.fpool = self.fpool[:self._nf].copy()

    @staticmethod
    def _grown(pool: np.ndarray, used: int, more: int) -> np.ndarray:
        """``pool`` with room for ``more`` entries after its first ``used`` (its size doubled where it lacks it)."""
        if used + more <= pool.size:
            return pool
        bigger = np.zeros(max(2 * pool.size, used + more), dtype=pool.dtype)
        bigger[:used] = pool[:used]
        return bigger
