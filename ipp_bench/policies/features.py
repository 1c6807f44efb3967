"""An extra node feature for the attention policy: what one look from each node would gain.

Greedy knows, for each neighbour, the predicted ROI trace reduction of flying there; the five
node features of :class:`~ipp_bench.envs.graph.GraphIPPEnv` (position, belief mean and std over
the footprint) do not say it, and on a 30 x 30 map a network imitating greedy from them alone
matched greedy's choice in 10% of the states. This module adds a sixth feature for every node:
the look gain of :class:`~ipp_bench.core.gains.LookGain`,

    g_i = 10 * (predicted ROI trace reduction of one read-out taken at node i) / Tr_ROI(P)

predicted from the belief's marginal variances (the formula and its cost: :mod:`ipp_bench.core.gains`),
or its map-invariant form (:func:`invariant_features`).

The environment is unchanged: :func:`gain_feature_wrapper` adds the column during training and
the ``attention`` planner adds it from its :class:`~ipp_bench.planners.base.RobotView` when the
checkpoint was trained with it (``NetConfig.node_dim == 6``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.belief import error_states
from ..core.gains import LookGain

BASE_NODE_DIM = 5  # the GraphIPPEnv node features
GAIN_NODE_DIM = BASE_NODE_DIM + 1


def _belief_of(source: Any) -> tuple[Any, np.ndarray, np.ndarray, Any]:
    """(source, variance, ROI, camera-error states or None) as the robot sees them; ``source`` a
    RobotView, or an env (unwrapped here)."""
    if hasattr(source, "belief_roi"):  # RobotView
        return source, source.belief.variance, source.belief_roi(), source.error_states()
    source = source.unwrapped
    mission = source.mission
    return source, mission.belief.variance, mission.belief_roi(), error_states(mission)


def add_gain_feature(obs: dict[str, np.ndarray], source: Any) -> dict[str, np.ndarray]:
    """``obs`` with the look-gain column appended to ``node_features`` (N, 5) -> (N, 6).

    Args:
        obs: a GraphIPPEnv observation.
        source: the planner's :class:`~ipp_bench.planners.base.RobotView`, or the env itself.
    """
    source, variance, roi, errors = _belief_of(source)
    gain = LookGain.of(source)(variance, roi, errors)
    out = dict(obs)
    out["node_features"] = np.concatenate([obs["node_features"], gain[:, None]], axis=1)
    return out


INVARIANT_LENGTH_M = 25.0  # [m] the unit of the invariant inputs' relative x, y (10 cells of 2.5 m)


def invariant_features(obs: dict[str, np.ndarray], source: Any) -> dict[str, np.ndarray]:
    """``obs`` with node features that mean the same on every map size and task family: (N, 5) -> (N, 6).

    - x, y: metres from the current node over :data:`INVARIANT_LENGTH_M` (the env's are min-max
      normalised over the roadmap, so one unit is 37.5 m on 15 x 15 and 75 m on 30 x 30);
    - z: the env's (the altitude levels are the same on every task);
    - mean: (footprint mean - mu_th) / sigma_0 and std: footprint std / sigma_0, with sigma_0 the
      prior's standard deviation (the env's are in field units: v1 and v2 priors differ 3x);
    - look gain: the ROI trace reduction of one look from the node over the mean ROI cell variance
      (how many ROI cells' worth of variance it removes), over 10 (the v1 feature divides by the whole
      map's ROI trace, which grows with the map).

    Args:
        obs: a GraphIPPEnv observation.
        source: the planner's :class:`~ipp_bench.planners.base.RobotView`, or the env itself.
    """
    source, variance, roi, errors = _belief_of(source)
    cfg = source.config
    sigma0 = float(np.sqrt(cfg.gp.signal_variance + cfg.gp.nugget))
    pos = source.roadmap.positions
    cur = int(np.asarray(obs["current_node"]).reshape(-1)[0])
    f = np.asarray(obs["node_features"], dtype=np.float32)
    out = np.empty((f.shape[0], BASE_NODE_DIM + 1), dtype=np.float32)
    out[:, :2] = (pos[:, :2] - pos[cur, :2]) / INVARIANT_LENGTH_M
    out[:, 2] = f[:, 2]
    out[:, 3] = (f[:, 3] - cfg.mission.mu_th) / sigma0
    out[:, 4] = f[:, 4] / sigma0
    out[:, 5] = LookGain.of(source)(variance, roi, errors) * (np.count_nonzero(roi) / 100.0)
    return dict(obs) | {"node_features": out}


def extend_observation(obs: dict[str, np.ndarray], view: Any, node_dim: int,
                       invariant: bool = False) -> dict[str, np.ndarray]:
    """``obs`` with the node features a network of ``node_dim`` was trained with (6: the look gain;
    ``invariant``: :func:`invariant_features`); unchanged if it has them or if no extension fits (the
    network's input check then names both sizes)."""
    have = np.shape(obs["node_features"])[-1]
    if have == BASE_NODE_DIM and node_dim == GAIN_NODE_DIM:
        return invariant_features(obs, view) if invariant else add_gain_feature(obs, view)
    return obs


def gain_feature_wrapper(env: Any, invariant: bool = False) -> Any:
    """``env`` (a GraphIPPEnv, possibly wrapped) whose observation carries the look-gain feature (with
    ``invariant`` the inputs of :func:`invariant_features` instead)."""
    import gymnasium as gym
    from gymnasium import spaces

    class GainFeatureWrapper(gym.ObservationWrapper):
        """Appends the look-gain node feature (see :mod:`ipp_bench.policies.features`)."""

        def __init__(self, env: gym.Env) -> None:
            super().__init__(env)
            space = env.observation_space
            n, f = space["node_features"].shape
            self.observation_space = spaces.Dict(
                {**space.spaces, "node_features": spaces.Box(-np.inf, np.inf, (n, f + 1), np.float32)})

        def observation(self, observation: dict) -> dict:
            if invariant:
                return invariant_features(observation, self.env.unwrapped)
            return add_gain_feature(observation, self.env.unwrapped)

        def action_masks(self) -> np.ndarray:
            return self.env.unwrapped.action_masks()

    return GainFeatureWrapper(env)


__all__ = ["BASE_NODE_DIM", "GAIN_NODE_DIM", "INVARIANT_LENGTH_M", "LookGain", "add_gain_feature", "extend_observation",
           "gain_feature_wrapper", "invariant_features"]
