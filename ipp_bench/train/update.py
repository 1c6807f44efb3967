"""The PPO update split in two halves of every minibatch, the second computed in a worker process.

``MaskablePPO.train`` computes each minibatch's loss and gradient in the main process while the
environment workers sleep: on two cores, one core idles for the whole update, which is about half
of a training run's wall time at 1 800 nodes. Here each minibatch is split into two fixed halves
(its first ``B // 2`` transitions and the rest): the main process computes the first half's
gradient while a worker of :class:`~ipp_bench.train.vec.ShardedSubprocVecEnv` computes the second
half's with its copy of the policy (the weights sent with the half); the main process adds the two
gradients (first + second), clips and steps the optimizer.

The loss is ``MaskablePPO``'s, written as a sum over the minibatch divided by its size, so that the
halves add up to it: the clipped surrogate with the advantages normalised over the whole minibatch,
the value error, the entropy term; the early stop on the approximate KL divergence and the logged
figures are the whole minibatch's. Only the order of the floating-point additions differs from
SB3's (float32 rounding). The halves are the same however many workers there are, and without
workers (``--vec-env dummy``, or a policy on a GPU) the main process computes both one after the
other and adds them in the same order: the same weights either way.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from stable_baselines3.common.utils import explained_variance

#: the per-minibatch sums a half returns, in this order
_SUMS = ("policy", "clipped", "value", "entropy", "kl")


def half_terms(policy: Any, batch: dict[str, Any], n_total: int, clip_range: float,
               clip_range_vf: float | None, ent_coef: float, vf_coef: float) -> tuple[torch.Tensor, np.ndarray]:
    """The loss of the transitions of ``batch`` as their share of a minibatch of ``n_total``
    (``MaskablePPO``'s terms summed over them and divided by ``n_total``), and the sums of
    :data:`_SUMS` over them (for the minibatch's logged means and its KL early stop)."""
    # copies in torch's own (64-byte aligned) memory: a view into a larger array, or an array unpickled in a
    # worker, may start elsewhere, and the vectorised kernels round by where the data starts. On the CPU: the
    # split runs on CPUs only.
    obs = {k: torch.tensor(v) for k, v in batch["obs"].items()}
    actions = torch.tensor(batch["actions"]).long().flatten()
    advantages, old_log_prob = torch.tensor(batch["advantages"]), torch.tensor(batch["old_log_prob"])
    returns, old_values = torch.tensor(batch["returns"]), torch.tensor(batch["old_values"])
    values, log_prob, entropy = policy.evaluate_actions(obs, actions, action_masks=torch.tensor(batch["masks"]))
    values = values.flatten()
    ratio = torch.exp(log_prob - old_log_prob)
    surrogate = -torch.min(advantages * ratio, advantages * torch.clamp(ratio, 1 - clip_range, 1 + clip_range))
    if clip_range_vf is not None:
        values = old_values + torch.clamp(values - old_values, -clip_range_vf, clip_range_vf)
    value_error = (returns - values) ** 2
    neg_entropy = -entropy if entropy is not None else log_prob
    loss = (surrogate.sum() + ent_coef * neg_entropy.sum() + vf_coef * value_error.sum()) / n_total
    with torch.no_grad():
        log_ratio = log_prob - old_log_prob
        sums = np.array([surrogate.sum().item(), (torch.abs(ratio - 1) > clip_range).float().sum().item(),
                         value_error.sum().item(), neg_entropy.sum().item(),
                         ((torch.exp(log_ratio) - 1) - log_ratio).sum().item()])
    return loss, sums


def half_gradient(policy: Any, data: tuple) -> tuple[list[np.ndarray], float, np.ndarray]:
    """A worker's half: load the weights of ``data``, and return the half's gradient (one array per
    parameter, in ``policy.parameters()`` order), its loss and its sums."""
    state, batch, n_total, coefs = data
    policy.load_state_dict({k: torch.from_numpy(v) for k, v in state.items()})
    policy.set_training_mode(True)
    policy.zero_grad(set_to_none=True)
    loss, sums = half_terms(policy, batch, n_total, *coefs)
    loss.backward()
    grads = [p.grad.numpy() if p.grad is not None else np.zeros(p.shape, np.float32) for p in policy.parameters()]
    return grads, loss.item(), sums


def _halves(data: Any, advantages: torch.Tensor, n: int) -> list[dict[str, Any]]:
    """The minibatch's two halves as arrays (the advantages normalised over the whole minibatch)."""
    cut = n // 2
    whole = {"obs": {k: v.cpu().numpy() for k, v in data.observations.items()},
             "actions": data.actions.cpu().numpy(), "masks": data.action_masks.cpu().numpy(),
             "advantages": advantages.cpu().numpy(), "old_log_prob": data.old_log_prob.cpu().numpy(),
             "returns": data.returns.cpu().numpy(), "old_values": data.old_values.cpu().numpy()}

    def part(sl: slice) -> dict[str, Any]:
        return {k: ({o: a[sl] for o, a in v.items()} if k == "obs" else v[sl]) for k, v in whole.items()}

    return [part(slice(0, cut)), part(slice(cut, n))]


def split_train(model: Any, remote_half: Any | None) -> None:
    """``MaskablePPO.train`` with every minibatch's gradient computed in two halves (module docstring).

    Args:
        model: the ``MaskablePPO`` (its policy, buffer, optimizer and settings).
        remote_half: a worker process's half (:class:`RemoteHalf`), or None to compute both halves here.
    """
    policy = model.policy
    policy.set_training_mode(True)
    model._update_learning_rate(policy.optimizer)
    clip_range = model.clip_range(model._current_progress_remaining)
    clip_range_vf = (None if model.clip_range_vf is None
                     else model.clip_range_vf(model._current_progress_remaining))
    coefs = (float(clip_range), None if clip_range_vf is None else float(clip_range_vf),
             float(model.ent_coef), float(model.vf_coef))
    params = list(policy.parameters())
    logged: dict[str, list[float]] = {k: [] for k in _SUMS}
    approx_kl_divs: list[float] = []
    loss_value = 0.0
    continue_training = True
    for _ in range(model.n_epochs):
        approx_kl_divs = []
        for data in model.rollout_buffer.get(model.batch_size):
            n = len(data.advantages)
            advantages = data.advantages
            if model.normalize_advantage and n > 1:
                advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
            first, second = _halves(data, advantages, n)
            state = None
            if remote_half is not None and len(second["actions"]):
                # numpy arrays: pickled whole (torch tensors would cross as shared-memory files, which costs more)
                state = {k: v.detach().cpu().numpy().copy() for k, v in policy.state_dict().items()}
                remote_half(state, second, n, coefs)  # sent: the worker computes while this process does
            policy.optimizer.zero_grad()
            loss, sums = half_terms(policy, first, n, *coefs)
            loss.backward()
            if state is not None:
                grads, other_loss, other_sums = remote_half.result()
            elif len(second["actions"]):
                own = [p.grad.clone() if p.grad is not None else torch.zeros_like(p) for p in params]
                policy.optimizer.zero_grad()
                loss2, other_sums = half_terms(policy, second, n, *coefs)
                loss2.backward()
                grads = [p.grad.numpy().copy() if p.grad is not None else np.zeros(p.shape, np.float32)
                         for p in params]
                other_loss = loss2.item()
                for p, g in zip(params, own, strict=True):
                    p.grad = g
            else:
                grads, other_loss, other_sums = None, 0.0, np.zeros(len(_SUMS))
            means = (sums + other_sums) / n
            for key, value in zip(_SUMS[:4], means[:4], strict=True):
                logged[key].append(float(value))
            approx_kl_divs.append(float(means[4]))
            loss_value = loss.item() + other_loss
            if model.target_kl is not None and means[4] > 1.5 * model.target_kl:
                continue_training = False
                break
            if grads is not None:
                for p, g in zip(params, grads, strict=True):
                    g = torch.as_tensor(g, device=p.device)
                    p.grad = g.clone() if p.grad is None else p.grad + g
            torch.nn.utils.clip_grad_norm_(params, model.max_grad_norm)
            policy.optimizer.step()
        model._n_updates += 1
        if not continue_training:
            break
    buffer = model.rollout_buffer
    model.logger.record("train/entropy_loss", np.mean(logged["entropy"]))
    model.logger.record("train/policy_gradient_loss", np.mean(logged["policy"]))
    model.logger.record("train/value_loss", np.mean(logged["value"]))
    model.logger.record("train/approx_kl", np.mean(approx_kl_divs))
    model.logger.record("train/clip_fraction", np.mean(logged["clipped"]))
    model.logger.record("train/loss", loss_value)
    model.logger.record("train/explained_variance",
                        explained_variance(buffer.values.flatten(), buffer.returns.flatten()))
    model.logger.record("train/n_updates", model._n_updates, exclude="tensorboard")
    model.logger.record("train/clip_range", clip_range)
    if clip_range_vf is not None:
        model.logger.record("train/clip_range_vf", clip_range_vf)


class RemoteHalf:
    """The second half of every minibatch, computed by the last worker of a
    :class:`~ipp_bench.train.vec.ShardedSubprocVecEnv` (its policy copy is the rollout's): call it to
    send the half, then :meth:`result` for its gradient, loss and sums."""

    def __init__(self, venv: Any) -> None:
        self.remote = venv.remotes[-1]

    def __call__(self, state: dict, batch: dict, n_total: int, coefs: tuple) -> None:
        self.remote.send(("half", (state, batch, n_total, coefs)))

    def result(self) -> tuple[list[np.ndarray], float, np.ndarray]:
        status, answer = self.remote.recv()
        if status == "error":
            raise answer
        return answer
