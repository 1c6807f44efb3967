"""Compiled kernels of the look-ahead planners' fast searches (numba; nothing cached on disk).

- both: :func:`camera_rows` turns read-out positions (:func:`leg_points`) into the camera's sparse rows
  and :func:`fold_repeated_rows` folds a footprint looked at twice into one row; :func:`roi_product` is
  the decision's B = P D P;
- MCTS (:mod:`ipp_bench.planners.mcts`, ``search = "lowrank"``): :func:`node_legs` lays out a node's legs
  (once per node and episode), :func:`state_terms` scores every leg out of one tree state from the
  state's low-rank factor, :func:`child_terms` does the same from the terms of the state's parent, and
  :func:`edge_terms` adds one edge to the factor;
- CMA-ES (:mod:`ipp_bench.planners.cmaes`, ``evaluation = "batched"``): :func:`readout_blocks` gives the
  S and G of a candidate path's predicted gain ``Tr(S^-1 G)``.

They compute the references' quantities in exact arithmetic (the Kalman update's ``Tr(S^-1 G)``
regrouped; floating point reordered, nothing approximated) and are deterministic: no fast-math, a fixed
loop order, one thread, BLAS only through ``np.dot`` (on one thread, ``ipp_bench._threads``).

A process compiles them once, when a planner that uses them is first reset (:func:`warm_up`: 10-30 s,
outside any decision), and writes no cache file (nothing compiled is loaded from disk; a read-only
install works).
"""

from __future__ import annotations

import math

import numpy as np

from ..mission import leg_length, leg_samples
from .base import MIN_LEG_M

try:
    import numba
except ImportError:  # pragma: no cover (the eval extra installs it)
    numba = None


def require_numba(what: str) -> None:
    """Raise, naming the extra to install, when numba is missing."""
    if numba is None:
        raise ImportError(f'{what} needs numba: pip install "ipp-bench[eval]"')


def _jit(fn):
    return fn if numba is None else numba.njit(cache=False, fastmath=False, nogil=True)(fn)


@_jit
def _cholesky_inverse(S, m, Linv):
    """``Linv[:m, :m]`` = L^-1 with L L^T = S[:m, :m] (lower triangular; S symmetric positive definite)."""
    L = np.zeros((m, m))
    for j in range(m):
        d = S[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            raise ValueError("S = H P H^T + R is not positive definite")
        d = np.sqrt(d)
        L[j, j] = d
        for i in range(j + 1, m):
            s = S[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
    for i in range(m):
        for j in range(m):
            Linv[i, j] = 0.0
    for j in range(m):  # column j of L^-1: forward substitution of e_j
        Linv[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, m):
            s = 0.0
            for k in range(j, i):
                s -= L[i, k] * Linv[k, j]
            Linv[i, j] = s / L[i, i]


@_jit
def _trace_inv_product(Linv, G, m):
    """Tr(S^-1 G) = sum_ij (L^-T L^-1)_ij G_ij for symmetric G."""
    total = 0.0
    for i in range(m):
        for j in range(i + 1):
            s = 0.0
            for k in range(i, m):  # (L^-T L^-1)_ij = sum_k Linv[k, i] Linv[k, j], k >= max(i, j)
                s += Linv[k, i] * Linv[k, j]
            total += s * G[i, j] if i == j else 2.0 * s * G[i, j]
    return total


@_jit
def node_legs(leg_rows, row_ptr, cells, weights, var):
    """A roadmap node's legs laid out for :func:`state_terms`, from their read-outs in sparse rows.

    Leg i has rows ``leg_rows[i]`` to ``leg_rows[i + 1]`` of (``row_ptr``, ``cells``, ``weights``, ``var``)
    (as :func:`camera_rows` gives them; none: the leg sees nothing). The b legs that see something are
    padded to M rows (padding: no weights, unit variance) over the union of their q cells.

    Returns:
        index (b,) the legs that see something; union (q,) their cells, ascending; m (b,) their rows;
        var (b, M); pair_ptr, pair_cell, pair_w: for leg j and rows (a, c), c <= a (entry ``j M (M + 1) / 2
        + a (a + 1) / 2 + c``), the products ``w_a[x] w_c[y]`` of their weights with the flat index ``x q +
        y`` of the cells (x, y: their indices in ``union``); nz_ptr, nz_row, nz_cell, nz_w: leg j's weights
        (row, index in ``union``, value) between ``nz_ptr[j]`` and ``nz_ptr[j + 1]``.
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
    q = union.size
    local = np.empty(cells.size, dtype=np.int64)
    for p in range(cells.size):
        local[p] = np.searchsorted(union, cells[p])
    var_pad = np.ones((b, M))
    tri = M * (M + 1) // 2
    pair_ptr = np.zeros(b * tri + 1, dtype=np.int64)
    for j in range(b):
        r0 = leg_rows[index[j]]
        for a in range(M):
            for c in range(a + 1):
                e = j * tri + a * (a + 1) // 2 + c
                count = 0
                if a < m[j]:
                    count = (row_ptr[r0 + a + 1] - row_ptr[r0 + a]) * (row_ptr[r0 + c + 1] - row_ptr[r0 + c])
                pair_ptr[e + 1] = pair_ptr[e] + count
    pair_cell = np.empty(pair_ptr[b * tri], dtype=np.int64)
    pair_w = np.empty(pair_ptr[b * tri])
    nz_ptr = np.zeros(b + 1, dtype=np.int64)
    for j in range(b):
        r0 = leg_rows[index[j]]
        nz_ptr[j + 1] = nz_ptr[j] + row_ptr[r0 + m[j]] - row_ptr[r0]
    nz_row = np.empty(nz_ptr[b], dtype=np.int64)
    nz_cell = np.empty(nz_ptr[b], dtype=np.int64)
    nz_w = np.empty(nz_ptr[b])
    for j in range(b):
        r0 = leg_rows[index[j]]
        t = nz_ptr[j]
        for a in range(m[j]):
            var_pad[j, a] = var[r0 + a]
            for p in range(row_ptr[r0 + a], row_ptr[r0 + a + 1]):
                nz_row[t] = a
                nz_cell[t] = local[p]
                nz_w[t] = weights[p]
                t += 1
            for c in range(a + 1):
                e = pair_ptr[j * tri + a * (a + 1) // 2 + c]
                for p in range(row_ptr[r0 + a], row_ptr[r0 + a + 1]):
                    for u in range(row_ptr[r0 + c], row_ptr[r0 + c + 1]):
                        pair_cell[e] = local[p] * q + local[u]
                        pair_w[e] = weights[p] * weights[u]
                        e += 1
    return index, union, m, var_pad, pair_ptr, pair_cell, pair_w, nz_ptr, nz_row, nz_cell, nz_w


@_jit
def _leg_blocks(Pf, Bf, j, M, m, pair_ptr, pair_cell, pair_w, var, S, G):
    """S = W P W^T + R and G = W B W^T of leg ``j``: entry (a, c), c <= a, sums ``pair_w * P[pair_cell]`` over
    the products of row a's and row c's weights (``Pf``, ``Bf``: P_cc and B_cc flattened)."""
    base = j * M * (M + 1) // 2
    for a in range(m):
        for c in range(a + 1):
            e = base + a * (a + 1) // 2 + c
            s = 0.0
            g = 0.0
            for p in range(pair_ptr[e], pair_ptr[e + 1]):
                w = pair_w[p]
                s += w * Pf[pair_cell[p]]
                g += w * Bf[pair_cell[p]]
            S[a, c] = s
            S[c, a] = s
            G[a, c] = g
            G[c, a] = g
        S[a, a] += var[j, a]


@_jit
def _edge_rows(P, B, header, idata, fdata, e, cells, UV):
    """Edge ``e``'s block of ``UV`` = [Ut | Vt] on the q cells ``cells``: its rows ``r_e`` to ``r_e + m`` from
    the rows before it (:func:`_factor_rows` reads the edges)."""
    q = cells.size
    m, re, nnz, fo, io = header[e, 0], header[e, 1], header[e, 2], header[e, 3], header[e, 4]
    E = np.zeros((m, 2 * q))  # [(H P0)[:, c] | (H B0)[:, c]]
    for p in range(nnz):
        a = idata[io + p]
        rowP = P[idata[io + nnz + p]]
        rowB = B[idata[io + nnz + p]]
        w = fdata[fo + p]
        for i in range(q):
            E[a, i] += w * rowP[cells[i]]
            E[a, q + i] += w * rowB[cells[i]]
    Linv = fdata[fo + nnz:fo + nnz + m * m].reshape((m, m))
    if re > 0:
        Y = fdata[fo + nnz + m * m:fo + nnz + m * m + m * re].reshape((m, re))
        E -= np.dot(Y, UV[:re])
    UV[re:re + m] = np.dot(Linv, E)


@_jit
def _factor_rows(P, B, header, idata, fdata, r, cells):
    """Ut, Vt (r, q): the rows of U^T and V^T = (P0 D U)^T on the q cells ``cells``, rebuilt edge by edge.

    Edge e (``header[e]`` = m, r_e (the rows before it), nnz, offset in ``fdata``, offset in ``idata``) is a
    leg of m read-out rows: its weights (row ``idata[io:io + nnz]``, map cell ``idata[io + nnz:io + 2 nnz]``,
    value ``fdata[fo:fo + nnz]``), then L^-1 (m, m) and Y = W U (m, r_e) of the state it leaves. Its block
    of the factor is A = C L^-T with C = P0 H^T - U Y^T, and that of V is P0 D A, with P0 D C = B0 H^T - V Y^T
    (``P`` = P0 and ``B`` = B0, both symmetric).
    """
    q = cells.size
    UV = np.empty((r, 2 * q))  # [Ut | Vt]
    for e in range(header.shape[0]):
        _edge_rows(P, B, header, idata, fdata, e, cells, UV)
    Ut = np.ascontiguousarray(UV[:, :q])
    Vt = np.ascontiguousarray(UV[:, q:])
    return Ut, Vt


@_jit
def _legs_gains(Pcc, Bcc, leg_m, pair_ptr, pair_cell, pair_w, var, M):
    """Each leg's gain Tr(S^-1 G) and its S, G (b, M, M) from P and P D P on the node's cells."""
    b = leg_m.size
    Pf = Pcc.ravel()
    Bf = Bcc.ravel()
    gains = np.empty(b)
    S = np.zeros((b, M, M))
    G = np.zeros((b, M, M))
    Linv = np.empty((M, M))
    for j in range(b):
        m = leg_m[j]
        _leg_blocks(Pf, Bf, j, M, m, pair_ptr, pair_cell, pair_w, var, S[j], G[j])
        _cholesky_inverse(S[j], m, Linv)
        gains[j] = _trace_inv_product(Linv, G[j], m)
    return gains, S, G


@_jit
def state_terms(P, B, header, idata, fdata, r, cells, K, leg_m, pair_ptr, pair_cell, pair_w, var, M):
    """The one-step gains of every leg out of a tree state, and the terms its edges reuse.

    The state's covariance is P0 - U U^T (U: the blocks of the edges from the root, ``header``, ``idata``,
    ``fdata`` as :func:`_factor_rows` reads them; r columns) and K = U^T D U; ``P`` = P0 and ``B`` = B0 =
    P0 D P0, both (n, n). On the node's q cells ``cells``, with Uc, Vc the rows of U and V = P0 D U there:
    ``P_cc = P0_cc - Uc Uc^T`` and ``B_cc = (P D P)_cc = B0_cc - Vc Uc^T - Uc Vc^T + Uc K Uc^T``. Each leg j
    (rows W_j over those cells, as the weight products ``pair_*`` of each pair of its rows; noise ``var[j]``) has ``S =
    W P_cc W^T + R``, ``G = W B_cc W^T`` and gain ``Tr(S^-1 G)``: the reduction of Tr(P) over the ROI D.

    Returns:
        gains (b,); S and G, each (b, M, M) (zero past each leg's ``leg_m`` rows); Uc^T and Vc^T, each (r, q);
        P_cc and B_cc (q, q) (what :func:`child_terms` starts from).
    """
    q = cells.size
    Ut, Vt = _factor_rows(P, B, header, idata, fdata, r, cells)
    Pcc = np.empty((q, q))
    Bcc = np.empty((q, q))
    for i in range(q):
        for k in range(q):
            Pcc[i, k] = P[cells[i], cells[k]]
            Bcc[i, k] = B[cells[i], cells[k]]
    if r > 0:
        Tt = 0.5 * np.dot(K, Ut) - Vt  # ((1/2) Uc K - Vc)^T: Uc T + T^T Uc^T = Uc K Uc^T - Uc Vc^T - Vc Uc^T
        both = np.empty((r, 2 * q))
        both[:, :q] = Ut
        both[:, q:] = Tt
        prod = np.dot(Ut.T, both)  # [Uc Uc^T | Uc T]
        for i in range(q):
            for k in range(q):
                Pcc[i, k] -= prod[i, k]
                Bcc[i, k] += prod[i, q + k] + prod[k, q + i]
    gains, S, G = _legs_gains(Pcc, Bcc, leg_m, pair_ptr, pair_cell, pair_w, var, M)
    return gains, S, G, Ut, Vt, Pcc, Bcc


@_jit
def child_terms(P, B, header, idata, fdata, r, cells, K, leg_m, pair_ptr, pair_cell, pair_w, var, M, pcells, pUt,
                pVt, pPcc, pBcc, eS, eG, em, erows, ecells, ew, eints):
    """:func:`state_terms` of a state from its parent's terms, with the edge that leads to it.

    ``header``, ``idata``, ``fdata``, ``r`` and ``K`` are the parent's factor, ``pcells`` the parent node's
    cells (ascending), ``pUt``, ``pVt`` (r_p, q_p) the rows of U^T and V^T there and ``pPcc``, ``pBcc`` P
    and P D P there. The edge is the parent's leg of ``em`` rows (0: it sees nothing, the factor stays)
    with the parent's ``eS``, ``eG`` of that leg and its weights (row ``erows``, index ``ecells`` among
    ``pcells``, value ``ew``; ``eints`` = rows, then map cells): :func:`edge_terms` adds it to the factor.

    Returns:
        what :func:`state_terms` returns, then the state's factor: header, idata, fdata, K.
    """
    if em > 0:
        Linv, Y, K = edge_terms(eS, eG, em, erows, ecells, ew, pUt, pVt, K)
        h = header.shape[0]
        nnz = ew.size
        head = np.empty((h + 1, 5), dtype=np.int64)
        head[:h] = header
        head[h, 0], head[h, 1], head[h, 2], head[h, 3], head[h, 4] = em, r, nnz, fdata.size, idata.size
        header = head
        idata = np.concatenate((idata, eints))
        fo = fdata.size
        fnew = np.empty(fo + nnz + em * em + em * r)
        fnew[:fo] = fdata
        fnew[fo:fo + nnz] = ew
        fnew[fo + nnz:fo + nnz + em * em] = Linv.ravel()
        fnew[fo + nnz + em * em:] = Y.ravel()
        fdata = fnew
        r = r + em
    gains, S, G, Ut, Vt, Pcc, Bcc = _from_parent(P, B, header, idata, fdata, r, cells, K, leg_m, pair_ptr, pair_cell,
                                                 pair_w, var, M, pcells, pUt, pVt, pPcc, pBcc)
    return gains, S, G, Ut, Vt, Pcc, Bcc, header, idata, fdata, K


@_jit
def _from_parent(P, B, header, idata, fdata, r, cells, K, leg_m, pair_ptr, pair_cell, pair_w, var, M, pcells, pUt,
                 pVt, pPcc, pBcc):
    """:func:`state_terms` of a state (its factor: ``header`` to ``K``) from its parent's terms: ``pcells`` the
    parent node's cells (ascending), ``pUt``, ``pVt`` (r_p, q_p) the rows of U^T and V^T there and ``pPcc``,
    ``pBcc`` P and P D P there.

    The rows of U, V, P and P D P on the cells both nodes' legs see are the parent's; those on the other
    cells are rebuilt from the root (:func:`_factor_rows`; ``P_ik = P0_ik - U_i U_k`` and ``(P D P)_ik =
    B0_ik + (K U_i - V_i) U_k - U_i V_k``), and the edge from the parent (if it saw something: rows A of U,
    P0 D A of V, r_p to r) then updates them: ``P -= A A^T`` and ``P D P += A T^T + T A^T`` with ``T =
    A K_aa / 2 + U K_ua - P0 D A`` (K_aa, K_ua: K's new corner and column block).
    """
    q = cells.size
    qp = pcells.size
    rp = pUt.shape[0]
    pos = np.empty(q, dtype=np.int64)  # each cell's index among the parent's (-1: not there)
    qn = 0
    for i in range(q):
        t = np.searchsorted(pcells, cells[i])
        if t < qp and pcells[t] == cells[i]:
            pos[i] = t
        else:
            pos[i] = -1
            qn += 1
    fresh = np.empty(qn, dtype=np.int64)  # indices (among ``cells``) of the cells the parent did not see
    t = 0
    for i in range(q):
        if pos[i] < 0:
            fresh[t] = i
            t += 1
    UV = np.empty((r, 2 * q))  # [Ut | Vt]
    if rp > 0:
        Un = np.empty((rp, 0))
        Vn = np.empty((rp, 0))
        if qn > 0:
            edges = header.shape[0] - (1 if r > rp else 0)
            Un, Vn = _factor_rows(P, B, header[:edges], idata, fdata, rp, cells[fresh])
        t = 0
        for i in range(q):
            if pos[i] >= 0:
                for k in range(rp):
                    UV[k, i] = pUt[k, pos[i]]
                    UV[k, q + i] = pVt[k, pos[i]]
            else:
                for k in range(rp):
                    UV[k, i] = Un[k, t]
                    UV[k, q + i] = Vn[k, t]
                t += 1
    Pcc = np.empty((q, q))
    Bcc = np.empty((q, q))
    for i in range(q):
        if pos[i] < 0:
            continue
        for k in range(q):
            if pos[k] >= 0:
                Pcc[i, k] = pPcc[pos[i], pos[k]]
                Bcc[i, k] = pBcc[pos[i], pos[k]]
    if qn > 0:
        rowsP = np.empty((qn, q))
        rowsB = np.empty((qn, q))
        for t in range(qn):
            c = cells[fresh[t]]
            for k in range(q):
                rowsP[t, k] = P[c, cells[k]]
                rowsB[t, k] = B[c, cells[k]]
        if rp > 0:
            Ut = np.ascontiguousarray(UV[:rp, :q])
            Vt = np.ascontiguousarray(UV[:rp, q:])
            UnT = np.ascontiguousarray(Ut[:, fresh].T)  # (qn, rp)
            # (K U_i - V_i)^T, K symmetric
            WnT = np.dot(UnT, np.ascontiguousarray(K[:rp, :rp])) - np.ascontiguousarray(Vt[:, fresh].T)
            rowsP -= np.dot(UnT, Ut)
            rowsB += np.dot(WnT, Ut) - np.dot(UnT, Vt)
        for t in range(qn):
            i = fresh[t]
            for k in range(q):
                Pcc[i, k] = rowsP[t, k]
                Pcc[k, i] = rowsP[t, k]
                Bcc[i, k] = rowsB[t, k]
                Bcc[k, i] = rowsB[t, k]
    if r > rp:
        _edge_rows(P, B, header, idata, fdata, header.shape[0] - 1, cells, UV)
        A = np.ascontiguousarray(UV[rp:, :q])  # (m, q)
        T = 0.5 * np.dot(np.ascontiguousarray(K[rp:, rp:]), A) - UV[rp:, q:]
        if rp > 0:
            T += np.dot(np.ascontiguousarray(K[:rp, rp:]).T, np.ascontiguousarray(UV[:rp, :q]))
        AA = np.dot(A.T, A)
        AT = np.dot(A.T, T)
        for i in range(q):
            for k in range(i + 1):
                p = Pcc[i, k] - AA[i, k]
                g = Bcc[i, k] + AT[i, k] + AT[k, i]
                Pcc[i, k] = p
                Pcc[k, i] = p
                Bcc[i, k] = g
                Bcc[k, i] = g
    gains, S, G = _legs_gains(Pcc, Bcc, leg_m, pair_ptr, pair_cell, pair_w, var, M)
    return gains, S, G, np.ascontiguousarray(UV[:, :q]), np.ascontiguousarray(UV[:, q:]), Pcc, Bcc


@_jit
def edge_terms(S, G, m, Wrows, wcell, wval, Ut, Vt, K):
    """The small terms of one edge, for a leg of m rows with the parent's terms: L^-1 (L L^T = S), Y = W Uc
    and the new K = [[K, X], [X^T, L^-1 G L^-T]] with X = U^T D A = (Z^T - K Y^T) L^-T, Z = W Vc (the leg's
    weight p in row ``Wrows[p]`` on the parent node's cell ``wcell[p]``; m rows)."""
    r = Ut.shape[0]
    Linv = np.empty((m, m))
    _cholesky_inverse(S, m, Linv)
    Y = np.zeros((m, r))
    Z = np.zeros((m, r))
    for p in range(wval.size):
        a, c, w = Wrows[p], wcell[p], wval[p]
        for k in range(r):
            Y[a, k] += w * Ut[k, c]
            Z[a, k] += w * Vt[k, c]
    Gm = np.ascontiguousarray(G[:m, :m])
    corner = np.dot(np.dot(Linv, Gm), Linv.T)
    Kn = np.empty((r + m, r + m))
    Kn[:r, :r] = K
    if r > 0:
        X = np.dot(Z.T - np.dot(K, Y.T), Linv.T)
        Kn[:r, r:] = X
        Kn[r:, :r] = X.T
    Kn[r:, r:] = corner
    return Linv, Y, Kn


@_jit
def readout_blocks(P, B, row_ptr, cells, weights, var):
    """S = W P W^T + R and G = W B W^T of one batch of read-outs, W in sparse rows (row a's weights
    ``weights`` on the map cells ``cells`` between ``row_ptr[a]`` and ``row_ptr[a + 1]``; ``var`` (m,) the
    rows' noise variances; ``P`` and ``B`` = P D P, both (n, n); a row averages at most a binning block):
    the batch's predicted reduction of Tr(P) over the ROI D is ``Tr(S^-1 G)``."""
    m = var.size
    n = P.shape[0]
    seen = np.zeros(n, dtype=np.bool_)
    for p in range(cells.size):
        seen[cells[p]] = True
    union = np.flatnonzero(seen)  # the batch's cells, ascending (rows of P and B read in address order)
    q = union.size
    local = np.full(n, -1, dtype=np.int64)  # map cell -> its index among the batch's cells
    for y in range(q):
        local[union[y]] = y
    loc = np.empty(cells.size, dtype=np.int64)
    for p in range(cells.size):
        loc[p] = local[cells[p]]
    Pu = np.empty((q, q))  # P and B on the batch's cells
    Bu = np.empty((q, q))
    for x in range(q):
        rowP = P[union[x]]
        rowB = B[union[x]]
        for y in range(q):
            Pu[x, y] = rowP[union[y]]
            Bu[x, y] = rowB[union[y]]
    XP = np.zeros((m, q))  # W P[:, union]
    XB = np.zeros((m, q))  # W B[:, union]
    for a in range(m):
        for p in range(row_ptr[a], row_ptr[a + 1]):
            w = weights[p]
            x = loc[p]
            for y in range(q):
                XP[a, y] += w * Pu[x, y]
                XB[a, y] += w * Bu[x, y]
    S = np.empty((m, m))
    G = np.empty((m, m))
    for a in range(m):
        for c in range(a + 1):
            s = 0.0
            g = 0.0
            for t in range(row_ptr[c], row_ptr[c + 1]):
                y = loc[t]
                s += weights[t] * XP[a, y]
                g += weights[t] * XB[a, y]
            S[a, c] = s
            S[c, a] = s
            G[a, c] = g
            G[c, a] = g
        S[a, a] += var[a]
    return S, G


_EPS = 1e-9  # [m] as ipp_bench.sensor: centres exactly on the footprint's edge are inside


@_jit
def camera_rows(points, noise_a, noise_b, binned_scale, tan, res, n_rows, n_cols, binning_altitude, binning,
                s_cell, s_binned, r_corr):
    """The camera's read-outs from each of ``points`` ((K, 3) [m]) in turn, as sparse rows: what
    :meth:`~ipp_bench.sensor.Sensor.observe` gives at each point (none where the footprint misses the map),
    row by row, compiled: the same footprint (``tan`` = tan(fov / 2); a ``n_rows`` x ``n_cols`` grid of
    ``res`` [m] cells), binning and weights, and the same noise variance, ``noise_a (1 - exp(-noise_b h))``
    (times ``binned_scale`` = f^e when binned) plus the persistent share ``s w^T C w`` (``s_cell``,
    ``s_binned``; C = ``r_corr``^(d^2) over a binned row's cells, summed in another order than the
    camera's: equal to rounding).

    Returns:
        (row_ptr (m + 1,), cells (nnz,), weights (nnz,), var (m,)): row a's nonzero weights ``weights`` on
        the map cells ``cells`` between ``row_ptr[a]`` and ``row_ptr[a + 1]``, and its noise variance.
    """
    K = points.shape[0]
    ranges = np.empty((K, 4), dtype=np.int64)
    m = 0
    nnz = 0
    for i in range(K):
        x, y, h = points[i, 0], points[i, 1], points[i, 2]
        half = h * tan
        c0 = max(0, int(np.ceil((x - half - _EPS) / res - 0.5)))
        c1 = min(n_cols - 1, int(np.floor((x + half + _EPS) / res - 0.5)))
        r0 = max(0, int(np.ceil((y - half - _EPS) / res - 0.5)))
        r1 = min(n_rows - 1, int(np.floor((y + half + _EPS) / res - 0.5)))
        ranges[i, 0], ranges[i, 1], ranges[i, 2], ranges[i, 3] = r0, r1, c0, c1
        if r1 < r0 or c1 < c0:
            continue
        cells = (r1 - r0 + 1) * (c1 - c0 + 1)
        nnz += cells
        if h > binning_altitude and binning > 1:
            m += ((r1 - r0) // binning + 1) * ((c1 - c0) // binning + 1)
        else:
            m += cells
    row_ptr = np.zeros(m + 1, dtype=np.int64)
    out_cells = np.empty(nnz, dtype=np.int64)
    weights = np.empty(nnz)
    var = np.empty(m)
    a = 0
    p = 0
    for i in range(K):
        r0, r1, c0, c1 = ranges[i, 0], ranges[i, 1], ranges[i, 2], ranges[i, 3]
        if r1 < r0 or c1 < c0:
            continue
        h = points[i, 2]
        white = noise_a * (1.0 - math.exp(-noise_b * h))
        if h > binning_altitude and binning > 1:
            white *= binned_scale
            for br in range(r0, r1 + 1, binning):
                for bc in range(c0, c1 + 1, binning):
                    re, ce = min(br + binning, r1 + 1), min(bc + binning, c1 + 1)
                    count = (re - br) * (ce - bc)
                    w = 1.0 / count
                    share = 0.0
                    for rr in range(br, re):
                        for cc in range(bc, ce):
                            out_cells[p] = rr * n_cols + cc
                            weights[p] = w
                            p += 1
                            if r_corr > 0:
                                for rr2 in range(br, re):
                                    for cc2 in range(bc, ce):
                                        share += w * w * r_corr ** ((rr - rr2) ** 2 + (cc - cc2) ** 2)
                            else:
                                share += w * w
                    var[a] = white + s_binned * share if s_binned > 0 else white
                    a += 1
                    row_ptr[a] = p
        else:
            for rr in range(r0, r1 + 1):
                for cc in range(c0, c1 + 1):
                    out_cells[p] = rr * n_cols + cc
                    weights[p] = 1.0
                    p += 1
                    var[a] = white + s_cell * 1.0 if s_cell > 0 else white
                    a += 1
                    row_ptr[a] = p
    return row_ptr, out_cells, weights, var


def leg_points(start, end, spacing: float) -> np.ndarray:
    """(K, 3) [m] where the mission reads the camera flying ``start -> end``: the positions of
    :meth:`~ipp_bench.planners.base.RobotView.leg_observations` (same spacing rule, same arithmetic)."""
    start = np.asarray(start, dtype=np.float64)
    delta = np.asarray(end, dtype=np.float64) - start
    dist = leg_length(start, end)
    if dist <= MIN_LEG_M:
        return np.zeros((0, 3))
    s = leg_samples(dist, 0.0, spacing)
    return start + np.outer(s / dist, delta)


def camera_args(sensor) -> tuple:
    """The constants of ``sensor`` (a :class:`~ipp_bench.sensor.Sensor`) that :func:`camera_rows` takes
    after the points, computed as the camera computes them."""
    cfg, grid = sensor.cfg, sensor.grid
    binned_scale = float(cfg.binning) ** cfg.binning_noise_exponent if cfg.binning_noise_exponent else 1.0
    tan = math.tan(math.radians(cfg.fov_deg) / 2.0)
    return (float(cfg.noise_a), float(cfg.noise_b), binned_scale, tan, float(grid.resolution), int(grid.rows),
            int(grid.cols), float(cfg.binning_altitude), int(cfg.binning), float(cfg.persistent(1)),
            float(cfg.persistent(cfg.binning)), float(cfg.persistent_neighbour_corr))


def roi_product(cov: np.ndarray, roi: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """B = P D P (D: the diagonal mask ``roi``) as one (n, n) product, into ``out`` where it fits."""
    n = cov.shape[0]
    if out is None or out.shape != (n, n):
        out = np.empty((n, n))
    P_roi = cov if roi.all() else cov[:, roi]
    return np.matmul(P_roi, P_roi.T, out=out)


@_jit
def fold_repeated_rows(row_ptr, cells, weights, var):
    """The read-out rows of ``camera_rows`` with repeated rows folded into one: a row with the same cells and
    weights as an earlier one (a look at the same footprint again) joins it, with the noise variance of
    both looks together, ``1 / (1 / r1 + 1 / r2)``. The same posterior covariance in exact arithmetic (two
    independent measurements of w^T x are one with their precisions added), with fewer rows.

    Returns (row_ptr, cells, weights, var) of the distinct rows, in the order of their first look.
    """
    m = var.size
    first = np.arange(m)
    for a in range(m):
        na = row_ptr[a + 1] - row_ptr[a]
        for c in range(a):
            if first[c] != c or row_ptr[c + 1] - row_ptr[c] != na:
                continue
            same = True
            for t in range(na):
                if cells[row_ptr[a] + t] != cells[row_ptr[c] + t] or weights[row_ptr[a] + t] != weights[row_ptr[c] + t]:
                    same = False
                    break
            if same:
                first[a] = c
                break
    precision = np.zeros(m)
    for a in range(m):
        precision[first[a]] += 1.0 / var[a]
    keep = 0
    nnz = 0
    for a in range(m):
        if first[a] == a:
            keep += 1
            nnz += row_ptr[a + 1] - row_ptr[a]
    out_ptr = np.zeros(keep + 1, dtype=np.int64)
    out_cells = np.empty(nnz, dtype=np.int64)
    out_w = np.empty(nnz)
    out_var = np.empty(keep)
    k = 0
    p = 0
    for a in range(m):
        if first[a] != a:
            continue
        for t in range(row_ptr[a], row_ptr[a + 1]):
            out_cells[p] = cells[t]
            out_w[p] = weights[t]
            p += 1
        out_var[k] = var[a] if precision[a] == 1.0 / var[a] else 1.0 / precision[a]
        k += 1
        out_ptr[k] = p
    return out_ptr, out_cells, out_w, out_var


def warm_up() -> None:
    """Compile every kernel now (10-30 s, once per process; nothing after it compiles), not in a decision."""
    require_numba("the fast searches")
    P = np.ones((2, 2)) + np.eye(2)
    readout_blocks(P, P, np.array([0, 1, 2], dtype=np.int64), np.array([0, 1], dtype=np.int64), np.ones(2), np.ones(2))
    fold_repeated_rows(np.array([0, 1, 2], dtype=np.int64), np.array([0, 0], dtype=np.int64), np.ones(2), np.ones(2))
    camera_rows(np.array([[1.0, 1.0, 2.0], [1.0, 1.0, 9.0]]), 0.05, 0.2, 8.0, 0.5, 1.0, 4, 4, 5.0, 2, 0.1, 0.1, 0.5)
    P = np.ones((4, 4)) + np.eye(4)
    leg_m = np.array([1], dtype=np.int64)
    ptr = np.array([0, 1, 1, 1], dtype=np.int64)
    cell = np.array([0], dtype=np.int64)
    w = np.ones(1)
    var = np.ones((1, 2))
    cells = np.array([0, 1], dtype=np.int64)
    node_legs(np.array([0, 1, 1], dtype=np.int64), np.array([0, 1], dtype=np.int64), cells[:1].copy(), w, np.ones(1))
    header = np.zeros((0, 5), dtype=np.int64)
    idata = np.zeros(0, dtype=np.int64)
    fdata = np.zeros(0)
    K = np.zeros((0, 0))
    for _ in range(2):
        r = K.shape[0]
        g, S, G, Ut, Vt, Pcc, Bcc = state_terms(P, P, header, idata, fdata, r, cells, K, leg_m, ptr, cell, w, var, 2)
        for em in (0, 1):
            child_terms(P, P, header, idata, fdata, r, cells[::-1].copy(), K, leg_m, ptr, cell, w, var, 2, cells, Ut,
                        Vt, Pcc, Bcc, S[0], G[0], em, cell, cell, w, np.zeros(2, dtype=np.int64))
        Linv, Y, K = edge_terms(S[0], G[0], 1, cell, cell, w, Ut, Vt, K)
        header = np.array([[1, r, 1, 0, 0]], dtype=np.int64)
        idata = np.array([0, 0], dtype=np.int64)
        fdata = np.concatenate([w, Linv.ravel(), Y.ravel()])
