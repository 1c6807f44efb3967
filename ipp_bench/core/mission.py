"""A mission: ground truth + belief + camera + budget clock (the world state, no task logic).

``fly_to(xyz)`` flies a straight line at the configured speed, measures every
``measurement_spacing`` metres travelled (the distance carries over between legs) and on arrival,
updates the belief, and records time-stamped metrics so that their values at any mission time
(50 / 100 / 150 / 200 s) can be read afterwards. Measurements of one leg go into one batch Kalman
update (equal to sequential updates), split at the report times so that ``metrics_at`` is exact.
Graph environments, continuous planners and the MuJoCo deployment all drive a ``Mission``.

Seams: a mission keeps the bookkeeping (clock, budget, report times, path, history, metrics) and
takes two parts. A :class:`Platform` flies a leg and returns its read-outs (:class:`StraightLegs`
here: the graph's straight legs at the mission speed, read by the sensor model; the MuJoCo
deployment's stop-and-go and continuous flights in ``ipp_bench.sim.mission``). A belief model
with one ``update(observations, values)`` (:func:`ipp_bench.core.belief.belief_model`: white noise or
the camera-error states) keeps ``belief``, the field belief that planners and metrics read.

The mission owns the clock: :meth:`Mission.leg_durations` is the one rule of what a straight leg
costs (length / speed here; the MuJoCo mission adds its velocity ramps), and
:meth:`Mission.affordable` the one rule of which legs the remaining budget can pay for. Action
masks, the robot's view and every look-ahead planner ask these two, never the speed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Protocol

import numpy as np

from . import metrics as M
from .belief import GPBelief, belief_model
from .belief_window import WindowBelief, prior_belief
from .config import TIME_TOL_S, IPPConfig, cell_centre, quoted
from .sensor import Observation, Sensor

#: a time-stamped read-out: (observation or None when nothing usable was seen, values z, time [s])
Record = tuple[Observation | None, np.ndarray | None, float]

#: the metrics an episode reports at each report time (:meth:`Mission.metrics_at`)
REPORT_KEYS = ("trace_roi", "rmse_roi", "uncertainty_reduction_pct", "rmse_reduction_pct")
_LENGTH_TOL_M = 1e-9  # [m] a read-out this close to the arrival point is the arrival read-out


class BudgetExceededError(ValueError):
    """A leg that the remaining flight-time budget cannot pay for."""


@dataclass(frozen=True)
class MetricRecord:
    """Evaluation metrics (over the ground-truth ROI) at one mission time."""

    time_s: float
    trace_roi: float
    rmse_roi: float
    uncertainty_reduction_pct: float
    rmse_reduction_pct: float
    measurements: int
    distance_m: float


@dataclass(frozen=True)
class FlownLeg:
    """What one ``fly_to`` did."""

    duration_s: float
    distance_m: float
    measurements: int
    arrival_time_s: float


def leg_samples(length: float, since_last: float, spacing: float) -> np.ndarray:
    """Distances along a leg of ``length`` [m] at which the camera is read.

    Every ``spacing`` metres travelled, counting the ``since_last`` metres flown since the last
    measurement before the leg, and once on arrival. Planners predict with the same rule.
    """
    s = np.arange(spacing - since_last, length - _LENGTH_TOL_M, spacing)
    return np.append(s[s > _LENGTH_TOL_M], length)


def leg_length(start, end) -> float:
    """Length [m] of the straight leg ``start -> end`` (the one formula every leg is measured by)."""
    d = np.asarray(end, dtype=np.float64) - np.asarray(start, dtype=np.float64)
    return math.sqrt(d.dot(d))


def leg_lengths(start, ends) -> np.ndarray:
    """(K,) lengths [m] of the legs from ``start`` to each of the (K, 3) ``ends``, each exactly
    :func:`leg_length` (row by row: a vectorised norm rounds differently in the last bit)."""
    d = np.asarray(ends, dtype=np.float64).reshape(-1, 3) - np.asarray(start, dtype=np.float64)
    return np.array([math.sqrt(v.dot(v)) for v in d], dtype=np.float64)


def fits_budget(duration_s, remaining_s):
    """Whether legs of ``duration_s`` [s] fit ``remaining_s`` [s] (the one tolerance: TIME_TOL_S)."""
    return np.asarray(duration_s) <= remaining_s + TIME_TOL_S


def cell_to_xyz(config: IPPConfig, col: float, row: float, altitude: float) -> np.ndarray:
    """Position [m] above the centre of cell (col, row) at ``altitude``."""
    res = config.grid.resolution
    return np.array([cell_centre(col, res), cell_centre(row, res), altitude], dtype=np.float64)


@dataclass(frozen=True)
class LegOutcome:
    """What a platform reports of one leg (the mission books it)."""

    records: list  # time-stamped read-outs (:data:`Record`), in order
    end_time_s: float  # [s] mission time at the end of the leg (the mission clips it to the budget)
    duration_s: float  # [s] the leg's duration as :class:`FlownLeg` reports it
    distance_m: float  # [m] flown
    position: np.ndarray  # (3,) [m] where the leg ends (the mission's position from then on)
    since_measurement_m: float  # [m] flown since the last read-out (carried into the next leg)


class Platform(Protocol):
    """How a mission's legs are flown and read: the graph's straight legs or a simulated drone."""

    def begin(self, mission: Mission) -> None:
        """Called once, when the mission starts (a simulated world paints its field here)."""

    def leg_durations(self, mission: Mission, start_xyz, end_xyzs) -> np.ndarray:
        """(K,) flight times [s] of legs from ``start_xyz`` to each of the (K, 3) ``end_xyzs``."""

    def fly(self, mission: Mission, target: np.ndarray, length_m: float) -> LegOutcome:
        """Fly the accepted leg from ``mission.position`` to ``target`` (straight length ``length_m``)."""

    def read_here(self, mission: Mission, time_s: float) -> list:
        """The read-outs taken where the drone is now, at mission time ``time_s``."""


class StraightLegs:
    """The graph tasks' platform: straight legs at the mission speed, read by the sensor model.

    A leg takes length / speed; the camera is read every ``measurement_spacing`` metres travelled
    (carried over between legs, :func:`leg_samples`) and on arrival, each read-out drawn from
    ``mission.sensor`` with the mission's noise generator.
    """

    def begin(self, mission: Mission) -> None:
        pass

    def leg_durations(self, mission: Mission, start_xyz, end_xyzs) -> np.ndarray:
        return leg_lengths(start_xyz, end_xyzs) / mission.config.mission.speed

    def fly(self, mission: Mission, target: np.ndarray, length_m: float) -> LegOutcome:
        start = mission.position
        delta = target - start
        speed = mission.config.mission.speed
        duration = mission.leg_time(target)
        s = leg_samples(length_m, mission._since_measurement, mission.config.mission.measurement_spacing)
        points = start + np.outer(s / length_m, delta)
        times = mission.time_s + s / speed
        end = mission.time_s + duration
        return LegOutcome(self._read(mission, points, times), end, duration, length_m, target, 0.0)

    def read_here(self, mission: Mission, time_s: float) -> list:
        return self._read(mission, [mission.position], [time_s])

    @staticmethod
    def _read(mission: Mission, points, times) -> list:
        records = []
        for p, t in zip(np.asarray(points), np.asarray(times)):
            obs, z = mission.sensor.measure(p, mission._truth_flat, mission.rng)
            mission.measurement_log.append((float(t), *map(float, p)))
            records.append((obs, z, float(t)))
        return records


class Mission:
    """World state of one episode.

    Args:
        config: the problem.
        truth: (rows, cols) ground truth in [0, 1]; never shown to planners.
        rng: generator of the sensor noise.
        start_xyz: start position [m].
        belief: initial belief (default: the prior of ``config.gp``, dense or window by ``gp.belief``).
        sensor: the camera model (default: built from ``config``; an env passes its own, so that
            it builds one).
        platform: what flies the legs and reads the camera (default: :class:`StraightLegs`).
    """

    def __init__(self, config: IPPConfig, truth: np.ndarray, rng: np.random.Generator,
                 start_xyz, belief: GPBelief | WindowBelief | None = None, sensor: Sensor | None = None,
                 platform: Platform | None = None):
        g = config.grid
        truth = np.array(truth, dtype=np.float64)
        if truth.shape != (g.rows, g.cols):
            raise ValueError(f"truth has shape {truth.shape}: expected (rows, cols) = ({g.rows}, {g.cols})")
        truth.flags.writeable = False
        self.config = config
        self.truth = truth
        self._truth_flat = truth.reshape(-1)
        self.rng = rng
        self.sensor = sensor if sensor is not None else Sensor(g, config.sensor)
        self.belief = belief if belief is not None else prior_belief(g, config.gp)
        #: what every update goes through (white noise, or the camera's error states): it keeps
        #: ``belief`` (the field's marginal) current
        self.belief_model = belief_model(self.belief, self.sensor.cfg)
        #: called with (read-outs, values, time [s]) before every update (the deployment logs NIS there)
        self.update_hooks: list[Callable[[list[Observation], list[np.ndarray], float], None]] = []
        self.platform = platform if platform is not None else StraightLegs()
        self.position = self.check_position(start_xyz)
        self.time_s = 0.0
        self.distance_m = 0.0
        self.n_measurements = 0
        self._since_measurement = 0.0  # [m] flown since the last measurement (0: just measured)
        self.path: list[tuple[float, float, float, float]] = [(0.0, *self.position)]
        self.measurement_log: list[tuple[float, float, float, float]] = []
        self.eval_roi = M.truth_roi(truth, config.mission.mu_th)
        self._roi_cells = int(self.eval_roi.sum())
        self._prior_trace = M.trace_roi(self.belief.variance, self.eval_roi)
        self._prior_rmse = M.rmse_roi(self.belief.mean, self._truth_flat, self.eval_roi)
        self.history: list[MetricRecord] = [self._evaluate(0.0)]
        self.platform.begin(self)
        if config.mission.measure_at_start:
            self.assimilate_records(self.platform.read_here(self, 0.0))

    # -- clock --------------------------------------------------------------------------------
    @property
    def budget_s(self) -> float:
        return self.config.mission.budget_s

    @property
    def remaining_s(self) -> float:
        return max(self.budget_s - self.time_s, 0.0)

    def leg_durations(self, start_xyz, end_xyzs) -> np.ndarray:
        """(K,) flight times [s] of the legs from ``start_xyz`` to each of the (K, 3) ``end_xyzs``,
        as the platform flies them. The one rule of what a leg costs."""
        return self.platform.leg_durations(self, start_xyz, end_xyzs)

    def static_leg_durations(self, start_xyz, end_xyzs) -> np.ndarray:
        """(K,) flight times [s] of the legs from ``start_xyz`` to each of the (K, 3) ``end_xyzs``
        whatever the drone is doing now: :meth:`leg_durations` is exact from the current position (the
        platform knows the drone's velocity there), this one never reads the drone's state, so a cache
        built from it is the same whenever it is built. The platform's ``static_leg_durations`` where it
        has one (a platform whose durations never read the drone's state needs none)."""
        static = getattr(self.platform, "static_leg_durations", None)
        return (static or self.platform.leg_durations)(self, start_xyz, end_xyzs)

    def leg_time(self, xyz) -> float:
        """Flight time [s] of the leg from the current position to ``xyz``."""
        return float(self.leg_durations(self.position, xyz)[0])

    def affordable(self, end_xyzs) -> np.ndarray:
        """(K,) bool: which legs from the current position the remaining budget can pay for."""
        return fits_budget(self.leg_durations(self.position, end_xyzs), self.remaining_s)

    # -- flight -------------------------------------------------------------------------------
    def check_position(self, xyz) -> np.ndarray:
        """``xyz`` as a float array, or a ValueError naming the flight envelope: the map and the
        task's altitude range (its roadmap's levels), whichever planner asks. The camera model, the
        noise and the budget were set for that range: a waypoint above it would be scored with a
        footprint and a noise the task never meant to offer."""
        try:
            p = np.asarray(xyz, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            p = np.full(1, np.nan)
        width, height = self.config.grid.size_m
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"position {quoted(xyz)} is invalid: expected three finite numbers (x, y, z) [m]")
        low, high = self.config.altitude_range
        tol = _LENGTH_TOL_M
        if not (-tol <= p[0] <= width + tol and -tol <= p[1] <= height + tol and low - tol <= p[2] <= high + tol):
            raise ValueError(
                f"position {tuple(float(v) for v in p)} is outside the map or the task's altitudes (its flight "
                f"envelope): valid is x in [0, {width:g}], y in [0, {height:g}], z in [{low:g}, {high:g}] [m] (the "
                "altitudes of graph.altitudes)")
        return p

    def check_leg(self, xyz) -> tuple[np.ndarray, float]:
        """Validate a leg to ``xyz``: returns (target, length [m]) or raises as ``fly_to`` does.

        A leg is refused when its nominal time (length / speed, the least any flight takes)
        exceeds the remaining budget. Here that is :meth:`leg_time` itself; a mission whose clock
        charges more (MuJoCo) flies an accepted leg until the budget ends. Masks offer only the
        legs :meth:`affordable` accepts.
        """
        target = self.check_position(xyz)
        dist = leg_length(self.position, target)
        if dist <= 1e-6:
            raise ValueError(f"fly_to({tuple(target)}): already there; a leg must move")
        duration = dist / self.config.mission.speed
        if not fits_budget(duration, self.remaining_s):
            raise BudgetExceededError(
                f"leg of {dist:.2f} m takes {duration:.2f} s but only {self.remaining_s:.2f} s of the "
                f"{self.budget_s:.0f} s budget remain")
        return target, dist

    def fly_to(self, xyz) -> FlownLeg:
        """Fly to ``xyz`` [m] on the platform, fusing what it read along the way and on arrival.

        Raises:
            BudgetExceededError: the leg's nominal time exceeds the remaining budget.
            ValueError: ``xyz`` is off the map or equals the current position.
        """
        target, dist = self.check_leg(xyz)
        leg = self.platform.fly(self, target, dist)
        self.time_s = min(leg.end_time_s, self.budget_s)
        self.distance_m += leg.distance_m
        self.position = leg.position
        self._since_measurement = leg.since_measurement_m
        self.path.append((self.time_s, *self.position))
        n = self.assimilate_records(leg.records)
        return FlownLeg(leg.duration_s, leg.distance_m, n, self.time_s)

    def assimilate_records(self, records: list[tuple[Observation | None, np.ndarray | None, float]]) -> int:
        """Fuse time-stamped read-outs ``(observation or None, z, time)``, in one batch update per
        stretch between report times, so that ``metrics_at`` a report time is exact."""
        if not records:
            self.assimilate([], [], self.time_s)
            return 0
        report = np.asarray(self.config.mission.report_times)
        groups = np.searchsorted(report, np.array([t for _, _, t in records]) - TIME_TOL_S, side="left")
        count = 0
        for g in np.unique(groups):
            chosen = [r for r, gi in zip(records, groups) if gi == g]
            seen = [(o, z) for o, z, _ in chosen if o is not None]
            count += self.assimilate([o for o, _ in seen], [z for _, z in seen], chosen[-1][2])
        return count

    def assimilate(self, observations: list[Observation], zs: list[np.ndarray], time_s: float) -> int:
        """Fuse a batch of read-outs into the belief and record the metrics at ``time_s``.

        Returns the number of scalar measurements fused.
        """
        if observations:
            for hook in self.update_hooks:
                hook(observations, zs, float(time_s))
            self.belief_model.update(observations, zs)
        m = sum(o.m for o in observations)
        self.n_measurements += m
        self.history.append(self._evaluate(float(time_s)))
        return m

    # -- metrics ------------------------------------------------------------------------------
    def _evaluate(self, time_s: float) -> MetricRecord:
        trace = M.trace_roi(self.belief.variance, self.eval_roi)
        rmse = M.rmse_roi(self.belief.mean, self._truth_flat, self.eval_roi)
        # never reported: a number or an error (the RMSE of an empty ROI, a truth of the caller's, is NaN)
        if not math.isfinite(trace) or (self._roi_cells and not math.isfinite(rmse)):
            gp, sensor = self.config.gp, self.config.sensor
            raise FloatingPointError(
                f"the belief is no longer finite at t = {time_s:g} s (ROI trace {trace}, RMSE {rmse}) with "
                f"gp.length_scale = {gp.length_scale:g}, gp.signal_variance = {gp.signal_variance:g}, "
                f"gp.nugget = {gp.nugget:g}, gp.prior_mean = {gp.prior_mean:g}, sensor.noise_a = {sensor.noise_a:g}, "
                f"sensor.noise_b = {sensor.noise_b:g}: bring them towards the field's scale")
        return MetricRecord(time_s, trace, rmse, M.reduction_pct(self._prior_trace, trace),
                            M.reduction_pct(self._prior_rmse, rmse), self.n_measurements, self.distance_m)

    def metrics(self) -> dict[str, float]:
        """The latest evaluation metrics, with the clock."""
        out = asdict(self.history[-1])
        out.update(time_s=self.time_s, remaining_s=self.remaining_s, distance_m=self.distance_m)
        return out

    def metrics_at(self, time_s: float) -> dict[str, float]:
        """Evaluation metrics as of mission time ``time_s`` (the last record at or before it)."""
        rec = self.history[0]
        for r in self.history:
            if r.time_s <= time_s + TIME_TOL_S:
                rec = r
            else:
                break
        out = asdict(rec)
        out["time_s"] = float(time_s)
        return out

    def report(self) -> list[dict[str, float]]:
        """The episode's report: at each report time within the budget, ``time_s`` and
        :data:`REPORT_KEYS` as of that time (:meth:`metrics_at`)."""
        rows = []
        for t in self.config.mission.report_times_in_budget:
            at = self.metrics_at(t)
            rows.append({"time_s": float(t), **{k: float(at[k]) for k in REPORT_KEYS}})
        return rows

    def belief_roi(self) -> np.ndarray:
        """The ROI a robot can compute: mean + beta sigma >= mu_th."""
        m = self.config.mission
        return M.belief_roi(self.belief.mean, self.belief.variance, m.mu_th, m.beta)

