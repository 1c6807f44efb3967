"""Isolated episodes: the planner flies in a process of its own; the truth never leaves the world's.

In one Python process a planner can reach anything: the frames that call it hold the env, the view's
table (:data:`~ipp_bench.planners.base._ENVS`) maps its view to the env, and ``gc.get_objects()`` lists the
:class:`~ipp_bench.core.mission.Mission` with its ``truth``. ``fly_episode(env, spec, seed, isolate=True)``
separates the two sides as a real robot is separated from the world: the world's process (this one) keeps
the env, its mission, the truth, the field and the simulated sensor; the planner is built from its spec in a
process of its own (:func:`ipp_bench.planners.robot.serve`, started with ``spawn``: nothing of this
process's memory is copied into it), which keeps its own belief from what the robot measures
(:class:`~ipp_bench.planners.robot.RobotMission`). The episode loop is the same
(:func:`~ipp_bench.planners.episode.fly_episode`); its planner is a :class:`RemotePlanner`.

What crosses the boundary:

=================  ===========================================================================================
world -> planner   once per planner process: the spec and the planner registry (names -> ``module:Class``);
                   once per task: the task's config and id, a digest of the roadmap, the platform's class and
                   clock constants (:data:`~ipp_bench.planners.robot.CLOCKS`);
                   once per episode: the seed ``reset`` gets (as in-process, :func:`planner_seed`) and the belief
                   model at the start
                   (the prior and the start read-out, fused while the world's mission is made; its arrays through
                   a file, :func:`pack`);
                   every belief update, as the world's mission fuses it (its
                   :attr:`~ipp_bench.core.mission.Mission.update_hooks`): the read-outs
                   (:class:`~ipp_bench.core.sensor.Observation`: cells, rows of H on them, noise variances,
                   altitude, factor) and their values, sent at once so that the planner's process fuses them
                   while this one books the leg (a core being free: ``benchmarks/RESULTS.md``);
                   every decision: the pose (node, position, clock,
                   distance, metres since the last read-out, read-outs so far, the platform's reference position
                   and velocity); to a graph planner the observation less ``pos_encoding`` (node features of the
                   belief, mask, neighbours, budget);
                   to the suite's own reference planners only (decided here, from the registry's target), with
                   the episode: the true ROI their TruthView grants.
planner -> world   JSON only (the world never unpickles what the planner's process sends): the planner's kind
                   and name, every action (a neighbour index or a waypoint), its think time, or an error
                   (one line; the class one of :data:`~ipp_bench.planners.robot.ERRORS`).
=================  ===========================================================================================

The belief update is the world's own call (``belief_model.update``) on the same read-outs in the same order, so
the robot's belief, and every decision made on it, equals the in-process one bit for bit
(``tests/planners/test_isolation.py``). Metrics are the world's.

What isolation does not stop: a planner that knows the task and its episode seeds can draw the field itself
(the field is a function of the seed; a planner other than the suite's gets a keyed hash of the episode's seed,
:func:`planner_seed`, whose key is public, and a board's seeds are public); hidden evaluation seeds are the
leaderboard's part of the boundary. Nor does it sandbox the operating system
(files, ``/proc``, the network): a submission in a container is the next step.

Planner processes are kept warm (one per planner spec and registry, at most :data:`MAX_WORKERS`, the least
recently used closed first) so that a leaderboard pays their start once; :func:`close_workers` ends them (and
runs at exit). An exchange that does not finish (an exception or Ctrl-C while waiting, a process that died)
ends its process, so none is left behind and none is reused out of step.
"""

from __future__ import annotations

import atexit
import functools
import hashlib
import json
import multiprocessing as mp
import os
import pickle
import tempfile
from collections import OrderedDict
from typing import Any

import numpy as np

from ..core.mission import Mission
from ..envs.graph import GraphIPPEnv
from . import BUILT_IN, REFERENCE_PLANNERS, PlannerError, PlannerRegistry, _installed_planners, _registry, parse_spec
from .robot import ERRORS, clock_of, kinematic_state, roadmap_digest, serve

#: planner processes kept warm at most (least recently used closed first)
MAX_WORKERS = 4
#: [B] the longest reply a planner's process may send (a reply is a few numbers)
MAX_REPLY_BYTES = 1 << 20
#: [s] how long a closing planner process may take before it is terminated
CLOSE_TIMEOUT_S = 2.0


class _Worker:
    """One planner process: its pipe, and the task it last flew (sent again only when it changes)."""

    def __init__(self, spec: str, registry: PlannerRegistry):
        self.spec, self.registry = spec, registry
        ctx = mp.get_context("spawn")
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=serve, args=(child, spec, registry), daemon=True,
                                   name=f"ipp-bench planner {spec}")
        try:
            self.process.start()
        except (pickle.PicklingError, AttributeError, TypeError) as err:
            self.conn.close()
            raise ValueError(f"planner {spec!r}: isolate=True builds the planner in its own process, which imports its "
                             f"class by name, and the registry could not be sent there ({err}): register a class "
                             "defined at a module's top level, or 'module:Class'") from None
        finally:
            child.close()
        self.task: tuple | None = None

    def post(self, msg: tuple) -> None:
        """Send without waiting for a reply (a belief update)."""
        self._guard(self.conn.send, msg)

    def request(self, msg: tuple) -> dict:
        """Send and wait for the reply; an error reply raises its one-line error (the process stays usable)."""
        self._guard(self.conn.send, msg)
        raw = self._guard(self.conn.recv_bytes, MAX_REPLY_BYTES)
        try:
            reply = json.loads(raw)
        except ValueError:
            reply = None
        if not isinstance(reply, dict):
            self.close()
            raise PlannerError(f"planner {self.spec!r}: its process sent a malformed reply ({raw[:80]!r})")
        if "error" in reply:
            raise ERRORS.get(reply["error"], PlannerError)(str(reply.get("message", "")))
        return reply

    def _guard(self, fn, *args):
        """``fn(*args)``; anything that interrupts an exchange (a dead process, Ctrl-C) ends the process."""
        try:
            return fn(*args)
        except (EOFError, OSError) as err:
            self.close()
            raise PlannerError(f"planner {self.spec!r}: its process ended (exit code {self.process.exitcode}) "
                               f"({type(err).__name__})") from None
        except BaseException:
            self.close()
            raise

    @property
    def alive(self) -> bool:
        return self.process.is_alive() and not self.conn.closed

    def close(self) -> None:
        """End the process: asked to, then terminated, then killed."""
        _forget(self)
        if not self.conn.closed:
            try:
                self.conn.send(("close",))
            except (OSError, ValueError):
                pass
            self.conn.close()
        self.process.join(CLOSE_TIMEOUT_S)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(CLOSE_TIMEOUT_S)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()


_POOL: OrderedDict[tuple, _Worker] = OrderedDict()


def _forget(worker: _Worker) -> None:
    for key, w in list(_POOL.items()):
        if w is worker:
            del _POOL[key]


def _worker(spec: str, registry: PlannerRegistry | None) -> _Worker:
    """The warm process of ``spec`` (started if there is none)."""
    registry = _registry(registry)
    key = (spec, id(registry))
    worker = _POOL.get(key)
    if worker is not None and worker.alive and worker.registry is registry:
        _POOL.move_to_end(key)
        return worker
    if worker is not None:
        worker.close()
    while len(_POOL) >= MAX_WORKERS:
        next(iter(_POOL.values())).close()
    worker = _POOL[key] = _Worker(spec, registry)
    return worker


def close_workers() -> None:
    """End every planner process kept warm."""
    for worker in list(_POOL.values()):
        worker.close()


atexit.register(close_workers)


def pose_of(env) -> tuple:
    """The robot's pose and clock now, as :meth:`~ipp_bench.planners.robot.RobotMission.set_pose` reads them."""
    m = env.mission
    return (int(env.current_node), m.position.copy(), float(m.time_s), float(m.distance_m),
            float(m._since_measurement), int(m.n_measurements), kinematic_state(m.platform))


class RemotePlanner:
    """The world's handle on a planner flying in its own process: :func:`~ipp_bench.planners.episode.fly_episode`
    drives it as a planner (``act`` sends the world's observation less its constant ``pos_encoding``: a function
    of the belief, equal to the one the planner's process would compute, and cheaper to send than to compute).

    Attributes:
        kind, name: the planner's (as its process reports them).
        pid: the planner process's id.
        think_s: the planner's own time per decision [s], as its process measured it (the episode's decision
            times are the world's, each a whole exchange).
    """

    def __init__(self, worker: _Worker, env, kind: str, name: str):
        self._worker, self._env = worker, env
        self.kind, self.name, self.spec, self.pid = kind, name, worker.spec, worker.process.pid
        self.think_s: list[float] = []
        self._active = True
        env.mission.update_hooks.append(self._tap)

    def _tap(self, observations, zs, time_s) -> None:
        del time_s
        if self._active:  # sent now: the planner's process fuses them while this one books the leg
            self._worker.post(("update", observations, zs))

    def _decide(self, obs: dict | None = None) -> dict:
        reply = self._worker.request(("decide", pose_of(self._env), obs))
        self.think_s.append(float(reply.get("t", 0.0)))
        return reply

    def act(self, obs) -> Any:
        action = self._decide({k: v for k, v in obs.items() if k != "pos_encoding"}).get("a")
        return np.asarray(action) if isinstance(action, list) else action

    def next_waypoint(self) -> np.ndarray | None:
        waypoint = self._decide().get("w")
        if waypoint is None:
            return None
        return np.asarray(waypoint, dtype=np.float64) if isinstance(waypoint, list) else waypoint

    def finish(self, end_process: bool = False) -> None:
        """The episode is over: its later belief updates are not the planner's; ``end_process``: end the planner's
        process too (a run being stopped)."""
        self._active = False
        hooks = self._env.mission.update_hooks if self._env.mission is not None else []
        if self._tap in hooks:
            hooks.remove(self._tap)
        if end_process:
            self._worker.close()


def check_isolable(env, spec: Any) -> None:
    """Refuse, in one line, what cannot be flown isolated: a team task, an env that is no roadmap task, a planner
    object (the planner is built from its spec in its own process). The MuJoCo world is refused at its start
    (:func:`start_isolated`: its mission's clock)."""
    task = getattr(env, "task_id", None) or "this env"
    if getattr(env, "seats", None) is not None:
        raise ValueError(f"isolate=True flies single-UAV tasks: {task} is a team task (one planner per UAV shares the "
                         "team's belief); fly it in-process")
    if not isinstance(env, GraphIPPEnv):
        raise ValueError(f"isolate=True flies roadmap tasks (a GraphIPPEnv), not {type(env).__name__}")
    if not isinstance(spec, str):
        raise ValueError(f"isolate=True takes a planner spec (the planner is built in its own process), not a "
                         f"{type(spec).__name__}")


def start_isolated(env, spec: str, seed: int, registry: PlannerRegistry | None = None) -> RemotePlanner:
    """Start episode ``seed`` of the planner ``spec`` in its process, on ``env`` already reset.

    Raises:
        ValueError: a team or MuJoCo task (:func:`check_isolable`), a planner object instead of a spec, or what
            the planner's ``reset`` refuses (a :class:`~ipp_bench.planners.PlannerError` where it raised).
    """
    check_isolable(env, spec)
    mission = env.mission
    task = getattr(env, "task_id", None) or "this env"
    if type(mission) is not Mission:
        raise ValueError(f"isolate=True cannot fly {task}: its mission is a {type(mission).__name__} (the MuJoCo "
                         "world), whose clock a planner's process cannot keep; fly it in-process")
    clock_cls, constants = clock_of(mission.platform, task)
    worker = _worker(spec, registry)
    task_msg = (env.config, getattr(env, "task_id", None), roadmap_digest(env.roadmap), clock_cls, constants)
    send = None if worker.task == task_msg[:2] + task_msg[3:] else task_msg
    roi = mission.eval_roi if _suite_reference(spec, registry) else None
    model = pack(mission.belief_model)
    try:
        reply = worker.request(("start", send, planner_seed(seed, _target(spec, registry)), model, pose_of(env), roi))
    finally:
        if model[1] is not None:
            os.unlink(model[1])
    worker.task = task_msg[:2] + task_msg[3:]
    return RemotePlanner(worker, env, str(reply.get("kind")), str(reply.get("name")))


#: where large arrays cross to a planner's process: a memory-backed folder where there is one
PARCEL_DIR = "/dev/shm"


def pack(obj: Any) -> tuple:
    """``obj`` as a parcel for :func:`~ipp_bench.planners.robot.unpack`: its pickle without its arrays' data, which
    goes into a file (in :data:`PARCEL_DIR`). A belief's covariance (6.5 MB on a 30 x 30 map, 83 MB for the
    128 x 128 window belief) through a pipe costs a switch between the processes per 64 kB, tens of ms on a
    busy CPU; through a file, a copy each way."""
    buffers: list = []
    data = pickle.dumps(obj, protocol=5, buffer_callback=buffers.append)
    if not buffers:
        return data, None, ()
    fd, path = tempfile.mkstemp(prefix="ipp-bench-belief-", dir=PARCEL_DIR if os.path.isdir(PARCEL_DIR) else None)
    with os.fdopen(fd, "wb") as f:
        for b in buffers:
            f.write(b.raw())
    return data, path, tuple(b.raw().nbytes for b in buffers)


#: the key of the seed a planner other than the suite's own gets (:func:`planner_seed`): public, so that a
#: planner's episodes are the same on every machine
PLANNER_SEED_KEY = b"ipp-bench planner seed"


@functools.cache
def _suite_targets() -> frozenset[str]:
    """The ``module:Class`` targets of the suite's own planners (:data:`BUILT_IN` and the suite's entry points)."""
    return frozenset(BUILT_IN.values()) | frozenset(_installed_planners()[0].values())


def planner_seed(seed: int, target: str) -> int:
    """The seed ``reset`` hands the planner ``target`` (its ``module:Class``) in episode ``seed``, in-process and
    isolated alike: the suite's own planners (and any class of the package) get the episode's seed (their
    published rows stay as they are); every other planner a keyed BLAKE2b of it (:data:`PLANNER_SEED_KEY`), an
    integer in [0, 2^63), which is no seed of the task's field generator (docs/planners.md, "Isolation": what this
    does and does not hide)."""
    if target in _suite_targets() or target.partition(":")[0].split(".")[0] == "ipp_bench":
        return int(seed)  # the suite's own code (its planners, and wrappers such as a warm start's DAgger student)
    digest = hashlib.blake2b(int(seed).to_bytes(8, "little", signed=True), digest_size=8, key=PLANNER_SEED_KEY)
    return int.from_bytes(digest.digest(), "little") >> 1


def target_of(planner: Any, registry: PlannerRegistry | None = None) -> str:
    """The ``module:Class`` of a planner: a spec's as ``registry`` names it (default: the suite's), an object's
    class's."""
    if isinstance(planner, str):
        return _target(planner, registry)
    return f"{type(planner).__module__}:{type(planner).__qualname__}"


def _target(spec: str, registry: PlannerRegistry | None) -> str:
    return _registry(registry).get(parse_spec(spec)[0], "")


def _suite_reference(spec: str, registry: PlannerRegistry | None) -> bool:
    """Whether ``spec`` names the suite's own reference planner (its TruthView reads the true ROI): decided here,
    from the registry's target, never from what the planner's process asks for."""
    registry = _registry(registry)
    name = parse_spec(spec)[0]
    return (name in REFERENCE_PLANNERS and name not in registry._classes
            and registry.get(name) == BUILT_IN.get(name))


def describe_planner(spec: str, registry: PlannerRegistry | None = None) -> dict[str, Any]:
    """The planner of ``spec`` as its own process builds it: ``name``, ``kind``, ``team``, ``settings`` (its Config's
    fields, JSON values) and ``fingerprint`` (its ``fingerprint()``), so that a leaderboard can plan an isolated
    planner without importing its code. Raises what building it raises (one line)."""
    return _worker(spec, registry).request(("describe",))


def isolated_by_default(spec: str, registry: PlannerRegistry | None = None) -> bool:
    """Whether the leaderboard isolates ``spec`` without ``--isolate``: a planner from an installed plugin's entry
    point (:data:`~ipp_bench.planners.ENTRY_POINT_GROUP`; the suite's own entry points are not plugins)."""
    registry = _registry(registry)
    registry.names()  # the installed plugins join on first use
    return parse_spec(spec)[0] in registry._entry_points


__all__ = ["MAX_WORKERS", "PLANNER_SEED_KEY", "RemotePlanner", "check_isolable", "close_workers", "describe_planner",
           "isolated_by_default", "planner_seed", "pose_of", "start_isolated", "target_of"]
