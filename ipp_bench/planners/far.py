"""Far targets: greedy's one-leg score, raised where a look far away is worth more per second.

Greedy scores the legs to the neighbours of the current node; a region two legs away is invisible to
it, and on sparse hotspots it then hovers over what it has mapped. The ``oracle`` reference adds
far targets on the true ROI; :func:`far_scores` does the same on the belief's ROI (no truth), and is
the teacher of the attention policy's ``skip_teacher = "far"`` networks
(:mod:`ipp_bench.policies.features`). Both use :func:`duration_graph`, the roadmap's legs weighted by
the mission's clock, built once per roadmap.
"""

from __future__ import annotations

import weakref
from typing import Any

import numpy as np

from .base import beats, first_best

_GRAPHS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def duration_graph(view: Any):
    """(N, N) sparse matrix of the roadmap's legs weighted by their flight time [s] by the mission's
    clock (what the quickest roadmap path to a target costs); built once per roadmap and mission."""
    from scipy.sparse import csr_matrix

    key = view.static_key()
    cached = _GRAPHS.get(view.roadmap)
    if cached is None or cached[0] != key:
        rm = view.roadmap
        n, k = rm.neighbours.shape
        durations = np.concatenate([view.neighbour_durations(i) for i in range(n)])
        graph = csr_matrix((durations, (np.repeat(np.arange(n), k), rm.neighbours.ravel())), shape=(n, n))
        cached = _GRAPHS[view.roadmap] = (key, graph)
    return cached[1]


def best_far_target(view: Any, obs: dict[str, np.ndarray], targets: np.ndarray, rates: Any,
                    with_path: bool = False) -> tuple:
    """(rate, neighbour index) of the best far target and the first leg of the quickest roadmap
    path to it, or (-inf, -1) when no target is reachable within the budget (``with_path``: and the
    path's nodes after the current one, ending at the target, as a third item; [] for none). ``rates(t, ok)`` gives
    each target's gain per second of flight from its flight times ``t`` (``ok``: reachable; -inf
    where not scored); it is called only when some target is reachable."""
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
             look_gains: Any) -> int:
    """Greedy's neighbour (the argmax of ``scores``, -inf where masked), or the first leg of the
    quickest roadmap path to the best far target when that target's gain per second of flight beats
    it: the rule of the ``oracle`` reference (on the true ROI) and of the ``far`` probe (on the
    belief's). ``look_gains()`` gives the gain of one look at each of ``targets`` (called only when a
    target is reachable within the budget)."""
    best = first_best(scores)
    rate, action = best_far_target(
        view, obs, targets, lambda t, ok: np.where(ok, look_gains() / np.where(ok, t, 1.0), -np.inf))
    if not beats(rate, scores[best]):
        return best
    return action if obs["action_mask"][action] else best


FAR_TOP = 16  # [-] far targets whose look gain is computed exactly per decision (see far_scores)


class FarTargets:
    """What :func:`far_scores` needs of one roadmap and camera (built once per roadmap): one look per
    node, padded for batched algebra."""

    def __init__(self, view: Any) -> None:
        from .oracle import LookBatch

        rm = view.roadmap
        looks = [(i, view.sensor.observe(rm.positions[i])) for i in range(rm.n_nodes)]
        looks = [(i, o) for i, o in looks if o is not None]
        self.targets = np.array([i for i, _ in looks], dtype=np.int64)
        self.looks = LookBatch([o for _, o in looks])

    @classmethod
    def of(cls, view: Any) -> FarTargets:
        key = view.static_key()
        cached = _FAR.get(view.roadmap)
        if cached is None or cached[0] != key:
            cached = _FAR[view.roadmap] = (key, cls(view))
        return cached[1]

    def gains(self, sel: np.ndarray, cov: np.ndarray, roi: np.ndarray) -> np.ndarray:
        """(M,) exact ROI trace reduction Tr_ROI(P - P+) of the looks ``sel`` (indices into
        ``targets``), each alone: the batch Kalman formula on each look's own cells."""
        lb = self.looks
        C, W, var = lb.cells[sel], lb.W[sel], lb.var[sel]
        Pr = cov[:, roi][C]  # (M, c, |ROI|): the covariance of each look's cells with the ROI
        Wt = W.transpose(0, 2, 1)
        S = W @ cov[C[:, :, None], C[:, None, :]] @ Wt
        idx = np.arange(S.shape[1])
        S[:, idx, idx] += var
        return (np.linalg.inv(S) * (W @ (Pr @ Pr.transpose(0, 2, 1)) @ Wt)).sum(axis=(1, 2))


_FAR: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def far_scores(view: Any, obs: dict[str, np.ndarray], top: int = FAR_TOP) -> np.ndarray:
    """(k,) greedy's score of each neighbour's leg, raised to the best far target reached through it.

    Greedy's one-leg score cannot see a region two legs away; on sparse hotspots it then hovers over
    what it has mapped. Far targets are the roadmap's nodes: one look at node j scores its exact ROI
    trace reduction per second of the quickest roadmap flight to it (Dijkstra on the mission's leg
    durations), the rule of the ``oracle`` reference, but on the belief's ROI. The look gains are
    exact for the ``top`` nodes with the best look-gain feature per second (:class:`LookGain`, the
    cheap approximation, ranks them) and not computed for the others. The best target's score goes
    to the first neighbour on its path when it beats every neighbour's leg (and that neighbour is
    allowed), so the argmax is greedy's choice unless then. Masked neighbours score -inf.
    """
    from ..policies.features import LookGain  # the cheap ranking (policies: the network's feature)
    from .greedy import greedy_scores

    view.require_dense_belief("far", "its far targets' look gains read the full covariance (FarTargets.gains)")
    mask = np.asarray(obs["action_mask"]).astype(bool).reshape(-1)
    scores = np.where(mask, greedy_scores(view, int(obs["current_node"][0])), -np.inf)
    ft = FarTargets.of(view)

    def rates(t: np.ndarray, ok: np.ndarray) -> np.ndarray:
        roi = view.belief_roi()
        g = LookGain.of(view)(view.belief.variance, roi)[ft.targets]
        approx = np.where(ok, g / np.where(ok, t, 1.0), -np.inf)
        sel = np.argpartition(-approx, top)[:top] if approx.size > top else np.arange(approx.size)
        sel = sel[np.isfinite(approx[sel])]
        out = np.full(t.size, -np.inf)
        out[sel] = ft.gains(sel, view.belief.cov, roi) / t[sel]
        return out

    rate, action = best_far_target(view, obs, ft.targets, rates)
    if beats(rate, scores.max()) and mask[action]:
        scores[action] = rate
    return scores
