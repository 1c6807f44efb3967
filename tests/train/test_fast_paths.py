"""The training's fast paths give what the plain formulas give: the encoder's fused attention against the
scores formulation it replaced (and, through ``tests/policies``, the full transformer layer)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from policies.conftest import fake_obs

from ipp_bench.policies.network import AttentionEncoder, AttentionNet, NetConfig, obs_to_inputs
from ipp_bench.policies.sb3 import AttentionPolicy


def scores_encoder(enc: AttentionEncoder, node_features, pos_encoding, current, neighbours, budget):
    """The encoder as it was before the fused attention (commit 4e9f32f): the (B, QH, N) scores formed,
    the current node's own input map added by ``scatter_add``, softmax, weighted sum of the inputs."""
    b, _, f = node_features.shape
    lay, d = enc.layer, enc.cfg.embed_dim
    heads = lay.n_heads
    dh = d // heads
    delta = enc._current_delta(node_features, current, budget)
    idx = torch.cat([current.view(b, 1), neighbours], dim=1)
    nq = idx.shape[1]
    x_q = node_features.gather(1, idx.unsqueeze(-1).expand(-1, -1, f))
    pe_q = pos_encoding.gather(1, idx.unsqueeze(-1).expand(-1, -1, pos_encoding.shape[2]))
    is_cur = (idx == current.view(b, 1)).unsqueeze(-1).to(x_q.dtype)
    h_q = enc.w_l(x_q) + enc.w_pe(pe_q) + is_cur * delta
    q = lay.w_q(h_q).view(b, nq, heads, dh)
    w_k = lay.w_kv.weight[:d].view(heads, dh, d)
    w_v = lay.w_kv.weight[d:].view(heads, dh, d)
    qk = torch.einsum("bqhe,hed->bqhd", q, w_k).reshape(b, nq * heads, d)
    x = torch.cat([node_features, pos_encoding], dim=-1)
    w_in = torch.cat([enc.w_l.weight, enc.w_pe.weight], dim=1)
    scores = (qk @ w_in) @ x.transpose(1, 2)
    cur_col = current.view(b, 1, 1).expand(b, nq * heads, 1)
    scores = scores.scatter_add(2, cur_col, qk @ delta.transpose(1, 2))
    attn = torch.softmax(scores * (1.0 / math.sqrt(dh)), dim=-1)
    agg = (attn @ x) @ w_in.T + (enc.w_l.bias + enc.w_pe.bias) + attn.gather(2, cur_col) * delta
    out = torch.einsum("bqhd,hed->bqhe", agg.view(b, nq, heads, d), w_v).reshape(b, nq, d)
    h = lay.norm1(h_q + lay.w_o(out))
    return lay.norm2(h + lay.ff(h))


@pytest.mark.parametrize("embed_dim, n_heads", [(64, 4), (128, 4), (48, 3)])
def test_fused_attention_equals_the_scores_formulation(embed_dim, n_heads):
    """Outputs and every weight's gradient agree to float32 rounding, the current node also a neighbour."""
    net = AttentionNet(NetConfig(embed_dim=embed_dim, n_heads=n_heads, ff_dim=2 * embed_dim))
    obs = fake_obs(n_nodes=300, batch=6)
    obs["neighbours"][0, 5] = obs["current_node"][0, 0]
    nf, pe, cur, nb, _, budget = obs_to_inputs(obs)
    outs, grads = [], []
    for fn in (net.encoder, lambda *a: scores_encoder(net.encoder, *a)):
        net.zero_grad()
        out = fn(nf, pe, cur, nb, budget)
        (out * torch.linspace(-1, 1, out.numel()).view_as(out)).sum().backward()
        outs.append(out.detach())
        grads.append(torch.cat([p.grad.reshape(-1) for p in net.encoder.parameters() if p.grad is not None]))
    torch.testing.assert_close(outs[0], outs[1], atol=2e-6, rtol=1e-5)
    torch.testing.assert_close(grads[0], grads[1], atol=1e-5, rtol=1e-4)


def test_report_value_is_the_sum_of_metrics_at_the_report_times():
    """The reward's value read in place equals, bit for bit, the sum over ``Mission.metrics_at`` at every
    step of whole episodes (a leg across a report time included)."""
    from ipp_bench.envs.registry import make_env
    from ipp_bench.train.vec import report_value

    env = make_env("ipp_bench/Grid15Train-v1")
    rng = np.random.default_rng(0)
    checked = 0
    for seed in range(2):
        obs, _ = env.reset(seed=seed)
        done = False
        while not done:
            mission = env.unwrapped.mission
            times = mission.config.mission.report_times_in_budget
            expected = float(sum(mission.metrics_at(t)["uncertainty_reduction_pct"] for t in times))
            assert report_value(mission) == expected
            checked += 1
            obs, _, term, trunc, _ = env.step(int(rng.choice(np.flatnonzero(obs["action_mask"]))))
            done = term or trunc
    assert checked > 20


def _rollout_buffer(algorithm, kind: str, monkeypatch, deterministic: bool = True) -> dict:
    """One rollout of ``algorithm`` (4 environments of Grid15Train-v1 with a 30 s budget, so that
    episodes end inside it) on a ``kind`` vec env, with the policy's most likely actions."""
    from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy

    from ipp_bench.train import rollout

    if not deterministic:
        return _buffer_of(algorithm, kind)
    forward = MaskableActorCriticPolicy.forward
    # inherited by the forked workers: the same actions in both loops, whatever their random numbers
    monkeypatch.setattr(MaskableActorCriticPolicy, "forward",
                        lambda self, obs, deterministic=False, action_masks=None:
                        forward(self, obs, deterministic=True, action_masks=action_masks))
    monkeypatch.setattr(rollout, "_draw", lambda probs, generators: probs.argmax(dim=1))
    return _buffer_of(algorithm, kind)


def _buffer_of(algorithm, kind: str) -> dict:
    from ipp_bench.train.args import TrainArgs
    from ipp_bench.train.ppo import make_ppo_vec_env, policy_kwargs

    cfg = TrainArgs(task="ipp_bench/Grid15Train-v1", env=["budget_s=30"], n_envs=4, n_steps=24, batch_size=32,
                    embed_dim=16, n_heads=2, ff_dim=32, vec_env=kind)
    venv = make_ppo_vec_env(cfg)
    torch.manual_seed(0)
    model = algorithm(AttentionPolicy, venv, n_steps=cfg.n_steps, batch_size=cfg.batch_size, seed=0,
                      policy_kwargs=policy_kwargs(cfg))
    _, callback = model._setup_learn(cfg.n_envs * cfg.n_steps, None)
    venv.seed(7)
    model._last_obs = venv.reset()
    model._last_episode_starts = np.ones(cfg.n_envs, dtype=bool)
    assert model.collect_rollouts(venv, callback, model.rollout_buffer, cfg.n_steps)
    buf = model.rollout_buffer
    out = {f"obs/{k}": v.copy() for k, v in buf.observations.items()}
    out |= {k: getattr(buf, k).copy() for k in ("actions", "rewards", "episode_starts", "values", "log_probs",
                                                  "action_masks", "advantages", "returns")}
    out["timesteps"], out["episodes"] = model.num_timesteps, len(model.ep_info_buffer)
    venv.close()
    return out


def test_worker_rollouts_store_what_sb3s_loop_stores(monkeypatch):
    """The workers' rollout (ipp_bench.train.rollout) fills the buffer as MaskablePPO's own loop does in one
    process: the same observations, actions, rewards, episode starts, masks (exactly), values, log-probabilities,
    advantages and returns (to float32 rounding: the workers' forward passes take 2 environments, not 4)."""
    from sb3_contrib import MaskablePPO

    from ipp_bench.train.rollout import WorkerRolloutPPO

    ref = _rollout_buffer(MaskablePPO, "dummy", monkeypatch)
    new = _rollout_buffer(WorkerRolloutPPO, "subproc", monkeypatch)
    assert ref["episode_starts"][1:].sum() >= 4  # episodes ended inside the rollout
    assert ref["timesteps"] == new["timesteps"] and ref["episodes"] == new["episodes"] > 0
    for key in ref:
        if key in ("values", "log_probs", "advantages", "returns"):
            np.testing.assert_allclose(new[key], ref[key], rtol=1e-5, atol=1e-5, err_msg=key)
        else:
            np.testing.assert_array_equal(new[key], ref[key], err_msg=key)


def test_the_draws_do_not_depend_on_how_the_environments_are_split(monkeypatch):
    """Each environment draws its actions from its own generator: one process (dummy) and worker processes
    (subproc, 2 workers here) store the same actions, rewards and episodes, with random draws."""
    from ipp_bench.train import rollout

    draws = rollout._draw
    monkeypatch.setattr(rollout, "_draw", draws)  # the real draws (the fixture below patches nothing else)
    one = _rollout_buffer(rollout.WorkerRolloutPPO, "dummy", monkeypatch, deterministic=False)
    split = _rollout_buffer(rollout.WorkerRolloutPPO, "subproc", monkeypatch, deterministic=False)
    for key in ("actions", "rewards", "episode_starts", "action_masks"):
        np.testing.assert_array_equal(split[key], one[key], err_msg=key)
    assert len(np.unique(one["actions"])) > 1 and one["episodes"] == split["episodes"]


def test_worker_rollouts_resume_from_a_saved_model(tmp_path):
    """A model saved after worker rollouts loads (its archive holds no worker state) and its new workers get the
    policy: learning goes on from the saved weights and step count."""
    from ipp_bench.train.archive import load_objects, pickled_entries, read_archive
    from ipp_bench.train.args import TrainArgs
    from ipp_bench.train.ppo import _archive_objects, make_ppo_vec_env, policy_kwargs
    from ipp_bench.train.rollout import WorkerRolloutPPO

    cfg = TrainArgs(task="ipp_bench/Grid15Train-v1", n_envs=2, n_steps=8, batch_size=16, embed_dim=16, n_heads=2,
                    ff_dim=32, vec_env="subproc")
    venv = make_ppo_vec_env(cfg)
    model = WorkerRolloutPPO(AttentionPolicy, venv, n_steps=8, batch_size=16, seed=0, policy_kwargs=policy_kwargs(cfg))
    model.learn(16)
    model.save(tmp_path / "latest.zip")
    venv.close()
    data, _ = read_archive(tmp_path / "latest.zip")
    assert "_policy_sent_to" not in data and "_rollouts" not in data
    venv = make_ppo_vec_env(cfg)
    loaded = WorkerRolloutPPO.load(tmp_path / "latest.zip", env=venv,
                                   custom_objects=load_objects(tmp_path / "latest.zip", _archive_objects(cfg, venv)))
    assert set(pickled_entries(data)) <= set(_archive_objects(cfg, venv))
    loaded.learn(16, reset_num_timesteps=False)
    assert loaded.num_timesteps == 32
    venv.close()
