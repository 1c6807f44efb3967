"""The MCTS's low-rank search, compiled (``mcts:search=lowrank``, :mod:`ipp_bench.planners.mcts_lowrank`):
:func:`state_terms` scores the legs out of a tree state from its factor, :func:`child_terms` from its parent's
terms (:func:`step_terms`: legs from the node table), and :func:`rollout` runs a rollout, drawing as NumPy does.

One module on purpose (over 400 lines): the rollout calls every kernel here, and numba's cache of a kernel,
keyed on its own file, holds the kernels it calls (one changed in another file would leave it stale).
"""

from __future__ import annotations

import math

import numpy as np

from .jit import kernel


@kernel
def _cholesky_inverse(S, m, Linv, j, L):
    """``Linv[j, :m, :m]`` = L^-1 with L L^T = S[:m, :m] (lower triangular; S symmetric positive definite;
    ``Linv[j]`` zero on entry; ``L``: room for the factor)."""
    for c in range(m):
        d = S[c, c]
        for k in range(c):
            d -= L[c, k] * L[c, k]
        if not d > 0.0:
            raise ValueError("S = H P H^T + R is not positive definite")
        d = np.sqrt(d)
        L[c, c] = d
        for i in range(c + 1, m):
            s = S[i, c]
            for k in range(c):
                s -= L[i, k] * L[c, k]
            L[i, c] = s / d
    for c in range(m):  # column c of L^-1: forward substitution of e_c
        Linv[j, c, c] = 1.0 / L[c, c]
        for i in range(c + 1, m):
            s = 0.0
            for k in range(c, i):
                s -= L[i, k] * Linv[j, k, c]
            Linv[j, i, c] = s / L[i, i]


@kernel
def _trace_inv_product(Linv, j, G, m):
    """Tr(S^-1 G) = sum_ik (L^-T L^-1)_ik G_ik for symmetric G (L^-1: ``Linv[j]``)."""
    total = 0.0
    for i in range(m):
        for c in range(i + 1):
            s = 0.0
            for k in range(i, m):  # (L^-T L^-1)_ic = sum_k Linv[k, i] Linv[k, c], k >= max(i, c)
                s += Linv[j, k, i] * Linv[j, k, c]
            total += s * G[i, c] if i == c else 2.0 * s * G[i, c]
    return total



@kernel
def _edge_rows(P, B, header, idata, fdata, e, cells, UV):
    """Edge ``e``: rows ``r_e`` to ``r_e + m`` of ``UV`` = [Ut | Vt] on the cells ``cells``, from the rows before it."""
    q = cells.size
    m, re, nnz, fo, io = header[e, 0], header[e, 1], header[e, 2], header[e, 3], header[e, 4]
    E = np.zeros((m, 2 * q))  # [(H P0)[:, c] | (H B0)[:, c]]
    for p in range(nnz):
        a = idata[io + p]
        x = idata[io + nnz + p]
        w = fdata[fo + p]
        for i in range(q):
            E[a, i] += w * P[x, cells[i]]
            E[a, q + i] += w * B[x, cells[i]]
    Linv = fdata[fo + nnz:fo + nnz + m * m].reshape((m, m))
    if re > 0:
        Y = fdata[fo + nnz + m * m:fo + nnz + m * m + m * re].reshape((m, re))
        E -= np.dot(Y, UV[:re])
    UV[re:re + m] = np.dot(Linv, E)


@kernel
def _factor_rows(P, B, header, idata, fdata, r, cells):
    """UV = [Ut | Vt] (r, 2 q): the rows of U^T and V^T = (P0 D U)^T on the q cells ``cells``, rebuilt edge by edge.

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
    return UV


@kernel
def _legs_gains(Pcc, Bcc, leg_m, rptr, nz_cell, nz_w, var, M):
    """Each leg's gain ``Tr(S^-1 G)`` from P and P D P on the node's cells (S = W P W^T + R, G = W P D P W^T;
    entry (a, c) sums ``w_a[x] w_c[y] P[x, y]`` over the two rows' weights), with its L^-1 (L L^T = S) and G,
    each (b, M, M) (zero past the leg's rows)."""
    b = leg_m.size
    Li = np.zeros((b, M, M))
    G = np.zeros((b, M, M))
    S = np.zeros((M, M))
    L = np.zeros((M, M))
    gains = np.empty(b)
    for j in range(b):
        m = leg_m[j]
        Gj = G[j]
        for a in range(m):
            for c in range(a + 1):
                s = 0.0
                g = 0.0
                for p in range(rptr[j, a], rptr[j, a + 1]):
                    x = nz_cell[p]
                    wp = nz_w[p]
                    for u in range(rptr[j, c], rptr[j, c + 1]):
                        w = wp * nz_w[u]
                        s += w * Pcc[x, nz_cell[u]]
                        g += w * Bcc[x, nz_cell[u]]
                S[a, c] = s
                S[c, a] = s
                Gj[a, c] = g
                Gj[c, a] = g
            S[a, a] += var[j, a]
        _cholesky_inverse(S, m, Li, j, L)
        gains[j] = _trace_inv_product(Li, j, Gj, m)
    return gains, Li, G


@kernel
def state_terms(P, B, header, idata, fdata, r, cells, K, leg_m, rptr, nz_cell, nz_w, var, M):
    """The one-step gains of every leg out of a tree state, and the terms its edges reuse.

    The state's covariance is P0 - U U^T (U: the blocks of the edges from the root, ``header``, ``idata``,
    ``fdata`` as :func:`_factor_rows` reads them; r columns) and K = U^T D U; ``P`` = P0 and ``B`` = B0 =
    P0 D P0, both (n, n). On the node's q cells ``cells``, with Uc, Vc the rows of U and V = P0 D U there:
    ``P_cc = P0_cc - Uc Uc^T`` and ``B_cc = (P D P)_cc = B0_cc - Vc Uc^T - Uc Vc^T + Uc K Uc^T``. Each leg j
    (rows W_j over those cells: row a's weights ``nz_w`` on the cells ``nz_cell`` between ``rptr[j, a]`` and
    ``rptr[j, a + 1]``; noise ``var[j]``) has ``S = W P_cc W^T + R``, ``G = W B_cc W^T`` and gain
    ``Tr(S^-1 G)``: the reduction of Tr(P) over the ROI D. Returns gains (b,); L^-1 (L L^T = S) and G, each
    (b, M, M) (zero past each leg's ``leg_m`` rows); UV = [Uc^T | Vc^T] (r, 2 q); P_cc and B_cc (q, q) (what
    :func:`child_terms` starts from).
    """
    q = cells.size
    UV = _factor_rows(P, B, header, idata, fdata, r, cells)
    Pcc = np.empty((q, q))
    Bcc = np.empty((q, q))
    for i in range(q):
        for k in range(q):
            Pcc[i, k] = P[cells[i], cells[k]]
            Bcc[i, k] = B[cells[i], cells[k]]
    if r > 0:
        Ut = np.ascontiguousarray(UV[:, :q])
        Tt = 0.5 * np.dot(K, Ut) - UV[:, q:]  # ((1/2) Uc K - Vc)^T: Uc T + T^T Uc^T = Uc K Uc^T - Uc Vc^T - Vc Uc^T
        both = np.empty((r, 2 * q))
        both[:, :q] = Ut
        both[:, q:] = Tt
        prod = np.dot(Ut.T, both)  # [Uc Uc^T | Uc T]
        for i in range(q):
            for k in range(q):
                Pcc[i, k] -= prod[i, k]
                Bcc[i, k] += prod[i, q + k] + prod[k, q + i]
    gains, Li, G = _legs_gains(Pcc, Bcc, leg_m, rptr, nz_cell, nz_w, var, M)
    return gains, Li, G, UV, Pcc, Bcc


@kernel
def child_terms(P, B, header, idata, fdata, r, cells, K, leg_m, rptr, nz_cell, nz_w, var, M, pcells, pUV, pPcc,
                pBcc, eLi, eG, ej, em, erows, ecells, ew, eints):
    """:func:`state_terms` of a state from its parent's terms, with the edge that leads to it; returns what
    :func:`state_terms` returns, then the state's factor: header, idata, fdata, K.

    ``header``, ``idata``, ``fdata``, ``r`` and ``K`` are the parent's factor, ``pcells`` the parent node's
    cells (ascending), ``pUV`` = [Ut | Vt] (r_p, 2 q_p) the rows of U^T and V^T there and ``pPcc``, ``pBcc`` P
    and P D P there. The edge is the parent's leg ``ej`` of ``em`` rows (0: it sees nothing, the factor
    stays; ``eLi``, ``eG``: the parent's legs' L^-1 and G, as :func:`state_terms` gives them), with its
    weights (row ``erows``, index ``ecells`` among ``pcells``, value ``ew``; ``eints`` = rows, then map
    cells): :func:`edge_terms` adds it to the factor.
    """
    pK = K
    X = np.zeros((r, 0))
    corner = np.zeros((0, 0))
    if em > 0:
        header, idata, fdata, K, X, corner = _append_edge(eLi, eG, ej, em, erows, ecells, ew, eints, pUV, header, idata,
                                                          fdata, r, K)
        r = r + em
    gains, Li, G, UV, Pcc, Bcc = _from_parent(P, B, header, idata, fdata, r, cells, pK, X, corner, leg_m, rptr,
                                             nz_cell, nz_w, var, M, pcells, pUV, pPcc, pBcc)
    return gains, Li, G, UV, Pcc, Bcc, header, idata, fdata, K


@kernel
def _from_parent(P, B, header, idata, fdata, r, cells, pK, X, corner, leg_m, rptr, nz_cell, nz_w, var, M, pcells,
                 pUV, pPcc, pBcc):
    """:func:`state_terms` of a state (its factor: ``header`` to ``K``) from its parent's terms (``pcells`` to
    ``pBcc``, as :func:`child_terms` takes them; ``X``, ``corner``: K's new column block and corner).

    The rows of U, V, P and P D P on the cells both nodes' legs see are the parent's; those on the other
    cells are rebuilt from the root (:func:`_factor_rows`; ``P_ik = P0_ik - U_i U_k`` and ``(P D P)_ik =
    B0_ik + (K U_i - V_i) U_k - U_i V_k``), and the edge from the parent (if it saw something: rows A of U,
    P0 D A of V, r_p to r) then updates them: ``P -= A A^T`` and ``P D P += A T^T + T A^T`` with ``T =
    A K_aa / 2 + U K_ua - P0 D A`` (K_aa, K_ua: K's new corner and column block).
    """
    q = cells.size
    qp = pcells.size
    rp = pUV.shape[0]
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
        UVn = np.empty((rp, 0))
        if qn > 0:
            edges = header.shape[0] - (1 if r > rp else 0)
            UVn = _factor_rows(P, B, header[:edges], idata, fdata, rp, cells[fresh])
        for k in range(rp):
            t = 0
            for i in range(q):
                if pos[i] >= 0:
                    UV[k, i] = pUV[k, pos[i]]
                    UV[k, q + i] = pUV[k, qp + pos[i]]
                else:
                    UV[k, i] = UVn[k, t]
                    UV[k, q + i] = UVn[k, qn + t]
                    t += 1
    Pcc = np.empty((q, q))
    Bcc = np.empty((q, q))
    for i in range(q):
        if pos[i] < 0:
            continue
        t = pos[i]
        for k in range(q):
            if pos[k] >= 0:
                Pcc[i, k] = pPcc[t, pos[k]]
                Bcc[i, k] = pBcc[t, pos[k]]
    if qn > 0:  # the rows of the cells the parent did not see, from the root: P0 - U U^T, B0 + (K U - V) U^T - U V^T
        rowsP = np.empty((qn, q))
        rowsB = np.empty((qn, q))
        for t in range(qn):
            c = cells[fresh[t]]
            for k in range(q):
                rowsP[t, k] = P[c, cells[k]]
                rowsB[t, k] = B[c, cells[k]]
        if rp > 0:
            UnT = np.empty((qn, rp))  # (qn, rp)
            VnT = np.empty((qn, rp))
            for t in range(qn):
                for k in range(rp):
                    UnT[t, k] = UV[k, fresh[t]]
                    VnT[t, k] = UV[k, q + fresh[t]]
            WnT = np.dot(UnT, pK) - VnT  # (K U_i - V_i)^T, K symmetric
            both = np.dot(np.concatenate((UnT, WnT)), UV[:rp])  # [Un Uc^T | Un Vc^T ; Wn Uc^T | Wn Vc^T]
            for t in range(qn):
                for k in range(q):
                    rowsP[t, k] -= both[t, k]
                    rowsB[t, k] += both[qn + t, k] - both[t, q + k]
        for t in range(qn):
            i = fresh[t]
            for k in range(q):
                Pcc[i, k] = rowsP[t, k]
                Bcc[i, k] = rowsB[t, k]
        for k in range(q):
            for t in range(qn):
                Pcc[k, fresh[t]] = rowsP[t, k]
                Bcc[k, fresh[t]] = rowsB[t, k]
    if r > rp:
        _edge_rows(P, B, header, idata, fdata, header.shape[0] - 1, cells, UV)
        A = np.ascontiguousarray(UV[rp:, :q])  # (m, q)
        T = 0.5 * np.dot(corner, A) - UV[rp:, q:]
        if rp > 0:
            T += np.dot(X.T, np.ascontiguousarray(UV[:rp, :q]))
        AA = np.dot(A.T, A)
        AT = np.dot(A.T, T)
        TA = np.ascontiguousarray(AT.T)
        for i in range(q):
            for k in range(q):
                Pcc[i, k] -= AA[i, k]
                Bcc[i, k] += AT[i, k] + TA[i, k]
    gains, Li, G = _legs_gains(Pcc, Bcc, leg_m, rptr, nz_cell, nz_w, var, M)
    return gains, Li, G, UV, Pcc, Bcc


@kernel
def edge_terms(Li, G, j, m, Wrows, wcell, wval, UV, K):
    """The small terms of one edge, for the parent's leg ``j`` of m rows with the parent's terms (``Li``, ``G``:
    its legs' L^-1 and G, as :func:`state_terms` gives them; ``UV`` = [Uc^T | Vc^T]): L^-1 (L L^T = S),
    Y = W Uc, the new K = [[K, X], [X^T, L^-1 G L^-T]] with X = U^T D A = (Z^T - K Y^T) L^-T, Z = W Vc (the
    leg's weight p in row ``Wrows[p]`` on the parent node's cell ``wcell[p]``; m rows), X and the corner."""
    r = UV.shape[0]
    qp = UV.shape[1] // 2
    Linv = np.ascontiguousarray(Li[j, :m, :m])
    Y = np.zeros((m, r))
    Z = np.zeros((m, r))
    for k in range(r):
        for p in range(wval.size):
            a, c, w = Wrows[p], wcell[p], wval[p]
            Y[a, k] += w * UV[k, c]
            Z[a, k] += w * UV[k, qp + c]
    Gm = np.ascontiguousarray(G[j, :m, :m])
    corner = np.dot(np.dot(Linv, Gm), Linv.T)
    Kn = np.empty((r + m, r + m))
    Kn[:r, :r] = K
    X = np.zeros((r, m))
    if r > 0:
        X = np.dot(Z.T - np.dot(K, Y.T), Linv.T)
        Kn[:r, r:] = X
        Kn[r:, :r] = X.T
    Kn[r:, r:] = corner
    return Linv, Y, Kn, X, corner


#: the columns of a node's row of the node table (:mod:`.node_table`): built (1: laid out), b, M, q, then where
#: each of its arrays starts in the int pool (row (k), index (b), cells (q), m (b), rptr (b (M + 1)), nz_ptr
#: (b + 1), nz_row, nz_cell, and per leg its rows then its map cells (2 nnz)) and in the float pool (var, nz_w)
(T_BUILT, T_B, T_M, T_Q, T_ROW, T_INDEX, T_CELLS, T_LEGM, T_RPTR, T_NZ_PTR, T_NZ_ROW, T_NZ_CELL, T_NZ_INTS, T_VAR,
 T_NZ_W) = range(15)
TABLE_WIDTH = 15


@kernel
def node_view(ipool, fpool, table, node, k):
    """The legs of roadmap node ``node`` (k legs) from the table, as views of the pools: b, M, row, index, cells,
    m, rptr (b, M + 1), var (b, M), nz_ptr, nz_row, nz_cell, nz_ints, nz_w (as ``node_table.node_legs``)."""
    t = table[node]
    b, M, q = t[T_B], t[T_M], t[T_Q]
    row = ipool[t[T_ROW]:t[T_ROW] + k]
    index = ipool[t[T_INDEX]:t[T_INDEX] + b]
    cells = ipool[t[T_CELLS]:t[T_CELLS] + q]
    m = ipool[t[T_LEGM]:t[T_LEGM] + b]
    rptr = ipool[t[T_RPTR]:t[T_RPTR] + b * (M + 1)].reshape((b, M + 1))
    nz_ptr = ipool[t[T_NZ_PTR]:t[T_NZ_PTR] + b + 1]
    nnz = nz_ptr[b]
    nz_row = ipool[t[T_NZ_ROW]:t[T_NZ_ROW] + nnz]
    nz_cell = ipool[t[T_NZ_CELL]:t[T_NZ_CELL] + nnz]
    nz_ints = ipool[t[T_NZ_INTS]:t[T_NZ_INTS] + 2 * nnz]
    var = fpool[t[T_VAR]:t[T_VAR] + b * M].reshape((b, M))
    nz_w = fpool[t[T_NZ_W]:t[T_NZ_W] + nnz]
    return b, M, row, index, cells, m, rptr, var, nz_ptr, nz_row, nz_cell, nz_ints, nz_w


@kernel
def step_terms(P, B, ipool, fpool, table, k, pnode, action, node, header, idata, fdata, r, K, UV, Pcc, Bcc, Li, G):
    """The terms of the state reached by leg ``action`` from a scored state at node ``pnode`` (its factor
    ``header`` to ``K`` and its terms ``UV`` to ``G``, as :func:`state_terms` gives them; empty where its node's
    legs see nothing), at node ``node``: from the parent's terms (:func:`child_terms`) where both nodes' legs
    see something, else from the root (:func:`state_terms`; a leg that sees nothing keeps the factor). Returns
    gains (k,) (0 for the legs that see nothing), then Li, G, UV, Pcc, Bcc (empty where the node's legs see
    nothing), header, idata, fdata, r, K.
    """
    pb, _, prow, _, pcells, plegm, _, _, pnz_ptr, pnz_row, pnz_cell, pnz_ints, pnz_w = node_view(ipool, fpool, table,
                                                                                              pnode, k)
    b, M, _, index, cells, legm, rptr, var, _, _, nz_cell, _, nz_w = node_view(ipool, fpool, table, node, k)
    j = prow[action]
    em = 0
    erows, ecells, ew, eints = pnz_row[:0], pnz_cell[:0], pnz_w[:0], pnz_ints[:0]
    if j >= 0:
        em = plegm[j]
        p0, p1 = pnz_ptr[j], pnz_ptr[j + 1]
        erows, ecells, ew, eints = pnz_row[p0:p1], pnz_cell[p0:p1], pnz_w[p0:p1], pnz_ints[2 * p0:2 * p1]
    out = np.zeros(k)
    if pb > 0 and b > 0:
        if em > 0:
            (g, Li2, G2, UV2, Pcc2, Bcc2, header2, idata2, fdata2,
             K2) = child_terms(P, B, header, idata, fdata, r, cells, K, legm, rptr, nz_cell, nz_w, var, M,
                               pcells, UV, Pcc, Bcc, Li, G, j, em, erows, ecells, ew, eints)
        else:
            (g, Li2, G2, UV2, Pcc2, Bcc2, header2, idata2, fdata2,
             K2) = child_terms(P, B, header, idata, fdata, r, cells, K, legm, rptr, nz_cell, nz_w, var, M,
                               pcells, UV, Pcc, Bcc, Li, G, 0, 0, erows, ecells, ew, eints)
        for i in range(b):
            out[index[i]] = g[i]
        return out, Li2, G2, UV2, Pcc2, Bcc2, header2, idata2, fdata2, r + em, K2
    # a node whose legs see nothing: the factor from the parent's (with the edge), the terms from the root
    if em > 0:
        header, idata, fdata, K, _, _ = _append_edge(Li, G, j, em, erows, ecells, ew, eints, UV, header, idata, fdata,
                                                      r, K)
    r2 = r + em
    if b == 0:
        Li2 = np.zeros((0, M, M))
        E2 = np.zeros((0, 0))
        return out, Li2, Li2.copy(), E2, E2.copy(), E2.copy(), header, idata, fdata, r2, K
    g, Li2, G2, UV2, Pcc2, Bcc2 = state_terms(P, B, header, idata, fdata, r2, cells, K, legm, rptr, nz_cell,
                                                  nz_w, var, M)
    for i in range(b):
        out[index[i]] = g[i]
    return out, Li2, G2, UV2, Pcc2, Bcc2, header, idata, fdata, r2, K


@kernel
def _append_edge(eLi, eG, ej, em, erows, ecells, ew, eints, UV, header, idata, fdata, r, K):
    """The factor with one edge appended (:func:`edge_terms`): header, idata, fdata, K."""
    Linv, Y, K, X, corner = edge_terms(eLi, eG, ej, em, erows, ecells, ew, UV, K)
    h = header.shape[0]
    nnz = ew.size
    head = np.empty((h + 1, 5), dtype=np.int64)
    head[:h] = header
    head[h, 0], head[h, 1], head[h, 2], head[h, 3], head[h, 4] = em, r, nnz, fdata.size, idata.size
    idata = np.concatenate((idata, eints))
    fo = fdata.size
    fnew = np.empty(fo + nnz + em * em + em * r)
    fnew[:fo] = fdata
    fnew[fo:fo + nnz] = ew
    fnew[fo + nnz:fo + nnz + em * em] = Linv.ravel()
    fnew[fo + nnz + em * em:] = Y.ravel()
    return head, idata, fnew, K, X, corner


@kernel
def _pairwise_block(a, lo, n):
    """NumPy's sum of a block of at most 128 terms ``a[lo:lo + n]`` (eight running sums, then the rest)."""
    if n < 8:
        res = -0.0
        for i in range(n):
            res += a[lo + i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - n % 8:
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@kernel
def _pairwise_sum(a, lo, n):
    """NumPy's pairwise summation of ``a[lo:lo + n]`` (``a.sum()``'s order): blocks of at most 128 terms, halves
    (at a multiple of 8) added as NumPy's recursion adds them, on a stack (numba caches no recursive function)."""
    if n <= 128:
        return _pairwise_block(a, lo, n)
    # work items (start, length): length > 0 sums that span, length 0 adds the two values on top of the stack
    work_lo = np.empty(256, dtype=np.int64)
    work_n = np.empty(256, dtype=np.int64)
    values = np.empty(128)
    w, v = 1, 0
    work_lo[0], work_n[0] = lo, n
    while w > 0:
        w -= 1
        start, length = work_lo[w], work_n[w]
        if length == 0:  # left + right, as the recursion returns them
            v -= 1
            values[v - 1] = values[v - 1] + values[v]
        elif length <= 128:
            values[v] = _pairwise_block(a, start, length)
            v += 1
        else:
            half = length // 2
            half -= half % 8
            work_lo[w], work_n[w] = 0, 0  # after both halves: their sum
            work_lo[w + 1], work_n[w + 1] = start + half, length - half  # the right half, summed second
            work_lo[w + 2], work_n[w + 2] = start, half  # the left half, summed first
            w += 3
    return values[0]


@kernel
def _order(gains, costs, remaining, tol):
    """The playable legs (``costs <= remaining + tol``), best ``gains / costs`` first, ties by index."""
    k = gains.size
    count = 0
    for i in range(k):
        if costs[i] <= remaining + tol:
            count += 1
    order = np.empty(count, dtype=np.int64)
    key = np.empty(count)
    t = 0
    for i in range(k):
        if costs[i] <= remaining + tol:
            order[t] = i
            key[t] = -(gains[i] / costs[i])
            t += 1
    for i in range(1, count):  # insertion sort: stable, as np.lexsort((actions, -rate))
        a, v = order[i], key[i]
        t = i - 1
        while t >= 0 and key[t] > v:
            order[t + 1] = order[t]
            key[t + 1] = key[t]
            t -= 1
        order[t + 1] = a
        key[t + 1] = v
    return order


@kernel
def _draw(rng, gains, costs, order, lam):
    """The rollout's move from a state (``order`` its playable legs): -1 where none gains anything, else the
    draw of ``rng.choice(order, p=softmax(lam * rate / max rate))``, rate = gains / costs: one ``rng.random()``
    against the same cumulative sum (NumPy's sums, in their order; ``exp`` as the C library computes it)."""
    n = order.size
    rate = np.empty(n)
    top = -np.inf
    for i in range(n):
        rate[i] = gains[order[i]] / costs[order[i]]
        top = max(top, rate[i])
    if not top > 0:
        return -1
    logits = np.empty(n)
    high = -np.inf
    for i in range(n):
        logits[i] = lam * rate[i] / top
        high = max(high, logits[i])
    p = np.empty(n)
    for i in range(n):
        p[i] = math.exp(logits[i] - high)
    total = _pairwise_sum(p, 0, n)
    cdf = np.empty(n)
    acc = 0.0
    for i in range(n):
        acc += p[i] / total
        cdf[i] = acc
    last = cdf[n - 1]
    for i in range(n):
        cdf[i] /= last
    u = rng.random()
    return order[np.searchsorted(cdf, u, side="right")]


@kernel
def rollout(P, B, ipool, fpool, table, neighbours, costs, known, rng, horizon, tol, gamma, period, lam, unit, mode,
            node, remaining, elapsed, gains, action, total, discount, header, idata, fdata, r, K, UV, Pcc, Bcc,
            Li, G):
    """A rollout of the MCTS from a scored state: the moves drawn with ``rng`` as the reference draws them
    (:mod:`ipp_bench.planners.mcts_reference`), the same rewards and discounts.

    ``mode`` 0: the rollout starts at the tree's new state, at node ``neighbours[node, action]``, reached from the
    scored state (``node``, its ``gains`` and terms) with ``remaining`` and ``elapsed`` its own (the caller
    made the move); 1: it goes on from the scored state (``node``, ``remaining``, ``elapsed``, ``gains``) with
    the move ``action`` drawn, ``total`` and ``discount`` so far. A state's flight times are row ``node`` of
    ``costs`` (``known``: which rows are set); its legs, the table's (laid out where the state is scored).

    Returns status (0: the rollout ended, with return ``total``; 1: it needs node ``need``'s flight times or
    legs: the caller sets them and goes on with mode 1 from the state returned), need, total, discount; the
    first state's gains (k,) (in units of ``unit``), order and terms (mode 0: the tree's new state; Li to r as
    :func:`step_terms` gives them); the state to go on from (node, remaining, elapsed, gains, the move drawn
    and its terms).
    """
    k = neighbours.shape[1]
    f_gains, f_order = gains, np.zeros(0, dtype=np.int64)
    f_terms = (Li, G, UV, Pcc, Bcc, header, idata, fdata, r, K)
    first = mode == 0
    pending = mode == 1
    a = action
    c_node, c_rem, c_el = node, remaining, elapsed
    if mode == 0:
        c_node = neighbours[node, action]
    while True:
        if pending:  # the move from the scored state (node, ...): its reward, and where it leads
            c_node = neighbours[node, a]
            cost = costs[node, a]
            c_el = elapsed + cost
            c_rem = remaining - cost
            if not known[c_node] or (c_el < horizon - tol and table[c_node, T_BUILT] == 0):
                return (1, c_node, total, discount, f_gains, f_order, f_terms, node, remaining, elapsed, gains, a,
                        (Li, G, UV, Pcc, Bcc, header, idata, fdata, r, K))
            share = min(1.0, (horizon - elapsed) / cost)
            d = gamma ** (cost / period)
            total += discount * (share * gains[a])
            discount *= d
        if c_el >= horizon - tol:
            break
        out = step_terms(P, B, ipool, fpool, table, k, node, a, c_node, header, idata, fdata, r, K, UV, Pcc, Bcc,
                         Li, G)
        gains = out[0] / unit
        Li, G, UV, Pcc, Bcc, header, idata, fdata, r, K = out[1:]
        node, remaining, elapsed = c_node, c_rem, c_el
        order = _order(gains, costs[node], remaining, tol)
        if first:
            f_gains, f_order, f_terms = gains, order, (Li, G, UV, Pcc, Bcc, header, idata, fdata, r, K)
            first = False
        if order.size == 0:
            break
        a = _draw(rng, gains, costs[node], order, lam)
        if a < 0:
            break
        pending = True
    return (0, -1, total, discount, f_gains, f_order, f_terms, node, remaining, elapsed, gains, a,
            (Li, G, UV, Pcc, Bcc, header, idata, fdata, r, K))
