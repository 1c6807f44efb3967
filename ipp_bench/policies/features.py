"""An extra node feature for the attention policy: what one look from each node would gain.

Greedy knows, for each neighbour, the predicted ROI trace reduction of flying there; the five
node features of :class:`~ipp_bench.envs.graph.GraphIPPEnv` (position, belief mean and std over
the footprint) do not say it, and on a 30 x 30 map a network imitating greedy from them alone
matched greedy's choice in 10% of the states. This module adds a sixth feature for every node:

    g_i = 10 * (predicted ROI trace reduction of one read-out taken at node i) / Tr_ROI(P)

with the prediction taken from the marginal variances only, assuming the cells of one read-out
fully correlated (one 8 m read-out is one cell; one 14 m read-out is the mean of a 2 x 2 block,
whose cells lie well within the GP length scale). For read-out j with rows ``w`` of H, noise
variance ``r_j`` and ``s_j = sum_c w_c sqrt(P_cc)``, the reduction is
``s_j^2 / (s_j^2 + r_j) * sum_{c in j, c in ROI} P_cc``, summed over the read-outs of node i.
It is exact for single-cell read-outs of an uncorrelated prior and costs three sparse
matrix-vector products per decision (well under a millisecond at 1800 nodes), where greedy's
exact leg predictions cost 1.6 ms at 450 nodes and 3.9 ms at 1800 nodes. The scale matches the
reward (paper eq. 9: 10 x the relative ROI trace reduction).

A seventh column (:func:`add_rate_feature`, for ``NetConfig.rate_skip`` networks) gives the
network greedy's own exact score of each neighbour, relative to the best one: the approximation
above, used as greedy's score (``benchmarks/bench_teachers.py``, planner ``lookrate``), flies 7-8
points below greedy on 15 x 15, so a network that must rebuild greedy from it starts far below it.

The environment is unchanged: :class:`GainFeatureWrapper` adds the column during training and
the ``attention`` planner adds it from its :class:`~ipp_bench.planners.base.RobotView` when the
checkpoint was trained with it (``NetConfig.node_dim == 6``).
"""

from __future__ import annotations

import weakref
from typing import Any

import numpy as np
from scipy import sparse

from ..belief import error_states
from .network import SKIP_TEACHERS  # the teachers of NetConfig.skip_teacher

BASE_NODE_DIM = 5  # the GraphIPPEnv node features
GAIN_NODE_DIM = BASE_NODE_DIM + 1
RATE_NODE_DIM = GAIN_NODE_DIM + 1  # and greedy's own score of the neighbours (see add_rate_feature)


class LookGain:
    """Per-node look-gain feature of one roadmap and camera (built once, then cheap per call)."""

    def __init__(self, positions: np.ndarray, sensor: Any, n_cells: int) -> None:
        rows, cols, w, noise, white, factor, node_of = [], [], [], [], [], [], []
        j = 0
        for i, p in enumerate(positions):
            obs = sensor.observe(p)
            if obs is None:
                continue
            for r in range(obs.m):
                nz = obs.weights[r] != 0
                cells = obs.cells[nz]
                rows.append(np.full(cells.size, j))
                cols.append(cells)
                w.append(obs.weights[r][nz])
                noise.append(obs.var[r])
                white.append(obs.var[r] - (0.0 if obs.persistent is None else obs.persistent[r]))
                factor.append(obs.factor)
                node_of.append(i)
                j += 1
        rows_a, cols_a = np.concatenate(rows), np.concatenate(cols)
        self.W = sparse.csr_matrix((np.concatenate(w), (rows_a, cols_a)), shape=(j, n_cells))
        self.ind = sparse.csr_matrix((np.ones(rows_a.size), (rows_a, cols_a)), shape=(j, n_cells))
        self.noise = np.asarray(noise, dtype=np.float64)  # one look's whole variance (white + persistent)
        self.white = np.asarray(white, dtype=np.float64)  # its look-to-look part
        self.factor = np.asarray(factor, dtype=np.int64)  # each read-out row's resolution factor
        self.node = sparse.csr_matrix((np.ones(j), (np.asarray(node_of), np.arange(j))), shape=(len(positions), j))

    @classmethod
    def of(cls, source: Any) -> LookGain:
        """The feature of ``source``'s roadmap and camera (a RobotView or an env), built once per roadmap
        and camera: tasks share a roadmap where their maps agree (``Grid15Eval-v1`` and the deployment's
        twin do), not always their camera's constants, so one process that flies both keeps one each."""
        roadmap = source.roadmap
        per_camera = _CACHE.setdefault(roadmap, {})
        key = (source.sensor.cfg, source.config.grid)
        cached = per_camera.get(key)
        if cached is None:
            cached = per_camera[key] = cls(roadmap.positions, source.sensor, source.config.grid.n_cells)
        return cached

    def __call__(self, variance: np.ndarray, roi: np.ndarray, errors: Any = None) -> np.ndarray:
        """(N,) float32: 10 x predicted relative ROI trace reduction of one look from each node.

        ``errors``: the mission's :class:`~ipp_bench.belief.PersistentErrorBelief` where the task models
        the camera's repeated error (:func:`error_states`), else None (white read-out noise, the formula
        of the module docstring). With it, a look at cell c measures y_c = x_c + d_c u_c (d_c u_c the
        persistent error, ``errors.sd``) plus white noise, and the formula reads the augmented state's
        marginals: a read-out j's block is ``S_j = sum_c w_c q_c`` with q_c^2 = Var(y_c), and each ROI
        cell loses ``S_j^2 / (S_j^2 + r_j) * k_c^2 / q_c^2`` with k_c = Cov(x_c, y_c) and r_j the white
        variance. A cell looked at again and again has y_c pinned, so k_c -> 0 and the look gains
        nothing, as the belief's update says; the white formula would keep promising a gain there
        (it treats the repeated error as fresh noise). Exact for single-cell read-outs of an
        uncorrelated belief; the same formula as the white one where d = 0 and the cross term is 0.
        """
        var = np.maximum(np.asarray(variance, dtype=np.float64), 0.0)
        roi_var = np.where(roi, var, 0.0)
        total = roi_var.sum()
        if total <= 0:
            return np.zeros(self.node.shape[0], dtype=np.float32)
        if errors is None:
            s2 = np.square(self.W @ np.sqrt(var))
            red = s2 / (s2 + self.noise) * (self.ind @ roi_var)
        else:
            red = self._error_reductions(var, roi, errors)
        return (10.0 * (self.node @ red) / total).astype(np.float32)

    def _error_reductions(self, var: np.ndarray, roi: np.ndarray, errors: Any) -> np.ndarray:
        """Per read-out row: the predicted ROI trace reduction under the camera-error states."""
        from ..belief import value_scale

        n = var.size
        cells = np.arange(n)
        cov, mean = errors.state.cov, errors.field.mean
        s_block = np.zeros(self.factor.size)
        gain = np.zeros(self.factor.size)
        for f in np.unique(self.factor):
            rows = self.factor == f
            if int(f) in errors.offset:  # y = x + d u: its variance and its covariance with x
                off = errors.offset[int(f)]
                unseen_sd = np.sqrt(errors.variances[int(f)] * value_scale(mean, errors.floor))
                d = np.where(errors.seen, errors.sd[int(f)], unseen_sd)
                cross = cov[cells, cells + off]  # Cov(x_c, u_c)
                k = var + d * cross
                q2 = np.maximum(k + d * cross + d * d * cov[cells + off, cells + off], 0.0)
            else:
                k, q2 = var, var
            ratio = np.divide(k * k, q2, out=np.zeros(n), where=q2 > 0)
            s_block[rows] = (self.W @ np.sqrt(q2))[rows]
            gain[rows] = (self.ind @ np.where(roi, ratio, 0.0))[rows]
        s2 = np.square(s_block)
        r = self.white * value_scale(self.W @ mean, errors.floor)
        return np.divide(s2, s2 + r, out=np.zeros_like(s2), where=s2 + r > 0) * gain


_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


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


def neighbour_rates(view: Any, obs: dict[str, np.ndarray], teacher: str = "greedy") -> np.ndarray:
    """(k,) the teacher's score of each neighbour, divided by the best allowed one: 1 marks the
    teacher's choice, whatever the map's size. ``greedy``: greedy's score (exact predicted ROI trace
    reduction of the leg per second of flight); ``far``: :func:`far_scores`. Masked neighbours and a
    state where nothing gains give 0."""
    from ..planners.greedy import greedy_scores

    if teacher not in SKIP_TEACHERS:
        raise ValueError(f"skip teacher {teacher!r} is invalid: expected one of {', '.join(SKIP_TEACHERS)}")
    mask = np.asarray(obs["action_mask"]).astype(bool).reshape(-1)
    if teacher == "far":
        from ..planners.far import far_scores

        rates = np.where(mask, far_scores(view, obs), 0.0)
    else:
        rates = np.where(mask, greedy_scores(view, int(obs["current_node"][0])), 0.0)
    best = rates.max() if mask.any() else 0.0
    return (rates / best if best > 0 else np.zeros_like(rates)).astype(np.float32)


def add_rate_feature(obs: dict[str, np.ndarray], view: Any, teacher: str = "greedy") -> dict[str, np.ndarray]:
    """``obs`` with the look-gain column and greedy's normalised score appended: (N, 5) -> (N, 7).

    The seventh column holds :func:`neighbour_rates` on the rows of the current node's neighbours and
    0 elsewhere; a network with ``NetConfig.rate_skip`` adds it, times a learned weight, to its
    pointer logits, so that it starts as (a softened) greedy on any map and learns where to deviate.
    Greedy's score costs what a greedy decision costs (1.6 ms at 450 nodes, 5 ms at 1800).

    Args:
        obs: a GraphIPPEnv observation.
        view: the planner's :class:`~ipp_bench.planners.base.RobotView` (an env is wrapped in one).
        teacher: whose score: ``greedy`` or ``far`` (:func:`neighbour_rates`).
    """
    if not hasattr(view, "belief_roi"):
        from ..planners.base import RobotView

        view = RobotView(view.unwrapped)
    out = add_gain_feature(obs, view)
    column = np.zeros((out["node_features"].shape[0], 1), dtype=np.float32)
    column[np.asarray(obs["neighbours"], dtype=np.int64).reshape(-1), 0] = neighbour_rates(view, obs, teacher)
    out["node_features"] = np.concatenate([out["node_features"], column], axis=1)
    return out


def extend_observation(obs: dict[str, np.ndarray], view: Any, node_dim: int,
                       teacher: str = "greedy", invariant: bool = False) -> dict[str, np.ndarray]:
    """``obs`` with the node features a network of ``node_dim`` was trained with (6: the look gain,
    7: and greedy's normalised score; ``invariant``: :func:`invariant_features`); unchanged if it has
    them or if no extension fits (the network's input check then names both sizes)."""
    have = np.shape(obs["node_features"])[-1]
    if invariant and have == BASE_NODE_DIM and node_dim == GAIN_NODE_DIM:
        return invariant_features(obs, view)
    if have == BASE_NODE_DIM and node_dim == GAIN_NODE_DIM:
        return add_gain_feature(obs, view)
    if have == BASE_NODE_DIM and node_dim == RATE_NODE_DIM:
        return add_rate_feature(obs, view, teacher)
    return obs


def gain_feature_wrapper(env: Any, rate: bool = False, teacher: str = "greedy", invariant: bool = False) -> Any:
    """``env`` (a GraphIPPEnv, possibly wrapped) whose observation carries the look-gain feature
    (and with ``rate`` the ``teacher``'s normalised score, :func:`add_rate_feature`; with
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
                {**space.spaces, "node_features": spaces.Box(-np.inf, np.inf, (n, f + 1 + rate), np.float32)})
            self._view = None

        def observation(self, observation: dict) -> dict:
            if invariant:
                return invariant_features(observation, self.env.unwrapped)
            if not rate:
                return add_gain_feature(observation, self.env.unwrapped)
            if self._view is None:
                from ..planners.base import RobotView

                self._view = RobotView(self.env.unwrapped)
            return add_rate_feature(observation, self._view, teacher)

        def action_masks(self) -> np.ndarray:
            return self.env.unwrapped.action_masks()

    return GainFeatureWrapper(env)
