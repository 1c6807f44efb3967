"""``attention``: the trained attention policy of the paper as a roadmap planner.

Loads the checkpoint shipped in the package (``ipp_bench/policies/checkpoints/attention_v5.pt``)
or ``checkpoint=PATH`` (an ``export.pt`` of an ``ipp-bench train`` run), and picks the neighbour
with the highest probability (``sample=true``: draws from the policy instead, seeded per episode).
Needs torch (``pip install "ipp-bench[train]"``); the planner registry imports it lazily. It
lives with the policy code (it is the policy's view as a planner), and the training code validates
a network in training through it (:meth:`AttentionPlanner.from_net`), so that validation and the
leaderboard decide the same way.

A decision is one forward pass of a small network (about 1 ms at 450 nodes): torch's intra-op
threads only add hand-over cost there, and they oversubscribe the CPU when the leaderboard runs
episodes in parallel processes, so the planner sets torch to one thread by default (``threads=0``
leaves torch's setting alone), as ``ipp_bench._threads`` does for BLAS.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..planners.base import GraphPlanner, RobotView, softmax

#: nodes the network attends to by default: all of them up to 30 x 30 (1800), at 128 x 128 (32 768
#: nodes) the 4096 nearest the UAV, a disc of about 64 m radius (benchmarks/RESULTS.md, issue 20)
DEFAULT_CONTEXT_NODES = 4096
MIN_CONTEXT_NODES = 64  # [-] a context smaller than this is hardly more than the k neighbours
CONTEXT_CACHE = 256  # [-] context node sets kept (least recently used dropped), one per current node


@dataclass(frozen=True)
class AttentionConfig:
    """Settings of the attention planner."""

    checkpoint: str = ""  # path of an exported checkpoint (.pt); "" = the shipped one
    sample: bool = False  # draw the action from the policy instead of taking the argmax
    device: str = "cpu"  # torch device of the network
    threads: int = 1  # torch intra-op threads to set; 0 = leave torch's setting alone
    # [-] the network attends to the roadmap's context_nodes nodes nearest the UAV (horizontally);
    # 0 = every node. Roadmaps of at most this many nodes (every task up to 30 x 30: 1800) see all of
    # them, so the decisions there are those of full attention, byte for byte.
    context_nodes: int = DEFAULT_CONTEXT_NODES

    def __post_init__(self) -> None:
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
        if not isinstance(self.threads, int) or self.threads < 0:
            try:
                object.__setattr__(self, "threads", int(self.threads))
            except (TypeError, ValueError):
                raise ValueError(f"attention.threads = {self.threads!r} is invalid: expected an integer >= 0") from None
            if self.threads < 0:
                raise ValueError(f"attention.threads = {self.threads!r} is invalid: expected an integer >= 0")


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

            path = Path(config.checkpoint) if config.checkpoint else SHIPPED_CHECKPOINT
            self.net, self.meta = load_checkpoint(path, device=self.device)
            self._source = config.checkpoint or "(shipped)"
            self._sha256 = hashlib.sha256(path.read_bytes()).hexdigest()
        else:
            self.net, self.meta, self._source, self._sha256 = net, {}, "(network in memory)", ""
        self._checked_shape: tuple | None = None

    def fingerprint(self) -> dict[str, str]:
        """The checkpoint's content hash: a results folder refuses rows of another network."""
        return {"checkpoint_sha256": self._sha256} if self._sha256 else {}

    @classmethod
    def from_net(cls, net, device="cpu", sample: bool = False) -> AttentionPlanner:
        """The planner deciding with ``net`` on ``device``, torch's threads left alone."""
        return cls(AttentionConfig(sample=sample, device=str(device), threads=0), net=net)

    def reset(self, view: RobotView, seed: int) -> None:
        """Refuses (CheckpointError, one line) a checkpoint whose inputs differ from the task's."""
        from .checkpoint import check_feature_dims

        # pe_dim is the task's; the node features are checked on the first observation (_check).
        check_feature_dims(self.net.cfg, self.net.cfg.node_dim, view.config.graph.pe_dim,
                           f"attention checkpoint {self._source}")
        if self.net.cfg.rate_skip and self.net.cfg.skip_teacher == "far":
            view.require_dense_belief(f"attention ({self._source})", "its rate feature is the far teacher's "
                                      "score, whose far targets' look gains read the full covariance")
        super().reset(view, seed)
        self._contexts: OrderedDict[int, np.ndarray] = OrderedDict()  # current node -> its context nodes

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

    def _logits(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        if self.net.cfg.node_dim != np.shape(obs["node_features"])[-1]:
            from .features import extend_observation  # trained with the look-gain (and rate) features

            obs = extend_observation(obs, self.view, self.net.cfg.node_dim, self.net.cfg.skip_teacher,
                                     self.net.cfg.invariant)
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

    def act(self, obs: dict[str, np.ndarray]) -> int:
        logits = self._logits(obs)
        if not self.settings.sample:
            return int(np.argmax(logits))
        return int(self.rng.choice(logits.size, p=softmax(logits)))
