"""PPO rollouts collected inside the environment workers: each worker runs the policy on its own
environments for the whole rollout, the main process only gathers the result.

SB3's rollout loop hands every step across the process boundary twice: the main process runs one
forward pass for all environments, sends the actions, and waits for the slowest worker's
observations before the next forward pass. On two cores that leaves one core idle during every
forward pass and every hand-over (and a busy machine charges each wake-up of a worker to the main
process). Here each worker of :class:`~ipp_bench.train.vec.ShardedSubprocVecEnv` holds a copy of the
policy (its constructor arguments and weights, sent once per rollout), samples its environments'
actions itself, steps them, and sends back the rollout of its share in one message; the workers run
in parallel without waiting on each other or on the main process.

The transitions are the ones SB3's loop (``MaskablePPO.collect_rollouts``) would store for the same
actions: observation, action, reward (a time-limit truncation bootstrapped with the value of the
terminal observation, as SB3 does), episode start, value, log-probability and action mask, step by
step in environment order; the callbacks see every step (``on_step``), the episode statistics every
``info``. Only where the random actions are drawn differs: each environment has its own torch
generator per rollout (seeded from the run's seed, the rollout and the environment's index,
:func:`rollout_seed`), not the main process's, so the draws are the same whether
the environments run in one process (``--vec-env dummy``) or are split among any number of workers.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from sb3_contrib import MaskablePPO
from stable_baselines3.common.utils import obs_as_tensor
from stable_baselines3.common.vec_env import DummyVecEnv


class WorkerRollout:
    """A worker's side: its policy copy and where its environments' episodes stand."""

    def __init__(self) -> None:
        self.policy: Any = None
        self.episode_starts: np.ndarray | None = None

    def reset(self, n_envs: int) -> None:
        self.episode_starts = np.ones(n_envs, dtype=bool)

    def run(self, venv: Any, data: tuple) -> dict[str, Any]:
        """``n_steps`` steps of every environment of ``venv`` (a ``DummyVecEnv``) with the policy of ``data``."""
        policy_spec, state, n_steps, gamma, env_seeds = data
        if policy_spec is not None or self.policy is None:  # the policy's class and arguments (the first rollout)
            cls, kwargs = policy_spec
            if type(venv).__name__ != "RolloutDummyVecEnv":  # a worker process: one thread, the cores are shared
                torch.set_num_threads(1)
            self.policy = cls(**kwargs)
        self.policy.load_state_dict(state)
        self.policy.set_training_mode(False)  # also after a half of an update (train.update) in this worker
        generators = [torch.Generator().manual_seed(int(s)) for s in env_seeds]
        if self.episode_starts is None:
            self.reset(venv.num_envs)
        obs = venv._obs_from_buf()
        steps: list[dict[str, Any]] = []
        for _ in range(n_steps):
            masks = obs["action_mask"].astype(bool)
            with torch.no_grad():
                actions, values, log_probs = _act(self.policy, obs_as_tensor(obs, "cpu"), masks, generators)
            actions = actions.numpy()
            new_obs, rewards, dones, infos = venv.step(actions)
            for i, done in enumerate(dones):  # SB3's bootstrap of a time-limit truncation
                terminal = infos[i].get("terminal_observation")
                if done and terminal is not None and infos[i].get("TimeLimit.truncated", False):
                    with torch.no_grad():
                        rewards[i] += gamma * self.policy.predict_values(self.policy.obs_to_tensor(terminal)[0])[0]
            steps.append({"obs": obs, "actions": actions, "rewards": rewards, "episode_starts": self.episode_starts,
                          "values": values.numpy().reshape(-1), "log_probs": log_probs.numpy(), "masks": masks,
                          "dones": dones, "infos": infos})
            obs, self.episode_starts = new_obs, dones
        with torch.no_grad():
            last_values = self.policy.predict_values(obs_as_tensor(obs, "cpu")).numpy().reshape(-1)
        return {"steps": steps, "last_obs": obs, "last_values": last_values, "dones": self.episode_starts}


def _act(policy: Any, obs: Any, masks: np.ndarray, generators: list[torch.Generator]) -> tuple:
    """``MaskableActorCriticPolicy.forward`` (sb3-contrib) with each environment's action drawn from its own
    generator: the actions, values and log-probabilities of the batch."""
    features = policy.extract_features(obs)
    if policy.share_features_extractor:
        latent_pi, latent_vf = policy.mlp_extractor(features)
    else:
        pi_features, vf_features = features
        latent_pi = policy.mlp_extractor.forward_actor(pi_features)
        latent_vf = policy.mlp_extractor.forward_critic(vf_features)
    values = policy.value_net(latent_vf)
    distribution = policy._get_action_dist_from_latent(latent_pi)
    distribution.apply_masking(masks)
    actions = _draw(distribution.distribution.probs, generators)
    return actions, values, distribution.log_prob(actions)


def _draw(probs: torch.Tensor, generators: list[torch.Generator]) -> torch.Tensor:
    """One action per environment (row of ``probs``), each from its environment's generator."""
    return torch.cat([torch.multinomial(probs[i], 1, generator=g) for i, g in enumerate(generators)])


_STEP_KEYS = ("obs", "actions", "rewards", "episode_starts", "values", "log_probs", "masks", "dones")


def _concat(parts: list[Any]) -> Any:
    if isinstance(parts[0], dict):
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return np.concatenate(parts)


class WorkerRolloutPPO(MaskablePPO):
    """``MaskablePPO`` whose rollouts the environment workers collect (:mod:`ipp_bench.train.rollout`),
    where its environments are a :class:`~ipp_bench.train.vec.ShardedSubprocVecEnv`, and whose update
    computes every minibatch's gradient in two halves, the second in a worker
    (:mod:`ipp_bench.train.update`); on any other environments, SB3's own rollout loop. Saving and
    loading are ``MaskablePPO``'s."""

    _rollouts = 0
    _policy_sent_to: Any = None  # the worker set that holds the policy's class and arguments

    def _excluded_save_params(self) -> list[str]:
        # a run state of this process, not of the model: a loaded model sends its policy to its own workers
        return [*super()._excluded_save_params(), "_policy_sent_to", "_rollouts"]

    def train(self) -> None:
        """``MaskablePPO``'s update with every minibatch's gradient computed in two halves, the second in
        a worker process where there are workers (:mod:`ipp_bench.train.update`); on a GPU, SB3's own."""
        from ipp_bench.train.update import RemoteHalf, split_train

        if self.device.type != "cpu":
            return super().train()
        venv = getattr(self.env, "worker_rollouts", None)
        workers = getattr(venv, "__self__", None)
        remote = RemoteHalf(workers) if workers is not None and hasattr(workers, "remotes") else None
        if remote is not None and self._policy_sent_to is not workers:  # the workers hold no policy yet
            remote = None
        return split_train(self, remote)

    def collect_rollouts(self, env: Any, callback: Any, rollout_buffer: Any, n_rollout_steps: int,
                         use_masking: bool = True) -> bool:
        sharded = getattr(env, "worker_rollouts", None)
        if sharded is None or not use_masking:
            return super().collect_rollouts(env, callback, rollout_buffer, n_rollout_steps, use_masking)
        self.policy.set_training_mode(False)
        rollout_buffer.reset()
        callback.on_rollout_start()
        spec = None
        if self._policy_sent_to is not sharded.__self__:
            spec = (type(self.policy), self.policy._get_constructor_parameters())
            self._policy_sent_to = sharded.__self__
        state = {k: v.detach().cpu().clone() for k, v in self.policy.state_dict().items()}
        seed = (0 if self.seed is None else int(self.seed)) * 1_000_003 + self._rollouts
        self._rollouts += 1
        parts = sharded(spec, state, n_rollout_steps, float(self.gamma), seed)
        for t in range(n_rollout_steps):
            step = {k: _concat([p["steps"][t][k] for p in parts]) for k in _STEP_KEYS}
            infos = [info for p in parts for info in p["steps"][t]["infos"]]
            self.num_timesteps += env.num_envs
            callback.update_locals({"infos": infos, "dones": step["dones"], "rewards": step["rewards"],
                                    "actions": step["actions"], "new_obs": None, "n_steps": t})
            if not callback.on_step():
                return False
            self._update_info_buffer(infos, step["dones"])
            rollout_buffer.add(step["obs"], step["actions"].reshape(-1, 1), step["rewards"], step["episode_starts"],
                               torch.as_tensor(step["values"]), torch.as_tensor(step["log_probs"]),
                               action_masks=step["masks"])
        self._last_obs = _concat([p["last_obs"] for p in parts])
        self._last_episode_starts = _concat([p["dones"] for p in parts])
        last_values = torch.as_tensor(_concat([p["last_values"] for p in parts]))
        rollout_buffer.compute_returns_and_advantage(last_values=last_values, dones=self._last_episode_starts)
        callback.on_rollout_end()
        return True


def rollout_seed(seed: int, env_index: int) -> int:
    """The seed of environment ``env_index``'s action draws in the rollout of seed ``seed``: one stream per
    environment, so the draws do not depend on how the environments are split among worker processes."""
    return seed * 1000 + env_index


class RolloutDummyVecEnv(DummyVecEnv):
    """SB3's ``DummyVecEnv`` that also collects whole rollouts in this process, as a
    :class:`ShardedSubprocVecEnv` worker does: the same transitions for the same seeds either way."""

    def __init__(self, env_fns: list[Callable[[], gym.Env]]) -> None:
        super().__init__(env_fns)
        self._rollouts = WorkerRollout()
        self._collecting = False

    def reset(self):
        obs = super().reset()
        self._rollouts.reset(self.num_envs)
        return obs

    def step_wait(self):
        obs, rewards, dones, infos = super().step_wait()
        if not self._collecting:  # a step from outside a rollout (a rollout keeps its own)
            self._rollouts.episode_starts = dones.copy()
        return obs, rewards, dones, infos

    def worker_rollouts(self, policy_spec: Any, state: dict, n_steps: int, gamma: float, seed: int) -> list[dict]:
        """The rollout of every environment, as one worker of :class:`ShardedSubprocVecEnv` would collect it."""
        env_seeds = [rollout_seed(seed, i) for i in range(self.num_envs)]
        self._collecting = True
        try:
            return [self._rollouts.run(self, (policy_spec, state, n_steps, gamma, env_seeds))]
        finally:
            self._collecting = False
