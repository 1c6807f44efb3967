"""The robot's side of an isolated episode: a mission without ground truth, and the process that flies a planner on it.

An isolated episode (``fly_episode(env, spec, seed, isolate=True)``, :mod:`ipp_bench.planners.isolation`) runs
the planner in a process of its own, the way a real robot is apart from the world it flies over. That process
holds what a robot holds and nothing else:

* the task (its :class:`~ipp_bench.core.config.IPPConfig`), and from it the roadmap, the camera model and the
  observation (:class:`~ipp_bench.envs.observation.GraphObservation`);
* a :class:`RobotMission`: the belief, the pose and the clock, with ``truth`` None. Its belief is the world's at
  the episode's start (the prior and the start read-out, which the world's mission fuses as it is made) and from
  then on its own: the world sends the read-outs of every update (:class:`~ipp_bench.core.sensor.Observation`
  rows and their values), and the robot applies the same ``belief_model.update`` in the same order, so its
  belief stays equal to the world's bit for bit;
* a platform that only tells time (:data:`CLOCKS`): the world's platform class, made from its clock constants,
  given the drone's pose and velocity at every decision, never flying (what a platform flies reads the truth);
* the planner, built here from its spec (:func:`serve`), so that its code never runs in the world's process.

The truth, the field, the simulated sensor and its noise generator stay in the world's process. What crosses
the boundary, and in which direction, is listed in :mod:`ipp_bench.planners.isolation`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import pickle
import signal
import time
from typing import Any

import numpy as np

from ..core._threads import limit_blas_threads
from ..core.belief import GPBelief, PersistentErrorBelief, WhiteNoiseBelief
from ..core.belief_window import WindowBelief
from ..core.mission import Mission, StraightLegs
from ..core.twin import CameraErrorLegs
from ..envs.graph import GraphIPPEnv
from ..envs.observation import GraphObservation
from . import PlannerError, make_planner, view_for, what_raised
from .base import TruthView

#: the platforms whose clock a robot can keep: class -> (constants it is made from, kinematic state the world
#: sends at every decision: the drone's reference position and velocity). Nothing here reads the truth
#: (``CameraErrorLegs.errors``, drawn from it, stays in the world).
CLOCKS: dict[type, tuple[tuple[str, ...], tuple[str, ...]]] = {
    StraightLegs: ((), ()),
    CameraErrorLegs: (("neighbour_corr", "ramp_s", "step_s"), ("ref_pos", "ref_vel")),
}
#: the keys of a graph observation, in the env's order (:meth:`~ipp_bench.envs.observation.GraphObservation.observe`)
OBS_KEYS = ("node_features", "pos_encoding", "current_node", "neighbours", "action_mask", "budget")
#: the belief models a robot's mission can take over (their fields: the dense or the window belief)
BELIEF_MODELS = (WhiteNoiseBelief, PersistentErrorBelief)
BELIEFS = (GPBelief, WindowBelief)


def clock_of(platform: Any, task: str) -> tuple[type, dict[str, float]]:
    """(class, constants) of the clock of the world's ``platform``, or a ValueError naming ``task``."""
    entry = CLOCKS.get(type(platform))
    if entry is None:
        names = ", ".join(c.__name__ for c in CLOCKS)
        raise ValueError(f"isolate=True cannot fly {task}: its legs are flown by {type(platform).__name__}, whose "
                         f"clock a planner's process cannot keep (supported: the graph tasks' {names}); fly it "
                         "in-process")
    return type(platform), {k: getattr(platform, k) for k in entry[0]}


def kinematic_state(platform: Any) -> tuple:
    """What the platform's clock needs of the drone now (its reference position and velocity), as copies."""
    return tuple(np.array(getattr(platform, k), dtype=np.float64) for k in CLOCKS[type(platform)][1])


def roadmap_digest(roadmap) -> str:
    """A short hash of a roadmap's nodes, edges and encoding: both sides must fly the same one."""
    h = hashlib.sha256(np.ascontiguousarray(roadmap.positions, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(roadmap.neighbours, dtype=np.int64).tobytes())
    h.update(np.ascontiguousarray(roadmap.pos_encoding).tobytes())
    return h.hexdigest()[:16]


class RobotMission(Mission):
    """A mission as the robot knows it: belief, pose, clock and budget; no truth, no sensor noise, no metrics.

    It takes over the world's belief model at the episode's start and is then updated only with read-outs
    (:meth:`assimilate_readouts`) and poses (:meth:`set_pose`) the world sends. The clock's rules
    (:meth:`~ipp_bench.core.mission.Mission.leg_durations`, ``affordable``, ``belief_roi``) are the
    mission's own. ``truth`` and ``eval_roi`` are None (``eval_roi`` is set only for the suite's reference
    planners, which a :class:`~ipp_bench.planners.base.TruthView` grants it).
    """

    def __init__(self, config, sensor, platform, model, pose: tuple):  # not Mission.__init__: that one takes a truth
        if not isinstance(model, BELIEF_MODELS) or not isinstance(model.field, BELIEFS):
            raise TypeError(f"a robot's mission takes a belief model of {[c.__name__ for c in BELIEF_MODELS]}, "
                            f"not {type(model).__name__}")
        self.config, self.sensor, self.platform = config, sensor, platform
        self.belief_model, self.belief = model, model.field
        self.truth = self._truth_flat = self.rng = self.eval_roi = None
        self.update_hooks: list = []
        self.path: list = []
        self.measurement_log: list = []
        self.history: list = []
        self.current_node = 0
        self.set_pose(pose)

    def set_pose(self, pose: tuple) -> None:
        """The robot's state from the world's pose message (:func:`~ipp_bench.planners.isolation.pose_of`)."""
        node, position, self.time_s, self.distance_m, self._since_measurement, self.n_measurements, kin = pose
        self.current_node = int(node)
        self.position = np.array(position, dtype=np.float64)
        for name, value in zip(CLOCKS[type(self.platform)][1], kin):
            setattr(self.platform, name, value)

    def assimilate_readouts(self, observations: list, zs: list) -> None:
        """Fuse one batch of read-outs as the world's mission did (its ``belief_model.update``, same order)."""
        self.belief_model.update(observations, zs)

    def fly_to(self, xyz):
        raise RuntimeError("a robot's mission flies no leg: the world flies it and sends what the camera read")

    def _evaluate(self, time_s: float):
        raise RuntimeError("a robot's mission has no ground truth: the metrics are the world's")

    def metrics(self):
        return self._evaluate(self.time_s)

    def metrics_at(self, time_s: float):
        return self._evaluate(time_s)

    def report(self):
        return self._evaluate(self.time_s)


class RobotEnv:
    """What a :class:`~ipp_bench.planners.base.RobotView` reads in the robot's process: the task's observation
    and a :class:`RobotMission`. Its masks and observations are the graph env's own methods."""

    team_env = None

    def __init__(self, config, task_id: str | None, observer: GraphObservation, mission: RobotMission):
        self.config, self.task_id, self.observer, self.mission = config, task_id, observer, mission
        self.roadmap, self.sensor = observer.roadmap, observer.sensor

    @property
    def current_node(self) -> int:
        return self.mission.current_node

    action_masks = GraphIPPEnv.action_masks
    _observation = GraphIPPEnv._observation
    _require_reset = GraphIPPEnv._require_reset
    node_features = GraphIPPEnv.node_features


class Robot:
    """The planner's process: one planner spec, one episode at a time (:func:`serve` feeds it messages)."""

    def __init__(self, spec: str, registry):
        self.spec, self.registry = spec, registry
        self.observer: GraphObservation | None = None
        self.task: tuple | None = None
        self.env: RobotEnv | None = None
        self.agent: Any = None
        self.failure: dict | None = None  # an update that failed: the next decision reports it

    # -- episode start ----------------------------------------------------------------------------
    def start(self, task: tuple | None, seed: int, model, pose: tuple, roi: np.ndarray | None = None) -> dict:
        """Episode ``seed``: the task (None: the last one), the world's belief model and pose at the start, and the
        true ROI where the world grants it (the suite's reference planners, whose TruthView reads it)."""
        self.agent = self.env = self.failure = None
        if task is not None:
            config, task_id, digest, clock_cls, constants = task
            observer = GraphObservation.for_config(config)
            if roadmap_digest(observer.roadmap) != digest:
                raise RuntimeError(f"the planner's process built another roadmap for {task_id or 'the task'} than the "
                                   "world's: isolate=True needs a roadmap built from the task's config alone")
            self.task, self.observer = task, observer
        config, task_id, _, clock_cls, constants = self.task
        mission = RobotMission(config, self.observer.sensor, clock_cls(**constants), unpack(model), pose)
        env = RobotEnv(config, task_id, self.observer, mission)
        agent = self._build()
        if isinstance(agent, dict):  # the one-line error of a planner that cannot be built
            return agent
        try:
            view = view_for(agent, env)
        except ValueError as err:
            return _error(err)
        if isinstance(view, TruthView):
            if roi is None:
                return _error(ValueError(f"planner {self.spec!r} reads the true ROI, which the world sends only to the "
                                         "suite's own reference planners"))
            mission.eval_roi = np.asarray(roi, dtype=bool)
        return self._reset(agent, env, view, seed)

    def _build(self) -> Any:
        """The planner of this process's spec, or the error reply saying why it cannot be built."""
        try:
            return make_planner(self.spec, registry=self.registry)
        except (ValueError, ImportError) as err:
            return _error(err)
        except (Exception, SystemExit) as err:
            return _error(PlannerError(f"planner {self.spec!r}: building it raised {what_raised(err)}"))

    def _reset(self, agent, env: RobotEnv, view, seed: int) -> dict:
        try:
            agent.reset(view, int(seed))
        except (ValueError, ImportError) as err:
            return _error(err)
        except (Exception, SystemExit) as err:
            return _error(PlannerError(f"planner {self.spec!r}: its reset raised {what_raised(err)}"))
        self.agent, self.env = agent, env
        return {"kind": str(agent.kind), "name": str(getattr(agent, "name", type(agent).__name__))}

    # -- the episode ------------------------------------------------------------------------------
    def update(self, observations: list, zs: list) -> None:
        """One belief update of the world's (read-outs and their values), in the world's order."""
        if self.failure is None and self.env is not None:
            self.env.mission.assimilate_readouts(observations, zs)

    def decide(self, pose: tuple, obs: dict | None = None) -> dict:
        """One decision in the state ``pose``; a graph planner acts on ``obs``, the world's observation less its
        constant ``pos_encoding`` (the belief's node features: equal to this process's, cheaper to send than to
        compute)."""
        if self.failure is not None:
            return self.failure
        env, agent = self.env, self.agent
        env.mission.set_pose(pose)
        if obs is not None:
            obs = {k: (env.roadmap.pos_encoding.copy() if k == "pos_encoding" else obs[k]) for k in OBS_KEYS}
        t0 = time.perf_counter()
        try:
            if agent.kind == "graph":
                out = {"a": _plain(agent.act(env._observation() if obs is None else obs))}
            else:
                waypoint = agent.next_waypoint()
                out = {"w": None if waypoint is None else _plain(waypoint)}
        except SystemExit as err:
            return _error(RuntimeError(f"planner {self.spec!r} called sys.exit during a decision: {what_raised(err)}"))
        except Exception as err:
            verb = "act" if agent.kind == "graph" else "next_waypoint"
            return _error(PlannerError(f"planner {self.spec!r}: its {verb} raised {what_raised(err)}"))
        out["t"] = time.perf_counter() - t0
        return out

    def describe(self) -> dict:
        """The planner's name, kind and settings, built here (a leaderboard's plan never imports its code)."""
        agent = self._build()
        if isinstance(agent, dict):  # the one-line error of a planner that cannot be built
            return agent
        settings = agent.settings if dataclasses.is_dataclass(getattr(agent, "settings", None)) else None
        fingerprint = getattr(agent, "fingerprint", None)
        return {"name": str(agent.name), "kind": str(agent.kind), "team": bool(getattr(agent, "team", False)),
                "settings": {} if settings is None else {f.name: _plain(getattr(settings, f.name))
                                                         for f in dataclasses.fields(settings)},
                "fingerprint": {str(k): str(v) for k, v in (fingerprint() if callable(fingerprint) else {}).items()}}


#: the exception classes a reply may name (the world rebuilds one of these, never a class of the planner's)
ERRORS = {cls.__name__: cls for cls in (PlannerError, ValueError, ImportError, RuntimeError, TypeError)}


def _error(err: BaseException) -> dict:
    cls = next((c for c in type(err).__mro__ if c.__name__ in ERRORS and ERRORS[c.__name__] is c), None)
    if cls is None:
        return {"error": "PlannerError", "message": what_raised(err)}
    return {"error": cls.__name__, "message": str(err)}


def _plain(value: Any) -> Any:
    """A JSON value of what a planner returned: numbers and lists as they are (float64 round-trips exactly), else
    its repr (which the world's checks refuse with their own message)."""
    if isinstance(value, (bool, int, float, str)) or value is None:
        return value
    try:
        arr = np.asarray(value)
    except Exception:
        return repr(value)[:200]
    if arr.dtype.kind in "iub":
        return arr.tolist()
    if arr.dtype.kind == "f":
        return arr.astype(np.float64).tolist()
    return repr(value)[:200]


def unpack(parcel: tuple) -> Any:
    """The object of a parcel (:func:`~ipp_bench.planners.isolation.pack`): its pickle, and its arrays' data read
    from the parcel's file (the world deletes the file once this process has answered)."""
    data, path, sizes = parcel
    if path is None:
        return pickle.loads(data)
    buffers = []
    with open(path, "rb") as f:
        for size in sizes:
            buffers.append(np.empty(size, dtype=np.uint8))
            if f.readinto(buffers[-1]) != size:
                raise RuntimeError(f"the parcel {path} is shorter than its arrays")
    return pickle.loads(data, buffers=buffers)


def serve(conn, spec: str, registry) -> None:
    """The planner process's loop: messages from the world (pickled: the world is trusted), replies as JSON bytes
    (the world never unpickles what a planner's process sends). Ends on ``("close",)`` or when the world's end of
    the pipe closes; Ctrl-C is the world's to handle (it ends this process)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    limit_blas_threads()
    robot = Robot(spec, registry)
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        op = msg[0]
        if op == "close":
            return
        try:
            if op == "update":
                robot.update(msg[1], msg[2])
                continue
            reply = {"decide": robot.decide, "start": robot.start, "describe": robot.describe}[op](*msg[1:])
        except Exception as err:  # the robot's own machinery failed: say so (an update's failure with the next reply)
            reply = {"error": "RuntimeError", "message": f"the planner's process failed: {what_raised(err)}"}
            if op == "update":
                robot.failure = robot.failure or reply
                continue
        try:
            conn.send_bytes(json.dumps(reply).encode())
        except (OSError, ValueError):
            return


__all__ = ["BELIEF_MODELS", "CLOCKS", "ERRORS", "Robot", "RobotEnv", "RobotMission", "clock_of", "kinematic_state",
           "roadmap_digest", "serve"]
