"""The PPO update in two halves (ipp_bench.train.update) against MaskablePPO's own update, and the same
weights whether the second half is computed in a worker process or in this one."""

import copy

import numpy as np
import pytest
import torch

pytest.importorskip("sb3_contrib")
gym = pytest.importorskip("gymnasium")

from sb3_contrib import MaskablePPO
from stable_baselines3.common.monitor import Monitor

import ipp_bench.envs  # noqa: F401
from ipp_bench.policies.sb3 import AttentionPolicy
from ipp_bench.train.rollout import WorkerRolloutPPO
from ipp_bench.train.update import RemoteHalf, split_train
from ipp_bench.train.vec import ShardedSubprocVecEnv, make_vec_env, roadmap_pos_encoding

TASK = "ipp_bench/Grid15-v0"
NET = {"embed_dim": 16, "n_heads": 2, "ff_dim": 32}


def _make():
    return Monitor(gym.make(TASK, budget_s=60.0))


def _pe():
    env = gym.make(TASK)
    pe = roadmap_pos_encoding(env)
    env.close()
    return pe


def _model(cls, venv, **kw):
    settings = {"n_steps": 16, "batch_size": 20, "n_epochs": 2, "seed": 0, "ent_coef": 0.01, "target_kl": None}
    settings.update(kw)
    return cls(AttentionPolicy, venv, policy_kwargs={"net_config": NET, "pos_encoding": _pe()}, **settings)


def _params(model) -> list[torch.Tensor]:
    return [p.detach().clone() for p in model.policy.parameters()]


@pytest.mark.parametrize("clip_range_vf", [None, 0.2])
def test_the_split_update_equals_maskable_ppos_update_to_float_rounding(clip_range_vf):
    """One rollout, then SB3's update and the split update from the same weights, optimizer state and buffer:
    the weights after two epochs agree to float32 rounding, and both moved (a test that can fail)."""
    venv = make_vec_env(_make, 3, "dummy")
    try:
        model = _model(MaskablePPO, venv, clip_range_vf=clip_range_vf)
        model._setup_learn(48, None)
        model.collect_rollouts(venv, model._init_callback(None), model.rollout_buffer, model.n_steps)
        before = _params(model)
        policy, optimizer = copy.deepcopy(model.policy.state_dict()), copy.deepcopy(model.policy.optimizer.state_dict())
        shuffle = np.random.get_state()  # the buffer's minibatches are drawn from numpy's global generator
        model.train()
        ours = _params(model)
        model.policy.load_state_dict(policy)
        model.policy.optimizer.load_state_dict(optimizer)
        np.random.set_state(shuffle)
        split_train(model, None)
        split = _params(model)
    finally:
        venv.close()
    moved = max(float((a - b).abs().max()) for a, b in zip(ours, before, strict=True))
    assert moved > 1e-4
    for a, b in zip(ours, split, strict=True):
        torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-6)


def test_a_kl_early_stop_stops_where_sb3s_does():
    """A tiny target KL stops both updates at the same minibatch: the weights still agree."""
    venv = make_vec_env(_make, 3, "dummy")
    try:
        model = _model(MaskablePPO, venv, target_kl=1e-6, learning_rate=3e-3)
        model._setup_learn(48, None)
        model.collect_rollouts(venv, model._init_callback(None), model.rollout_buffer, model.n_steps)
        state = copy.deepcopy(model.policy.state_dict()), copy.deepcopy(model.policy.optimizer.state_dict())
        shuffle = np.random.get_state()
        model.train()
        ours, updates = _params(model), model._n_updates
        model.policy.load_state_dict(state[0])
        model.policy.optimizer.load_state_dict(state[1])
        model._n_updates = 0
        np.random.set_state(shuffle)
        split_train(model, None)
        assert model._n_updates == updates
        for a, b in zip(ours, _params(model), strict=True):
            torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-6)
    finally:
        venv.close()


@pytest.fixture
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as the workers: the same kernels, the same rounding
    yield
    torch.set_num_threads(threads)


def test_the_worker_half_gives_the_same_weights_as_this_process(one_thread, monkeypatch):
    """From the same rollout, weights and optimizer state: the update whose second halves a worker process
    computes and the one computing both halves here give bit-identical weights (one torch thread in each)."""
    venv = make_vec_env(_make, 3, "subproc")
    try:
        assert isinstance(venv.venv, ShardedSubprocVecEnv)
        model = _model(WorkerRolloutPPO, venv)
        model._setup_learn(48, None)
        model.collect_rollouts(model.env, model._init_callback(None), model.rollout_buffer, model.n_steps)
        before = _params(model)
        state = copy.deepcopy(model.policy.state_dict()), copy.deepcopy(model.policy.optimizer.state_dict())
        shuffle = np.random.get_state()
        sent = []
        send = RemoteHalf.__call__
        monkeypatch.setattr(RemoteHalf, "__call__", lambda self, *a: (sent.append(a[2]), send(self, *a)))
        model.train()  # a worker computes the second halves
        assert sent == [20, 20, 8] * 2  # every minibatch's second half went to the worker (2 epochs)
        remote = _params(model)
        model.policy.load_state_dict(state[0])
        model.policy.optimizer.load_state_dict(state[1])
        np.random.set_state(shuffle)
        split_train(model, None)
        here = _params(model)
    finally:
        venv.close()
    assert max(float((a - b).abs().max()) for a, b in zip(remote, before, strict=True)) > 1e-4
    for a, b in zip(remote, here, strict=True):
        np.testing.assert_array_equal(a.numpy(), b.numpy())
