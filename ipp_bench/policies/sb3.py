"""The attention network as a stable-baselines3 policy: ``MaskablePPO(AttentionPolicy, env)``.

Built on SB3's extension points, without forking any of its code:

- features extractor (:class:`AttentionExtractor`): the encoder; its features are the encodings of
  the current node and its k neighbours, flattened, with the action mask appended;
- ``mlp_extractor`` (:class:`AttentionDecoderExtractor`, set in ``_build_mlp_extractor``): the
  current -> neighbours attention; ``latent_vf`` is the context, ``latent_pi`` the context with the
  neighbour encodings and the mask;
- ``value_net``: SB3's own ``Linear(d, 1)`` on the context;
- ``action_net``: replaced after ``_build`` by the pointer head (:class:`PointerActionNet`), after
  which the optimizer is rebuilt (SB3 creates it last, over the old ``action_net``).

The positional encoding is a constant of the roadmap (``GraphIPPEnv`` hands the same (N, P) array
in every observation). Training passes it once as ``policy_kwargs["pos_encoding"]`` and drops it
from the observations (:class:`~ipp_bench.train.vec.DropPosEncoding`): the features extractor
keeps it as a buffer and attaches it to every batch, so the rollout buffer does not store it per
step (at 1800 nodes 230 kB of the 275 kB an observation takes) and worker processes do not send
it. The policy saves it with its constructor arguments; without it, the observation must carry it.

``policy.attention_net()`` returns a plain :class:`~ipp_bench.policies.network.AttentionNet` that
shares these modules, which is what the shipped checkpoint stores.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.type_aliases import Schedule
from torch import nn

from ipp_bench.policies.checkpoint import check_feature_dims
from ipp_bench.policies.network import (
    MASKED_LOGIT,
    AttentionEncoder,
    AttentionNet,
    ContextDecoder,
    NetConfig,
    PointerHead,
    obs_to_inputs,
)

OBS_KEYS = ("node_features", "pos_encoding", "current_node", "neighbours", "action_mask", "budget")


def _as_pos_encoding(pos_encoding: Any) -> torch.Tensor | None:
    """``policy_kwargs["pos_encoding"]`` (array-like (N, P) or None) as a float32 tensor."""
    if pos_encoding is None:
        return None
    pe = torch.tensor(np.array(pos_encoding, dtype=np.float32))
    if pe.dim() != 2:
        raise ValueError(f"pos_encoding must be the roadmap's (N, P) array; got shape {tuple(pe.shape)}")
    return pe


def _check_obs_space(observation_space: spaces.Space, cfg: NetConfig, pos_encoding: torch.Tensor | None = None) -> int:
    """Validate the Dict observation space (``pos_encoding`` may come from the policy); return k."""
    if not isinstance(observation_space, spaces.Dict):
        raise TypeError(
            f"AttentionPolicy needs the Dict observation of GraphIPPEnv (keys {OBS_KEYS}); "
            f"got {type(observation_space).__name__}"
        )
    needed = OBS_KEYS if pos_encoding is None else tuple(k for k in OBS_KEYS if k != "pos_encoding")
    missing = [key for key in needed if key not in observation_space.spaces]
    if missing:
        raise ValueError(f"observation space lacks {missing}; AttentionPolicy needs the keys {needed}"
                         + ("" if pos_encoding is not None else " (or pos_encoding in policy_kwargs)"))
    n_nodes, n_feat = observation_space["node_features"].shape
    if pos_encoding is None:
        pe_dim = observation_space["pos_encoding"].shape[-1]
    else:
        if pos_encoding.shape[0] != n_nodes:
            raise ValueError(f"policy_kwargs pos_encoding has {pos_encoding.shape[0]} rows, the observation "
                             f"{n_nodes} nodes: it must be the roadmap of the training task")
        pe_dim = pos_encoding.shape[1]
    check_feature_dims(cfg, n_feat, pe_dim, source="AttentionPolicy")
    return int(observation_space["neighbours"].shape[0])


class AttentionExtractor(BaseFeaturesExtractor):
    """Encoder as an SB3 features extractor: (B, (1 + k) d + k) = [h_current, h_neighbours, mask]."""

    def __init__(self, observation_space: spaces.Dict, net_config: dict[str, Any] | None = None,
                 pos_encoding: Any = None) -> None:
        cfg = NetConfig.from_dict(net_config or {})
        pe = _as_pos_encoding(pos_encoding)
        k = _check_obs_space(observation_space, cfg, pe)
        super().__init__(observation_space, features_dim=(1 + k) * cfg.embed_dim + k)
        self.cfg, self.k = cfg, k
        self.encoder = AttentionEncoder(cfg)
        # Not in the state dict: the policy's constructor arguments carry it (and checkpoints stay as they are).
        self.register_buffer("pos_encoding", pe, persistent=False)

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        if "pos_encoding" not in observations:  # the roadmap's constant, attached without a copy
            b = observations["node_features"].shape[0]
            observations = {**observations, "pos_encoding": self.pos_encoding.expand(b, *self.pos_encoding.shape)}
        nf, pe, cur, nb, mask, budget = obs_to_inputs(observations)
        enc = self.encoder(nf, pe, cur, nb, budget)  # (B, 1 + k, d)
        return torch.cat([enc.flatten(1), mask.to(enc.dtype)], dim=1)


def _split_features(features: torch.Tensor, k: int, d: int):
    """[h_current, h_neighbours, mask] -> (h_cur, h_nb, mask)."""
    enc = features[:, : (1 + k) * d].reshape(-1, 1 + k, d)
    mask = features[:, (1 + k) * d : (1 + k) * d + k] > 0.5
    return enc[:, 0], enc[:, 1:], mask


class AttentionDecoderExtractor(nn.Module):
    """The context decoder in the place of SB3's ``MlpExtractor``."""

    def __init__(self, cfg: NetConfig, k: int) -> None:
        super().__init__()
        self.cfg, self.k = cfg, k
        self.decoder = ContextDecoder(cfg)
        self.latent_dim_vf = cfg.embed_dim
        self.latent_dim_pi = (1 + k) * cfg.embed_dim + k  # [context, h_nb, mask]

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h_cur, h_nb, mask = _split_features(features, self.k, self.cfg.embed_dim)
        ctx = self.decoder(h_cur, h_nb, mask)
        latent_pi = torch.cat([ctx, h_nb.flatten(1), mask.to(ctx.dtype)], dim=1)
        return latent_pi, ctx

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return self(features)[0]

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        return self(features)[1]


class PointerActionNet(nn.Module):
    """Pointer head in the place of SB3's ``action_net``: latent_pi -> k logits."""

    def __init__(self, cfg: NetConfig, k: int) -> None:
        super().__init__()
        self.cfg, self.k = cfg, k
        self.pointer = PointerHead(cfg)

    def forward(self, latent_pi: torch.Tensor) -> torch.Tensor:
        ctx, h_nb, mask = _split_features(latent_pi, self.k, self.cfg.embed_dim)
        return self.pointer(ctx, h_nb, mask, masked_value=MASKED_LOGIT)


class AttentionPolicy(MaskableActorCriticPolicy):
    """Attention encoder / pointer decoder policy for ``MaskablePPO`` on ``GraphIPPEnv``.

    Args:
        observation_space: the env's Dict observation space.
        action_space: ``Discrete(k)``.
        lr_schedule: SB3 learning-rate schedule.
        net_config: :class:`NetConfig` fields (``embed_dim``, ``n_heads``, ...) as a dict.
        pos_encoding: the roadmap's (N, P) positional encoding, for observations without one.
        **kwargs: passed to ``MaskableActorCriticPolicy`` (``optimizer_kwargs``, ...).
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        net_config: dict[str, Any] | None = None,
        pos_encoding: Any = None,
        **kwargs: Any,
    ) -> None:
        self.net_config = NetConfig.from_dict(net_config or {}).to_dict()
        pe = _as_pos_encoding(pos_encoding)
        self.pos_encoding = None if pe is None else pe.numpy()
        k = _check_obs_space(observation_space, NetConfig.from_dict(self.net_config), pe)
        if not isinstance(action_space, spaces.Discrete) or int(action_space.n) != k:
            raise ValueError(f"AttentionPolicy needs action space Discrete({k}) (one action per neighbour); "
                             f"got {action_space}")
        kwargs.setdefault("ortho_init", False)  # PyTorch's default init suits attention layers better
        kwargs["features_extractor_class"] = AttentionExtractor
        kwargs["features_extractor_kwargs"] = {"net_config": self.net_config, "pos_encoding": self.pos_encoding}
        kwargs.setdefault("share_features_extractor", True)
        if not kwargs["share_features_extractor"]:
            raise ValueError("AttentionPolicy shares its encoder between actor and critic "
                             "(share_features_extractor=True)")
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = AttentionDecoderExtractor(self.features_extractor.cfg, self.features_extractor.k)

    def _build(self, lr_schedule: Schedule) -> None:
        super()._build(lr_schedule)
        self.action_net = PointerActionNet(self.features_extractor.cfg, self.features_extractor.k)
        # SB3 built the optimizer over the old action_net: rebuild it over the current parameters.
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.pop("features_extractor_class", None)
        data.pop("features_extractor_kwargs", None)
        data["net_config"] = self.net_config
        data["pos_encoding"] = self.pos_encoding
        return data

    def attention_net(self) -> AttentionNet:
        """A plain AttentionNet sharing this policy's modules (for export and the planner)."""
        return AttentionNet(
            NetConfig.from_dict(self.net_config),
            encoder=self.features_extractor.encoder,
            decoder=self.mlp_extractor.decoder,
            pointer=self.action_net.pointer,
            value_head=self.value_net,
        )
