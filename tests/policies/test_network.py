"""The attention network: exactness of the shortcut, masking, size independence."""

import numpy as np
import pytest
import torch

from ipp_bench.policies.network import AttentionNet, NetConfig, obs_to_inputs

from .conftest import fake_obs, to_batch


def test_fast_encoder_equals_full_transformer_layer():
    net = AttentionNet().eval()
    obs = fake_obs(n_nodes=80)
    obs["neighbours"][0, 5] = obs["current_node"][0, 0]  # the current node may also be a neighbour
    nf, pe, cur, nb, _, budget = obs_to_inputs(obs)
    with torch.no_grad():
        fast = net.encoder(nf, pe, cur, nb, budget)
        full = net.encoder.encode_all(nf, pe, cur, budget)
    idx = torch.cat([cur[:, None], nb], dim=1)
    ref = full.gather(1, idx[..., None].expand(-1, -1, full.shape[-1]))
    torch.testing.assert_close(fast, ref, atol=1e-5, rtol=1e-5)


def test_masked_neighbours_get_no_probability():
    net = AttentionNet().eval()
    obs = fake_obs()
    with torch.no_grad():
        logits, value = net.forward_obs(obs)
    probs = torch.softmax(logits, dim=-1)
    mask = obs["action_mask"].bool()
    assert torch.all(probs[~mask] == 0)
    torch.testing.assert_close(probs.sum(-1), torch.ones(len(probs)))
    assert torch.all(mask.gather(1, logits.argmax(-1, keepdim=True)))
    assert value.shape == (4,) and torch.isfinite(value).all()
    assert torch.all(logits[mask].abs() <= net.cfg.tanh_clip)


def test_single_valid_neighbour_always_chosen():
    net = AttentionNet().eval()
    obs = fake_obs(batch=1)
    for j in (0, 7, 19):
        obs["action_mask"][:] = 0
        obs["action_mask"][0, j] = 1
        with torch.no_grad():
            logits, _ = net.forward_obs(obs)
        probs = torch.softmax(logits, -1)[0]
        assert probs[j] == 1.0
        draws = torch.multinomial(probs, 200, replacement=True)
        assert torch.all(draws == j)


def test_no_valid_neighbour_stays_finite_in_value():
    net = AttentionNet().eval()
    obs = fake_obs(batch=2)
    obs["action_mask"][:] = 0
    with torch.no_grad():
        _, value = net.forward_obs(obs)
    assert torch.isfinite(value).all()


@pytest.mark.parametrize("n_nodes,k", [(30, 20), (450, 20), (800, 20), (800, 12)])
def test_same_weights_any_number_of_nodes_and_neighbours(n_nodes, k):
    net = AttentionNet().eval()
    obs = fake_obs(n_nodes=n_nodes, k=k, batch=2)
    with torch.no_grad():
        logits, value = net.forward_obs(obs)
    assert logits.shape == (2, k) and value.shape == (2,)
    assert torch.isfinite(logits[obs["action_mask"].bool()]).all()


def test_node_order_does_not_matter():
    """Relabelling the nodes (and the indices with them) leaves the policy unchanged."""
    net = AttentionNet().eval()
    obs = fake_obs(n_nodes=50, batch=2)
    perm = torch.randperm(50)
    inv = torch.argsort(perm)
    permuted = dict(obs)
    permuted["node_features"] = obs["node_features"][:, perm]
    permuted["pos_encoding"] = obs["pos_encoding"][:, perm]
    permuted["current_node"] = inv[obs["current_node"]]
    permuted["neighbours"] = inv[obs["neighbours"]]
    with torch.no_grad():
        a, va = net.forward_obs(obs)
        b, vb = net.forward_obs(permuted)
    torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(va, vb, atol=1e-5, rtol=1e-5)


def test_same_weights_on_grid15_and_grid20_envs():
    gym = pytest.importorskip("gymnasium")
    import ipp_bench.envs  # noqa: F401

    net = AttentionNet().eval()
    for task, n in (("ipp_bench/Grid15Eval-v1", 450), ("ipp_bench/Grid20Eval-v1", 800)):
        env = gym.make(task)
        obs, _ = env.reset(seed=3)
        assert obs["node_features"].shape[0] == n
        for _ in range(5):
            with torch.no_grad():
                logits, _ = net.forward_obs(to_batch(obs))
            a = int(logits.argmax())
            assert env.unwrapped.action_masks()[a]
            obs, *_ = env.step(a)


def test_config_validation_names_the_field():
    with pytest.raises(ValueError, match="embed_dim"):
        NetConfig(embed_dim=130, n_heads=4)
    with pytest.raises(ValueError, match="unknown NetConfig fields"):
        NetConfig.from_dict({"hidden": 3})
    with pytest.raises(ValueError, match="NetConfig.invariant needs node_dim = 6"):
        NetConfig(node_dim=7, invariant=True)


def test_inert_fields_are_accepted_at_their_value_and_refused_at_any_other():
    """A net_config written with the keys of a network that adds greedy's score to its logits loads as the
    plain network where they are off, and is refused (one line naming the key and the value it needs)
    where the network would need them."""
    from ipp_bench.policies.network import INERT_FIELDS

    base = {"node_dim": 6, "embed_dim": 16, "n_heads": 2, "ff_dim": 32, "invariant": True}
    assert NetConfig.from_dict({**base, **INERT_FIELDS}) == NetConfig.from_dict(base)
    assert set(INERT_FIELDS).isdisjoint(NetConfig().to_dict())  # never written again
    for name, value in (("rate_skip", True), ("rate_skip_init", 5.0), ("skip_teacher", "far")):
        with pytest.raises(ValueError) as err:
            NetConfig.from_dict({**base, **INERT_FIELDS, name: value})
        msg = str(err.value)
        assert f"NetConfig.{name} = {value!r} is not supported" in msg and f"{INERT_FIELDS[name]!r}" in msg
        assert "\n" not in msg


def test_gradients_reach_every_parameter():
    net = AttentionNet()
    logits, value = net.forward_obs(fake_obs())
    (torch.log_softmax(logits.clamp_min(-1e8), -1)[:, 0].sum() + value.sum()).backward()
    missing = [n for n, p in net.named_parameters() if p.grad is None or not torch.isfinite(p.grad).all()]
    assert not missing
    assert np.isfinite(float(value.detach().sum()))
