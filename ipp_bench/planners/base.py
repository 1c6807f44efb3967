"""The planner interface and the robot's-eye view every planner gets.

A planner is reset at the start of an episode with a :class:`RobotView` and then asked for one
decision at a time: a neighbour index (``kind = "graph"``, like a policy on the roadmap MDP) or a
3D waypoint (``kind = "continuous"``, flown with ``Mission.fly_to``). The view holds what a real
robot has (belief, roadmap, camera model, clock and budget) and nothing of the ground truth.
Look-ahead planners predict information gain with the belief's covariance only
(:meth:`RobotView.predict_variance`), never by stepping the real episode. What a leg costs and
whether the budget pays for it, they ask the mission's clock (:meth:`RobotView.leg_durations`,
:meth:`RobotView.affordable`), never the speed.
"""

from __future__ import annotations

import weakref
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from ..core import metrics as M
from ..core.belief import GPBelief, PredictedBelief, error_states
from ..core.belief_window import WindowBelief
from ..core.config import IPPConfig
from ..core.gains import TIE_RTOL, beats, first_best  # noqa: F401  (the planners' argmax and comparison, here for plugins)
from ..core.mission import fits_budget, leg_length, leg_samples
from ..core.roadmap import Roadmap
from ..core.sensor import Observation, Sensor, stack

#: view -> the env it reads: the one place a view's env is kept (a view holds no reference to it)
_ENVS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def stacked_leg(view: RobotView, node: int, action: int) -> tuple | None:
    """The read-outs of the roadmap leg from ``node`` to its neighbour number ``action`` as the mission
    would take them, stacked into one ``(cells, W, var)`` (:func:`~ipp_bench.core.sensor.stack`); None where
    the camera sees nothing on the leg."""
    rm = view.roadmap
    obs = view.leg_observations(rm.positions[node], rm.positions[rm.neighbours[node, action]])
    return stack(obs) if obs else None


def without_level(mask: np.ndarray, altitudes: np.ndarray, z: float) -> np.ndarray:
    """``mask`` (the neighbours one may fly to) without those at altitude ``z`` (``altitudes``: the
    neighbours' altitudes [m]); ``mask`` itself when nothing else would be left."""
    kept = np.asarray(mask, dtype=bool) & ~np.isclose(altitudes, z)
    return kept if kept.any() else np.asarray(mask, dtype=bool)


def softmax(logits: np.ndarray) -> np.ndarray:
    """Probabilities ``exp(l - max l) / sum``; ``-inf`` logits get probability 0."""
    p = np.exp(logits - logits.max())
    return p / p.sum()


#: [m] with less flight than this left, a continuous mission is over (no leg worth flying)
MIN_FLIGHT_M = 0.5
#: [m] legs shorter than this are no legs (the mission refuses them as "already there")
MIN_LEG_M = 1e-6


class RobotView:
    """What a planner may see of an episode: belief, roadmap, camera model, clock, budget.

    Wraps a :class:`~ipp_bench.envs.graph.GraphIPPEnv` (or subclass) after ``reset``. The view
    holds no reference to the env, its mission or anything else from which the ground truth could be
    reached by following attributes: it has no instance attributes at all (``__slots__``), its
    methods are plain functions (no closures), and the env it reads is kept in this module's private
    table (:data:`_ENVS`), keyed by the view. Python has no private memory, so a planner that goes
    through module internals, ``gc`` or interpreter frames can find anything in its process; the
    suite's rule is that a planner reads an episode only through its view's public methods, and one
    that reads the truth otherwise breaks the benchmark's rules. An isolated episode
    (``fly_episode(..., isolate=True)``, :mod:`ipp_bench.planners.isolation`) enforces it: the view's env
    there is the robot's (:class:`~ipp_bench.planners.robot.RobotEnv`), in a process without the truth.
    """

    __slots__ = ("__weakref__",)

    def __init__(self, env):
        _ENVS[self] = env

    def __copy__(self):
        return self  # a view is a handle on a live episode: a copy is the same view

    def __deepcopy__(self, memo):
        return self

    def __reduce__(self):
        raise TypeError(f"a {type(self).__name__} is a handle on a live episode in this process: it cannot be "
                        "pickled (build the planner in the process that flies the episode)")

    # -- static knowledge ------------------------------------------------------------------------
    @property
    def config(self) -> IPPConfig:
        return _ENVS[self].config

    @property
    def roadmap(self) -> Roadmap:
        return _ENVS[self].roadmap

    @property
    def sensor(self) -> Sensor:
        return _ENVS[self].sensor

    # -- state -------------------------------------------------------------------------------------
    @property
    def belief(self) -> GPBelief | WindowBelief:
        """The live belief (read it; never update it: that is the mission's job)."""
        return _ENVS[self].mission.belief

    @property
    def position(self) -> np.ndarray:
        return _ENVS[self].mission.position.copy()

    @property
    def current_node(self) -> int:
        return _ENVS[self].current_node

    @property
    def time_s(self) -> float:
        return _ENVS[self].mission.time_s

    @property
    def remaining_s(self) -> float:
        return _ENVS[self].mission.remaining_s

    def action_mask(self) -> np.ndarray:
        return _ENVS[self].action_masks()

    def leg_durations(self, start_xyz, end_xyzs) -> np.ndarray:
        """(K,) flight times [s] of the legs from ``start_xyz`` ((3,) x, y, z [m]) to each of ``end_xyzs``
        ((K, 3) [m]) by the mission's clock: positions in metres, not node indices (node i is at
        ``roadmap.positions[i]``)."""
        return _ENVS[self].mission.leg_durations(start_xyz, end_xyzs)

    def affordable(self, end_xyzs) -> np.ndarray:
        """(K,) bool: which legs from the current position to ``end_xyzs`` ((K, 3) [m]) the remaining
        budget pays for."""
        return _ENVS[self].mission.affordable(end_xyzs)

    def neighbour_durations(self, node: int, from_xyz=None) -> np.ndarray:
        """(k,) flight times [s] from node ``node`` (or from ``from_xyz``) to its neighbours."""
        rm = self.roadmap
        start = rm.positions[node] if from_xyz is None else from_xyz
        return self.leg_durations(start, rm.positions[rm.neighbours[node]])

    def static_neighbour_durations(self, node: int) -> np.ndarray:
        """(k,) flight times [s] from node ``node`` to its neighbours whatever the drone's state now
        (:meth:`~ipp_bench.core.mission.Mission.static_leg_durations`): what caches kept across decisions and
        episodes hold, so that what they hold does not depend on when they were built."""
        rm = self.roadmap
        return _ENVS[self].mission.static_leg_durations(rm.positions[node], rm.positions[rm.neighbours[node]])

    @staticmethod
    def fits_budget(duration_s, remaining_s):
        """Whether legs of ``duration_s`` fit ``remaining_s`` [s]: the mission's rule, for look-ahead."""
        return fits_budget(duration_s, remaining_s)

    def belief_roi(self) -> np.ndarray:
        return _ENVS[self].mission.belief_roi()

    def node_footprint(self):
        """(N, n_cells) sparse: row i averages the cells one look from roadmap node i sees (the env's
        node features read the belief's mean and standard deviation through it)."""
        return _ENVS[self].observer.footprint

    def static_key(self) -> tuple:
        """What the roadmap's static predictions (read-outs along legs, leg flight times) depend on beyond
        the roadmap, as a hashable value: the camera's constants, the grid, the mission's constants and the
        platform's clock. Caches of such predictions live per roadmap and must key on it too: tasks share
        a roadmap object where their maps agree (``Grid15Eval-v1`` and the deployment's twin), not their
        camera or clock, and an object's ``id`` can be reused once it is freed."""
        platform = _ENVS[self].mission.platform
        clock = (type(platform).__module__, type(platform).__qualname__, getattr(platform, "ramp_s", None))
        return self.sensor.cfg, self.config.grid, self.config.mission, clock

    def error_states(self):
        """The camera-error states of the belief (:class:`~ipp_bench.core.belief.PersistentErrorBelief`:
        the deployment and its twin, whose camera repeats its error at a cell), or None where the
        task's read-out noise is white (read it; never update it)."""
        return error_states(_ENVS[self].mission)

    def require_dense_belief(self, planner: str, reason: str) -> None:
        """Refuse, in one line naming the task, the planner and ``reason``, a task whose belief is not the
        dense :class:`~ipp_bench.core.belief.GPBelief` (``gp.belief = "window"``): for planners that need
        its full covariance. Called in ``reset``, so a leaderboard refuses before the first episode."""
        gp, grid = self.config.gp, self.config.grid
        if gp.belief != "dense":
            task = getattr(_ENVS[self], "task_id", None) or f"a {grid.rows} x {grid.cols} map"
            raise ValueError(f"planner {planner!r} cannot run on {task} (gp.belief = {gp.belief!r}): {reason}")

    # -- prediction --------------------------------------------------------------------------------
    def leg_observations(self, start, end) -> list[Observation]:
        """The read-outs the mission would take flying ``start -> end`` (same spacing rule)."""
        start = np.asarray(start, dtype=np.float64)
        delta = np.asarray(end, dtype=np.float64) - start
        dist = leg_length(start, end)
        if dist <= MIN_LEG_M:
            return []
        s = leg_samples(dist, 0.0, self.config.mission.measurement_spacing)
        out = []
        for p in start + np.outer(s / dist, delta):
            obs = self.sensor.observe(p)
            if obs is not None:
                out.append(obs)
        return out

    @staticmethod
    def predict_variance(belief: GPBelief | WindowBelief, observations: list[Observation]) -> np.ndarray:
        """Posterior marginal variances after the read-outs (values do not matter)."""
        if not observations:
            return belief.variance
        cells, W, var = stack(observations)
        return belief.predict_variance_local(cells, W, var)

    def roi_trace(self, variance: np.ndarray, roi: np.ndarray) -> float:
        return M.trace_roi(variance, roi)


class TruthView(RobotView):
    """The robot's view plus one piece of the ground truth: the evaluation ROI mask.

    Made only for the suite's reference planners (:data:`~ipp_bench.planners.REFERENCE_PLANNERS`,
    whose class sets ``reads_truth = True``), which show how much knowing where the region of
    interest lies is worth. It holds the true ROI (the cells the metrics are computed on), not the
    field values, so what such a planner knows stays small and explicit (a training run may use it
    as a privileged teacher or critic input, knowingly). Ordinary planners get a
    :class:`RobotView`, which has no way to it.
    """

    __slots__ = ()

    def true_roi(self) -> np.ndarray:
        """(n_cells,) bool, row-major: the cells whose true value is at least ``mu_th`` (a copy)."""
        return _ENVS[self].mission.eval_roi.copy()


class TeamRobotView(RobotView):
    """A UAV's view in a team episode (:class:`~ipp_bench.envs.team.TeamGraphEnv`): the robot's view of
    its own UAV (position, clock, budget, mask) on the team's shared belief, plus what a team shares
    by radio: where its teammates are bound and the read-outs their committed legs will take (where
    and how noisy, never the values). On a single-UAV task it is the view of a team of one (no
    teammates), so a team-aware planner flies it as its single-UAV counterpart."""

    __slots__ = ()

    @property
    def uav(self) -> int:
        """This UAV's index in the team (0-based)."""
        return getattr(_ENVS[self], "index", 0)

    @property
    def team_size(self) -> int:
        team = getattr(_ENVS[self], "team_env", None)
        return 1 if team is None else team.team.size

    def teammate_nodes(self) -> list[int]:
        """The roadmap nodes the other UAVs stand on or are flying to."""
        team = getattr(_ENVS[self], "team_env", None)
        return [] if team is None else [seat.current_node for seat in team.seats if seat.index != self.uav]

    def teammates_pending(self) -> list[Observation]:
        """The read-outs the other UAVs' committed legs take after this UAV's clock (not yet in the
        belief): their observations only, in time order."""
        team = getattr(_ENVS[self], "team_env", None)
        return [] if team is None else team.mission.pending_observations(exclude=self.uav)

    def belief_ahead(self) -> GPBelief | PredictedBelief:
        """The belief with the teammates' pending read-outs fused into its covariance in advance
        (:class:`~ipp_bench.core.belief.PredictedBelief`; the mean is today's): the covariance does not
        depend on the values read, so this is exactly the covariance the belief will have once they
        are taken. The live belief where none are pending."""
        self.require_dense_belief("a team-aware planner", "the teammates' read-outs are fused into the full "
                                  "covariance")
        pending = self.teammates_pending()
        return PredictedBelief(self.belief, pending) if pending else self.belief


class TeamTruthView(TeamRobotView, TruthView):
    """A UAV's team view plus the evaluation ROI, for the suite's team reference planner."""

    __slots__ = ()


@runtime_checkable
class Planner(Protocol):
    """One decision at a time.

    Attributes:
        name: registry name.
        kind: ``"graph"`` (``act`` returns a neighbour index) or ``"continuous"``
            (``next_waypoint`` returns a 3D point, or None when done).
    """

    name: ClassVar[str]
    kind: ClassVar[str]

    def reset(self, view: RobotView, seed: int) -> None: ...


class _PlannerBase:
    """Settings, view and a per-episode random generator (seeded by ``reset``).

    ``settings`` is the planner's own ``Config`` dataclass (``mcts:simulations=50``); the task's
    configuration is ``view.config`` (an :class:`~ipp_bench.core.config.IPPConfig`): two names, two things.
    """

    name: ClassVar[str] = "base"
    kind: ClassVar[str] = "base"
    #: a reference planner that reads the true ROI (given a :class:`TruthView`); only the suite's
    #: own reference planners may set it (:func:`~ipp_bench.planners.view_for`)
    reads_truth: ClassVar[bool] = False

    def __init__(self, settings: Any = None):
        self.settings = settings
        self.view: RobotView | None = None
        self.rng = np.random.default_rng(0)

    def reset(self, view: RobotView, seed: int) -> None:
        self.view = view
        self.rng = np.random.default_rng(seed)


class GraphPlanner(_PlannerBase):
    """Base of roadmap planners: ``act(obs) -> neighbour index``."""

    kind: ClassVar[str] = "graph"

    def act(self, obs: dict[str, np.ndarray]) -> int:
        raise NotImplementedError


class ContinuousPlanner(_PlannerBase):
    """Base of continuous planners: ``next_waypoint() -> xyz`` (None: nothing affordable)."""

    kind: ClassVar[str] = "continuous"

    def next_waypoint(self) -> np.ndarray | None:
        raise NotImplementedError

    def flight_left_m(self, margin_s: float = 1e-6) -> float:
        """[m] the remaining budget (less ``margin_s``) flies at the nominal speed: an upper bound."""
        view = self.view
        return max(view.remaining_s - margin_s, 0.0) * view.config.mission.speed

    def affordable(self, target: np.ndarray, margin_s: float = 1e-6) -> np.ndarray | None:
        """``target``, or the point on the way to it where the nominal reach (remaining time x
        speed) ends (None: less than :data:`MIN_FLIGHT_M` of flight is left, the mission is over).

        On the core mission that is exactly what its clock affords. A mission whose clock charges
        more (MuJoCo's velocity ramps) accepts the leg all the same and flies it until the budget
        ends (``MuJoCoMission.fly_to``), so continuous planners never see a refusal.
        """
        view = self.view
        here = view.position
        delta = np.asarray(target, dtype=np.float64) - here
        dist = leg_length(here, target)
        reach = self.flight_left_m(margin_s)
        if reach < MIN_FLIGHT_M or dist <= MIN_LEG_M:
            return None
        return here + delta * min(1.0, reach / dist)
