"""Ensemble checkpoints (ipp_bench.policies.network.AttentionEnsemble, benchmarks/ensemble_checkpoints.py):
the decision is the mean of the members' log-probabilities, the file round-trips, malformed ones and
training from one are one line."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
gym = pytest.importorskip("gymnasium")

import ipp_bench.envs  # noqa: E402,F401
from ipp_bench.planners import make_planner  # noqa: E402
from ipp_bench.planners.base import RobotView  # noqa: E402
from ipp_bench.policies.checkpoint import CheckpointError, load_checkpoint, save_checkpoint  # noqa: E402
from ipp_bench.policies.network import AttentionEnsemble, AttentionNet, NetConfig, obs_to_inputs  # noqa: E402

from .conftest import fake_obs  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import ensemble_checkpoints  # noqa: E402

CFG = NetConfig(embed_dim=16, n_heads=2, ff_dim=32)


def _nets(n: int, cfg: NetConfig = CFG) -> list[AttentionNet]:
    return [AttentionNet(cfg).eval() for _ in range(n)]


def test_the_ensemble_is_the_normalised_product_of_its_members_policies():
    nets = _nets(3)
    inputs = obs_to_inputs(fake_obs())
    mask = inputs[4]
    with torch.no_grad():
        log_p, value = AttentionEnsemble(nets)(*inputs)
        probs = [torch.softmax(n(*inputs)[0], -1) for n in nets]
        values = [n(*inputs)[1] for n in nets]
    # the geometric mean of the members' probabilities, renormalised, is softmax of the ensemble's output
    geo = (probs[0] * probs[1] * probs[2]) ** (1 / 3)
    geo = geo / geo.sum(-1, keepdim=True)
    assert torch.allclose(torch.softmax(log_p, -1), geo, atol=1e-6)
    assert torch.allclose(value, (values[0] + values[1] + values[2]) / 3, atol=1e-6)
    assert torch.isneginf(log_p[~mask]).all() and torch.isfinite(log_p[mask]).all()


def test_an_ensemble_of_one_network_twice_decides_as_the_network():
    net = _nets(1)[0]
    inputs = obs_to_inputs(fake_obs(seed=3))
    with torch.no_grad():
        one, _ = net(*inputs)
        two, _ = AttentionEnsemble([net, net])(*inputs)
    assert torch.allclose(two, torch.log_softmax(one, -1), atol=1e-6)


def test_members_must_share_one_network_shape():
    with pytest.raises(ValueError, match="share one NetConfig"):
        AttentionEnsemble([AttentionNet(CFG), AttentionNet(NetConfig(embed_dim=32, n_heads=2, ff_dim=32))])
    with pytest.raises(ValueError, match="2 to 16 networks"):
        AttentionEnsemble(_nets(1))


@pytest.fixture()
def members(tmp_path):
    paths = []
    for i, net in enumerate(_nets(2, NetConfig(node_dim=6, embed_dim=16, n_heads=2, ff_dim=32))):
        paths.append(save_checkpoint(net, tmp_path / f"m{i}.pt", meta={"command": f"made {i}"}))
    return paths


def test_the_script_writes_an_ensemble_that_loads_bit_for_bit(members, tmp_path):
    out = tmp_path / "ens.pt"
    assert ensemble_checkpoints.main([str(p) for p in members] + ["--out", str(out)]) == 0
    ens, meta = load_checkpoint(out)
    assert isinstance(ens, AttentionEnsemble) and len(ens.members) == 2
    for member, path in zip(ens.members, members):
        single, _ = load_checkpoint(path)
        assert all(torch.equal(a, b) for a, b in zip(member.state_dict().values(), single.state_dict().values()))
    assert meta["phase"] == "ensemble" and [m["command"] for m in meta["members"]] == ["made 0", "made 1"]


def test_the_attention_planner_flies_an_ensemble(members, tmp_path):
    out = tmp_path / "ens.pt"
    ensemble_checkpoints.main([str(p) for p in members] + ["--out", str(out)])
    env = gym.make("ipp_bench/Grid15Eval-v1")
    obs, _ = env.reset(seed=0)
    planner = make_planner(f"attention:checkpoint={out}")
    planner.reset(RobotView(env.unwrapped), 0)
    for _ in range(5):
        logits = planner._logits(obs)
        a = planner.act(obs)
        assert env.unwrapped.action_masks()[a] and a == int(np.argmax(logits))
        # its probabilities are a distribution over the allowed neighbours
        assert abs(planner.probabilities(obs).sum() - 1.0) < 1e-9
        obs, *_ = env.step(a)


@pytest.mark.parametrize("edit, message", [
    (lambda p: p.update(members=5), "members is int, expected a list of 2 to 16 state dicts"),
    (lambda p: p.update(members=p["members"][:1]), "members is a list of 1, expected"),
    (lambda p: p["members"][1].pop(next(iter(p["members"][1]))), r"\(member 1\) does not fit .*missing"),
    (lambda p: p["members"].__setitem__(1, 7), r"\(member 1\): state_dict is int"),
])
def test_a_malformed_ensemble_is_a_checkpoint_error(members, tmp_path, edit, message):
    out = tmp_path / "ens.pt"
    ensemble_checkpoints.main([str(p) for p in members] + ["--out", str(out)])
    payload = torch.load(out, map_location="cpu", weights_only=True)
    edit(payload)
    torch.save(payload, out)
    with pytest.raises(CheckpointError, match=message):
        load_checkpoint(out)


def test_training_refuses_an_ensemble_as_init_in_one_line(members, tmp_path):
    from ipp_bench.policies.train import TrainArgs, load_init

    out = tmp_path / "ens.pt"
    ensemble_checkpoints.main([str(p) for p in members] + ["--out", str(out)])
    with pytest.raises(ValueError, match="is an ensemble of 2 networks .* training starts from one network"):
        load_init(TrainArgs(init=str(out)))


def test_the_script_refuses_an_ensemble_member_and_mixed_shapes(members, tmp_path, capsys):
    ens = tmp_path / "ens.pt"
    ensemble_checkpoints.main([str(p) for p in members] + ["--out", str(ens)])
    with pytest.raises(SystemExit):
        ensemble_checkpoints.main([str(ens), str(members[0]), "--out", str(tmp_path / "x.pt")])
    assert "already an ensemble of 2 networks" in capsys.readouterr().err
    other = save_checkpoint(AttentionNet(NetConfig(node_dim=6, embed_dim=32, n_heads=2, ff_dim=32)), tmp_path / "o.pt")
    with pytest.raises(SystemExit):
        ensemble_checkpoints.main([str(members[0]), str(other), "--out", str(tmp_path / "y.pt")])
    assert "is a different network" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        ensemble_checkpoints.main([str(members[0]), "--out", str(tmp_path / "z.pt")])
    assert "an ensemble holds 2 to 16" in capsys.readouterr().err
