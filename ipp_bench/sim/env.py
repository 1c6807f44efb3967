"""The MuJoCo deployment task: the graph MDP, flown by a simulated quadrotor with a real camera.

:class:`MuJoCoIPPEnv` is the task's gymnasium environment (``gym.make(task_id)``). Its dm_control
view is a separate object that holds it: :class:`~ipp_bench.sim.dmenv.DeploymentTask`, the
``control.Task`` that :func:`ipp_bench.sim.load` puts with the world's Physics into a
``control.Environment``.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

import ipp_bench.sim.gl  # noqa: F401  (chooses MUJOCO_GL before dm_control imports mujoco)

# isort: split
from ipp_bench.core.config import IPPConfig
from ipp_bench.envs.graph import GraphIPPEnv
from ipp_bench.envs.panels import render_mission
from ipp_bench.sim.mission import MuJoCoMission
from ipp_bench.sim.render import azimuth_to_centre, chase_camera
from ipp_bench.sim.world import SimConfig, WeedWorld, split_sim_settings


class MuJoCoIPPEnv(GraphIPPEnv):
    """Adaptive 3D IPP on the roadmap, deployed in MuJoCo (the paper's Gazebo weed-field setting).

    ## Description
    The same roadmap MDP as :class:`~ipp_bench.envs.graph.GraphIPPEnv`, but the world is simulated:
    a 1.5 kg quadrotor with four thrust actuators flies each chosen leg under a cascaded
    position -> attitude -> thrust controller at up to the mission speed; its 60 deg downward camera
    renders the textured weed field (generated per seed from a ``weed_patches`` ground truth),
    an HSV threshold classifies weed pixels, the pixels are projected to the ground with the
    camera's intrinsics and actual pose, and each observed cell's weed fraction becomes a
    measurement with the sensor model's binning and altitude noise. Mission time is simulated time.

    ## Action Space
    ``Discrete(k)`` as in the graph tasks. ``action_masks()`` marks a neighbour affordable when
    its reference flight time (length / speed plus the 1 s of velocity ramps) fits the budget.

    ## Observation Space
    Identical to :class:`~ipp_bench.envs.graph.GraphIPPEnv` (node features, positional
    encoding, current node, neighbours, action mask, remaining budget fraction).

    ## Rewards
    ``10 (Tr(P-) - Tr(P+)) / Tr(P-)`` over the belief ROI, as in the graph tasks.

    ## Episode End
    Terminated when no neighbour is affordable (or the flight used up the budget). Never truncated.

    ## Arguments
    ``gym.make("ipp_bench/MuJoCoWeed15-v0", **overrides)``: any :class:`IPPConfig` field by name,
    any :class:`~ipp_bench.sim.world.SimConfig` leaf field by name (``image_size=480``,
    ``wind_max=2.0``, ``mode="stop"``; the task file's ``[sim]`` table is the default), or
    ``sim=SimConfig(...)`` in place of the task file's table;
    ``airframe=`` a PyMJCF quadrotor in place of the shipped one (:mod:`ipp_bench.sim.scene`);
    ``render_mode="rgb_array"`` (chase view, downward camera, truth / mean / std panels).
    Needs ``pip install "ipp-bench[sim]"`` and EGL or OSMesa (``MUJOCO_GL``).

    ## Version History
    - v1 (``tasks/mujoco_weed15_v1.toml``: the same class, its ``[sim]`` table): the v0 task with a
      realistic deployment (the :class:`~ipp_bench.sim.world.SimConfig` defaults):
      a 320 x 320 camera (2.9 cm ground sampling distance at 8 m, 5.1 cm at 14 m, read out 2 x 2
      binned above 10 m) with lens blur, motion blur where the image moves, shot and read noise, and
      per-episode sun direction, exposure and white-balance errors; plant margins whose colours mix
      with the soil's. The frame goes through OpenCV (HSV threshold, closing, homography onto the
      ground with the *estimated* pose, area resampling to cells) and the measurement z is what
      that pipeline estimates: no synthetic noise is added. The camera's error is mostly persistent,
      so the belief carries it as states (:class:`~ipp_bench.core.belief.PersistentErrorBelief`: a
      per-cell error per resolution factor, plus white noise, both larger in part-weed cells); the
      constants of the task file are fitted to the pipeline by ``python -m ipp_bench.sim.calibrate``.
      The drone flies through waypoints without stopping (velocity-continuous legs at up to 2 m/s,
      slowing only where a leg turns back), in a per-episode wind with gusts, controlled from an
      estimated state (GPS-like bias and noise, attitude noise).
    - v0: initial release (``tasks/mujoco_weed15_v0.toml``: ideal 128 px camera, the sensor model's
      noise added, stop at every waypoint, no wind, perfect state).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(self, config: IPPConfig | dict | None = None, render_mode: str | None = None,
                 task_id: str | None = None, sim: SimConfig | None = None, sim_section: dict | None = None,
                 airframe=None, **overrides: Any):
        self.sim_config = split_sim_settings(
            lambda rest: super(MuJoCoIPPEnv, self).__init__(config, render_mode=render_mode, task_id=task_id, **rest),
            overrides, sim, sim_section)
        self.world = WeedWorld(self.config.grid, self.config.sensor, self.config.mission.speed, self.sim_config,
                               airframe=airframe)
        self._chase = chase_camera(self.world.scene)

    def _make_mission(self, truth: np.ndarray, rng: np.random.Generator, start_xyz: np.ndarray) -> MuJoCoMission:
        # drawn from a copy: the sensor-noise stream itself is not advanced
        texture_seed = int(copy.deepcopy(rng).integers(2**63 - 1))
        return MuJoCoMission(self.config, truth, rng, start_xyz, self.world, texture_seed, sensor=self.sensor)

    def render(self):
        """(H, W, 3) uint8: chase view and downward camera above the truth / mean / std panels."""
        if self.render_mode is None:
            return super().render()
        self._require_reset()
        panels = render_mission(self.mission)
        h = panels.shape[0]
        renderer = self.world.renderer
        down = renderer.render(None, h, h)
        chase_w = panels.shape[1] - h - 4
        self._chase.azimuth = azimuth_to_centre(self.world.scene)
        chase = renderer.render(self._chase, chase_w, h)
        top = np.concatenate([chase, np.full((h, 4, 3), 255, np.uint8), down], axis=1)
        return np.ascontiguousarray(np.concatenate([top, np.full((4, top.shape[1], 3), 255, np.uint8), panels]))

    def close(self) -> None:
        self.world.close()
        super().close()
