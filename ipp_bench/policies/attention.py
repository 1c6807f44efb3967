"""The encoder's attention over all nodes, in the input space of the nodes: ``softmax(scale q x^T) x``.

Most of the attention network's work (:mod:`ipp_bench.policies.network`) is this one product: every query
of the current node and its neighbours attends over all N nodes' inputs. :func:`input_attention` runs it
as PyTorch's fused kernel, which never forms the (B, L, N) weights, with a backward pass that takes only
the gradients the network needs (:class:`_InputAttention`).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F


def _fused(q: torch.Tensor, x: torch.Tensor, scale: float) -> torch.Tensor:
    kv = x.unsqueeze(1)
    return F.scaled_dot_product_attention(q.unsqueeze(1), kv, kv, scale=scale).squeeze(1)


class _InputAttention(torch.autograd.Function):
    """``softmax(scale q x^T) x`` for queries q (B, L, E) over inputs x (B, N, E) that are both keys and values.

    Forward: PyTorch's fused attention kernel (the (B, L, N) weights are never formed). Backward: the
    fused kernel's own would also compute the gradients of the keys and the values, which the encoder's
    inputs (observations, the roadmap's constant) never need; here the weights are formed again a few
    samples at a time and only the queries' gradient is taken (the inputs' too, if they need one).
    """

    CHUNK = 8  # [samples] whose (L, N) weights are formed at once in the backward pass

    @staticmethod
    def forward(ctx, q: torch.Tensor, x: torch.Tensor, scale: float) -> torch.Tensor:
        out = _fused(q, x, scale)
        ctx.save_for_backward(q, x, out)
        ctx.scale = scale
        return out

    @staticmethod
    def backward(ctx, d_out: torch.Tensor):
        q, x, out = ctx.saved_tensors
        scale = ctx.scale
        want_x = ctx.needs_input_grad[1]
        d_q = torch.empty_like(q)
        d_x = torch.empty_like(x) if want_x else None
        d_out = d_out.contiguous()
        for lo in range(0, q.shape[0], _InputAttention.CHUNK):
            sl = slice(lo, lo + _InputAttention.CHUNK)
            xt = x[sl].transpose(1, 2)
            row = (d_out[sl] * out[sl]).sum(-1, keepdim=True)  # sum_j a_j dA_j: the softmax's shift
            a = torch.softmax(torch.bmm(q[sl], xt).mul_(scale), dim=-1)  # (b, L, N)
            d_s = torch.bmm(d_out[sl], xt).sub_(row).mul_(a)  # dLoss / d(scores), scores before scale
            d_q[sl] = torch.bmm(d_s, x[sl]).mul_(scale)
            if want_x:
                d_x[sl] = (torch.bmm(d_s.transpose(1, 2), q[sl]).mul_(scale)
                           + torch.bmm(a.transpose(1, 2), d_out[sl]))
        return d_q, d_x, None


def input_attention(q: torch.Tensor, x: torch.Tensor, scale: float) -> torch.Tensor:
    """(B, L, E): ``softmax(scale q x^T) x``, x (B, N, E) the keys and the values (:class:`_InputAttention`)."""
    if torch.is_grad_enabled() and (q.requires_grad or x.requires_grad):
        return _InputAttention.apply(q, x, scale)
    return _fused(q, x, scale)


__all__ = ["input_attention"]
