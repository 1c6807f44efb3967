"""The attention network of the paper (Section IV-B): encoder, context decoder, pointer head.

Pure torch, no stable-baselines3: the `attention` planner runs this module alone, and
:mod:`ipp_bench.policies.sb3` wraps the same sub-modules as an SB3 policy.

Shapes (B = batch, N = nodes, F = node features, P = positional-encoding size, k = neighbours,
d = embedding size):

- ``node_features`` (B, N, F): x, y, z (min-max normalised), belief mean and std per footprint
- ``pos_encoding`` (B, N, P): Laplacian eigenvectors
- ``current`` (B,) long, ``neighbours`` (B, k) long, ``mask`` (B, k) bool (True = allowed)
- ``budget`` (B, 1): remaining fraction of the budget

Architecture:

- Embedding: ``h_i = W^L v_i + W^PE lambda_i`` for every node; the current node uses its own map
  ``W^D [v_c, budget]`` instead of ``W^L`` (the budget enters through the current node, which is the
  agent's state s_c).
- Encoder: one Transformer layer (multi-head self-attention over all N nodes, feed-forward with
  ReLU, residuals and post-layer-norm as in Vaswani et al.).
- Decoder: an attention layer from the current node to its neighbours gives the context; a linear
  map of the context is the state value; a single-head pointer attention from the context to the
  neighbours gives one logit per neighbour, ``10 tanh(q.k / sqrt(d))``; masked neighbours get
  ``-inf`` (zero probability).

Exact shortcuts (tested against :meth:`AttentionEncoder.encode_all`, the plain full layer):

- with one encoder layer the decoder reads the encoder output of only the current node and its k
  neighbours, so queries, attention and feed-forward are computed for those ``1 + k`` nodes only;
  keys and values still come from all N nodes;
- with post-norm, keys and values are linear in each node's raw inputs ``[v_i, lambda_i]``
  (F + P = 37 numbers), so the scores are ``(W^K^T q)`` mapped back to the input space dotted
  with the inputs, and the attention-weighted sum is taken over the inputs before ``W^V``: no
  (N, d) tensor is ever formed. This makes training about twice as fast on a CPU and keeps a
  450-node decision near 1 ms.

Nothing here depends on N, the grid size or k: the same weights run on any roadmap.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from .attention import input_attention

NEG_INF = float("-inf")
MASKED_LOGIT = -1e8  # finite stand-in for -inf where SB3 needs finite logits (as MaskableCategorical)


@dataclass(frozen=True)
class NetConfig:
    """Sizes of the attention network (CAtNIPP / paper values as defaults)."""

    node_dim: int = 5  # [-] node features: x, y, z, mean, std
    pe_dim: int = 32  # [-] Laplacian eigenvectors
    embed_dim: int = 128  # [-] d
    n_heads: int = 4  # [-] heads of the encoder and decoder attention
    ff_dim: int = 512  # [-] hidden width of the feed-forward sublayers
    tanh_clip: float = 10.0  # [-] C in C tanh(u) of the pointer logits
    invariant: bool = False  # node features that mean the same on every map (features.invariant_features)

    def __post_init__(self) -> None:
        for name in ("node_dim", "pe_dim", "embed_dim", "n_heads", "ff_dim"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ValueError(f"NetConfig.{name} = {v!r} is invalid: expected an integer >= 1")
        if self.embed_dim % self.n_heads:
            raise ValueError(
                f"NetConfig.embed_dim = {self.embed_dim} is invalid: expected a multiple of "
                f"n_heads = {self.n_heads}"
            )
        if not isinstance(self.invariant, bool):
            raise ValueError(f"NetConfig.invariant = {self.invariant!r} is invalid: expected true or false")
        if self.invariant and self.node_dim != 6:
            raise ValueError(f"NetConfig.invariant needs node_dim = 6 (x, y, z, mean, std, look gain): "
                             f"node_dim = {self.node_dim}")
        if not self.tanh_clip > 0:
            raise ValueError(f"NetConfig.tanh_clip = {self.tanh_clip!r} is invalid: expected > 0")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> NetConfig:
        """The config of ``d`` (a checkpoint's ``net_config``). The keys of :data:`INERT_FIELDS` are
        accepted at their value there (they change nothing) and refused, in one line, at any other."""
        d = dict(d)
        for name, inert in INERT_FIELDS.items():
            if name in d:
                value = d.pop(name)
                if value != inert:
                    raise ValueError(f"NetConfig.{name} = {value!r} is not supported: ipp-bench's network "
                                     f"{INERT_FIELDS_WHY}; expected {name} = {inert!r} or no {name}")
        known = {f for f in cls.__dataclass_fields__}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown NetConfig fields {sorted(unknown)}; expected a subset of {sorted(known)}")
        return cls(**d)


#: ``net_config`` keys a checkpoint may carry at these values, which change nothing: a network that adds
#: greedy's score of each neighbour to its pointer logits (``rate_skip``), with its initial weight and its
#: teacher, is not part of the suite
INERT_FIELDS: dict[str, Any] = {"rate_skip": False, "rate_skip_init": 20.0, "skip_teacher": "greedy"}
INERT_FIELDS_WHY = "reads no planner's score as an input (rate_skip, rate_skip_init, skip_teacher)"


def _split_heads(x: torch.Tensor, n_heads: int) -> torch.Tensor:
    b, n, d = x.shape
    return x.view(b, n, n_heads, d // n_heads).transpose(1, 2)  # (B, H, n, d/H)


def _onehot(index: torch.Tensor, n: int, dtype: torch.dtype) -> torch.Tensor:
    """(B,) indices -> (B, n, 1) one-hot column, to add a per-sample row update out of place."""
    return F.one_hot(index.view(-1), n).to(dtype).unsqueeze(-1)


def _merge_heads(x: torch.Tensor) -> torch.Tensor:
    b, h, n, dh = x.shape
    return x.transpose(1, 2).reshape(b, n, h * dh)


class AttentionLayer(nn.Module):
    """Transformer layer: multi-head attention then ReLU feed-forward, residuals, post-layer-norm.

    ``forward(q, k, v)`` takes already projected keys and values of shape (B, H, n_kv, d/H) so that
    the encoder can fold the projections into the node embedding; :meth:`project_kv` gives them
    from raw features.
    """

    def __init__(self, embed_dim: int, n_heads: int, ff_dim: int) -> None:
        super().__init__()
        self.n_heads = n_heads
        self.w_q = nn.Linear(embed_dim, embed_dim, bias=False)
        self.w_kv = nn.Linear(embed_dim, 2 * embed_dim, bias=False)
        self.w_o = nn.Linear(embed_dim, embed_dim)
        self.norm1 = nn.LayerNorm(embed_dim)
        self.ff = nn.Sequential(nn.Linear(embed_dim, ff_dim), nn.ReLU(), nn.Linear(ff_dim, embed_dim))
        self.norm2 = nn.LayerNorm(embed_dim)

    def project_kv(self, h_kv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        k, v = self.w_kv(h_kv).chunk(2, dim=-1)
        return _split_heads(k, self.n_heads), _split_heads(v, self.n_heads)

    def forward(
        self,
        h_q: torch.Tensor,
        k: torch.Tensor,
        v: torch.Tensor,
        attn_mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Args: h_q (B, n_q, d); k, v (B, H, n_kv, d/H); attn_mask (B, n_kv) bool, True = attend."""
        q = _split_heads(self.w_q(h_q), self.n_heads)
        mask = None if attn_mask is None else attn_mask[:, None, None, :]
        a = F.scaled_dot_product_attention(q, k, v, attn_mask=mask)
        h = self.norm1(h_q + self.w_o(_merge_heads(a)))
        return self.norm2(h + self.ff(h))


class AttentionEncoder(nn.Module):
    """Node embedding + one self-attention layer; returns the encodings of [current, neighbours]."""

    def __init__(self, cfg: NetConfig) -> None:
        super().__init__()
        self.cfg = cfg
        d = cfg.embed_dim
        self.w_l = nn.Linear(cfg.node_dim, d)  # W^L, every node
        self.w_d = nn.Linear(cfg.node_dim + 1, d)  # W^D, current node: its features and the budget
        self.w_pe = nn.Linear(cfg.pe_dim, d)  # W^PE
        self.layer = AttentionLayer(d, cfg.n_heads, cfg.ff_dim)

    def embed(
        self, node_features: torch.Tensor, pos_encoding: torch.Tensor, current: torch.Tensor, budget: torch.Tensor
    ) -> torch.Tensor:
        """Node embeddings h^n (B, N, d) with the current node's row from W^D."""
        h = self.w_l(node_features) + self.w_pe(pos_encoding)
        return h + _onehot(current, h.shape[1], h.dtype) * self._current_delta(node_features, current, budget)

    def _current_delta(self, node_features: torch.Tensor, current: torch.Tensor, budget: torch.Tensor) -> torch.Tensor:
        """(W^D [v_c, budget] + b^D) - (W^L v_c + b^L), shape (B, 1, d)."""
        b = node_features.shape[0]
        x_c = node_features.gather(1, current.view(b, 1, 1).expand(b, 1, node_features.shape[2]))
        return self.w_d(torch.cat([x_c, budget.view(b, 1, 1).to(x_c.dtype)], dim=-1)) - self.w_l(x_c)

    def forward(
        self,
        node_features: torch.Tensor,
        pos_encoding: torch.Tensor,
        current: torch.Tensor,
        neighbours: torch.Tensor,
        budget: torch.Tensor,
    ) -> torch.Tensor:
        """Encoder output of the current node and its neighbours, (B, 1 + k, d)."""
        b, n, f = node_features.shape
        lay = self.layer
        heads = lay.n_heads
        d = self.cfg.embed_dim
        dh = d // heads
        delta = self._current_delta(node_features, current, budget)  # (B, 1, d)
        # Queries: embeddings of [current, neighbours] only.
        idx = torch.cat([current.view(b, 1), neighbours], dim=1)  # (B, Q), Q = 1 + k
        nq = idx.shape[1]
        x_q = node_features.gather(1, idx.unsqueeze(-1).expand(-1, -1, f))
        pe_q = pos_encoding.gather(1, idx.unsqueeze(-1).expand(-1, -1, pos_encoding.shape[2]))
        is_cur = (idx == current.view(b, 1)).unsqueeze(-1).to(x_q.dtype)  # a neighbour may be the current node
        h_q = self.w_l(x_q) + self.w_pe(pe_q) + is_cur * delta  # (B, Q, d)
        # Attention over all N nodes in the input space: with h_i = W^L x_i + W^PE pe_i + b (+ delta on
        # the current node), q.(W^K h_i) = (W^K^T q).h_i and sum_i a_i W^V h_i = W^V sum_i a_i h_i, so
        # scores and the weighted sum need only the F + P inputs of each node, never (N, d) tensors.
        # (The bias adds the same to every score of a query: softmax ignores it.)
        q = lay.w_q(h_q).view(b, nq, heads, dh)
        w_k = lay.w_kv.weight[:d].view(heads, dh, d)
        w_v = lay.w_kv.weight[d:].view(heads, dh, d)
        qk = torch.einsum("bqhe,hed->bqhd", q, w_k).reshape(b, nq * heads, d)  # W^K^T q per head
        w_in = torch.cat([self.w_l.weight, self.w_pe.weight], dim=1)  # (d, F + P)
        # One more input column, the current node's indicator, carries its own input map: its score gains
        # (W^K^T q).delta and the weighted sum gains a_current delta. Keys and values are then the same
        # (B, N, F + P + 1) inputs, so the attention is one fused kernel that never forms the (B, QH, N) scores.
        x = torch.cat([node_features, pos_encoding, _onehot(current, n, node_features.dtype)], dim=-1)
        q_in = torch.cat([qk @ w_in, qk @ delta.transpose(1, 2)], dim=-1)  # (B, QH, F + P + 1)
        a = input_attention(q_in, x, 1.0 / math.sqrt(dh))  # (B, QH, F + P + 1)
        agg = a[..., :-1] @ w_in.T + (self.w_l.bias + self.w_pe.bias) + a[..., -1:] * delta
        out = torch.einsum("bqhd,hed->bqhe", agg.view(b, nq, heads, d), w_v).reshape(b, nq, d)
        h = lay.norm1(h_q + lay.w_o(out))
        return lay.norm2(h + lay.ff(h))

    def encode_all(
        self, node_features: torch.Tensor, pos_encoding: torch.Tensor, current: torch.Tensor, budget: torch.Tensor
    ) -> torch.Tensor:
        """Reference path: the full encoder layer over all N nodes, (B, N, d). Used by tests."""
        h = self.embed(node_features, pos_encoding, current, budget)
        k, v = self.layer.project_kv(h)
        return self.layer(h, k, v)


class ContextDecoder(nn.Module):
    """Attention from the current node to its neighbours: the context vector (B, d)."""

    def __init__(self, cfg: NetConfig) -> None:
        super().__init__()
        self.layer = AttentionLayer(cfg.embed_dim, cfg.n_heads, cfg.ff_dim)

    def forward(self, h_cur: torch.Tensor, h_nb: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        k, v = self.layer.project_kv(h_nb)
        # A row with no allowed neighbour (terminal states only) attends to all, to stay finite.
        att = mask | ~mask.any(dim=1, keepdim=True)
        return self.layer(h_cur.unsqueeze(1), k, v, attn_mask=att).squeeze(1)


class PointerHead(nn.Module):
    """Single-head pointer attention: one logit per neighbour, C tanh(q.k / sqrt(d))."""

    def __init__(self, cfg: NetConfig) -> None:
        super().__init__()
        self.w_q = nn.Linear(cfg.embed_dim, cfg.embed_dim, bias=False)
        self.w_k = nn.Linear(cfg.embed_dim, cfg.embed_dim, bias=False)
        self.clip = cfg.tanh_clip
        self.scale = 1.0 / math.sqrt(cfg.embed_dim)

    def forward(
        self, context: torch.Tensor, h_nb: torch.Tensor, mask: torch.Tensor, masked_value: float = NEG_INF,
    ) -> torch.Tensor:
        """Logits (B, k); masked neighbours get ``masked_value``."""
        q = self.w_q(context).unsqueeze(1)  # (B, 1, d)
        k = self.w_k(h_nb)  # (B, k, d)
        u = (q * k).sum(-1) * self.scale
        logits = self.clip * torch.tanh(u)
        return logits.masked_fill(~mask, masked_value)


class AttentionNet(nn.Module):
    """The whole network: ``forward(...) -> (logits (B, k), value (B,))``."""

    def __init__(
        self,
        cfg: NetConfig | None = None,
        *,
        encoder: AttentionEncoder | None = None,
        decoder: ContextDecoder | None = None,
        pointer: PointerHead | None = None,
        value_head: nn.Linear | None = None,
    ) -> None:
        super().__init__()
        self.cfg = cfg or NetConfig()
        self.encoder = encoder or AttentionEncoder(self.cfg)
        self.decoder = decoder or ContextDecoder(self.cfg)
        self.pointer = pointer or PointerHead(self.cfg)
        self.value_head = value_head or nn.Linear(self.cfg.embed_dim, 1)

    def forward(
        self,
        node_features: torch.Tensor,
        pos_encoding: torch.Tensor,
        current: torch.Tensor,
        neighbours: torch.Tensor,
        mask: torch.Tensor,
        budget: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        enc = self.encoder(node_features, pos_encoding, current, neighbours, budget)
        ctx = self.decoder(enc[:, 0], enc[:, 1:], mask)
        return self.pointer(ctx, enc[:, 1:], mask), self.value_head(ctx).squeeze(-1)

    def forward_obs(self, obs: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """Same as forward, from a batched observation dict of tensors (any numeric dtype)."""
        return self(*obs_to_inputs(obs))


def obs_to_inputs(obs: dict[str, Any]) -> tuple[torch.Tensor, ...]:
    """Batched env observation (dict of tensors) -> the AttentionNet input tuple.

    Accepts integer or float tensors for the index entries (SB3 hands everything over as float).
    """
    nf = obs["node_features"].float()
    pe = obs["pos_encoding"].float()
    cur = obs["current_node"].reshape(-1).round().long()
    nb = obs["neighbours"].round().long()
    mask = obs["action_mask"] > 0.5
    budget = obs["budget"].float().reshape(-1, 1)
    return nf, pe, cur, nb, mask, budget


#: the most networks one ensemble checkpoint may hold
MAX_MEMBERS = 16


class AttentionEnsemble(nn.Module):
    """Several :class:`AttentionNet` of one :class:`NetConfig` deciding together, for a teacher or a
    reference row: ``forward(...) -> (mean of the members' log-probabilities (B, k), mean value (B,))``.

    The argmax of the mean log-probability is the choice the members' policies agree on most (their
    geometric mean); masked neighbours stay at -inf. Each decision costs one forward pass per member.
    An ensemble is not trained: training starts from one network (``--init`` refuses an ensemble).
    """

    def __init__(self, members: list[AttentionNet]) -> None:
        super().__init__()
        if not 2 <= len(members) <= MAX_MEMBERS:
            raise ValueError(f"an ensemble holds 2 to {MAX_MEMBERS} networks, got {len(members)}")
        configs = {m.cfg for m in members}
        if len(configs) != 1:
            raise ValueError(f"an ensemble's networks must share one NetConfig, got {len(configs)} different ones")
        self.members = nn.ModuleList(members)
        self.cfg = members[0].cfg

    def forward(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``inputs``: :meth:`AttentionNet.forward`'s (node_features, pos_encoding, current, neighbours,
        mask, budget)."""
        log_p, values = [], []
        for net in self.members:
            logits, value = net(*inputs)
            log_p.append(torch.log_softmax(logits, dim=-1))
            values.append(value)
        return torch.stack(log_p).mean(0), torch.stack(values).mean(0)
