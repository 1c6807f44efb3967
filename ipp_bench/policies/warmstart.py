"""The warm start of ``ipp-bench train``: behaviour cloning with DAgger from a roadmap planner.

Round 0 flies the expert; round r > 0 flies the student (the expert's action taken with
probability 0.5^r) and labels every visited state with the expert's choice. After every round
the network is fitted to the labels (cross-entropy to soft targets from the expert's scores)
and its value head to the discounted returns observed, so that PPO starts from a policy near the
expert and a critic that knows its scale.

Resumable: after each round the round's samples (``warmstart/data_<r>.npz``), the student's
weights (``warmstart/student.pt``) and the random generator's state go to disk and
``warmstart/progress.json`` records the round; an interrupted warm start continues with the
next round and gives the same result as an uninterrupted one (the network has no dropout, so
the numpy generator is the only randomness after initialisation). ``bc_log.csv`` keeps its rows.
"""

from __future__ import annotations

import csv
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from ipp_bench.planners.base import GraphPlanner, softmax
from ipp_bench.planners.episode import fly_episode
from ipp_bench.policies.checkpoint import load_checkpoint, save_checkpoint
from ipp_bench.policies.features import extend_observation
from ipp_bench.policies.network import MASKED_LOGIT, AttentionNet, NetConfig


def check_expert(name: str, distill: bool = False) -> None:
    """Raise ValueError unless ``name`` is a roadmap planner of the registry (and, with ``distill``, one with a
    policy to distil), called before a run starts."""
    make_expert(name, distill)


def check_expert_on(name: str, env: Any, task: str) -> None:
    """Raise ValueError (one line) unless the expert ``name`` can start an episode of ``env`` (the
    unwrapped task environment): a planner that needs the dense belief refuses a window-belief task
    at its reset, which comes before the run folder when checked here."""
    from ipp_bench.planners import view_for

    planner = make_expert(name).planner
    env.reset(seed=0)
    try:
        planner.reset(view_for(planner, env), 0)
    except ValueError as err:
        raise ValueError(f"--warm-start {name} on {task}: {err}") from None


def make_expert(name: str, distill: bool = False) -> _PlannerExpert:
    """``expert(obs) -> (action, scores)`` from the planner registry (``greedy``, ``mcts``, ...);
    ``distill``: a network teacher (``attention``) labels with its policy (:class:`PolicyLogits`)."""
    try:
        from ipp_bench.planners import make_planner
    except ImportError as err:
        raise ValueError(f"--warm-start {name}: the planner registry is not available ({err})") from None
    try:
        planner = make_planner(name)
    except (ValueError, TypeError) as err:
        raise ValueError(f"--warm-start {name!r} is invalid: {err}") from None
    if getattr(planner, "kind", None) != "graph":
        raise ValueError(f"--warm-start {name!r} is invalid: it is a {planner.kind} planner; a roadmap planner "
                         "(kind 'graph': greedy, mcts, random) is needed to label neighbours, or 'none'")
    if distill and not hasattr(planner, "policy_logits"):
        raise ValueError(f"--bc-distill needs a network teacher (attention:...) whose labels are its policy; "
                         f"--warm-start {name!r} is a planner with no policy to distil")
    return _PlannerExpert(planner, distill)


class PolicyLogits(np.ndarray):
    """A network teacher's logits over the k neighbours (-inf: not allowed), as its label under
    ``--bc-distill``: :func:`soft_target` makes them ``softmax(logits / temperature)``."""


class _PlannerExpert:
    """A registry planner as ``expert(obs) -> (action, scores)``; reset with the episode's view."""

    def __init__(self, planner: Any, distill: bool = False) -> None:
        self.planner, self.distill = planner, distill

    def __call__(self, obs: dict) -> tuple[int, np.ndarray | None]:
        """The expert's action and, where the planner exposes them, its scores per neighbour (under
        ``distill``, a network teacher's logits: :class:`PolicyLogits`; None, a one-hot label, where a rule
        of its own (the stall guard) or its trajectory sampling flew another leg than their argmax)."""
        if self.distill:
            action = int(self.planner.act(obs))
            logits = self.planner.policy_logits
            if logits is None or action != int(np.argmax(logits)):  # its own rule or its search flew another leg
                return action, None
            return action, np.asarray(logits, dtype=np.float64).view(PolicyLogits)
        if getattr(self.planner, "reads_truth", False):
            # a reference planner (the oracle) may fly towards a far target rather than its scores'
            # argmax: the label is its move, soft over its scores only where the two agree
            action = int(self.planner.act(obs))
            if hasattr(self.planner, "scores"):
                scores = np.asarray(self.planner.scores(obs), dtype=np.float64)
                if action == int(np.argmax(scores)):
                    return action, scores
            return action, None
        if hasattr(self.planner, "scores"):
            scores = np.asarray(self.planner.scores(obs), dtype=np.float64)
            # np.argmax, not the planners' first_best: the shipped checkpoints' warm starts were made
            # with it, and their commands reproduce them (on the CPU kind that made them: a mirror tie
            # goes the way its rounding falls)
            return int(np.argmax(scores)), scores
        return int(self.planner.act(obs)), None


class _DaggerPlanner(GraphPlanner):
    """DAgger's behaviour policy as a planner, so that its episodes go through the one episode loop
    (:func:`ipp_bench.planners.episode.fly_episode`): every state is labelled with the expert's
    action, which is executed with probability ``beta`` (else the student's, sampled)."""

    name = "dagger"

    def __init__(self, expert: _PlannerExpert, net: AttentionNet | None, beta: float, rng: np.random.Generator,
                 device: torch.device, temperature: float, node_dim: int, teacher: str = "greedy",
                 invariant: bool = False) -> None:
        super().__init__(None)
        self.expert, self.net, self.beta, self.student_rng = expert, net, beta, rng
        self.device, self.temperature, self.node_dim = device, temperature, node_dim
        self.teacher, self.invariant = teacher, invariant
        self.obs_list: list[dict] = []
        self.actions: list[int] = []
        self.targets: list[np.ndarray] = []

    def reset(self, view: Any, seed: int) -> None:
        super().reset(view, seed)
        expert = self.expert.planner
        if getattr(expert, "reads_truth", False):
            # a privileged teacher (the oracle at training time): it gets the truth's view of the same
            # environment, the student only ever the robot's (view_for refuses any other planner)
            from ipp_bench.planners import view_for

            view = view_for(expert, view._env)
        expert.reset(view, seed)

    def act(self, obs: dict) -> int:
        # the expert sees the environment's observation, as in a leaderboard episode (a network teacher
        # adds its own features; trajectory sampling needs the base ones); the student is trained on its own
        a_exp, scores = self.expert(obs)
        obs = extend_observation(obs, self.view, self.node_dim, self.teacher, self.invariant)
        self.targets.append(soft_target(a_exp, scores, len(obs["action_mask"]), self.temperature))
        a = a_exp
        if self.net is not None and self.student_rng.random() >= self.beta:
            a = net_action(self.net, obs, self.device, deterministic=False, rng=self.student_rng)
        self.obs_list.append(obs)
        self.actions.append(a_exp)
        return a


def soft_target(action: int, scores: np.ndarray | None, k: int, temperature: float) -> np.ndarray:
    """Imitation target over the k neighbours.

    With expert scores (e.g. greedy's predicted gain per second), neighbours scoring close to the
    best share the probability: ``p ~ exp((s / s_max - 1) / temperature)`` over the valid ones, so
    near-ties are not forced apart. Without scores (or ``temperature = 0``): one-hot on the action.
    A network teacher's logits (:class:`PolicyLogits`, ``--bc-distill``): ``softmax(logits / temperature)``,
    its own policy at temperature 1.
    """
    target = np.zeros(k, dtype=np.float32)
    if scores is None or temperature <= 0:
        target[action] = 1.0
        return target
    if isinstance(scores, PolicyLogits):  # -inf logits (what the teacher does not allow) get 0
        return softmax(np.asarray(scores, dtype=np.float64) / temperature).astype(np.float32)
    valid = np.isfinite(scores)
    best = scores[action]
    if best <= 0 or not valid.any():
        target[action] = 1.0
        return target
    z = np.where(valid, (scores / best - 1.0) / temperature, -np.inf)
    p = np.exp(z - z.max())
    return (p / p.sum()).astype(np.float32)


def obs_batch(obs_list: list[dict], device: torch.device) -> dict[str, torch.Tensor]:
    return {k: torch.as_tensor(np.stack([o[k] for o in obs_list])).to(device) for k in obs_list[0]}


@torch.no_grad()
def net_action(net: AttentionNet, obs: dict, device: torch.device, deterministic: bool = True,
               rng: np.random.Generator | None = None) -> int:
    logits, _ = net.forward_obs(obs_batch([obs], device))
    logits = logits[0].cpu().numpy().astype(np.float64)
    if deterministic:
        return int(np.argmax(logits))
    p = np.exp(logits - logits.max())
    p /= p.sum()
    return int((rng or np.random.default_rng()).choice(p.size, p=p))




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


def collect_episodes(env, expert, net: AttentionNet | None, episodes: int, beta: float, data: BCDataset,
                     gamma: float, rng: np.random.Generator, seed0: int, device: torch.device,
                     temperature: float = 0.0, net_config: NetConfig | None = None) -> dict[str, float]:
    """Fly ``episodes`` episodes through the episode loop; at each state the expert's action is
    executed with probability ``beta`` (else the student's, sampled); every state is labelled with
    the expert's action. ``env`` is the training env (the look-gain wrapper adds that feature)."""
    base = env.unwrapped
    node_dim = env.observation_space["node_features"].shape[-1]
    red, steps = [], 0
    for e in range(episodes):
        planner = _DaggerPlanner(expert, net, beta, rng, device, temperature, node_dim,
                                 net_config.skip_teacher if net_config else "greedy",
                                 bool(net_config and net_config.invariant))
        rewards: list[float] = []
        result = fly_episode(base, planner, seed0 + e, on_decision=lambda d: rewards.append(float(d.reward)))
        data.add_episode(planner.obs_list, planner.actions, planner.targets, rewards, gamma)
        red.append(result.final["uncertainty_reduction_pct"])
        steps += len(planner.actions)
    return {"episodes": episodes, "steps": steps, "unc_red_final": float(np.mean(red)) if red else float("nan")}


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




# ------------------------------------------------------------------------------------------------
# Saving the dataset per round (resumable warm start)
# ------------------------------------------------------------------------------------------------
def _save_chunk(data: BCDataset, start: int, path: Path) -> None:
    """Samples ``start:`` of ``data`` (one round) to ``path`` (npz, written then renamed)."""
    # states of several roadmaps have different node counts: rows concatenated, with each one's count
    nf, pes = data.nf[start:], data.pes
    tmp = path.with_name(path.stem + ".tmp.npz")
    np.savez(tmp, nf=np.concatenate(nf), nf_nodes=np.array([a.shape[0] for a in nf]),
             small=np.stack(data.small[start:]), pe_id=np.asarray(data.pe_id[start:]),
             action=np.asarray(data.action[start:]), target=np.stack(data.target[start:]),
             ret=np.asarray(data.ret[start:], dtype=np.float64),
             pes=np.concatenate(pes) if pes else np.zeros((0, 0), np.float32),
             pes_nodes=np.array([p.shape[0] for p in pes], dtype=np.int64))
    tmp.replace(path)


def _split_rows(rows: np.ndarray, counts: np.ndarray) -> list[np.ndarray]:
    return list(np.split(rows, np.cumsum(counts)[:-1])) if len(counts) else []


def _load_chunk(data: BCDataset, path: Path) -> None:
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


def warm_start_seeds(cfg: Any) -> range:
    """The episode seeds of a warm start (``cfg.seed * 1 000 003`` on, round 0's episodes then each
    DAgger round's); empty without a warm start."""
    n = cfg.bc_episodes + cfg.bc_rounds * cfg.bc_round_episodes if cfg.warm_start != "none" else 0
    return range(cfg.seed * 1_000_003, cfg.seed * 1_000_003 + n)


def warm_start(cfg: Any, run: Path, device: torch.device, say: Callable[[str], None],
               make_env: Callable[..., Any], validate: Callable[[AttentionNet], dict[str, float]],
               net_config: NetConfig, init: AttentionNet | None = None) -> tuple[AttentionNet, dict[str, float]]:
    """Behaviour cloning (DAgger) from ``cfg.warm_start``; writes ``warmstart/bc.pt``; resumable.

    Args:
        cfg: the run's ``TrainArgs`` (``warm_start``, ``bc_*``, ``batch_size``, ``gamma``, ``seed``).
        run: the run folder.
        device: torch device of the fit.
        say: progress messages.
        make_env: builds the training environment (``make_env(i)``: that of task i of ``cfg.tasks``
            when the run has several; each round's episodes are split over them in turn).
        validate: validation figures of a network (``val/score``, ``val/unc_red_<t>s``, ...).
        net_config: sizes of the network.
        init: weights to start from (``--init``) instead of a fresh initialisation.
    """
    out = run / "warmstart"
    out.mkdir(exist_ok=True)
    progress_file = out / "progress.json"
    progress = json.loads(progress_file.read_text()) if progress_file.is_file() else {}
    n_tasks = len(getattr(cfg, "tasks", [None]))
    envs = [make_env(i) for i in range(n_tasks)] if n_tasks > 1 else [make_env()]
    names = cfg.experts() if hasattr(cfg, "experts") else [cfg.warm_start]
    experts = [make_expert(name, getattr(cfg, "bc_distill", False)) for name in names]  # one per task, in order
    torch.manual_seed(cfg.seed)
    net = AttentionNet(net_config).to(device)
    if init is not None:
        net.load_state_dict(init.state_dict())
    data = BCDataset()
    rng = np.random.default_rng(cfg.seed)
    log_path = out / "bc_log.csv"
    rows: list[dict] = []
    seed = warm_start_seeds(cfg).start
    wall0 = 0.0
    first = 0
    if progress.get("rounds_done", 0) > 0:  # resume after the last completed round
        first = progress["rounds_done"]
        for r in range(first):
            _load_chunk(data, out / f"data_{r}.npz")
        student, _ = load_checkpoint(out / "student.pt", device=device)
        net.load_state_dict(student.state_dict())
        rng.bit_generator.state = progress["rng_state"]
        seed, wall0 = progress["next_seed"], progress["wall_s"]
        if log_path.is_file():
            with log_path.open(newline="") as fh:
                rows = [{k: v for k, v in r.items() if v != ""} for r in csv.DictReader(fh)]
        say(f"resuming the warm start after round {first - 1} ({len(data)} samples)")
    t0 = time.time() - wall0
    rnd = first

    def log(row: dict) -> None:
        rows.append({"round": rnd, "samples": len(data), "wall_s": round(time.time() - t0, 1), **row})
        with log_path.open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=sorted({k for r in rows for k in r}))
            w.writeheader()
            w.writerows(rows)

    for rnd in range(first, cfg.bc_rounds + 1):
        n_ep = cfg.bc_episodes if rnd == 0 else cfg.bc_round_episodes
        beta = 0.5 ** rnd
        start = len(data)
        parts = []
        for i, env in enumerate(envs):  # one task: all episodes; several: split in turn, seeds consecutive
            n_i = n_ep // len(envs) + (i < n_ep % len(envs))
            parts.append(collect_episodes(env, experts[i], None if rnd == 0 else net, n_i, beta, data, cfg.gamma, rng,
                                          seed, device, temperature=cfg.bc_temperature, net_config=net_config))
            seed += n_i
        stats = parts[0] if len(parts) == 1 else {
            "episodes": sum(p["episodes"] for p in parts), "steps": sum(p["steps"] for p in parts),
            "unc_red_final": float(np.average([p["unc_red_final"] for p in parts if p["episodes"]],
                                              weights=[p["episodes"] for p in parts if p["episodes"]]))}
        say(f"warm start round {rnd}: {stats['episodes']} episodes (beta {beta:.2f}), {len(data)} samples, "
            f"final ROI uncertainty reduction of the flown paths {stats['unc_red_final']:.1f}%")
        fit_rows: list[dict] = []
        fit_bc(net, data, cfg.bc_epochs, cfg.bc_lr, cfg.batch_size, rng, device,
               log=lambda r: (fit_rows.append(r),
                              say(f"  epoch {r['epoch']}: loss_pi {r['loss_pi']:.3f} loss_v {r['loss_v']:.3f} "
                                  f"acc {r['acc']:.3f} target_p {r['target_p']:.3f}")))
        # The round is complete: its samples, the student and the generator go to disk together.
        _save_chunk(data, start, out / f"data_{rnd}.npz")
        save_checkpoint(net, out / "student.pt", meta={"round": rnd})
        log({"phase": "collect", **stats})
        for r in fit_rows:
            log({"phase": "fit", **r})
        progress = {"rounds_done": rnd + 1, "rng_state": rng.bit_generator.state, "next_seed": seed,
                    "wall_s": time.time() - t0}
        tmp = progress_file.with_name("progress.json.tmp")
        tmp.write_text(json.dumps(progress, indent=2) + "\n")
        tmp.replace(progress_file)
    val = validate(net)
    log({"phase": "validate", **val})
    wall = time.time() - t0
    say(f"warm start done in {wall:.0f} s; validation: " + ", ".join(
        f"{k.split('/', 1)[-1]} {v:.2f}" for k, v in val.items()))
    save_checkpoint(net, out / "bc.pt", meta={"task": cfg.task, "phase": "warm start",
                                               "expert": ", ".join(dict.fromkeys(names)),
                                               "samples": len(data), "wall_s": wall, **val})
    for r in range(cfg.bc_rounds + 1):  # the samples are no longer needed once bc.pt exists
        (out / f"data_{r}.npz").unlink(missing_ok=True)
    return net, val
