"""AttentionPolicy inside sb3-contrib's MaskablePPO."""

import numpy as np
import pytest
import torch

pytest.importorskip("sb3_contrib")
gym = pytest.importorskip("gymnasium")

from sb3_contrib import MaskablePPO

import ipp_bench.envs  # noqa: F401
from ipp_bench.policies.sb3 import AttentionPolicy, PointerActionNet


@pytest.fixture(scope="module")
def env():
    return gym.make("ipp_bench/Grid15-v0")


@pytest.fixture(scope="module")
def model(env):
    return MaskablePPO(AttentionPolicy, env, n_steps=32, batch_size=16, n_epochs=1, seed=0,
                       policy_kwargs={"net_config": {"embed_dim": 32, "n_heads": 2, "ff_dim": 64}})


def test_policy_is_built_on_sb3_hooks_and_optimizer_sees_the_pointer(model):
    policy = model.policy
    assert isinstance(policy.action_net, PointerActionNet)
    in_optimizer = {id(p) for group in policy.optimizer.param_groups for p in group["params"]}
    assert all(id(p) in in_optimizer for p in policy.parameters())
    assert all(id(p) in in_optimizer for p in policy.action_net.parameters())


def test_masked_actions_never_taken_while_sampling(env, model):
    obs, _ = env.reset(seed=1)
    for _ in range(60):
        mask = env.unwrapped.action_masks()
        action, _ = model.predict(obs, action_masks=mask, deterministic=False)
        assert mask[int(action)]
        obs, _, term, _, _ = env.step(int(action))
        if term:
            obs, _ = env.reset()


def test_single_valid_neighbour(env, model):
    obs, _ = env.reset(seed=2)
    for j in (0, 13):
        only = {**obs, "action_mask": np.eye(20, dtype=np.int8)[j]}
        mask = only["action_mask"].astype(bool)
        for deterministic in (True, False):
            for _ in range(20):
                action, _ = model.predict(only, action_masks=mask, deterministic=deterministic)
                assert int(action) == j
        # Also without SB3's own masking: the policy reads the mask from the observation.
        obs_t, _ = model.policy.obs_to_tensor(only)
        dist = model.policy.get_distribution(obs_t)
        assert dist.distribution.probs[0, j].item() == pytest.approx(1.0)


def test_save_load_round_trip_gives_identical_actions(env, model, tmp_path):
    model.learn(32)  # some non-initial weights
    path = tmp_path / "model.zip"
    model.save(path)
    loaded = MaskablePPO.load(path)
    obs, _ = env.reset(seed=5)
    for _ in range(15):
        mask = env.unwrapped.action_masks()
        a1, _ = model.predict(obs, action_masks=mask, deterministic=True)
        a2, _ = loaded.predict(obs, action_masks=mask, deterministic=True)
        assert int(a1) == int(a2)
        t1, _ = model.policy.obs_to_tensor(obs)
        with torch.no_grad():
            torch.testing.assert_close(model.policy.get_distribution(t1).distribution.logits,
                                       loaded.policy.get_distribution(t1).distribution.logits)
        obs, _, term, _, _ = env.step(int(a1))
        if term:
            break


def test_attention_net_view_matches_policy(env, model):
    obs, _ = env.reset(seed=7)
    t, _ = model.policy.obs_to_tensor(obs)
    net = model.policy.attention_net()
    with torch.no_grad():
        logits, value = net.forward_obs(t)
        ref_value = model.policy.predict_values(t)
        ref_logits = model.policy.get_distribution(t).distribution.logits
    torch.testing.assert_close(value, ref_value[:, 0])
    mask = t["action_mask"].bool()
    torch.testing.assert_close(torch.softmax(logits, -1), torch.softmax(ref_logits, -1))
    assert torch.all(torch.softmax(logits, -1)[~mask] == 0)


def test_wrong_observation_space_is_refused():
    from gymnasium import spaces

    box = spaces.Box(0, 1, (4,))
    with pytest.raises(TypeError, match="Dict observation"):
        AttentionPolicy(box, spaces.Discrete(3), lambda _: 1e-4)
