"""The PPO phase of ``ipp-bench train``: sb3-contrib's ``MaskablePPO`` with the attention policy, its
rollouts collected inside the environment workers (:mod:`ipp_bench.train.rollout`).

SB3's callbacks do what they were written for: ``CheckpointCallback`` keeps the numbered
checkpoints and ``learn(progress_bar=True)`` draws the bar. :class:`AfterUpdate` runs after every
PPO update, where SB3 has no hook of its own: it writes ``latest.zip`` (so that an interrupt loses
at most the rollout being collected) and validates when due. SB3's ``EvalCallback`` is not used: it
fires mid-rollout and scores episode returns, while validation here scores the ROI uncertainty
reduction at the report times through the leaderboard's episode loop
(:mod:`ipp_bench.train.validation`).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback

from ipp_bench.core.data import write_atomically
from ipp_bench.envs.registry import make_env, parse_overrides
from ipp_bench.policies.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from ipp_bench.train.archive import load_objects
from ipp_bench.train.args import TrainArgs
from ipp_bench.train.export import run_meta
from ipp_bench.train.validation import greedy_reference, validation


class ResumeError(ValueError):
    """A run folder's PPO checkpoint cannot be continued by this version."""


def policy_kwargs(cfg: TrainArgs) -> dict[str, Any]:
    """``AttentionPolicy`` arguments: the network sizes and the training roadmap's positional encoding."""
    from ipp_bench.train.vec import roadmap_pos_encoding

    env = make_env(cfg.task, **parse_overrides(cfg.env))
    pe = roadmap_pos_encoding(env)
    env.close()
    return {"net_config": cfg.net_config().to_dict(), "pos_encoding": pe}


def make_ppo_vec_env(cfg: TrainArgs):
    """The PPO environments (:func:`ipp_bench.train.vec.make_vec_env`): environment i on task
    ``cfg.tasks[i % n]``, Monitor-wrapped, no positional encoding in the observations."""
    from stable_baselines3.common.monitor import Monitor

    from ipp_bench.train.vec import make_train_env, make_vec_env

    def maker(i: int):
        return lambda: Monitor(make_train_env(cfg, i))

    return make_vec_env([maker(i) for i in range(cfg.n_envs)], cfg.n_envs, cfg.vec_env)


def atomic_save(model: Any, path: Path) -> None:
    """``model.save`` to a temporary file, then rename: an interrupt never leaves a broken archive."""
    write_atomically(path, model.save)


class AtomicCheckpoints(CheckpointCallback):
    """SB3's numbered checkpoints (``step_<n>_steps.zip``), each written whole or not at all."""

    def _on_step(self) -> bool:
        if self.n_calls % self.save_freq == 0:
            write_atomically(self._checkpoint_path(extension="zip"), self.model.save)
        return True


def _logger(run: Path):
    from stable_baselines3.common.logger import CSVOutputFormat, Logger, TensorBoardOutputFormat

    class AppendingCSV(CSVOutputFormat):
        """SB3's CSV output, keeping the rows written before a resume."""

        def __init__(self, filename: str) -> None:
            old = Path(filename).read_text() if Path(filename).is_file() else ""
            super().__init__(filename)
            if old.strip():
                self.file.write(old if old.endswith("\n") else old + "\n")
                self.file.flush()
                self.keys = old.splitlines()[0].split(self.separator)

    formats = [AppendingCSV(str(run / "progress.csv"))]
    try:
        formats.append(TensorBoardOutputFormat(str(run / "tb")))
    except (ImportError, AssertionError):
        print("tensorboard is not installed: no TensorBoard logs (pip install tensorboard)", file=sys.stderr)
    return Logger(str(run), formats)


def _fmt(d: dict) -> str:
    return ", ".join(f"{k.split('/', 1)[-1]} {v:.2f}" if isinstance(v, float) else f"{k} {v}" for k, v in d.items())


class AfterUpdate(BaseCallback):
    """After every PPO update: ``latest.zip``, the run state, the throughput, and the validation when
    due (a better score also writes ``best.zip`` and ``export.pt``)."""

    def __init__(self, cfg: TrainArgs, run: Path, state: Any, say: Callable[[str], None]) -> None:
        super().__init__()
        self.cfg, self.run, self.state, self.say = cfg, run, state, say
        self.t_last, self.steps_last = time.time(), 0

    def _on_training_start(self) -> None:
        self.t_last, self.steps_last = time.time(), self.num_timesteps

    def _on_step(self) -> bool:
        return True

    def _on_rollout_start(self) -> None:
        # called after each update (and once at the start): the model holds every step counted
        self.after_update()

    def after_update(self) -> None:
        n, state = self.model.num_timesteps, self.state
        if n == state.ppo_steps and (self.run / "checkpoints" / "latest.zip").is_file():
            return
        now = time.time()
        state.ppo_wall_s += now - self.t_last
        self.logger.record("time/steps_per_s", (n - self.steps_last) / max(now - self.t_last, 1e-9))
        self.t_last, self.steps_last = now, n
        atomic_save(self.model, self.run / "checkpoints" / "latest.zip")
        if n // self.cfg.eval_every > state.ppo_steps // self.cfg.eval_every or n >= self.cfg.total_steps:
            self.validate(n)
        state.ppo_steps = n
        state.save(self.run)
        self.t_last = time.time()  # validation time is not training time

    def validate(self, n: int) -> None:
        net = self.model.policy.attention_net()
        if self.state.greedy_val is None:
            self.state.greedy_val = greedy_reference(self.cfg)
        val = validation(net, self.cfg, self.state.greedy_val)
        self.model.policy.set_training_mode(False)
        for key, v in val.items():
            self.logger.record(key, v)
        msg = f"step {n}: validation {_fmt(val)}"
        if val["val/score"] > self.state.best_score:
            self.state.best_score, self.state.best_step = val["val/score"], n
            atomic_save(self.model, self.run / "checkpoints" / "best.zip")
            save_checkpoint(net, self.run / "export.pt", meta=run_meta(self.cfg, self.state, n, val))
            msg += " (best)"
        self.say(msg)
        self.logger.dump(n)


def _archive_objects(cfg: TrainArgs, venv: Any) -> dict[str, Any]:
    """What this package writes in the pickled entries of ``latest.zip``, rebuilt from the run's
    settings, so that resuming unpickles nothing (:func:`ipp_bench.train.archive.load_objects`).
    SB3 rebuilds the schedules and the rollout buffer from the plain entries, and the rollout state
    (last observation, episode starts) on the reset it does after every load; the episode-statistics
    window behind the logged ``rollout/ep_*`` means restarts empty."""
    from ipp_bench.policies.sb3 import AttentionPolicy

    return {"policy_class": AttentionPolicy, "policy_kwargs": policy_kwargs(cfg),
            "observation_space": venv.observation_space, "action_space": venv.action_space,
            "lr_schedule": None, "clip_range": cfg.clip_range, "clip_range_vf": None,
            "rollout_buffer_class": None, "_last_obs": None, "_last_episode_starts": None,
            "_last_original_obs": None, "ep_info_buffer": None, "ep_success_buffer": None}


def ppo(cfg: TrainArgs, run: Path, device: torch.device, state: Any, start: Path | None,
        say: Callable[[str], None]) -> None:
    """Train (or continue from ``checkpoints/latest.zip``) to ``cfg.total_steps``; ``start``: the
    weights a new PPO phase starts from. Writes ``last.pt``, and ``export.pt`` if no validation did."""
    from ipp_bench.policies.sb3 import AttentionPolicy
    from ipp_bench.train.rollout import WorkerRolloutPPO as MaskablePPO  # MaskablePPO, rollouts in the workers

    venv = make_ppo_vec_env(cfg)
    latest = run / "checkpoints" / "latest.zip"
    (run / "checkpoints").mkdir(exist_ok=True)
    if latest.is_file():
        try:
            model = MaskablePPO.load(latest, env=venv, device=device,
                                     custom_objects=load_objects(latest, _archive_objects(cfg, venv)))
        except CheckpointError as err:
            venv.close()
            raise ResumeError(f"--resume: {err}") from None
        except (ValueError, RuntimeError) as err:  # observations or weights that do not fit this version's
            venv.close()
            why = " ".join(str(err).split())
            raise ResumeError(f"--resume: {latest} does not fit this version's training environments ({why}); "
                              "finish that run with the ipp-bench version that started it, or start a new --out"
                              ) from None
        say(f"resuming PPO from {latest} at step {model.num_timesteps}")
    else:
        model = MaskablePPO(
            AttentionPolicy, venv, learning_rate=cfg.learning_rate, n_steps=cfg.n_steps,
            batch_size=cfg.batch_size, n_epochs=cfg.n_epochs, gamma=cfg.gamma, gae_lambda=cfg.gae_lambda,
            clip_range=cfg.clip_range, ent_coef=cfg.ent_coef, vf_coef=cfg.vf_coef,
            max_grad_norm=cfg.max_grad_norm, target_kl=cfg.target_kl or None,
            policy_kwargs=policy_kwargs(cfg), seed=cfg.seed, device=device, verbose=0)
        if start is not None:
            net, _ = load_checkpoint(start, device=device)
            model.policy.attention_net().load_state_dict(net.state_dict())
            say(f"PPO starts from the weights {start}")
        state.ppo_steps = 0
    model.set_logger(_logger(run))
    remaining = cfg.total_steps - model.num_timesteps
    if remaining <= 0:
        say(f"PPO already has {model.num_timesteps} >= --total-steps {cfg.total_steps} steps")
    else:
        after = AfterUpdate(cfg, run, state, say)
        numbered = AtomicCheckpoints(save_freq=max(cfg.checkpoint_every // cfg.n_envs, 1),
                                     save_path=str(run / "checkpoints"), name_prefix="step")
        model.learn(total_timesteps=remaining, callback=[after, numbered], reset_num_timesteps=False,
                    progress_bar=cfg.progress)
        after.after_update()  # the last update is followed by no rollout
    net = model.policy.attention_net()
    save_checkpoint(net, run / "last.pt", meta=run_meta(cfg, state, model.num_timesteps, {}))
    if not (run / "export.pt").is_file():
        save_checkpoint(net, run / "export.pt", meta=run_meta(cfg, state, model.num_timesteps, {}))
    venv.close()
