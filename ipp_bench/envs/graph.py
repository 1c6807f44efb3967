"""Graph MDP view of a mission on the 3D roadmap (paper Section IV-A).

The env holds the episode (its mission, node and seed) and the task logic (masks, rewards, ends); what
an agent observes is its :class:`~ipp_bench.envs.observation.GraphObservation` (``env.observer``), the
object a team env shares with every UAV.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from ..core import metrics as M
from ..core.config import IPPConfig
from ..core.mission import Mission, cell_to_xyz
from .episode import check_render_mode, draw_episode, episode_seed, resolve_config
from .observation import GraphObservation
from .panels import render_mission


class GraphIPPEnv(gym.Env):
    """Adaptive 3D informative path planning on a probabilistic roadmap.

    ## Description
    A UAV with a downward camera flies between the nodes of a 3D roadmap (cell centres at every
    altitude level, or sampled positions). Every ``measurement_spacing`` metres and on arrival it
    takes a camera measurement whose footprint grows and whose noise grows with altitude; a
    Gaussian-process belief over the grid is updated by a Kalman filter. The goal is to reduce the
    uncertainty in the region of interest (cells likely above ``mu_th``) within a flight-time budget.

    ## Action Space
    ``Discrete(k)``: the index of a neighbour of the current node in ``obs["neighbours"]``.
    Neighbours whose travel time exceeds the remaining budget are masked (``action_masks()``,
    the sb3-contrib convention); a masked or out-of-range action raises ``ValueError`` naming the
    valid actions.

    ## Observation Space
    ``Dict`` of ``Box`` spaces, N nodes, k neighbours:
    - ``node_features`` (N, 5) float32: x, y, z min-max normalised over the roadmap (in [0, 1]), belief
      mean (any finite value) and belief standard deviation (in [0, the prior's]) averaged over the
      node's camera footprint;
    - ``pos_encoding`` (N, pe_dim) float32: Laplacian eigenvectors of the roadmap (constant);
    - ``current_node`` (1,) int64; ``neighbours`` (k,) int64: node indices;
    - ``action_mask`` (k,) int8: 1 where the neighbour is affordable;
    - ``budget`` (1,) float32: remaining fraction of the budget.

    ## Rewards
    ``10 (Tr(P-) - Tr(P+)) / Tr(P-)`` over the belief ROI ``mu + beta sigma >= mu_th`` taken before
    the leg (paper eq. 9). ``info["reward_info_gain"]`` holds it.

    ## Episode End
    Terminated when no neighbour of the current node is affordable. Never truncated. ``step``
    after the end raises ``RuntimeError`` ("the episode is over: call reset()"); ``reset`` raises
    ``ValueError`` naming ``budget_s`` when the budget pays for no move from the start.

    ## Arguments
    ``gym.make(task_id, **overrides)``: any field of :class:`ipp_bench.core.config.IPPConfig` by name
    (``budget_s=200``, ``rows=20``, ``field="regions"``, ...), or ``config=IPPConfig(...)``;
    ``render_mode="rgb_array"`` (the only mode; another one is refused, naming it). Constructing an
    environment limits numpy/scipy BLAS to one thread per process (``IPP_BENCH_BLAS_THREADS``
    overrides; see ``ipp_bench.core._threads``). ``gym.make`` wraps it in gymnasium's
    ``OrderEnforcing`` and ``PassiveEnvChecker``; :func:`ipp_bench.envs.make_env` returns it bare
    (its ``mission``, ``roadmap``, ``observer`` and ``action_masks()``, which wrappers do not forward).

    ## Version History
    - v1 (benchmark v1): GP prior fitted to the field family (``ipp-bench fit-prior``), the
      lineage's f^3 noise of binned read-outs, a 30 x 30 task, training tasks on episode seeds
      disjoint from the evaluation seeds (``mission.episode_seeds``); ``reset(seed=s)`` plays the
      task's episode seed ``lo + s mod (hi - lo)``, reported as ``info["episode_seed"]``.
    - v0: initial release (the paper's constants).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(self, config: IPPConfig | dict | None = None, render_mode: str | None = None,
                 task_id: str | None = None, **overrides: Any):
        self.config = resolve_config(config, overrides)
        check_render_mode(render_mode, self.metadata["render_modes"])
        self.task_id = task_id
        self.render_mode = render_mode
        self.observer = GraphObservation.for_config(self.config)
        self.roadmap, self.sensor = self.observer.roadmap, self.observer.sensor
        self.observation_space, self.action_space = self.observer.observation_space, self.observer.action_space
        self.mission: Mission | None = None
        self.current_node = 0
        self.episode_seed: int | None = None

    def _make_mission(self, truth: np.ndarray, rng: np.random.Generator, start_xyz: np.ndarray) -> Mission:
        """The world of one episode; the MuJoCo deployment overrides this."""
        return Mission(self.config, truth, rng, start_xyz, sensor=self.sensor)

    # -- gymnasium API ------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Draw a field, a start and a sensor-noise stream from ``seed``.

        ``options={"start_node": i}`` starts at node i instead of the configured start.
        """
        if seed is None and self._np_random is None:
            super().reset(seed=None)  # every episode has a seed (info["episode_seed"]) that replays it
        seed = episode_seed(self.config, seed, lambda n: self.np_random.integers(n))
        super().reset(seed=seed)
        self.episode_seed = seed
        truth, start_seed, noise_seed = draw_episode(self.config, self.np_random)
        start = self.config.mission.start
        if options and "start_node" in options:
            node = int(options["start_node"])
            if not 0 <= node < self.roadmap.n_nodes:
                raise ValueError(f"options['start_node'] = {node} is invalid: valid are 0..{self.roadmap.n_nodes - 1}")
        elif start is None:
            node = int(np.random.default_rng(start_seed).integers(self.roadmap.n_nodes))
        else:
            node = self.roadmap.nearest_node(cell_to_xyz(self.config, *start))
        self.current_node = node
        self.mission = self._make_mission(truth, np.random.default_rng(noise_seed), self.roadmap.positions[node])
        mask = self.action_masks()
        if not mask.any():
            nbrs = self.roadmap.positions[self.roadmap.neighbours[node]]
            cheapest = float(self.mission.leg_durations(self.mission.position, nbrs).min())
            raise ValueError(
                f"budget_s = {self.config.mission.budget_s} is too small: no move from the start node {node} fits "
                f"(the cheapest takes {cheapest:.2f} s); raise budget_s")
        return self._observation(mask), self._info(0.0, 0.0)

    def action_masks(self) -> np.ndarray:
        """(k,) bool: neighbours whose leg the mission's remaining budget can pay for."""
        self._require_reset()
        return self.mission.affordable(self.roadmap.positions[self.roadmap.neighbours[self.current_node]])

    def step(self, action):
        self._require_reset()
        mask = self.action_masks()
        if not mask.any():
            raise RuntimeError("the episode is over (no neighbour is affordable): call reset()")
        a = self.observer.check_action(action, mask)
        mission = self.mission
        roi = mission.belief_roi()
        before = M.trace_roi(mission.belief.variance, roi)
        target = int(self.roadmap.neighbours[self.current_node, a])
        mission.fly_to(self.roadmap.positions[target])
        self.current_node = target
        after = M.trace_roi(mission.belief.variance, roi)
        reward = M.info_gain_reward(before, after)
        next_mask = self.action_masks()
        return self._observation(next_mask), reward, not bool(next_mask.any()), False, self._info(reward, after)

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without render_mode; use render_mode='rgb_array'")
            return None
        self._require_reset()
        return render_mission(self.mission)

    # -- helpers ------------------------------------------------------------------------------
    def _require_reset(self) -> None:
        if self.mission is None:
            raise RuntimeError("call reset() before step(), action_masks() or render()")

    def node_features(self) -> np.ndarray:
        """(N, 5) float32 node features of the current belief."""
        return self.observer.node_features(self.mission.belief)

    def _observation(self, mask: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """The observation of the current state; ``mask``: :meth:`action_masks`, when already computed."""
        return self.observer.observe(self.mission, self.current_node, self.action_masks() if mask is None else mask)

    def _info(self, reward: float, trace_belief: float) -> dict[str, Any]:
        info = self.mission.metrics()
        info.update(reward_info_gain=reward, trace_roi_belief=trace_belief, node=self.current_node,
                    episode_seed=self.episode_seed)
        return info
