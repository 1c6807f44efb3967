"""A ``dm_env.Environment`` view of the MuJoCo deployment, for dm_control / Acme users.

The same episode as the gymnasium task (``ipp_bench/MuJoCoWeed15-v1`` by default): the
:class:`DeploymentEnvironment` wraps the gymnasium environment and only translates the interface.

* Observations: a dict of named arrays, the gymnasium observation (``node_features``,
  ``pos_encoding``, ``current_node``, ``neighbours``, ``action_mask``, ``budget``) plus
  ``estimated_position`` (3,) [m], what the drone's state estimator says (never the true pose).
* Action: the index of a neighbour in ``observation["neighbours"]`` (``DiscreteArray(k)``).
  dm_env has no action masks: an unaffordable neighbour (``action_mask`` 0) ends the episode
  (LAST, reward 0, discount 0) instead of raising, since the drone asked for a leg the budget
  cannot pay for. Episodes also end, as in gymnasium, when no neighbour is affordable.
* Reward: the gymnasium reward (ROI trace reduction); discount 1 until the end (0 at the end).
* Seeding: ``seed`` draws every episode's seed; the same seed gives the same episodes.

Why only ``dm_env`` of the dm-control stack: the scene is composed with MuJoCo's own ``MjSpec``
from a per-seed texture, and the realism (image formation, wind, state estimation) acts inside
the camera pipeline and the controller, where composer's observables (which perturb what an
agent observes) and variations (which re-sample model fields) do not reach. ``dm_env`` is the
interface that lets Acme agents drive the task.
"""

from __future__ import annotations

from typing import Any

import dm_env
import numpy as np
from dm_env import specs

DEFAULT_TASK = "ipp_bench/MuJoCoWeed15-v1"


def _spec_of(name: str, space) -> specs.Array:
    low, high = np.broadcast_to(space.low, space.shape), np.broadcast_to(space.high, space.shape)
    if np.all(np.isfinite(low)) and np.all(np.isfinite(high)):
        return specs.BoundedArray(space.shape, space.dtype, low, high, name=name)
    return specs.Array(space.shape, space.dtype, name=name)


class DeploymentEnvironment(dm_env.Environment):
    """dm_env view of a MuJoCo deployment task (see the module docstring).

    Args:
        task_id: a task whose entry point is in ``ipp_bench.sim``.
        seed: seed of the episode seeds.
        **overrides: passed to ``gym.make`` (config fields, ``sim=SimConfig(...)``).
    """

    def __init__(self, task_id: str = DEFAULT_TASK, seed: int | None = 0, **overrides: Any) -> None:
        import gymnasium as gym

        import ipp_bench.envs as envs

        spec = envs.task_spec(task_id)
        if not spec.entry_point.startswith("ipp_bench.sim"):
            raise ValueError(f"task {task_id!r} is not a MuJoCo deployment: valid are {envs.tagged('deployment')}")
        self._env = gym.make(task_id, **overrides).unwrapped
        self._rng = np.random.default_rng(seed)
        space = self._env.observation_space
        self._obs_spec = {name: _spec_of(name, sub) for name, sub in space.spaces.items()}
        self._obs_spec["estimated_position"] = specs.Array((3,), np.float64, name="estimated_position")
        self._action_spec = specs.DiscreteArray(int(self._env.action_space.n), dtype=np.int64, name="neighbour")
        self._needs_reset = True

    @property
    def gym_env(self):
        """The wrapped gymnasium environment (its ``mission`` holds the world state)."""
        return self._env

    def _observation(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        out = {k: np.asarray(v, dtype=self._obs_spec[k].dtype) for k, v in obs.items()}
        out["estimated_position"] = self._env.world.flight.estimated_position().astype(np.float64)
        return out

    def reset(self) -> dm_env.TimeStep:
        obs, _ = self._env.reset(seed=int(self._rng.integers(0, 2**31 - 1)))
        self._needs_reset = False
        return dm_env.restart(self._observation(obs))

    def step(self, action) -> dm_env.TimeStep:
        if self._needs_reset:
            return self.reset()
        a = int(np.asarray(action).reshape(-1)[0])
        if not 0 <= a < self._action_spec.num_values:
            raise ValueError(f"action {a} is invalid: expected a neighbour index in "
                             f"[0, {self._action_spec.num_values})")
        mask = self._env.action_masks()
        if not mask[a]:
            self._needs_reset = True
            return dm_env.termination(0.0, self._observation(self._env._observation()))
        obs, reward, terminated, truncated, _ = self._env.step(a)
        observation = self._observation(obs)
        if terminated:
            self._needs_reset = True
            return dm_env.termination(float(reward), observation)
        if truncated:
            self._needs_reset = True
            return dm_env.truncation(float(reward), observation)
        return dm_env.transition(float(reward), observation)

    def observation_spec(self) -> dict[str, specs.Array]:
        return dict(self._obs_spec)

    def action_spec(self) -> specs.DiscreteArray:
        return self._action_spec

    def reward_spec(self) -> specs.Array:
        return specs.Array((), np.float64, name="reward")

    def discount_spec(self) -> specs.BoundedArray:
        return specs.BoundedArray((), np.float64, 0.0, 1.0, name="discount")

    def close(self) -> None:
        self._env.close()
