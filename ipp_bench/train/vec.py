"""The training environments of ``ipp-bench train``: the reward, where the environments run, and
what crosses from them to the policy.

- :func:`make_train_env`: a run's training task with its reward (:class:`MetricReward`) and the
  node features its network reads.

- :class:`DropPosEncoding` (inside each environment): the positional encoding is a constant of
  the roadmap, so it leaves the observation; the policy holds it once
  (``AttentionPolicy(pos_encoding=...)``). Per step this saves pickling it out of a worker,
  stacking it, and storing it in the rollout buffer (P = 32 of the F + P = 38 numbers per node).
- :class:`MasksFromObservation` (around the vec env): ``MaskablePPO`` asks the environments for
  their action masks before every step (``env_method("action_masks")``), one more round trip to
  every worker process; the observation already carries the same mask, so it is answered from
  the last observation.
- :func:`make_vec_env`: ``subproc`` splits the environments over one worker process per CPU
  (:func:`worker_cpus`: the CPUs this process may run on, within its cgroup's CPU quota;
  :class:`ShardedSubprocVecEnv`: each worker steps its share with a ``DummyVecEnv``), so that the
  belief updates of a step run on all cores while the main process waits; ``dummy`` steps them one
  after the other in the main process (``DummyVecEnv``). Both give the same transitions for the
  same seeds (environment i is seeded ``seed + i`` either way): only the speed differs. The
  ``subproc`` workers also collect whole PPO rollouts with a copy of the policy
  (:meth:`ShardedSubprocVecEnv.worker_rollouts`, :mod:`ipp_bench.train.rollout`).

Why not SB3's ``SubprocVecEnv``: it runs one process per environment and sends each its own
message every step. With 16 environments on 2 cores that is 32 pipe hand-overs per step, and on
a busy machine each wake-up of a worker costs the main process its time slice, so the main process
spends its step writing actions to the pipes.
"""

from __future__ import annotations

import bisect
import multiprocessing as mp
import signal
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import CloudpickleWrapper

from ipp_bench.core._threads import available_cpus
from ipp_bench.core.config import TIME_TOL_S

VEC_ENVS = ("subproc", "dummy")


def worker_cpus() -> int:
    """The CPUs the training may keep busy: those this process may run on, within its cgroup's quota
    (:func:`~ipp_bench.core._threads.available_cpus`)."""
    return available_cpus()


def roadmap_pos_encoding(env: gym.Env) -> np.ndarray:
    """The (N, P) float32 positional encoding of a (wrapped) ``GraphIPPEnv``'s roadmap."""
    return np.asarray(env.unwrapped.roadmap.pos_encoding, dtype=np.float32)


REWARDS = ("paper", "metric")


def _record_time(record: Any) -> float:
    return record.time_s


def report_value(mission: Any) -> float:
    """Sum over the report times (within the budget) of the ROI uncertainty reduction [%] as of that
    time, counting those not reached yet at the latest value: what the episode's metric would be if
    nothing more were measured."""
    total = 0
    history = mission.history
    for t in mission.config.mission.report_times_in_budget:
        # Mission.metrics_at(t)'s record (the last one at or before t; the records are in time order), read in
        # place: metrics_at copies it into a dict (dataclasses.asdict), which cost more than the rest of the reward
        i = bisect.bisect_right(history, t + TIME_TOL_S, key=_record_time)
        total += history[max(i - 1, 0)].uncertainty_reduction_pct
    return float(total)


class MetricReward(gym.Wrapper):
    """The leaderboard's metric as the reward (``ipp-bench train --reward metric``): each step earns
    the change of :func:`report_value` over (10 x the number of report times), so an episode's
    rewards sum to its mean ROI uncertainty reduction over the report times / 10, less what the
    start's read-out gave before the first action (the evaluation ROI is the truth's: a training
    signal the policy never observes).

    The paper's reward (the env's own: the step's reduction of the belief-ROI trace relative to the
    trace before it) pays a late relative reduction as much as an early one of the same ratio, so a
    policy trained on it may trade the early report times for the late ones.
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self._value = 0.0
        self._scale = 1.0

    def reset(self, **kwargs: Any):
        obs, info = self.env.reset(**kwargs)
        mission = self.env.unwrapped.mission
        self._value = report_value(mission)
        self._scale = 10.0 * (len(mission.config.mission.report_times_in_budget) or 1)
        return obs, info

    def step(self, action: Any):
        obs, _, terminated, truncated, info = self.env.step(action)
        value = report_value(self.env.unwrapped.mission)
        reward, self._value = (value - self._value) / self._scale, value
        return obs, reward, terminated, truncated, info

    def action_masks(self) -> np.ndarray:
        return self.env.unwrapped.action_masks()


def make_train_env(cfg: Any, index: int = 0) -> gym.Env:
    """Training task ``index`` of a run (``cfg.tasks[index % n]``, a :class:`~ipp_bench.train.args.TrainArgs`)
    with its ``--env`` overrides, its reward and the node features its network reads."""
    from ipp_bench.envs.registry import make_env, parse_overrides
    from ipp_bench.policies.features import gain_feature_wrapper

    env = make_env(cfg.tasks[index % len(cfg.tasks)], **parse_overrides(cfg.env))
    if cfg.reward == "metric":
        env = MetricReward(env)
    if cfg.invariant:
        return gain_feature_wrapper(env, invariant=True)
    return gain_feature_wrapper(env) if cfg.gain_feature else env


class DropPosEncoding(gym.ObservationWrapper):
    """Removes ``pos_encoding`` from a graph observation (the policy holds the roadmap's constant)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.observation_space = spaces.Dict(
            {k: v for k, v in env.observation_space.spaces.items() if k != "pos_encoding"})

    def observation(self, observation: dict) -> dict:
        return {k: v for k, v in observation.items() if k != "pos_encoding"}

    def action_masks(self) -> np.ndarray:
        return self.env.unwrapped.action_masks()


class MasksFromObservation(VecEnvWrapper):
    """Answers ``env_method("action_masks")`` from the ``action_mask`` of the last observation."""

    def __init__(self, venv: VecEnv) -> None:
        super().__init__(venv)
        self._masks: np.ndarray | None = None

    def reset(self):
        obs = self.venv.reset()
        self._masks = obs["action_mask"].astype(bool)
        return obs

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        self._masks = obs["action_mask"].astype(bool)  # after an auto-reset: the new episode's mask
        return obs, rewards, dones, infos

    def env_method(self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any) -> list:
        if method_name == "action_masks" and indices is None and self._masks is not None:
            return list(self._masks)
        return self.venv.env_method(method_name, *method_args, indices=indices, **method_kwargs)


def _shard_worker(remote, parent_remote, env_fns: CloudpickleWrapper) -> None:
    """Worker process of :class:`ShardedSubprocVecEnv`: a ``DummyVecEnv`` over its environments."""
    # Ctrl-C is the main process's to handle (it saves and says how to resume); the workers end with it.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # a forked worker inherits the main process's SIGTERM handler (`ipp-bench train` raises
    # KeyboardInterrupt there to save and stop); a worker terminated at exit just ends, silently
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    parent_remote.close()
    venv = DummyVecEnv(env_fns.var)
    from ipp_bench.train.rollout import WorkerRollout

    rollouts = WorkerRollout()
    while True:
        try:
            cmd, data = remote.recv()
        except (EOFError, KeyboardInterrupt):
            break
        try:
            if cmd == "step":
                obs, rewards, dones, infos = venv.step(data)
                rollouts.episode_starts = dones
                result: Any = (obs, rewards, dones, infos, venv.reset_infos)
            elif cmd == "rollout":  # a whole rollout of this worker's environments (train.rollout)
                result = rollouts.run(venv, data.var)
            elif cmd == "half":  # the second half of a PPO minibatch's gradient (train.update)
                from ipp_bench.train.update import half_gradient

                result = half_gradient(rollouts.policy, data)
            elif cmd == "reset":
                venv._seeds, venv._options = data
                result = (venv.reset(), venv.reset_infos)
                rollouts.reset(venv.num_envs)
            elif cmd == "spaces":
                result = (venv.observation_space, venv.action_space)
            elif cmd == "close":
                venv.close()
                remote.send(("ok", None))
                break
            else:  # has_attr, env_method, get_attr, set_attr, env_is_wrapped (on some of its envs)
                args, kwargs = data
                result = getattr(venv, cmd)(*args, **kwargs)
            remote.send(("ok", result))  # pickled before anything is written: a failure sends nothing
        except Exception as err:  # noqa: BLE001 - handed to the main process, which raises it
            remote.send(("error", err))
    remote.close()


class ShardedSubprocVecEnv(VecEnv):
    """Environments split over ``n_workers`` processes, each stepping its share one after the other.

    Environment i is the same in every respect as in a ``DummyVecEnv`` of the same ``env_fns``
    (seeded ``seed + i``, auto-reset with ``terminal_observation`` in its info).
    """

    def __init__(self, env_fns: Sequence[Callable[[], gym.Env]], n_workers: int, start_method: str = "fork") -> None:
        shards = [s for s in np.array_split(np.arange(len(env_fns)), max(1, n_workers)) if len(s)]
        self._shards = [s.tolist() for s in shards]
        self._owner = {i: (w, j) for w, shard in enumerate(self._shards) for j, i in enumerate(shard)}
        ctx = mp.get_context(start_method)
        self.remotes, self.processes = [], []
        for shard in self._shards:
            remote, work_remote = ctx.Pipe()
            proc = ctx.Process(target=_shard_worker, daemon=True,
                               args=(work_remote, remote, CloudpickleWrapper([env_fns[i] for i in shard])))
            proc.start()
            work_remote.close()
            self.remotes.append(remote)
            self.processes.append(proc)
        self.closed = False
        self.remotes[0].send(("spaces", None))
        observation_space, action_space = self._recv_all(self.remotes[:1])[0]
        super().__init__(len(env_fns), observation_space, action_space)

    @staticmethod
    def _recv_all(remotes: Sequence[Any]) -> list:
        """Every worker's answer (all read before an error is raised, so none is left in a pipe)."""
        answers = [remote.recv() for remote in remotes]
        for status, result in answers:
            if status == "error":
                raise result
        return [result for _, result in answers]

    def _merge_obs(self, parts: list) -> Any:
        if isinstance(parts[0], dict):
            return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        return np.concatenate(parts)

    def reset(self):
        for remote, shard in zip(self.remotes, self._shards, strict=True):
            remote.send(("reset", ([self._seeds[i] for i in shard], [self._options[i] for i in shard])))
        results = self._recv_all(self.remotes)
        self.reset_infos = [info for _, infos in results for info in infos]
        self._reset_seeds()
        self._reset_options()
        return self._merge_obs([obs for obs, _ in results])

    def step_async(self, actions: np.ndarray) -> None:
        for remote, shard in zip(self.remotes, self._shards, strict=True):
            remote.send(("step", actions[shard]))

    def step_wait(self):
        results = self._recv_all(self.remotes)
        self.reset_infos = [info for *_, infos in results for info in infos]
        return (self._merge_obs([r[0] for r in results]), np.concatenate([r[1] for r in results]),
                np.concatenate([r[2] for r in results]), [info for r in results for info in r[3]])

    def worker_rollouts(self, policy_spec: Any, state: dict, n_steps: int, gamma: float, seed: int) -> list[dict]:
        """Every worker's rollout of its environments (:class:`ipp_bench.train.rollout.WorkerRollout`), in
        environment order; ``policy_spec`` (the policy's class and constructor arguments) is needed once."""
        from ipp_bench.train.rollout import rollout_seed

        for remote, shard in zip(self.remotes, self._shards, strict=True):
            env_seeds = [rollout_seed(seed, i) for i in shard]
            remote.send(("rollout", CloudpickleWrapper((policy_spec, state, n_steps, gamma, env_seeds))))
        return self._recv_all(self.remotes)

    def close(self) -> None:
        if self.closed:
            return
        for remote in self.remotes:
            remote.send(("close", None))
        for remote in self.remotes:
            try:
                remote.recv()
            except EOFError:
                pass
        for proc in self.processes:
            proc.join()
        self.closed = True

    def _call(self, cmd: str, indices: Any, *args: Any, **kwargs: Any) -> list:
        """``DummyVecEnv.<cmd>(*args, indices=local, **kwargs)`` in the workers owning ``indices``."""
        order = [self._owner[i] for i in self._get_indices(indices)]
        asked = [w for w in range(len(self._shards)) if any(o[0] == w for o in order)]
        for w in asked:
            local = [j for ow, j in order if ow == w]
            self.remotes[w].send((cmd, (args, {**kwargs, "indices": local})))
        results = self._recv_all([self.remotes[w] for w in asked])
        answers = {w: iter(r if r is not None else [None] * len(order)) for w, r in zip(asked, results, strict=True)}
        return [next(answers[w]) for w, _ in order]

    def has_attr(self, attr_name: str) -> bool:
        for remote in self.remotes:
            remote.send(("has_attr", ((attr_name,), {})))
        return all(self._recv_all(self.remotes))

    def env_method(self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any) -> list:
        return self._call("env_method", indices, method_name, *method_args, **method_kwargs)

    def get_attr(self, attr_name: str, indices: Any = None) -> list:
        return self._call("get_attr", indices, attr_name)

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        self._call("set_attr", indices, attr_name, value)

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: Any = None) -> list[bool]:
        return self._call("env_is_wrapped", indices, wrapper_class)


def make_vec_env(make_env: Callable[[], gym.Env] | Sequence[Callable[[], gym.Env]], n_envs: int,
                 kind: str = "subproc") -> VecEnv:
    """``n_envs`` copies of ``make_env()`` (a graph env, Monitor-wrapped by the caller), or one
    environment from each of ``n_envs`` factories, without the positional encoding in the
    observations, with masks from the observations.

    Raises:
        ValueError: ``kind`` is not one of :data:`VEC_ENVS`.
    """
    if kind not in VEC_ENVS:
        raise ValueError(f"vec env {kind!r} is invalid: expected one of {VEC_ENVS}")

    factories = list(make_env) if isinstance(make_env, Sequence) else [make_env] * n_envs
    if len(factories) != n_envs:
        raise ValueError(f"make_vec_env: {len(factories)} environment factories for n_envs = {n_envs}")

    def dropping(factory: Callable[[], gym.Env]) -> Callable[[], gym.Env]:
        return lambda: DropPosEncoding(factory())

    makers = [dropping(f) for f in factories]
    if kind == "subproc":
        # fork: the workers start in well under a second (forkserver would re-import torch in each).
        venv: VecEnv = ShardedSubprocVecEnv(makers, min(n_envs, worker_cpus()))
    else:
        from ipp_bench.train.rollout import RolloutDummyVecEnv

        venv = RolloutDummyVecEnv(makers)
    return MasksFromObservation(venv)
