"""Gain predictors: what one look from a roadmap node, or a flight to a far node, is predicted to gain.

Pure numpy and scipy, below the planners and the policies, which both read these predictions:

- :class:`LookGain`: the cheap per-node look gain from the belief's marginal variances (the attention
  network's sixth node feature, and the stall guard's ranking of far nodes);
- :class:`LookBatch`: the exact ROI trace reduction of single looks spread over the map (the ``oracle``
  reference's far targets);
- :func:`duration_graph`, :func:`best_far_target`, :func:`far_move`: far targets, scored by their gain
  per second of the quickest roadmap flight to them (Dijkstra on the mission's leg durations);
- :func:`first_best`, :func:`beats`: the argmax and the comparison of scores that every planner uses,
  the same on every CPU.

The functions that take a ``view`` read it as a :class:`~ipp_bench.planners.base.RobotView` (roadmap,
camera, clock and budget); nothing here reads the ground truth.

The look-gain feature, for node i:

    g_i = 10 * (predicted ROI trace reduction of one read-out taken at node i) / Tr_ROI(P)

with the prediction taken from the marginal variances only, assuming the cells of one read-out fully
correlated (one 8 m read-out is one cell; one 14 m read-out is the mean of a 2 x 2 block, whose cells lie
well within the GP length scale). For read-out j with rows ``w`` of H, noise variance ``r_j`` and
``s_j = sum_c w_c sqrt(P_cc)``, the reduction is ``s_j^2 / (s_j^2 + r_j) * sum_{c in j, c in ROI} P_cc``,
summed over the read-outs of node i. It is exact for single-cell read-outs of an uncorrelated prior and
costs three sparse matrix-vector products per decision (well under a millisecond at 1800 nodes), where
greedy's exact leg predictions cost 1.6 ms at 450 nodes and 3.9 ms at 1800 nodes. The scale matches the
reward (paper eq. 9: 10 x the relative ROI trace reduction).
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy import sparse

from .belief import value_scale

#: scores closer than this, relative to the best, are a tie: a mirror-image pair of legs scores the same
#: up to the last bits, and which bits those are depends on the CPU's BLAS kernels (AVX2 or AVX-512)
TIE_RTOL = 1e-9


def first_best(scores: np.ndarray, rtol: float = TIE_RTOL) -> int:
    """The index of the best score, ties (within ``rtol`` of the best) going to the lowest index.

    ``np.argmax`` on scores that tie exactly in exact arithmetic picks whichever the floating-point
    rounding of this machine favours, so the same seed flew other paths on other CPUs; this rule
    makes the choice the same on every machine. -inf (masked) entries are never picked unless all are.
    """
    scores = np.asarray(scores, dtype=np.float64).reshape(-1)
    best = scores.max()
    if not np.isfinite(best):
        return int(np.argmax(scores))
    return int(np.flatnonzero(scores >= best - rtol * abs(best))[0])


def beats(a: float, b: float, rtol: float = TIE_RTOL) -> bool:
    """``a > b`` by more than a tie (:data:`TIE_RTOL` relative): the same answer on every CPU."""
    return bool(a > b + rtol * max(abs(a), abs(b))) if np.isfinite(b) else bool(a > b)


# -- the look-gain feature --------------------------------------------------------------------------


class LookGain:
    """Per-node look-gain feature of one roadmap and camera (built once, then cheap per call)."""

    def __init__(self, positions: np.ndarray, sensor: Any, n_cells: int) -> None:
        rows, cols, w, noise, white, factor, node_of = [], [], [], [], [], [], []
        j = 0
        for i, p in enumerate(positions):
            obs = sensor.observe(p)
            if obs is None:
                continue
            for r in range(obs.m):
                nz = obs.weights[r] != 0
                cells = obs.cells[nz]
                rows.append(np.full(cells.size, j))
                cols.append(cells)
                w.append(obs.weights[r][nz])
                noise.append(obs.var[r])
                white.append(obs.var[r] - (0.0 if obs.persistent is None else obs.persistent[r]))
                factor.append(obs.factor)
                node_of.append(i)
                j += 1
        rows_a, cols_a = np.concatenate(rows), np.concatenate(cols)
        self.W = sparse.csr_matrix((np.concatenate(w), (rows_a, cols_a)), shape=(j, n_cells))
        self.ind = sparse.csr_matrix((np.ones(rows_a.size), (rows_a, cols_a)), shape=(j, n_cells))
        self.noise = np.asarray(noise, dtype=np.float64)  # one look's whole variance (white + persistent)
        self.white = np.asarray(white, dtype=np.float64)  # its look-to-look part
        self.factor = np.asarray(factor, dtype=np.int64)  # each read-out row's resolution factor
        self.node = sparse.csr_matrix((np.ones(j), (np.asarray(node_of), np.arange(j))), shape=(len(positions), j))

    @classmethod
    def of(cls, source: Any) -> LookGain:
        """The feature of ``source``'s roadmap and camera (a RobotView or an env), built once per roadmap
        and camera: tasks share a roadmap where their maps agree (``Grid15Eval-v1`` and the deployment's
        twin do), not always their camera's constants, so one process that flies both keeps one each."""
        roadmap = source.roadmap
        per_camera = _LOOK_GAINS.setdefault(roadmap, {})
        key = (source.sensor.cfg, source.config.grid)
        cached = per_camera.get(key)
        if cached is None:
            cached = per_camera[key] = cls(roadmap.positions, source.sensor, source.config.grid.n_cells)
        return cached

    def __call__(self, variance: np.ndarray, roi: np.ndarray, errors: Any = None) -> np.ndarray:
        """(N,) float32: 10 x predicted relative ROI trace reduction of one look from each node.

        ``errors``: the mission's :class:`~ipp_bench.core.belief.PersistentErrorBelief` where the task models
        the camera's repeated error (:func:`~ipp_bench.core.belief.error_states`), else None (white read-out
        noise, the formula of the module docstring). With it, a look at cell c measures y_c = x_c + d_c u_c
        (d_c u_c the persistent error, ``errors.sd``) plus white noise, and the formula reads the augmented
        state's marginals: a read-out j's block is ``S_j = sum_c w_c q_c`` with q_c^2 = Var(y_c), and each
        ROI cell loses ``S_j^2 / (S_j^2 + r_j) * k_c^2 / q_c^2`` with k_c = Cov(x_c, y_c) and r_j the white
        variance. A cell looked at again and again has y_c pinned, so k_c -> 0 and the look gains
        nothing, as the belief's update says; the white formula would keep promising a gain there
        (it treats the repeated error as fresh noise). Exact for single-cell read-outs of an
        uncorrelated belief; the same formula as the white one where d = 0 and the cross term is 0.
        """
        var = np.maximum(np.asarray(variance, dtype=np.float64), 0.0)
        roi_var = np.where(roi, var, 0.0)
        total = roi_var.sum()
        if total <= 0:
            return np.zeros(self.node.shape[0], dtype=np.float32)
        if errors is None:
            s2 = np.square(self.W @ np.sqrt(var))
            red = s2 / (s2 + self.noise) * (self.ind @ roi_var)
        else:
            red = self._error_reductions(var, roi, errors)
        return (10.0 * (self.node @ red) / total).astype(np.float32)

    def _error_reductions(self, var: np.ndarray, roi: np.ndarray, errors: Any) -> np.ndarray:
        """Per read-out row: the predicted ROI trace reduction under the camera-error states."""
        n = var.size
        cells = np.arange(n)
        cov, mean = errors.state.cov, errors.field.mean
        s_block = np.zeros(self.factor.size)
        gain = np.zeros(self.factor.size)
        for f in np.unique(self.factor):
            rows = self.factor == f
            if int(f) in errors.offset:  # y = x + d u: its variance and its covariance with x
                off = errors.offset[int(f)]
                unseen_sd = np.sqrt(errors.variances[int(f)] * value_scale(mean, errors.floor))
                d = np.where(errors.seen, errors.sd[int(f)], unseen_sd)
                cross = cov[cells, cells + off]  # Cov(x_c, u_c)
                k = var + d * cross
                q2 = np.maximum(k + d * cross + d * d * cov[cells + off, cells + off], 0.0)
            else:
                k, q2 = var, var
            ratio = np.divide(k * k, q2, out=np.zeros(n), where=q2 > 0)
            s_block[rows] = (self.W @ np.sqrt(q2))[rows]
            gain[rows] = (self.ind @ np.where(roi, ratio, 0.0))[rows]
        s2 = np.square(s_block)
        r = self.white * value_scale(self.W @ mean, errors.floor)
        return np.divide(s2, s2 + r, out=np.zeros_like(s2), where=s2 + r > 0) * gain


_LOOK_GAINS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


# -- exact look gains ---------------------------------------------------------------------------------


class LookBatch:
    """Single read-outs (one per target node), each on its own cells, padded for batched algebra.

    Unlike :class:`~ipp_bench.core.belief.LegBatch` (one union of cells for all legs, right for the
    neighbours of one node), each look keeps its own few cells, so looks spread over the whole map
    cost what their own cells cost.
    """

    def __init__(self, observations: list) -> None:
        m = max(o.weights.shape[0] for o in observations)
        c = max(o.cells.size for o in observations)
        self.cells = np.zeros((len(observations), c), dtype=np.int64)  # padding: cell 0 with weight 0
        self.W = np.zeros((len(observations), m, c))
        self.var = np.ones((len(observations), m))  # padding rows: unit variance, zero weight
        for j, o in enumerate(observations):
            rows, q = o.weights.shape
            self.cells[j, :q] = o.cells
            self.W[j, :rows, :q] = o.weights
            self.var[j, :rows] = o.var

    def trace_reductions(self, cov: np.ndarray, roi: np.ndarray) -> np.ndarray:
        """(b,) Tr(P - P+) over the cells ``roi`` (bool mask) of each look alone.

        With S = H P H^T + R, the reduction is sum over ROI columns r of (H P)_r^T S^-1 (H P)_r
        = sum(S^-1 * H Q H^T) with Q = P[:, roi] P[roi, :]: one product over the whole map, then
        each look reads its own few cells of P and Q.
        """
        n = cov.shape[0]
        if getattr(self, "_n", None) != n:
            self._n, self._flat = n, self.cells[:, :, None] * n + self.cells[:, None, :]
        P_roi = cov[:, roi]
        Q = P_roi @ P_roi.T
        Wt = self.W.transpose(0, 2, 1)
        S = self.W @ cov.ravel()[self._flat] @ Wt
        idx = np.arange(S.shape[1])
        S[:, idx, idx] += self.var
        return (np.linalg.inv(S) * (self.W @ Q.ravel()[self._flat] @ Wt)).sum(axis=(1, 2))


# -- far targets ----------------------------------------------------------------------------------------

_GRAPHS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def duration_graph(view: Any) -> sparse.csr_matrix:
    """(N, N) sparse matrix of the roadmap's legs weighted by their flight time [s] by the mission's
    clock (what the quickest roadmap path to a target costs), whatever the drone's state
    (:meth:`~ipp_bench.core.mission.Mission.static_leg_durations`); built once per roadmap and mission
    constants, so the same whichever decision of whichever episode built it."""
    key = view.static_key()
    cached = _GRAPHS.get(view.roadmap)
    if cached is None or cached[0] != key:
        rm = view.roadmap
        n, k = rm.neighbours.shape
        # never from the drone's current state: the cache outlives the decision (and the episode) that built it
        durations = np.concatenate([view.static_neighbour_durations(i) for i in range(n)])
        graph = sparse.csr_matrix((durations, (np.repeat(np.arange(n), k), rm.neighbours.ravel())), shape=(n, n))
        cached = _GRAPHS[view.roadmap] = (key, graph)
    return cached[1]


def best_far_target(view: Any, obs: dict[str, np.ndarray], targets: np.ndarray,
                    rates: Callable[[np.ndarray, np.ndarray], np.ndarray], with_path: bool = False) -> tuple:
    """(rate, neighbour index) of the best far target and the first leg of the quickest roadmap
    path to it, or (-inf, -1) when no target is reachable within the budget (``with_path``: and the
    path's nodes after the current one, ending at the target, as a third item; [] for none).

    ``rates(t, ok)`` gives each target's gain per second of flight from its flight times ``t``
    (``ok``: reachable; -inf where not scored); it is called only when some target is reachable.
    """
    from scipy.sparse.csgraph import dijkstra

    cur = int(obs["current_node"][0])
    t, pred = dijkstra(duration_graph(view), indices=cur, return_predecessors=True)
    t = t[targets]
    ok = (t > 0) & np.isfinite(t) & view.fits_budget(t, view.remaining_s)
    none = (-np.inf, -1, []) if with_path else (-np.inf, -1)
    if not ok.any():
        return none
    far = rates(t, ok)
    j = first_best(far)
    if not np.isfinite(far[j]):
        return none
    path = [int(targets[j])]
    while pred[path[-1]] != cur:
        path.append(int(pred[path[-1]]))
    out = float(far[j]), int(np.flatnonzero(view.roadmap.neighbours[cur] == path[-1])[0])
    return (*out, path[::-1]) if with_path else out


def far_move(view: Any, obs: dict[str, np.ndarray], scores: np.ndarray, targets: np.ndarray,
             look_gains: Callable[[], np.ndarray]) -> int:
    """The neighbour with the best of ``scores`` (-inf where masked), or the first leg of the quickest
    roadmap path to the best far target when that target's gain per second of flight beats it (the rule
    of the ``oracle`` reference). ``look_gains()`` gives the gain of one look at each of ``targets``
    (called only when a target is reachable within the budget)."""
    best = first_best(scores)
    rate, action = best_far_target(
        view, obs, targets, lambda t, ok: np.where(ok, look_gains() / np.where(ok, t, 1.0), -np.inf))
    if not beats(rate, scores[best]):
        return best
    return action if obs["action_mask"][action] else best


__all__ = ["TIE_RTOL", "LookBatch", "LookGain", "beats", "best_far_target", "duration_graph", "far_move",
           "first_best"]
