"""Behaviour cloning: the imitation targets, the dataset of labelled states, the fit.

The data of a DAgger warm start (:mod:`ipp_bench.train.warmstart`): every visited state with the
teacher's label (:func:`soft_target`) and the discounted return that followed, fitted by
cross-entropy to the labels plus a Huber loss of the value head to the returns
(:func:`fit_bc`), so that PPO starts from a policy near the teacher's and a critic that knows its
scale. A round's samples are written to disk (:func:`save_chunk`) so that a warm start resumes.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from ipp_bench.core.data import write_atomically
from ipp_bench.policies.network import MASKED_LOGIT, AttentionNet


def soft_target(action: int, scores: np.ndarray | None, k: int, temperature: float) -> np.ndarray:
    """Imitation target over the k neighbours.

    With expert scores (e.g. greedy's predicted gain per second), neighbours scoring close to the
    best share the probability: ``p ~ exp((s / s_max - 1) / temperature)`` over the valid ones, so
    near-ties are not forced apart. Without scores (or ``temperature = 0``): one-hot on the action.
    """
    target = np.zeros(k, dtype=np.float32)
    if scores is None or temperature <= 0:
        target[action] = 1.0
        return target
    valid = np.isfinite(scores)
    best = scores[action]
    if best <= 0 or not valid.any():
        target[action] = 1.0
        return target
    z = np.where(valid, (scores / best - 1.0) / temperature, -np.inf)
    p = np.exp(z - z.max())
    return (p / p.sum()).astype(np.float32)


class BCDataset:
    """States visited, expert labels and discounted returns (positional encodings stored once)."""

    def __init__(self) -> None:
        self.nf: list[np.ndarray] = []
        self.small: list[np.ndarray] = []  # [current, neighbours (k), mask (k), budget]
        self.pe_id: list[int] = []
        self.action: list[int] = []
        self.target: list[np.ndarray] = []
        self.ret: list[float] = []
        self.pes: list[np.ndarray] = []

    def __len__(self) -> int:
        return len(self.action)

    def _pe_index(self, pe: np.ndarray) -> int:
        for i, p in enumerate(self.pes):
            if p.shape == pe.shape and np.array_equal(p, pe):
                return i
        self.pes.append(np.array(pe, dtype=np.float32))
        return len(self.pes) - 1

    def add_episode(self, obs_list: list[dict], actions: list[int], targets: list[np.ndarray], rewards: list[float],
                    gamma: float) -> None:
        g, rets = 0.0, []
        for r in reversed(rewards):
            g = r + gamma * g
            rets.append(g)
        rets.reverse()
        for o, a, tg, rt in zip(obs_list, actions, targets, rets):
            self.nf.append(o["node_features"].astype(np.float32))
            self.small.append(np.concatenate([o["current_node"].astype(np.float32), o["neighbours"].astype(np.float32),
                                              o["action_mask"].astype(np.float32), o["budget"].astype(np.float32)]))
            self.pe_id.append(self._pe_index(o["pos_encoding"]))
            self.action.append(int(a))
            self.target.append(tg)
            self.ret.append(float(rt))

    def batches(self, batch_size: int, rng: np.random.Generator, device: torch.device):
        """Minibatches in a random order; with states of several roadmaps (map sizes) each batch holds
        one roadmap's (the order within a roadmap is the shuffled one, batches taken in turn by their
        first sample's place), so that one fit sees every size; with one roadmap the plain shuffle."""
        order = rng.permutation(len(self))
        k = (self.small[0].size - 2) // 2
        pes = [torch.as_tensor(p) for p in self.pes]
        n_nodes = np.array([self.nf[i].shape[0] for i in order])
        chunks = []
        for n in dict.fromkeys(n_nodes.tolist()):
            place = np.flatnonzero(n_nodes == n)
            chunks += [place[s : s + batch_size] for s in range(0, place.size, batch_size)]
        for chunk in sorted(chunks, key=lambda c: c[0]):
            idx = order[chunk]
            small = torch.as_tensor(np.stack([self.small[i] for i in idx]))
            obs = {
                "node_features": torch.as_tensor(np.stack([self.nf[i] for i in idx])),
                "pos_encoding": torch.stack([pes[self.pe_id[i]] for i in idx]),
                "current_node": small[:, :1],
                "neighbours": small[:, 1 : 1 + k],
                "action_mask": small[:, 1 + k : 1 + 2 * k],
                "budget": small[:, -1:],
            }
            obs = {key: t.to(device) for key, t in obs.items()}
            yield obs, torch.as_tensor(np.stack([self.target[i] for i in idx])).to(device), \
                torch.as_tensor(np.array([self.ret[i] for i in idx], dtype=np.float32)).to(device)


def fit_bc(net: AttentionNet, data: BCDataset, epochs: int, lr: float, batch_size: int, rng: np.random.Generator,
           device: torch.device, vf_coef: float = 0.5, log: Callable[[dict], None] | None = None) -> None:
    """Cross-entropy to the expert's targets + ``vf_coef`` x Huber loss of the value to the returns.

    Logged: the losses, ``acc`` (argmax = the expert's best) and ``target_p`` (the target probability
    of the student's argmax, 1 = as good as the expert's choice by the expert's own scores)."""
    net.train()
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    for epoch in range(epochs):
        tot = {"loss_pi": 0.0, "loss_v": 0.0, "acc": 0.0, "target_p": 0.0, "n": 0}
        for obs, target, ret in data.batches(batch_size, rng, device):
            logits, value = net.forward_obs(obs)
            logits = logits.clamp_min(MASKED_LOGIT)
            loss_pi = -(target * torch.log_softmax(logits, -1)).sum(-1).mean()
            loss_v = F.smooth_l1_loss(value, ret)
            loss = loss_pi + vf_coef * loss_v
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            opt.step()
            n = target.shape[0]
            tot["loss_pi"] += loss_pi.item() * n
            tot["loss_v"] += loss_v.item() * n
            choice = logits.argmax(-1, keepdim=True)
            tot["acc"] += (choice[:, 0] == target.argmax(-1)).float().sum().item()
            tot["target_p"] += (target.gather(1, choice) / target.max(-1, keepdim=True).values).sum().item()
            tot["n"] += n
        if log is not None:
            n = max(tot["n"], 1)
            log({"epoch": epoch, "loss_pi": tot["loss_pi"] / n, "loss_v": tot["loss_v"] / n, "acc": tot["acc"] / n,
                 "target_p": tot["target_p"] / n})
    net.eval()


def save_chunk(data: BCDataset, start: int, path: Path) -> None:
    """Samples ``start:`` of ``data`` (one round) to ``path`` (npz, written then renamed)."""
    # states of several roadmaps have different node counts: rows concatenated, with each one's count
    nf, pes = data.nf[start:], data.pes
    write_atomically(path, lambda tmp: np.savez(
        tmp, nf=np.concatenate(nf), nf_nodes=np.array([a.shape[0] for a in nf]),
        small=np.stack(data.small[start:]), pe_id=np.asarray(data.pe_id[start:]),
        action=np.asarray(data.action[start:]), target=np.stack(data.target[start:]),
        ret=np.asarray(data.ret[start:], dtype=np.float64),
        pes=np.concatenate(pes) if pes else np.zeros((0, 0), np.float32),
        pes_nodes=np.array([p.shape[0] for p in pes], dtype=np.int64)))


def _split_rows(rows: np.ndarray, counts: np.ndarray) -> list[np.ndarray]:
    return list(np.split(rows, np.cumsum(counts)[:-1])) if len(counts) else []


def load_chunk(data: BCDataset, path: Path) -> None:
    z = np.load(path)
    if "nf_nodes" in z:
        pes, nf = _split_rows(z["pes"], z["pes_nodes"]), _split_rows(z["nf"], z["nf_nodes"])
    else:  # a run folder of the one-roadmap layout: (samples, N, F) and (roadmaps, N, P)
        pes, nf = list(z["pes"]), list(z["nf"])
    remap = [data._pe_index(p) for p in pes]
    data.nf += nf
    data.small += list(z["small"])
    data.pe_id += [remap[i] for i in z["pe_id"]]
    data.action += [int(a) for a in z["action"]]
    data.target += list(z["target"])
    data.ret += [float(r) for r in z["ret"]]
