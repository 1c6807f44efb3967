"""Graph MDP view of a mission on the 3D roadmap (paper Section IV-A)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from scipy import sparse

from ..core import metrics as M
from ..core._threads import limit_blas_threads
from ..core.config import IPPConfig, invalid
from ..core.fields import make_field
from ..core.limits import check_sizes
from ..core.mission import Mission, cell_to_xyz
from ..core.roadmap import Roadmap
from ..core.sensor import Sensor
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
    environment limits numpy/scipy BLAS to one
    thread per process (``IPP_BENCH_BLAS_THREADS`` overrides; see ``ipp_bench.core._threads``).

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
        if config is None:
            config = IPPConfig()
        elif isinstance(config, dict):
            config = IPPConfig.from_dict(config)
        elif not isinstance(config, IPPConfig):
            invalid("config", config, "an ipp_bench.core.config.IPPConfig, a dict of its sections or None "
                                      "(or set fields by name: gym.make(task, budget_s=100))")
        if overrides:
            config = config.replace(**overrides)
        check_sizes(config)  # before the roadmap: a map or spacing too large costs nothing
        limit_blas_threads()
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode={render_mode!r} is invalid: valid are {self.metadata['render_modes']} "
                             "or None")
        self.config = config
        self.task_id = task_id
        self.render_mode = render_mode
        self.roadmap = Roadmap.build(config.grid, config.graph, config.mission.speed)
        self.sensor = Sensor(config.grid, config.sensor)
        N, k = self.roadmap.n_nodes, self.roadmap.k
        pos = self.roadmap.positions
        span = pos.max(axis=0) - pos.min(axis=0)
        self._norm_xyz = ((pos - pos.min(axis=0)) / np.where(span > 0, span, 1.0)).astype(np.float32)
        self._footprint = self._footprint_matrix()
        pe_dim = config.graph.pe_dim
        self.observation_space = spaces.Dict({
            "node_features": spaces.Box(*self._feature_bounds(N), (N, 5), np.float32),
            "pos_encoding": spaces.Box(-1.0, 1.0, (N, pe_dim), np.float32),
            "current_node": spaces.Box(0, N - 1, (1,), np.int64),
            "neighbours": spaces.Box(0, N - 1, (k,), np.int64),
            "action_mask": spaces.Box(0, 1, (k,), np.int8),
            "budget": spaces.Box(0.0, 1.0, (1,), np.float32),
        })
        self.action_space = spaces.Discrete(k)
        self.mission: Mission | None = None
        self.current_node = 0
        self.episode_seed: int | None = None

    # -- construction -------------------------------------------------------------------------
    def _footprint_matrix(self) -> sparse.csr_matrix:
        """(N, n) averaging matrix: row i averages the cells seen from node i."""
        rows, cols, vals = [], [], []
        for i, p in enumerate(self.roadmap.positions):
            obs = self.sensor.observe(p)
            cells = obs.cells if obs is not None else np.zeros(0, int)
            rows.append(np.full(cells.size, i))
            cols.append(cells)
            vals.append(np.full(cells.size, 1.0 / max(cells.size, 1)))
        n = self.config.grid.n_cells
        return sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                 shape=(self.roadmap.n_nodes, n))

    def _feature_bounds(self, n_nodes: int) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) of ``node_features``: x, y, z in [0, 1]; the belief mean has no bound of its own
        (any finite float32); its standard deviation is in [0, the prior's], which no update raises."""
        gp = self.config.gp
        prior_std = np.float32(np.sqrt(gp.signal_variance + gp.nugget)) * np.float32(1 + 1e-5)  # rounding
        finite = np.finfo(np.float32).max
        low = np.array([0.0, 0.0, 0.0, -finite, 0.0], dtype=np.float32)
        high = np.array([1.0, 1.0, 1.0, finite, prior_std], dtype=np.float32)
        return np.broadcast_to(low, (n_nodes, 5)).copy(), np.broadcast_to(high, (n_nodes, 5)).copy()

    def _make_mission(self, truth: np.ndarray, rng: np.random.Generator, start_xyz: np.ndarray) -> Mission:
        """The world of one episode; the MuJoCo deployment overrides this."""
        return Mission(self.config, truth, rng, start_xyz, sensor=self.sensor)

    # -- gymnasium API ------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Draw a field, a start and a sensor-noise stream from ``seed``.

        ``options={"start_node": i}`` starts at node i instead of the configured start.
        """
        lo, hi = self.config.mission.episode_seeds
        if seed is None:  # every episode has a seed (info["episode_seed"]) that replays it
            if self._np_random is None:
                super().reset(seed=None)
            seed = int(self.np_random.integers(hi - lo))
        elif not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
            raise ValueError(f"seed = {seed!r} is invalid: expected an integer >= 0 or None")
        seed = lo + int(seed) % (hi - lo)  # the task's episode seeds (mission.episode_seeds)
        super().reset(seed=seed)
        self.episode_seed = int(seed)
        field_seed, start_seed, noise_seed = self.np_random.integers(0, 2**63 - 1, size=3)
        truth = make_field(self.config.mission.field, self.config.grid, np.random.default_rng(field_seed))
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
        a = self._check_action(action, mask)
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

    def _check_action(self, action, mask: np.ndarray) -> int:
        arr = np.asarray(action)
        valid = np.flatnonzero(mask).tolist()
        if arr.size != 1 or not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"action {action!r} is invalid: expected one integer; valid actions now are {valid}")
        a = int(arr.reshape(-1)[0])
        if not 0 <= a < mask.size or not mask[a]:
            why = "out of range" if not 0 <= a < mask.size else "masked (neighbour not affordable)"
            raise ValueError(f"action {a} is invalid ({why}): valid actions now are {valid}")
        return a

    def node_features(self) -> np.ndarray:
        """(N, 5) float32 node features of the current belief."""
        belief = self.mission.belief
        feats = np.empty((self.roadmap.n_nodes, 5), dtype=np.float32)
        feats[:, :3] = self._norm_xyz
        feats[:, 3] = self._footprint @ belief.mean
        feats[:, 4] = self._footprint @ np.sqrt(belief.variance)
        return feats

    def _observation(self, mask: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """The observation of the current state; ``mask``: :meth:`action_masks`, when already computed."""
        mission = self.mission
        if mask is None:
            mask = self.action_masks()
        return {
            "node_features": self.node_features(),
            "pos_encoding": self.roadmap.pos_encoding.copy(),
            "current_node": np.array([self.current_node], dtype=np.int64),
            "neighbours": self.roadmap.neighbours[self.current_node].copy(),
            "action_mask": mask.astype(np.int8),
            "budget": np.array([mission.remaining_s / mission.budget_s], dtype=np.float32),
        }

    def _info(self, reward: float, trace_belief: float) -> dict[str, Any]:
        info = self.mission.metrics()
        info.update(reward_info_gain=reward, trace_roi_belief=trace_belief, node=self.current_node,
                    episode_seed=self.episode_seed)
        return info
