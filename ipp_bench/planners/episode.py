"""The one episode loop: a planner flies one episode of an environment.

Every episode of the suite goes through :func:`fly_episode`: the leaderboard's
(:func:`ipp_bench.eval.runner.run_episode`), the MuJoCo demo's and the training code's
validation. What they add rides on two hooks: ``on_reset(env)`` after the reset (the demo
attaches its video there) and ``on_decision(decision)`` after every decision (per-decision
logging). The result is one :class:`EpisodeResult`.

A roadmap planner (``kind = "graph"``) acts on the env's observation and the env steps; a
continuous planner (``kind = "continuous"``) gives a waypoint that the mission flies. The episode
ends when no neighbour is affordable (graph) or the planner returns None (continuous). A team
task's env (:class:`~ipp_bench.envs.team.TeamGraphEnv`) goes to :func:`fly_team_episode`: one planner
per UAV, each deciding when its UAV's leg ends.

``isolate=True`` flies the planner in a process of its own, which receives what the robot measures and never
the ground truth (:mod:`ipp_bench.planners.isolation`); the loop is the same, its planner a
:class:`~ipp_bench.planners.isolation.RemotePlanner`, and the metrics equal the in-process ones.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from ..core.limits import MAX_DECISIONS
from . import PlannerError, PlannerRegistry, make_planner, view_for, what_raised
from .isolation import check_isolable, planner_seed, start_isolated, target_of


@dataclass
class Decision:
    """One decision, as ``on_decision`` sees it.

    Attributes:
        index: 0-based decision number.
        obs: the observation the decision was made on (graph planners; None for continuous).
        action: the neighbour index (graph) or the waypoint [m] (continuous).
        reward: the env's reward of the step (graph; 0.0 for continuous).
        wall_s: wall time of the decision [s].
    """

    index: int
    obs: dict[str, np.ndarray] | None
    action: Any
    reward: float
    wall_s: float


@dataclass
class EpisodeResult:
    """One episode of one planner: its report, its clock and the planner's decision times.

    Attributes:
        task: task id of the env (None for an env made without one).
        planner: planner spec (or the planner's name when an object was passed).
        seed: episode seed.
        report: one dict per report time within the budget: ``time_s`` and the report metrics
            (:meth:`ipp_bench.core.mission.Mission.report`).
        decisions: decisions made.
        decision_times_s: wall time of every decision [s].
        episode_wall_s: wall time of the whole episode [s].
        final: the mission's metrics at the end (:meth:`~ipp_bench.core.mission.Mission.metrics`).
        total_reward: sum of the env's rewards (graph planners; 0.0 for continuous).
        history: the mission's time-stamped metric records.
        isolated: the planner flew in a process of its own (``isolate=True``).
    """

    task: str | None
    planner: str
    seed: int
    report: list[dict[str, float]]
    decisions: int
    decision_times_s: list[float] = field(repr=False)
    episode_wall_s: float
    final: dict[str, float]
    total_reward: float = 0.0
    history: list = field(default_factory=list, repr=False)
    isolated: bool = False

    @property
    def decision_time_mean_s(self) -> float:
        return float(np.mean(self.decision_times_s)) if self.decision_times_s else 0.0

    @property
    def decision_time_max_s(self) -> float:
        return float(np.max(self.decision_times_s)) if self.decision_times_s else 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the decision times as mean and max, no history."""
        out = {k: v for k, v in asdict(self).items() if k not in ("decision_times_s", "history")}
        out.update(decision_time_mean_s=self.decision_time_mean_s, decision_time_max_s=self.decision_time_max_s)
        return out


def is_team_env(env) -> bool:
    """Whether ``env`` is a team task's env (:class:`~ipp_bench.envs.team.TeamGraphEnv`): one planner per UAV."""
    return getattr(env, "seats", None) is not None and getattr(env, "possible_agents", None) is not None


def start_episode(env, planner, seed: int, options: dict | None = None, registry: PlannerRegistry | None = None,
                  *, isolate: bool = False):
    """Reset ``env`` and ``planner`` for episode ``seed``, as :func:`fly_episode` does before its
    first decision; returns (planner, first observation). A spec is built from ``registry`` (default:
    the suite's); with ``isolate`` in a process of its own, and the planner returned is its
    :class:`~ipp_bench.planners.isolation.RemotePlanner`.

    A leaderboard calls it once per task and planner before its first episode, so that what an
    episode's start refuses (a budget that pays for no first move, a checkpoint whose inputs do not
    fit the task) is refused before anything is written.
    """
    if isolate:
        check_isolable(env, planner)
        obs, _ = env.reset(seed=int(seed), options=options)
        return start_isolated(env, planner, seed, registry), obs
    if is_team_env(env):
        return start_team_episode(env, planner, seed, options, registry), None
    agent = make_planner(planner, registry=registry) if isinstance(planner, str) else planner
    obs, _ = env.reset(seed=int(seed), options=options)
    view = view_for(agent, env)
    try:
        agent.reset(view, planner_seed(seed, target_of(planner, registry)))
    except (ValueError, ImportError):
        raise  # a task the planner refuses (or an extra it needs), in its own words
    except (Exception, SystemExit) as err:
        raise PlannerError(f"planner {_label(planner, agent)!r}: its reset raised {what_raised(err)}") from err
    return agent, obs


def _label(planner, agent) -> str:
    return planner if isinstance(planner, str) else getattr(agent, "name", type(agent).__name__)


def _decide(decide: Callable[..., Any], label: str, *args: Any) -> Any:
    """One decision; a planner that calls ``sys.exit`` raises a RuntimeError naming it (never ends the run)."""
    try:
        return decide(*args)
    except SystemExit as err:
        raise RuntimeError(f"planner {label!r} called sys.exit during a decision: {what_raised(err)}") from err


def fly_episode(env, planner, seed: int, *, options: dict | None = None,
                on_reset: Callable[[Any], None] | None = None,
                on_decision: Callable[[Decision], None] | None = None,
                registry: PlannerRegistry | None = None, isolate: bool = False) -> EpisodeResult:
    """Fly one episode of ``planner`` on ``env``.

    Args:
        env: an unwrapped :class:`~ipp_bench.envs.graph.GraphIPPEnv` (or subclass), or a team task's
            :class:`~ipp_bench.envs.team.TeamGraphEnv` (:func:`~ipp_bench.planners.team.fly_team_episode`:
            one planner per UAV, built from the spec).
        planner: a planner spec (``"mcts:simulations=50"``) or a planner object.
        seed: episode seed: field, start and sensor noise (every planner meets the same episode),
            and the seed of the planner's own generator (a planner other than the suite's gets
            :func:`~ipp_bench.planners.isolation.planner_seed` of it).
        options: ``env.reset`` options (e.g. ``{"start_node": 3}``).
        on_reset: called with the env after the reset, before the first decision.
        on_decision: called with every :class:`Decision`, after it was carried out.
        registry: where a spec's planner is looked up (default: the suite's; a probe's own
            :class:`~ipp_bench.planners.PlannerRegistry`).
        isolate: fly the planner (a spec) in a process of its own, which never holds the ground truth
            (:mod:`ipp_bench.planners.isolation`): the same metrics, decision times that include the
            exchange. Single-UAV roadmap tasks only (a team or MuJoCo task is refused, in one line).

    Raises:
        RuntimeError: the planner made :data:`MAX_DECISIONS` decisions without ending the episode, or
            called ``sys.exit`` in a decision.
        PlannerError: the planner's ``reset`` raised (a ValueError it raises passes as it is); isolated,
            also a decision that raised, and a planner process that ended.
    """
    if is_team_env(env) and not isolate:
        return fly_team_episode(env, planner, seed, options=options, on_reset=on_reset, on_decision=on_decision,
                                registry=registry)
    agent, obs = start_episode(env, planner, seed, options, registry, isolate=isolate)
    try:
        return _fly(env, planner, agent, obs, seed, on_reset, on_decision, isolate)
    except (KeyboardInterrupt, SystemExit):
        if isolate:
            agent.finish(end_process=True)  # a run being stopped: its planner process with it
        raise
    finally:
        if isolate:
            agent.finish()


def _fly(env, planner, agent, obs, seed: int, on_reset, on_decision, isolate: bool) -> EpisodeResult:
    """The loop of :func:`fly_episode` after its start."""
    label = _label(planner, agent)
    if on_reset is not None:
        on_reset(env)
    times: list[float] = []
    total = 0.0
    t_start = time.perf_counter()
    if agent.kind == "graph":
        while obs["action_mask"].any() and len(times) < MAX_DECISIONS:
            t0 = time.perf_counter()
            action = _decide(agent.act, label, obs)
            times.append(time.perf_counter() - t0)
            before = obs
            obs, reward, terminated, truncated, _ = env.step(action)
            total += reward
            if on_decision is not None:
                on_decision(Decision(len(times) - 1, before, action, float(reward), times[-1]))
            if terminated or truncated:
                break
    else:
        while len(times) < MAX_DECISIONS:
            t0 = time.perf_counter()
            waypoint = _decide(agent.next_waypoint, label)
            wall = time.perf_counter() - t0
            if waypoint is None:
                break
            times.append(wall)
            env.mission.fly_to(waypoint)
            if on_decision is not None:
                on_decision(Decision(len(times) - 1, None, waypoint, 0.0, wall))
    if len(times) >= MAX_DECISIONS:
        raise RuntimeError(f"planner {label!r} made {MAX_DECISIONS} decisions without ending the episode")
    wall = time.perf_counter() - t_start
    mission = env.mission
    return EpisodeResult(getattr(env, "task_id", None), label, int(seed), mission.report(), len(times), times,
                         wall, mission.metrics(), float(total), list(mission.history), isolate)


def start_team_episode(env, planner: str | Any, seed: int, options: dict | None = None,
                       registry: PlannerRegistry | None = None) -> list:
    """Reset the team env for episode ``seed`` and one planner per UAV built from ``planner`` (a spec, or
    a planner object not yet reset, copied per UAV); UAV i's generator is seeded with ``seed + i`` (a planner
    other than the suite's with its :func:`~ipp_bench.planners.isolation.planner_seed`).
    Returns the planners. As :func:`~ipp_bench.planners.episode.start_episode`, a leaderboard calls it
    before the first episode."""
    label = planner if isinstance(planner, str) else getattr(planner, "name", type(planner).__name__)
    env.reset(seed=int(seed), options=options)
    agents = []
    for i, seat in enumerate(env.seats):
        agent = make_planner(planner, registry=registry) if isinstance(planner, str) else copy.deepcopy(planner)
        view = view_for(agent, seat)
        try:
            agent.reset(view, planner_seed(int(seed) + i, target_of(planner, registry)))
        except (ValueError, ImportError):
            raise
        except (Exception, SystemExit) as err:
            raise PlannerError(f"planner {label!r}: its reset raised {what_raised(err)}") from err
        agents.append(agent)
    return agents


def fly_team_episode(env, planner: str | Any, seed: int, *, options: dict | None = None,
                     on_reset: Callable[[Any], None] | None = None,
                     on_decision: Callable[[Decision], None] | None = None,
                     registry: PlannerRegistry | None = None) -> EpisodeResult:
    """Fly one episode of a team task with one planner per UAV, each built from the spec ``planner``.

    Args:
        env: a :class:`~ipp_bench.envs.team.TeamGraphEnv`.
        planner: a planner spec (or a planner object not yet reset); every UAV gets its own planner.
        seed: the episode seed (field, starts, camera noise); UAV i's planner gets the seed seed + i (a planner
            other than the suite's: its :func:`~ipp_bench.planners.isolation.planner_seed`).
        options: ``env.reset`` options (``{"start_nodes": [...]}``).
        on_reset: called with the env after the reset, before the first decision.
        on_decision: called with every :class:`~ipp_bench.planners.episode.Decision` (its ``action`` is
            ``(uav, neighbour index or waypoint)``), after it was carried out.
        registry: where the spec's planner is looked up (default: the suite's).

    Returns:
        The team's :class:`~ipp_bench.planners.episode.EpisodeResult`: the shared belief's report, every
        UAV's decisions, ``total_reward`` the team reward's sum.

    Raises:
        RuntimeError: the planners made :data:`~ipp_bench.core.limits.MAX_DECISIONS` decisions per UAV without
            ending the episode, or one called ``sys.exit``.
        PlannerError: a planner's ``reset`` raised (a ValueError it raises passes as it is).
    """
    agents = start_team_episode(env, planner, seed, options, registry)
    label = planner if isinstance(planner, str) else agents[0].name
    if on_reset is not None:
        on_reset(env)
    times: list[float] = []
    total = 0.0
    t_start = time.perf_counter()
    for name in env.agent_iter(MAX_DECISIONS * env.team.size):
        obs, _, terminated, truncated, _ = env.last()
        if terminated or truncated:
            env.step(None)
            continue
        uav = env.uav_index(name)
        agent = agents[uav]
        t0 = time.perf_counter()
        if agent.kind == "graph":
            action = _decide(agent.act, label, obs)
            times.append(time.perf_counter() - t0)
            env.step(action)
        else:
            action = _decide(agent.next_waypoint, label)
            wall = time.perf_counter() - t0
            if action is None:  # this UAV is done: not a decision (as the single-UAV loop counts)
                env.retire()
                continue
            times.append(wall)
            env.fly_waypoint(action)
        reward = env.rewards.get(name, 0.0)
        total += reward
        if on_decision is not None:
            on_decision(Decision(len(times) - 1, obs if agent.kind == "graph" else None, (uav, action),
                                 float(reward), times[-1]))
    if env.agents:
        raise RuntimeError(f"planner {label!r} made {MAX_DECISIONS} decisions per UAV without ending the team "
                           "episode")
    wall = time.perf_counter() - t_start
    mission = env.mission
    return EpisodeResult(env.task_id, label, int(seed), mission.report(), len(times), times, wall,
                         mission.metrics(), float(total), list(mission.history))


