"""What an agent on the roadmap observes: one object per task, shared by every env that shows it.

:class:`GraphObservation` is built once from a task's config, roadmap and camera model. It owns the
observation and action spaces, the per-node camera footprints and normalised positions, and turns a
mission's state (its belief, the agent's node, the action mask, its clock) into the observation dict.
The single-UAV env (:class:`~ipp_bench.envs.graph.GraphIPPEnv`) holds one; a team env
(:class:`~ipp_bench.envs.team.TeamGraphEnv`) holds one for all its UAVs, so a UAV of a team observes
exactly what the single-UAV env observes in the same state.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces
from scipy import sparse

from ..core.config import IPPConfig
from ..core.mission import Mission
from ..core.roadmap import Roadmap
from ..core.sensor import Sensor

#: the node features, in their column order
NODE_FEATURES = ("x", "y", "z", "belief_mean", "belief_std")


class GraphObservation:
    """The observation of a roadmap task: spaces, footprints, and the observation of a state.

    Args:
        config: the task's configuration (its grid, graph and GP prior).
        roadmap: the task's roadmap.
        sensor: the task's camera model.

    Attributes:
        observation_space: ``Dict`` of ``node_features`` (N, 5), ``pos_encoding`` (N, pe_dim),
            ``current_node`` (1,), ``neighbours`` (k,), ``action_mask`` (k,), ``budget`` (1,).
        action_space: ``Discrete(k)``: an index into the observation's ``neighbours``.
        footprint: (N, n_cells) sparse averaging matrix: row i averages the cells one look from node i sees.
        norm_xyz: (N, 3) float32 node positions, min-max normalised over the roadmap.
    """

    def __init__(self, config: IPPConfig, roadmap: Roadmap, sensor: Sensor):
        self.config, self.roadmap, self.sensor = config, roadmap, sensor
        n, k = roadmap.n_nodes, roadmap.k
        pos = roadmap.positions
        span = pos.max(axis=0) - pos.min(axis=0)
        self.norm_xyz = ((pos - pos.min(axis=0)) / np.where(span > 0, span, 1.0)).astype(np.float32)
        self.footprint = footprint_matrix(roadmap, sensor, config.grid.n_cells)
        self.observation_space = spaces.Dict({
            "node_features": spaces.Box(*feature_bounds(config, n), (n, len(NODE_FEATURES)), np.float32),
            "pos_encoding": spaces.Box(-1.0, 1.0, (n, config.graph.pe_dim), np.float32),
            "current_node": spaces.Box(0, n - 1, (1,), np.int64),
            "neighbours": spaces.Box(0, n - 1, (k,), np.int64),
            "action_mask": spaces.Box(0, 1, (k,), np.int8),
            "budget": spaces.Box(0.0, 1.0, (1,), np.float32),
        })
        self.action_space = spaces.Discrete(k)

    @classmethod
    def for_config(cls, config: IPPConfig) -> GraphObservation:
        """The observation of ``config``'s task: its roadmap (cached per process) and a camera model of its own."""
        return cls(config, Roadmap.build(config.grid, config.graph, config.mission.speed),
                   Sensor(config.grid, config.sensor))

    def node_features(self, belief) -> np.ndarray:
        """(N, 5) float32: normalised x, y, z and the belief's mean and std averaged over each node's footprint."""
        feats = np.empty((self.roadmap.n_nodes, len(NODE_FEATURES)), dtype=np.float32)
        feats[:, :3] = self.norm_xyz
        feats[:, 3] = self.footprint @ belief.mean
        feats[:, 4] = self.footprint @ np.sqrt(belief.variance)
        return feats

    def observe(self, mission: Mission, node: int, mask: np.ndarray) -> dict[str, np.ndarray]:
        """The observation of an agent at roadmap node ``node`` flying ``mission`` (its belief and its
        clock), with ``mask`` ((k,) bool) the neighbours it may fly to."""
        return {
            "node_features": self.node_features(mission.belief),
            "pos_encoding": self.roadmap.pos_encoding.copy(),
            "current_node": np.array([node], dtype=np.int64),
            "neighbours": self.roadmap.neighbours[node].copy(),
            "action_mask": mask.astype(np.int8),
            "budget": np.array([mission.remaining_s / mission.budget_s], dtype=np.float32),
        }

    @staticmethod
    def check_action(action, mask: np.ndarray) -> int:
        """``action`` as a neighbour index, or a ValueError naming the valid ones (``mask``: (k,) bool)."""
        arr = np.asarray(action)
        valid = np.flatnonzero(mask).tolist()
        if arr.size != 1 or not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"action {action!r} is invalid: expected one integer; valid actions now are {valid}")
        a = int(arr.reshape(-1)[0])
        if not 0 <= a < mask.size or not mask[a]:
            why = "out of range" if not 0 <= a < mask.size else "masked (neighbour not affordable)"
            raise ValueError(f"action {a} is invalid ({why}): valid actions now are {valid}")
        return a


def footprint_matrix(roadmap: Roadmap, sensor: Sensor, n_cells: int) -> sparse.csr_matrix:
    """(N, n_cells) averaging matrix: row i averages the cells one look from node i sees."""
    rows, cols, vals = [], [], []
    for i, p in enumerate(roadmap.positions):
        obs = sensor.observe(p)
        cells = obs.cells if obs is not None else np.zeros(0, int)
        rows.append(np.full(cells.size, i))
        cols.append(cells)
        vals.append(np.full(cells.size, 1.0 / max(cells.size, 1)))
    return sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(roadmap.n_nodes, n_cells))


def feature_bounds(config: IPPConfig, n_nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) of ``node_features``: x, y, z in [0, 1]; the belief mean has no bound of its own
    (any finite float32); its standard deviation is in [0, the prior's], which no update raises."""
    gp = config.gp
    prior_std = np.float32(np.sqrt(gp.signal_variance + gp.nugget)) * np.float32(1 + 1e-5)  # rounding
    finite = np.finfo(np.float32).max
    low = np.array([0.0, 0.0, 0.0, -finite, 0.0], dtype=np.float32)
    high = np.array([1.0, 1.0, 1.0, finite, prior_std], dtype=np.float32)
    return np.broadcast_to(low, (n_nodes, 5)).copy(), np.broadcast_to(high, (n_nodes, 5)).copy()


__all__ = ["NODE_FEATURES", "GraphObservation", "feature_bounds", "footprint_matrix"]
