"""The warm start of ``ipp-bench train``: behaviour cloning with DAgger from roadmap planners.

Round 0 flies the teacher; round r > 0 flies the student (the teacher's action taken with
probability 0.5^r) and labels every visited state with the teacher's choice. After every round the
network is fitted to all labels so far (:func:`ipp_bench.train.bc.fit_bc`).

Several training tasks (``--mix``) split each round's episodes over them in turn, with consecutive
seeds; a task may be named twice (twice its episodes) and the tasks may lie on roadmaps of
different sizes (one fit sees them all: the minibatches hold one roadmap each). Each task has its
teacher (``--warm-start``, or ``--warm-start-for TASK=PLANNER``): e.g. greedy on the v1 tasks and
the starting network's own argmax on the hotspot tasks, so that the fit moves one behaviour towards
greedy's and keeps the other (the joint warm start of ``recipes/attention_v6.toml``).

Resumable: after each round the round's samples (``warmstart/data_<r>.npz``), the student's
weights (``warmstart/student.pt``) and the random generator's state go to disk and
``warmstart/progress.json`` records the round; an interrupted warm start continues with the next
round and gives the same result as an uninterrupted one (the network has no dropout, so the numpy
generator is the only randomness after initialisation). ``bc_log.csv`` keeps its rows.
"""

from __future__ import annotations

import csv
import io
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ipp_bench.planners.base import GraphPlanner
from ipp_bench.planners.episode import fly_episode
from ipp_bench.policies.checkpoint import load_checkpoint, save_checkpoint
from ipp_bench.policies.features import extend_observation
from ipp_bench.policies.network import AttentionNet, NetConfig
from ipp_bench.train.args import TrainArgs, warm_start_seeds
from ipp_bench.train.bc import BCDataset, fit_bc, load_chunk, save_chunk, soft_target
from ipp_bench.train.files import write_json_atomic, write_text_atomic
from ipp_bench.train.teachers import PlannerExpert, make_expert
from ipp_bench.train.vec import make_train_env


class _DaggerPlanner(GraphPlanner):
    """DAgger's behaviour policy as a planner, so that its episodes go through the one episode loop
    (:func:`ipp_bench.planners.episode.fly_episode`): every state is labelled with the expert's
    action, which is executed with probability ``beta`` (else the student's, sampled)."""

    name = "dagger"

    def __init__(self, expert: PlannerExpert, net: AttentionNet | None, beta: float, rng: np.random.Generator,
                 device: torch.device, temperature: float, node_dim: int, invariant: bool = False,
                 env: Any = None) -> None:
        super().__init__(None)
        self.env = env  # the episode's env: a privileged teacher's truth view is made from it
        self.expert, self.net, self.beta, self.student_rng = expert, net, beta, rng
        self.device, self.temperature, self.node_dim = device, temperature, node_dim
        self.invariant = invariant
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

            view = view_for(expert, self.env)
        expert.reset(view, seed)

    def act(self, obs: dict) -> int:
        # the expert sees the environment's observation, as in a leaderboard episode (a network teacher
        # adds its own features; trajectory sampling needs the base ones); the student is trained on its own
        a_exp, scores = self.expert(obs)
        obs = extend_observation(obs, self.view, self.node_dim, invariant=self.invariant)
        self.targets.append(soft_target(a_exp, scores, len(obs["action_mask"]), self.temperature))
        a = a_exp
        if self.net is not None and self.student_rng.random() >= self.beta:
            a = net_action(self.net, obs, self.device, deterministic=False, rng=self.student_rng)
        self.obs_list.append(obs)
        self.actions.append(a_exp)
        return a


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
                                 invariant=bool(net_config and net_config.invariant), env=base)
        rewards: list[float] = []
        result = fly_episode(base, planner, seed0 + e,
                             on_decision=lambda d, rewards=rewards: rewards.append(float(d.reward)))
        data.add_episode(planner.obs_list, planner.actions, planner.targets, rewards, gamma)
        red.append(result.final["uncertainty_reduction_pct"])
        steps += len(planner.actions)
    return {"episodes": episodes, "steps": steps, "unc_red_final": float(np.mean(red)) if red else float("nan")}


def warm_start(cfg: TrainArgs, run: Path, device: torch.device, say: Callable[[str], None],
               validate: Callable[[AttentionNet], dict[str, float]],
               init: AttentionNet | None = None) -> tuple[AttentionNet, dict[str, float]]:
    """Behaviour cloning (DAgger) from ``cfg``'s teachers; writes ``warmstart/bc.pt``; resumable.

    Args:
        cfg: the run's settings (``tasks``, ``experts()``, ``bc_*``, ``batch_size``, ``gamma``, ``seed``).
        run: the run folder.
        device: torch device of the fit.
        say: progress messages.
        validate: validation figures of a network (``val/score``, ``val/unc_red_<t>s``, ...).
        init: weights to start from (``--init``) instead of a fresh initialisation.
    """
    net_config = cfg.net_config()
    out = run / "warmstart"
    out.mkdir(exist_ok=True)
    progress_file = out / "progress.json"
    progress = json.loads(progress_file.read_text()) if progress_file.is_file() else {}
    envs = [make_train_env(cfg, i) for i in range(len(cfg.tasks))]
    names = cfg.experts()
    experts = [make_expert(name) for name in names]  # one per task entry, in order
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
            load_chunk(data, out / f"data_{r}.npz")
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
        text = io.StringIO()
        w = csv.DictWriter(text, fieldnames=sorted({k for r in rows for k in r}), lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
        write_text_atomic(log_path, text.getvalue())

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
               log=lambda r, fit_rows=fit_rows: (fit_rows.append(r),
                              say(f"  epoch {r['epoch']}: loss_pi {r['loss_pi']:.3f} loss_v {r['loss_v']:.3f} "
                                  f"acc {r['acc']:.3f} target_p {r['target_p']:.3f}")))
        # The round is complete: its samples, the student and the generator go to disk together.
        save_chunk(data, start, out / f"data_{rnd}.npz")
        save_checkpoint(net, out / "student.pt", meta={"round": rnd})
        log({"phase": "collect", **stats})
        for r in fit_rows:
            log({"phase": "fit", **r})
        write_json_atomic(progress_file, {"rounds_done": rnd + 1, "rng_state": rng.bit_generator.state,
                                          "next_seed": seed, "wall_s": time.time() - t0})
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
