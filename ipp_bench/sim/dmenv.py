"""The deployment as a dm_control environment: :func:`load` (the dm_control suite's convention).

``load(task_id, **overrides)`` returns a ``dm_control.rl.control.Environment`` whose ``physics``
is the world's ``dm_control.mujoco.Physics`` (:class:`~ipp_bench.sim.scene.DeploymentPhysics`)
and whose task is the deployment environment itself (:class:`~ipp_bench.sim.env.MuJoCoIPPEnv`
implements ``control.Task``; see :mod:`ipp_bench.sim.env` for why not ``composer``). One time step
is one planner decision:

* Observations: a dict of named arrays, the gymnasium observation (``node_features``,
  ``pos_encoding``, ``current_node``, ``neighbours``, ``action_mask``, ``budget``) plus
  ``estimated_position`` (3,) [m], what the drone's state estimator says (never the true pose).
* Action: the index of a neighbour in ``observation["neighbours"]`` (``DiscreteArray(k)``).
  dm_env has no action masks: an unaffordable neighbour (``action_mask`` 0) ends the episode
  (LAST, reward 0, discount 0) instead of raising. Episodes also end, as in gymnasium, when no
  neighbour is affordable.
* Reward: the gymnasium reward (ROI trace reduction); discount 1 until the end (0 at the end).
* Seeding: ``seed`` draws every episode's seed; the same seed gives the same episodes.
"""

from __future__ import annotations

from typing import Any

import ipp_bench.sim.gl  # noqa: F401  (chooses MUJOCO_GL before dm_control imports mujoco)

# isort: split
from dm_control.rl import control

DEFAULT_TASK = "ipp_bench/MuJoCoWeed15-v1"


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
    task = envs.make_env(spec.id, **overrides)
    task.seed_episodes(seed)
    return control.Environment(task.world.scene.physics, task, n_sub_steps=1)


def DeploymentEnvironment(task_id: str = DEFAULT_TASK, seed: int | None = 0, **overrides: Any) -> control.Environment:
    """Former name of :func:`load` (the dm_env view is now the dm_control environment itself)."""
    return load(task_id, seed=seed, **overrides)
