"""The deployment as a dm_control environment: :func:`load` (the dm_control suite's convention).

``load(task_id, **overrides)`` returns a ``dm_control.rl.control.Environment`` whose ``physics``
is the world's ``dm_control.mujoco.Physics`` (:class:`~ipp_bench.sim.scene.DeploymentPhysics`)
and whose task is a :class:`DeploymentTask`: a ``control.Task`` that holds the task's gymnasium
environment (:class:`~ipp_bench.sim.env.MuJoCoIPPEnv`, ``task.env``) and delegates the episode to
it, as a dm_control suite task holds its own state. One mission, one clock: the gymnasium env flies
it, the task only turns it into time steps. One time step is one planner decision:

* Observations: a dict of named arrays, the gymnasium observation (``node_features``,
  ``pos_encoding``, ``current_node``, ``neighbours``, ``action_mask``, ``budget``) plus
  ``estimated_position`` (3,) [m], what the drone's state estimator says (never the true pose).
* Action: the index of a neighbour in ``observation["neighbours"]`` (``DiscreteArray(k)``).
  dm_env has no action masks: an unaffordable neighbour (``action_mask`` 0) ends the episode
  (LAST, reward 0, discount 0) instead of raising. Episodes also end, as in gymnasium, when no
  neighbour is affordable.
* Reward: the gymnasium reward (ROI trace reduction); discount 1 until the end (0 at the end).
* Seeding: ``seed`` draws every episode's seed; the same seed gives the same episodes.

Why ``control.Task`` and not ``composer.Task``: composer's value is in entities, observables
(noise and delays on what an agent observes, at sub-step rates) and variations (model fields
re-drawn per episode). Here one environment step is a planner decision (a whole leg, thousands
of physics steps under the cascaded controller, the camera read along the way), the realism acts
inside the camera pipeline and the controller's state estimate, and the per-episode texture is
written into the compiled model directly; composer's per-physics-step hooks and observables would
only add a second, unused stepping loop. ``control.Task`` is the protocol of the dm_control
suite: a Physics plus a task with those methods, which is what this is.
"""

from __future__ import annotations

from typing import Any

import ipp_bench.sim.gl  # noqa: F401  (chooses MUJOCO_GL before dm_control imports mujoco)

# isort: split
import numpy as np
from dm_control.rl import control
from dm_env import specs

DEFAULT_TASK = "ipp_bench/MuJoCoWeed15-v1"


class DeploymentTask(control.Task):
    """The dm_control task of a MuJoCo deployment: holds its gymnasium env and delegates the episode.

    Args:
        env: the task's :class:`~ipp_bench.sim.env.MuJoCoIPPEnv` (its world's Physics is the
            environment's ``physics``).
        seed: seed of the episode seeds (None: fresh entropy).
    """

    def __init__(self, env, seed: int | None = None):
        self.env = env
        self._rng = np.random.default_rng(seed)
        self._dm_last: tuple[dict, float, bool] | None = None  # the last step's (observation, reward, ended)
        specs_ = {name: _spec_of(name, sub) for name, sub in env.observation_space.spaces.items()}
        specs_["estimated_position"] = specs.Array((3,), np.float64, name="estimated_position")
        self._observation_spec = specs_

    @property
    def mission(self):
        """The episode's mission (the held env's)."""
        return self.env.mission

    @property
    def world(self):
        """The simulated world (the held env's), whose ``scene.physics`` the environment steps."""
        return self.env.world

    def initialize_episode(self, physics) -> None:
        self._check_physics(physics)
        obs, _ = self.env.reset(seed=int(self._rng.integers(0, 2**31 - 1)))
        self._dm_last = (obs, 0.0, False)

    def before_step(self, action, physics) -> None:
        self._check_physics(physics)
        env = self.env
        k = env.roadmap.k
        arr = np.asarray(action)
        if arr.size != 1 or not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"action {action!r} is invalid: expected one neighbour index in [0, {k})")
        a = int(arr.reshape(-1)[0])
        if not 0 <= a < k:
            raise ValueError(f"action {a} is invalid: expected a neighbour index in [0, {k})")
        mask = env.action_masks()
        if not mask[a]:  # the drone asked for a leg the budget cannot pay for: the episode ends
            self._dm_last = (env.observer.observe(env.mission, env.current_node, mask), 0.0, True)
            return
        obs, reward, terminated, _, _ = env.step(a)
        self._dm_last = (obs, float(reward), bool(terminated))

    def get_observation(self, physics) -> dict[str, np.ndarray]:
        spec = self._observation_spec
        out = {k: np.asarray(v, dtype=spec[k].dtype) for k, v in self._dm_last[0].items()}
        out["estimated_position"] = self.env.world.flight.estimated_position().astype(np.float64)
        return out

    def get_reward(self, physics) -> float:
        return self._dm_last[1]

    def get_termination(self, physics):
        return 0.0 if self._dm_last[2] else None

    def action_spec(self, physics) -> specs.DiscreteArray:
        return specs.DiscreteArray(int(self.env.roadmap.k), dtype=np.int64, name="neighbour")

    def observation_spec(self, physics) -> dict[str, specs.Array]:
        return dict(self._observation_spec)

    def _check_physics(self, physics) -> None:
        if physics is not self.env.world.scene.physics:
            raise ValueError("this task runs on its own world's physics (task.env.world.scene.physics); "
                             "build the environment with ipp_bench.sim.load()")


def _spec_of(name: str, space) -> specs.Array:
    """The dm_env spec of a gymnasium Box (bounded where its bounds are finite)."""
    low, high = np.broadcast_to(space.low, space.shape), np.broadcast_to(space.high, space.shape)
    if np.all(np.isfinite(low)) and np.all(np.isfinite(high)):
        return specs.BoundedArray(space.shape, space.dtype, low, high, name=name)
    return specs.Array(space.shape, space.dtype, name=name)


def load(task_id: str = DEFAULT_TASK, *, seed: int | None = 0, **overrides: Any) -> control.Environment:
    """The deployment task ``task_id`` as a dm_control environment.

    Args:
        task_id: a task tagged ``deployment`` (``"MuJoCoWeed15-v1"`` stands for ``"ipp_bench/MuJoCoWeed15-v1"``).
        seed: seed of the episode seeds (None: fresh entropy).
        **overrides: as ``gym.make``: config fields by name, ``sim=SimConfig(...)``, ``airframe=``.

    Raises:
        ValueError: ``task_id`` is not a MuJoCo deployment task, ``seed`` is not None or an integer >= 0,
            or an override is invalid.
    """
    import ipp_bench.envs as envs
    from ipp_bench.core.config import check_integer
    from ipp_bench.envs.registry import is_team_task

    if seed is not None:  # before the world is built: numpy's own error names no argument
        check_integer("load(seed)", seed, 0)
    spec = envs.task_spec(task_id)
    single = [t for t in envs.tagged("deployment") if not is_team_task(t)]
    if "deployment" not in spec.tags:  # the MuJoCo tasks carry the tag
        raise ValueError(f"task {task_id!r} is not a MuJoCo deployment: valid are {single}")
    if is_team_task(spec.id):
        raise ValueError(f"task {spec.id!r} is a team (a PettingZoo AEC environment, ipp_bench.envs.make_env); "
                         f"a dm_control Environment flies one drone: valid are {single}")
    env = envs.make_env(spec.id, **overrides)
    return control.Environment(env.world.scene.physics, DeploymentTask(env, seed), n_sub_steps=1)
