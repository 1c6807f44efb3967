"""Receding-horizon CMA-ES over continuous 3D waypoints (Hitz et al. 2017; Popovic et al. 2020).

At every decision CMA-ES (pycma, seeded, writing no files) optimises ``n_waypoints`` points in
[0, width] x [0, height] x [lowest, highest altitude level] (``reach_m``: within that half-width of the
UAV in x and y, for maps much larger than the paper's). The objective is the predicted
reduction of Tr(P) over the belief ROI from the measurements the mission would take along the
path (same spacing rule, values not needed), divided by the path's flight time, the path cut at
the remaining budget. The first waypoint is flown; the rest warm-starts the next optimisation.

How a population is scored with ``evaluation = "batched"`` (the default, on the dense belief): the
reduction of Tr(P) over the ROI D by a path's read-outs (rows W on cells c, noise R) is
``Tr(S^-1 G)`` with ``S = W P[c, c] W^T + R`` and ``G = W B[c, c] W^T``, ``B = P D P``: the sum over
the ROI of the Kalman update's ``diag(C S^-1 C^T)`` (``C = P H^T``) regrouped. B is computed once
per decision (one n x n x n_ROI product) and shared by every candidate of every population. A
candidate's read-outs are placed as the mission places them (the spacing rule of
:meth:`~ipp_bench.planners.base.RobotView.leg_observations`) and turned into the camera's sparse rows, a
footprint looked at twice folded into one row with both looks' precision (the same posterior); S and G
are summed from the nonzero weights (each row averages at most a binning block). That is compiled code
(:mod:`~ipp_bench.planners.kernels.readouts`; numba, the ``eval`` extra); then one Cholesky
factorisation and inverse of S (LAPACK). A candidate of m rows on q cells costs O(nnz(W) q + m^3)
instead of the O(n q m + n m^2) of its update against the whole map. ``evaluation = "reference"`` scores
each candidate with the belief's own prediction (:meth:`~ipp_bench.planners.base.RobotView.predict_variance`),
as the window belief always is (it has no dense P). Both give the same values up to rounding, so CMA-ES
takes the same steps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from ..core.belief import GPBelief
from ..core.config import check_integer, check_number
from .base import MIN_FLIGHT_M, ContinuousPlanner

#: how a population's objective values are computed (the same values, up to rounding)
EVALUATIONS = ("batched", "reference")


@dataclass(frozen=True)
class CMAESConfig:
    """CMA-ES settings (REFERENCE.md: step ~0.2-0.3 of the range, population ~12).

    Attributes:
        n_waypoints: waypoints optimised per decision.
        popsize: CMA-ES population size.
        max_evals: objective evaluations per decision.
        sigma0: initial step size as a fraction of each axis' range.
        min_leg_m: shortest first leg [m] (shorter candidates are stretched to it).
        reach_m: half-width [m] of the search box in x and y, centred on the UAV (cut at the map's
            edges); 0: the whole map. On a map much larger than the paper's the whole map is a box in
            which ``sigma0`` is tens of metres and every candidate path crosses it; ``reach_m`` keeps
            the search (and an objective evaluation's cost) the size it is on a small map.
        evaluation: ``"batched"`` (a population's predicted reductions from B = P D P, once per
            decision) or ``"reference"`` (each candidate's own Kalman prediction against the map).
    """

    n_waypoints: int = 3
    popsize: int = 12
    max_evals: int = 72
    sigma0: float = 0.25
    min_leg_m: float = 2.5  # [m]
    reach_m: float = 0.0  # [m] 0: the whole map
    evaluation: str = "batched"

    def __post_init__(self):
        check_integer("cmaes.n_waypoints", self.n_waypoints, 1, 100)
        check_integer("cmaes.popsize", self.popsize, 2, 10_000)
        check_integer("cmaes.max_evals", self.max_evals, self.popsize, 10_000_000)
        check_number("cmaes.sigma0", self.sigma0, 0.0, 1.0, low_open=True)
        check_number("cmaes.min_leg_m", self.min_leg_m, 0.0, low_open=True, unit="m")
        check_number("cmaes.reach_m", self.reach_m, 0.0, unit="m")
        if self.evaluation not in EVALUATIONS:
            raise ValueError(f"cmaes.evaluation = {self.evaluation!r} is invalid: expected one of {list(EVALUATIONS)}")


class CMAESPlanner(ContinuousPlanner):
    """Receding-horizon CMA-ES over continuous waypoints (the paper's deployment baseline)."""

    name = "cmaes"
    Config = CMAESConfig

    def __init__(self, config: CMAESConfig | None = None):
        try:  # at construction, so that a leaderboard leaves it out up front, not part-way
            import cma  # noqa: F401
        except ImportError:
            raise ImportError('the cmaes planner needs pycma: pip install "ipp-bench[eval]"') from None
        super().__init__(config or CMAESConfig())
        if self.settings.evaluation == "batched":
            from .kernels import readouts
            from .kernels.jit import require_numba

            require_numba("cmaes:evaluation=batched")
            self._kernels = readouts

    def fingerprint(self) -> dict[str, str]:
        """The evaluation, whose rounding can turn a step of CMA-ES: a results folder refuses the other's rows
        (on a window belief both score with the belief's own prediction)."""
        return {"evaluation": self.settings.evaluation}

    def reset(self, view, seed):
        super().reset(view, seed)
        cfg = view.config
        width, height = cfg.grid.size_m
        alts = cfg.graph.altitudes
        self._map_lo = np.array([0.0, 0.0, alts[0]])
        self._map_hi = np.array([width, height, alts[-1] if alts[-1] > alts[0] else alts[0] + 1e-6])
        self._lo, self._hi = self._map_lo, self._map_hi  # the search box of the decision
        self._plan: np.ndarray | None = None  # (n_waypoints, 3) [m] the last decision's waypoints
        self._P: np.ndarray | None = None  # the decision's covariance (None: the reference evaluation)
        self._B: np.ndarray | None = None  # (n, n) P D P, its buffer reused by the decisions
        if self.settings.evaluation == "batched":
            from . import kernels

            self._camera = self._kernels.camera_args(view.sensor)
            kernels.warm_up()  # compiled once per process, before the first decision's clock starts

    def _search_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The box CMA-ES searches in: the map's, or ``reach_m`` around the UAV within it."""
        reach = self.settings.reach_m
        if not reach:
            return self._map_lo, self._map_hi
        here = self.view.position
        lo, hi = self._map_lo.copy(), self._map_hi.copy()
        lo[:2] = np.maximum(lo[:2], here[:2] - reach)
        hi[:2] = np.minimum(hi[:2], here[:2] + reach)
        return lo, hi

    def _to_xyz(self, u: np.ndarray) -> np.ndarray:
        pts = self._lo + np.clip(u.reshape(-1, 3), 0.0, 1.0) * (self._hi - self._lo)
        here = self.view.position
        d = pts[0] - here
        dist = float(np.linalg.norm(d))
        if dist < self.settings.min_leg_m:  # stretch a too-short first leg (inside the box)
            direction = d / dist if dist > 1e-9 else np.array([1.0, 0.0, 0.0])
            pts[0] = np.clip(here + direction * self.settings.min_leg_m, self._lo, self._hi)
        return pts

    def _path(self, pts: np.ndarray, points: bool = False) -> tuple[list, float]:
        """Observations along the path and its flight time, cut at the remaining budget (``points``: the
        read-out positions instead, one (K, 3) array per leg, as :meth:`~ipp_bench.planners.base.RobotView.
        leg_observations` places them).

        The objective's model of the flight is the nominal one (length / speed); the waypoint
        actually flown is cut to what the mission's clock affords (:meth:`affordable`).
        """
        view = self.view
        speed = view.config.mission.speed
        left = self.flight_left_m()  # [m]
        here, obs, flown = view.position, [], 0.0
        for p in pts:
            dist = float(np.linalg.norm(p - here))
            if dist <= 1e-9:
                continue
            if dist > left:
                p = here + (p - here) * (left / dist)
                dist = left
            if dist < MIN_FLIGHT_M:
                break
            if points:
                obs.append(self._kernels.leg_points(here, p, view.config.mission.measurement_spacing))
            else:
                obs += view.leg_observations(here, p)
            flown += dist
            left -= dist
            here = p
        return obs, flown / speed

    def _objective(self, u: np.ndarray) -> float:
        """The reference objective of one candidate: minus the predicted reduction of Tr(P) over the ROI
        per second of flight, from the belief's own prediction of the variances after the path."""
        obs, duration = self._path(self._to_xyz(u))
        if duration <= 0:
            return 0.0
        var = self.view.predict_variance(self._belief, obs)
        return -(self._before - self.view.roi_trace(var, self._roi)) / duration

    def _objectives(self, cands) -> list[float]:
        """The objective of every candidate of a population (:meth:`_objective`'s values up to rounding)."""
        if self._P is None:
            return [self._objective(np.asarray(c)) for c in cands]
        out = []
        for c in cands:
            legs, duration = self._path(self._to_xyz(np.asarray(c)), points=True)
            out.append(0.0 if duration <= 0 else -self._reduction(np.concatenate(legs)) / duration)
        return out

    def _begin_batched(self) -> None:
        """P and B = P D P of the decision (D: its ROI); None where the belief has no dense P or the reference
        evaluation is asked for."""
        self._P = None
        belief = self._belief
        if self.settings.evaluation != "batched" or not isinstance(belief, GPBelief):
            return
        self._P = np.ascontiguousarray(belief.cov)
        self._B = self._kernels.roi_product(self._P, self._roi, self._B)

    def _reduction(self, points: np.ndarray) -> float:
        """Tr(S^-1 G): the reduction of Tr(P) over the ROI by the read-outs from ``points`` ((K, 3) [m]; one
        batch: the camera's rows from :func:`~ipp_bench.planners.kernels.readouts.camera_rows`, repeated rows
        folded by :func:`~ipp_bench.planners.kernels.readouts.fold_repeated_rows`, S and G from
        :func:`~ipp_bench.planners.kernels.readouts.readout_blocks`)."""
        rows = self._kernels.fold_repeated_rows(*self._kernels.camera_rows(points, *self._camera))
        if rows[3].size == 0:
            return 0.0
        S, G = self._kernels.readout_blocks(self._P, self._B, *rows)
        # S is symmetric: its transpose is the Fortran-ordered S that LAPACK factors in place
        c, info = lapack.dpotrf(S.T, lower=1, clean=1, overwrite_a=1)  # the upper triangle is zeroed
        if info == 0:
            low, info = lapack.dpotri(c, lower=1, overwrite_c=1)  # S^-1 in the lower triangle, zeros above
        if info != 0:
            raise np.linalg.LinAlgError(f"{self.name}: S = H P H^T + R is not positive definite (LAPACK info {info})")
        # sum_ij (S^-1)_ij G_ij from the lower triangle (both symmetric; G's rows are its columns)
        return float(2.0 * np.dot(low.ravel(order="F"), G.ravel()) - np.dot(np.diagonal(low), np.diagonal(G)))

    def next_waypoint(self):
        import cma

        view = self.view
        cfg = self.settings
        if self.flight_left_m() < MIN_FLIGHT_M:  # then affordable() below would say None too
            return None
        self._belief = view.belief
        self._roi = view.belief_roi()
        self._before = view.roi_trace(self._belief.variance, self._roi)
        self._begin_batched()
        self._lo, self._hi = self._search_box()
        here_u = (view.position - self._lo) / (self._hi - self._lo)
        if self._plan is None:
            x0 = np.tile(np.clip(here_u, 0, 1), cfg.n_waypoints)
        else:  # warm start: the rest of the last plan, then its last point again (in this box)
            plan = np.clip((self._plan - self._lo) / (self._hi - self._lo), 0.0, 1.0)
            rest = plan[1:]
            x0 = np.concatenate([rest, np.repeat(rest[-1:] if len(rest) else plan[-1:], 1, axis=0)]).ravel()
        opts = {"bounds": [0.0, 1.0], "popsize": cfg.popsize, "maxfevals": cfg.max_evals,
                "seed": int(self.rng.integers(1, 2**31 - 1)), "verbose": -9, "verb_log": 0,
                "verb_disp": 0, "tolfun": 1e-12, "tolx": 1e-9}
        es = cma.CMAEvolutionStrategy(np.clip(x0, 1e-3, 1 - 1e-3), cfg.sigma0, opts)
        best_u, best_f = x0, self._objectives([x0])[0]
        while not es.stop():
            cands = es.ask()
            fs = self._objectives(cands)
            es.tell(cands, fs)
            i = int(np.argmin(fs))
            if fs[i] < best_f:
                best_u, best_f = np.asarray(cands[i]), fs[i]
        pts = self._to_xyz(best_u)
        self._plan = pts
        return self.affordable(pts[0])
