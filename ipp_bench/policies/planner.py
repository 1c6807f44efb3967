"""``attention``: the trained attention policy of the paper as a roadmap planner.

Loads the checkpoint shipped in the package (``ipp_bench/policies/checkpoints/attention_v6.pt``)
or ``checkpoint=PATH`` (an ``export.pt`` of an ``ipp-bench train`` run; ``A.pt+B.pt``: a method over several
networks, which the leaderboard flies one network per episode, :mod:`ipp_bench.policies.networks`), and picks
the neighbour with the highest probability (``sample=true``: draws from the policy instead, seeded per episode;
``samples=K``: flies the first leg of the best of K flights imagined on the belief's covariance,
CAtNIPP's test-time trajectory sampling, see :class:`AttentionConfig`).
Needs torch (``pip install "ipp-bench[train]"``); the planner registry imports it lazily. It
lives with the policy code (it is the policy's view as a planner), and the training code validates
a network in training through it (:meth:`AttentionPlanner.from_net`), so that validation and the
leaderboard decide the same way.

A decision is one forward pass of a small network (about 1 ms at 450 nodes): torch's intra-op
threads only add hand-over cost there, and they oversubscribe the CPU when the leaderboard runs
episodes in parallel processes, so the planner sets torch to one thread by default (``threads=0``
leaves torch's setting alone), as ``ipp_bench.core._threads`` does for BLAS.

One module on purpose (over 400 lines): the planner, its stall guard and its test-time sampling
share the network's view of a decision state.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from ..core._threads import available_cpus
from ..core.belief import downdate_inplace, gain_factor
from ..core.config import TIME_TOL_S
from ..core.gains import LookGain, beats, best_far_target
from ..core.mission import fits_budget
from ..planners.base import GraphPlanner, RobotView, softmax, stacked_leg, without_level

#: nodes the network attends to by default: all of them up to 30 x 30 (1800), at 128 x 128 (32 768
#: nodes) the 4096 nearest the UAV, a disc of about 64 m radius (docs/decisions/ten-hectares.md)
DEFAULT_CONTEXT_NODES = 4096
MIN_CONTEXT_NODES = 64  # [-] a context smaller than this is hardly more than the k neighbours
CONTEXT_CACHE = 256  # [-] context node sets kept (least recently used dropped), one per current node
#: the stall guard's defaults: a belief whose total variance fell by less than 2.7 times its mean cell variance
#: (2.7 cells' worth: 1.2 % of it on 15 x 15, 0.3 % on 30 x 30, 0.016 % on 128 x 128) over 4 decisions has
#: stalled (the network flies back and forth over cells its camera has already pinned, on the deployment
#: and its twin, or over cells it has mapped, late in a hotspot mission); chosen on validation episodes
#: (why these two numbers: docs/decisions/stall-guard.md)
STALL_LEGS = 4
STALL_CELLS = 2.7
MAX_SAMPLES = 256  # [-] imagined trajectories per decision, at most


@dataclass(frozen=True)
class AttentionConfig:
    """Settings of the attention planner."""

    # path of an exported checkpoint (.pt); "" = the shipped one. A.pt+B.pt+...: a method over several trained
    # networks (training seeds), flown by the leaderboard over its episodes (ipp_bench.policies.networks)
    checkpoint: str = ""
    sample: bool = False  # draw the action from the policy instead of taking the argmax
    device: str = "cpu"  # torch device of the network
    threads: int = 1  # torch intra-op threads to set (at most the CPUs this process may run on); 0 = torch's own
    # [-] the network attends to the roadmap's context_nodes nodes nearest the UAV (horizontally);
    # 0 = every node. Roadmaps of at most this many nodes (every task up to 30 x 30: 1800) see all of
    # them, so the decisions there are those of full attention, byte for byte.
    context_nodes: int = DEFAULT_CONTEXT_NODES
    # the stall guard: when the belief's total variance fell by less than stall_cells times its mean cell
    # variance (n_cells x its relative drop: the same on every map size) over the last stall_legs
    # decisions, the planner flies to the node whose one look gains most per second of flight (the
    # network's own look-gain input, Dijkstra on the roadmap's flight times), then hands back to the
    # network; stall_legs = 0: off (the network alone)
    stall_legs: int = STALL_LEGS
    stall_cells: float = STALL_CELLS  # [cells] > 0
    # trajectory sampling at test time (CAtNIPP's, Cao et al. 2023): 0 = off (the network's argmax alone).
    # samples = K >= 2: before each decision the planner imagines K flights of plan_s seconds on a copy of
    # the belief's covariance (the variance does not depend on the values measured; the mean and the ROI
    # stay as they are now), the first taking the network's argmax at every step, the others drawing from
    # its policy, and flies the first leg of the one whose imagined ROI trace reduction is largest (the leg
    # that crosses plan_s counts pro rata). About K x (legs in plan_s) forward passes per decision.
    samples: int = 0
    plan_s: float = 30.0  # [s] flight time each imagined trajectory covers, > 0
    # a flight level kept out of the mission's later part (a hand rule, off by default): from mission time
    # avoid_from_s on, the planner never picks a neighbour at altitude avoid_altitude [m] while another
    # neighbour is affordable (the network, the stall guard and imagined flights alike). 0 = off. For
    # roadmaps of three flight levels, where a network may keep flying the lowest level late in a hotspot
    # mission and lose to the middle one there (docs/decisions/roadmap.md, docs/decisions/training-variants.md).
    avoid_altitude: float = 0.0
    avoid_from_s: float = 0.0  # [s] mission time from which avoid_altitude holds, >= 0

    def __post_init__(self) -> None:
        from .networks import checkpoint_set

        value, paths = checkpoint_set(str(self.checkpoint))
        object.__setattr__(self, "checkpoint", value)
        object.__setattr__(self, "_paths", paths)
        try:
            samples = int(self.samples.strip()) if isinstance(self.samples, str) else self.samples
            plan_s = float(self.plan_s)
        except (TypeError, ValueError):
            samples, plan_s = -1, float("nan")
        if (isinstance(samples, bool) or not isinstance(samples, int) or samples < 0 or samples == 1
                or samples > MAX_SAMPLES):
            raise ValueError(f"attention.samples = {self.samples!r} is invalid: expected 0 (no trajectory sampling) "
                             f"or an integer from 2 to {MAX_SAMPLES}")
        if isinstance(self.plan_s, bool) or not 0.0 < plan_s < float("inf"):
            raise ValueError(f"attention.plan_s = {self.plan_s!r} is invalid: expected a number > 0 [s]")
        object.__setattr__(self, "samples", samples)
        object.__setattr__(self, "plan_s", plan_s)
        for field, low in (("avoid_altitude", "0 (off) or a flight level's altitude > 0 [m]"),
                           ("avoid_from_s", "a mission time >= 0 [s]")):
            raw = getattr(self, field)
            try:
                value = float(raw) if not isinstance(raw, bool) else float("nan")
            except (TypeError, ValueError):
                value = float("nan")
            if not 0.0 <= value < float("inf"):
                raise ValueError(f"attention.{field} = {raw!r} is invalid: expected {low}")
            object.__setattr__(self, field, value)
        try:
            legs = int(self.stall_legs.strip()) if isinstance(self.stall_legs, str) else self.stall_legs
            cells = float(self.stall_cells)
        except (TypeError, ValueError):
            legs, cells = -1, float("nan")
        if isinstance(legs, bool) or not isinstance(legs, int) or legs < 0:
            raise ValueError(f"attention.stall_legs = {self.stall_legs!r} is invalid: expected 0 (no stall guard) "
                             "or an integer >= 1")
        if not 0.0 < cells < float("inf"):
            raise ValueError(f"attention.stall_cells = {self.stall_cells!r} is invalid: expected a number > 0 "
                             "(cells' worth of the belief's mean cell variance)")
        object.__setattr__(self, "stall_legs", legs)
        object.__setattr__(self, "stall_cells", cells)
        raw = self.context_nodes
        try:  # an int, or its text from "attention:context_nodes=512"
            context = int(raw.strip()) if isinstance(raw, str) else (int(raw) if int(raw) == raw else -1)
        except (TypeError, ValueError, OverflowError):
            context = -1
        if isinstance(raw, bool) or context < 0 or 0 < context < MIN_CONTEXT_NODES:
            raise ValueError(f"attention.context_nodes = {self.context_nodes!r} is invalid: expected 0 (every "
                             f"node) or an integer >= {MIN_CONTEXT_NODES}")
        object.__setattr__(self, "context_nodes", context)
        if isinstance(self.sample, str):  # from "attention:sample=true"
            object.__setattr__(self, "sample", self.sample.strip().lower() in ("1", "true", "yes", "on"))
        if self.sample and self.samples:
            raise ValueError(f"attention.sample = true and attention.samples = {self.samples} exclude each other: "
                             "sample draws the flown leg from the policy, samples flies the best imagined trajectory's")
        raw = self.threads
        try:  # an int, or its text from "attention:threads=2"
            threads = int(raw.strip()) if isinstance(raw, str) else (int(raw) if int(raw) == raw else -1)
        except (TypeError, ValueError, OverflowError):
            threads = -1
        cpus = available_cpus()
        if isinstance(raw, bool) or not 0 <= threads <= cpus:
            raise ValueError(f"attention.threads = {raw!r} is invalid: expected 0 (leave torch's setting alone) or "
                             f"an integer from 1 to {cpus} (the CPUs this process may run on)")
        object.__setattr__(self, "threads", threads)


    def members(self) -> tuple[tuple[str, dict[str, str]], ...]:
        """A method over several networks: per network, in order, its name and the settings that fly it alone
        (``{"checkpoint": PATH}``); () for one network."""
        paths = self._paths
        if len(paths) < 2:
            return ()
        named = self.checkpoint.split("+") if "+" in self.checkpoint else [Path(p).name for p in paths]
        return tuple((name, {"checkpoint": path}) for name, path in zip(named, paths))


class _Imagined:
    """What the node-feature functions read of an imagined state: the view's roadmap, camera and task, an
    imagined belief variance, the ROI of the decision (held fixed) and white read-out noise."""

    def __init__(self, view: RobotView, variance: np.ndarray, roi: np.ndarray) -> None:
        self.config, self.roadmap, self.sensor = view.config, view.roadmap, view.sensor
        self.belief = SimpleNamespace(variance=variance)
        self._roi = roi

    def belief_roi(self) -> np.ndarray:
        return self._roi

    def error_states(self) -> None:
        return None


def resolve_device(torch, device: str):
    """``torch.device(device)`` if this machine has it, else ValueError (one line, what is valid)."""
    try:
        dev = torch.device(str(device))
    except (RuntimeError, TypeError, ValueError):
        raise ValueError(f"attention.device = {device!r} is invalid: "
                         "expected 'cpu', 'cuda', 'cuda:N' or 'mps'") from None
    if dev.type == "cpu":
        return dev
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"attention.device = {device!r} is unavailable: torch {torch.__version__} sees no "
                             "CUDA device here; use device=cpu")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ValueError(f"attention.device = {device!r} is unavailable: this machine has "
                             f"{torch.cuda.device_count()} CUDA devices (cuda:0..cuda:{torch.cuda.device_count() - 1})")
        return dev
    if dev.type == "mps":
        if not (getattr(torch.backends, "mps", None) and torch.backends.mps.is_available()):
            raise ValueError(f"attention.device = {device!r} is unavailable: no MPS device here; use device=cpu")
        return dev
    raise ValueError(f"attention.device = {device!r} is invalid: expected 'cpu', 'cuda', 'cuda:N' or 'mps'")


class AttentionPlanner(GraphPlanner):
    """Attention encoder / pointer decoder policy (paper Section IV-B), one forward pass per decision."""

    name = "attention"
    kind = "graph"
    Config = AttentionConfig
    #: the last decision's logits over the k neighbours (-inf: masked, the avoid rule's included); None when
    #: the stall guard decided (or before the first decision)
    policy_logits: np.ndarray | None = None

    def __init__(self, config: AttentionConfig | None = None, net=None, **kwargs: Any):
        """Args: ``config`` (or its fields as keywords); ``net``: decide with this network (e.g.
        one in training, see :meth:`from_net`) instead of loading ``config.checkpoint``."""
        if config is None:
            config = AttentionConfig(**kwargs)
        elif kwargs:
            raise TypeError("pass either an AttentionConfig or keyword settings, not both")
        super().__init__(config)
        try:
            import torch
        except ImportError:
            raise ImportError(
                'the attention planner needs torch: pip install "ipp-bench[train]"') from None
        from .checkpoint import load_checkpoint

        self._torch = torch
        if config.threads:
            torch.set_num_threads(config.threads)
        self.device = resolve_device(torch, config.device)
        if net is None:
            from .checkpoint import SHIPPED_CHECKPOINT

            paths = [Path(p) for p in config._paths] or [SHIPPED_CHECKPOINT]
            loaded = [load_checkpoint(path, device=self.device) for path in paths]  # each refused by name
            self.net, self.meta = loaded[0]
            #: a method's networks (several checkpoints): the leaderboard flies each alone (AttentionConfig.members)
            self.networks = [net for net, _ in loaded]
            self._source = config.checkpoint or "(shipped)"
            self._sha256 = "+".join(hashlib.sha256(path.read_bytes()).hexdigest() for path in paths)
        else:
            self.net, self.meta, self._source, self._sha256 = net, {}, "(network in memory)", ""
            self.networks = [net]
        self._checked_shape: tuple | None = None

    def fingerprint(self) -> dict[str, str]:
        """The checkpoint's content hash (a method's: each network's, in order, joined by ``+``): a results
        folder refuses rows of another network, or of the same networks in another order."""
        return {"checkpoint_sha256": self._sha256} if self._sha256 else {}

    @classmethod
    def from_net(cls, net, device="cpu", sample: bool = False) -> AttentionPlanner:
        """The planner deciding with ``net`` on ``device``, torch's threads left alone."""
        return cls(AttentionConfig(sample=sample, device=str(device), threads=0), net=net)

    def reset(self, view: RobotView, seed: int) -> None:
        """Refuses (CheckpointError, one line) a checkpoint whose inputs differ from the task's."""
        from .checkpoint import check_feature_dims

        if len(self.networks) > 1:
            k = len(self.networks)
            raise ValueError(f"attention.checkpoint = {self.settings.checkpoint} names {k} networks, a method: the "
                             f"leaderboard flies it over its episodes (episode i: network i mod {k}); to fly one "
                             "episode, name one checkpoint")
        # pe_dim is the task's; the node features are checked on the first observation (_check).
        check_feature_dims(self.net.cfg, self.net.cfg.node_dim, view.config.graph.pe_dim,
                           f"attention checkpoint {self._source}")
        if self.settings.samples:
            self._check_sampling(view)
        if self.settings.avoid_altitude:
            levels = np.unique(np.round(view.roadmap.positions[:, 2], 6))
            if not np.isclose(levels, self.settings.avoid_altitude).any():
                named = [float(f"{z:g}") for z in levels]
                raise ValueError(f"attention.avoid_altitude = {self.settings.avoid_altitude:g} is not a flight level "
                                 f"of this task: its roadmap flies at {named} m (or 0: off)")
        super().reset(view, seed)
        self._legs: dict[tuple[int, int], tuple | None] = {}  # (node, action) -> the leg's read-outs, stacked
        self._costs: dict[int, np.ndarray] = {}  # node -> flight times to its neighbours [s]
        self.plans: list[tuple[list[int], float]] = []  # the last decision's imagined (actions, ROI reduction)
        self._contexts: OrderedDict[int, np.ndarray] = OrderedDict()  # current node -> its context nodes
        self._totals: list[float] = []  # the belief's total variance at the last stall_legs + 1 decisions
        self._escape: list[int] = []  # the stall guard's path still to fly, ending at its target ([]: the network)
        self.guard_decisions = 0  # decisions of this episode that the stall guard made
        self.policy_logits = None

    def context(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """``obs`` on the nodes the network attends to: the ``context_nodes`` roadmap nodes nearest the
        current node horizontally (ties by index; the current node and its neighbours always among them),
        their indices remapped; ``obs`` itself if the roadmap has no more nodes than that."""
        n_ctx = self.settings.context_nodes
        n = np.shape(obs["node_features"])[0]
        if not n_ctx or n <= n_ctx:
            return obs
        cur = int(np.asarray(obs["current_node"]).reshape(-1)[0])
        nb = np.asarray(obs["neighbours"], dtype=np.int64).reshape(-1)
        nodes = self._contexts.get(cur)
        if nodes is None:
            pos = self.view.roadmap.positions
            d2 = np.square(pos[:, 0] - pos[cur, 0]) + np.square(pos[:, 1] - pos[cur, 1])
            nodes = np.union1d(np.argsort(d2, kind="stable")[:n_ctx], np.append(nb, cur))
            self._contexts[cur] = nodes
            if len(self._contexts) > CONTEXT_CACHE:
                self._contexts.popitem(last=False)
        else:
            self._contexts.move_to_end(cur)
        out = dict(obs)
        out["node_features"] = np.asarray(obs["node_features"])[nodes]
        out["pos_encoding"] = np.asarray(obs["pos_encoding"])[nodes]
        out["current_node"] = np.searchsorted(nodes, np.asarray(obs["current_node"], dtype=np.int64))
        out["neighbours"] = np.searchsorted(nodes, nb).reshape(np.shape(obs["neighbours"]))
        return out

    def _check(self, obs: dict[str, np.ndarray]) -> None:
        shape = (obs["node_features"].shape[-1], obs["pos_encoding"].shape[-1])
        if shape == self._checked_shape:
            return
        from .checkpoint import check_feature_dims

        check_feature_dims(self.net.cfg, *shape, source=f"attention checkpoint {self._source}")
        self._checked_shape = shape

    def probabilities(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """Policy over the k neighbours (masked neighbours have probability 0)."""
        return softmax(self._logits(obs))

    def _logits(self, obs: dict[str, np.ndarray], source: Any = None) -> np.ndarray:
        """The network's logits over the k neighbours (masked: -inf); ``source``: whose belief the added
        node features read (default: the view's, the live belief)."""
        if self.net.cfg.node_dim != np.shape(obs["node_features"])[-1]:
            from .features import extend_observation  # trained with the look-gain feature

            obs = extend_observation(obs, self.view if source is None else source, self.net.cfg.node_dim,
                                     invariant=self.net.cfg.invariant)
        obs = self.context(obs)
        self._check(obs)
        torch = self._torch
        mask = np.asarray(obs["action_mask"]).astype(bool).reshape(-1)
        if not mask.any():
            raise ValueError("no neighbour is affordable: the episode is over (action_mask is all zero)")
        dev = self.device
        with torch.inference_mode():
            logits, _ = self.net(
                torch.as_tensor(np.asarray(obs["node_features"], dtype=np.float32)).unsqueeze(0).to(dev),
                torch.as_tensor(np.asarray(obs["pos_encoding"], dtype=np.float32)).unsqueeze(0).to(dev),
                torch.as_tensor(np.asarray(obs["current_node"], dtype=np.int64).reshape(1)).to(dev),
                torch.as_tensor(np.asarray(obs["neighbours"], dtype=np.int64)).unsqueeze(0).to(dev),
                torch.as_tensor(mask).unsqueeze(0).to(dev),
                torch.as_tensor(np.asarray(obs["budget"], dtype=np.float32).reshape(1, 1)).to(dev),
            )
        out = logits[0].cpu().numpy().astype(np.float64)
        out[~mask] = -np.inf  # masked neighbours never win, whatever the network says
        return out

    def _avoid(self, mask: np.ndarray, neighbours: np.ndarray, time_s: float) -> np.ndarray:
        """``mask`` without the neighbours at ``avoid_altitude`` once ``time_s`` reached ``avoid_from_s``
        (``mask`` itself before then, when the rule is off, or when nothing else would be left)."""
        z, start = self.settings.avoid_altitude, self.settings.avoid_from_s
        if not z or time_s < start - TIME_TOL_S:
            return mask
        return without_level(mask, self.view.roadmap.positions[np.asarray(neighbours).reshape(-1), 2], z)

    def act(self, obs: dict[str, np.ndarray]) -> int:
        if self.settings.avoid_altitude:
            mask = np.asarray(obs["action_mask"])
            kept = self._avoid(mask.astype(bool).reshape(-1), obs["neighbours"], self.view.time_s)
            obs = dict(obs) | {"action_mask": kept.astype(mask.dtype).reshape(mask.shape)}
        self.policy_logits = None
        guard = self._stall_guard(obs)
        if guard >= 0:
            self.guard_decisions += 1
            return guard
        logits = self._logits(obs)
        self.policy_logits = logits  # the policy this decision drew on (a distilling warm start's target)
        if self.settings.samples:
            return self._best_imagined(obs, logits)
        if not self.settings.sample:
            return int(np.argmax(logits))
        return int(self.rng.choice(logits.size, p=softmax(logits)))

    # -- trajectory sampling (AttentionConfig.samples) --------------------------------------------------
    def _check_sampling(self, view: RobotView) -> None:
        """Refuse, in one line at reset, what trajectory sampling cannot imagine."""
        view.require_dense_belief("attention:samples", "its imagined flights copy and downdate the full covariance")
        if view.error_states() is not None:
            raise ValueError("attention.samples cannot run on a task whose camera repeats its error (the deployment "
                             "and its twin): the imagined flights would need the camera-error states too; "
                             "use samples=0")

    def _leg(self, node: int, action: int):
        """The read-outs of the leg from ``node`` to its neighbour ``action``, stacked (None: it sees nothing)."""
        if (node, action) not in self._legs:
            self._legs[node, action] = stacked_leg(self.view, node, action)
        return self._legs[node, action]

    def _node_costs(self, node: int) -> np.ndarray:
        costs = self._costs.get(node)
        if costs is None:
            costs = self._costs[node] = self.view.neighbour_durations(node)
        return costs

    def imagined_state(self, obs: dict[str, np.ndarray], node: int, variance: np.ndarray, remaining_s: float,
                       roi: np.ndarray) -> tuple[dict[str, np.ndarray], Any]:
        """(observation, feature source) of an imagined state: the UAV at ``node`` with ``remaining_s`` of
        budget and the belief variance ``variance``; the belief's mean (the footprint-mean column of ``obs``,
        the environment's observation now) and the ROI ``roi`` held as they are now."""
        from .features import BASE_NODE_DIM

        view = self.view
        base = np.asarray(obs["node_features"], dtype=np.float32)
        if base.shape[-1] != BASE_NODE_DIM:
            raise ValueError(f"attention.samples needs the environment's own observation ({BASE_NODE_DIM} node "
                             f"features), not one with {base.shape[-1]}")
        feats = base.copy()
        feats[:, 4] = view.node_footprint() @ np.sqrt(variance)
        mask = self._avoid(fits_budget(self._node_costs(node), remaining_s), view.roadmap.neighbours[node],
                           view.config.mission.budget_s - remaining_s)
        imagined = dict(obs) | {
            "node_features": feats, "current_node": np.array([node], dtype=np.int64),
            "neighbours": view.roadmap.neighbours[node].copy(), "action_mask": mask.astype(np.int8),
            "budget": np.array([max(remaining_s, 0.0) / view.config.mission.budget_s], dtype=np.float32)}
        return imagined, _Imagined(view, variance, roi)

    def _best_imagined(self, obs: dict[str, np.ndarray], logits: np.ndarray) -> int:
        """The first leg of the imagined trajectory with the largest ROI trace reduction (ties: the earlier
        trajectory, the argmax one first); the trajectories are kept in :attr:`plans`."""
        view, cfg = self.view, self.settings
        rm = view.roadmap
        roi = view.belief_roi()
        cur = int(np.asarray(obs["current_node"]).reshape(-1)[0])
        costs0 = view.neighbour_durations(cur, view.position)
        self.plans = []
        best, best_red = -1, -np.inf
        for j in range(cfg.samples):
            cov = view.belief.cov.copy()
            node, remaining, elapsed, reduction = cur, view.remaining_s, 0.0, 0.0
            costs, lg, path = costs0, logits, []
            while True:
                a = int(np.argmax(lg)) if j == 0 else int(self.rng.choice(lg.size, p=softmax(lg)))
                path.append(a)
                cost = float(costs[a])
                leg = self._leg(node, a)
                gain = 0.0
                if leg is not None:
                    A = gain_factor(cov, *leg)[0]
                    gain = float(np.square(A[roi]).sum())
                    downdate_inplace(cov, A)
                reduction += min(1.0, (cfg.plan_s - elapsed) / cost) * gain
                elapsed, remaining, node = elapsed + cost, remaining - cost, int(rm.neighbours[node, a])
                if elapsed >= cfg.plan_s - TIME_TOL_S:
                    break
                costs = self._node_costs(node)
                imagined, source = self.imagined_state(obs, node, np.maximum(cov.diagonal(), 0.0), remaining, roi)
                if not imagined["action_mask"].any():
                    break
                lg = self._logits(imagined, source)
            self.plans.append((path, reduction))
            if beats(reduction, best_red):
                best, best_red = path[0], reduction
        return best

    def _stall_guard(self, obs: dict[str, np.ndarray]) -> int:
        """The stall guard's neighbour, or -1 when the network decides (see ``AttentionConfig.stall_legs``).

        A camera that repeats its error (the deployment, its twin) pins the cells it has seen: another
        look there changes nothing, and a network trained where every look still helps can then fly back
        and forth between two such nodes until the budget is spent (``docs/decisions/stall-guard.md``). The guard
        sees it in the belief (its total variance stopped falling) and flies the quickest roadmap path to
        the node whose one look gains most per second of flight (the network's look-gain input over the
        flight time, :func:`~ipp_bench.core.gains.best_far_target`), then resets its window and hands back to
        the network.
        """
        legs = self.settings.stall_legs
        if not legs:
            return -1
        view = self.view
        cur = int(np.asarray(obs["current_node"]).reshape(-1)[0])
        mask = np.asarray(obs["action_mask"]).astype(bool).reshape(-1)
        if self._escape:  # on the way: the next node of the path, while its leg is affordable
            if self._escape[0] == cur:
                self._escape.pop(0)
            if not self._escape:  # arrived: the network again, with a fresh window
                self._totals = []
            else:
                hit = np.flatnonzero(view.roadmap.neighbours[cur] == self._escape[0])
                if hit.size and mask[hit[0]]:
                    return int(hit[0])
                self._escape = []
        self._totals.append(float(view.belief.variance.sum()))
        del self._totals[:-(legs + 1)]
        n = view.config.grid.n_cells
        stalled = self._totals[0] - self._totals[-1] < self.settings.stall_cells * self._totals[0] / n
        if not (len(self._totals) > legs and stalled):
            return -1
        gains = LookGain.of(view)(view.belief.variance, view.belief_roi(), view.error_states())
        rate, action, path = best_far_target(view, obs, np.arange(view.roadmap.n_nodes),
                                             lambda t, ok: np.where(ok, gains / np.where(ok, t, 1.0), -np.inf),
                                             with_path=True)
        if action < 0 or not rate > 0 or not mask[action]:  # nothing worth a flight: the network decides
            return -1
        self._escape = path
        return action
