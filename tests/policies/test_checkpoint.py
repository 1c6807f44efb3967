"""Malformed checkpoints and attention options (ipp_bench.policies.checkpoint, .planner): every
one is one line (CheckpointError, or ValueError for an option), before anything runs."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from ipp_bench.cli import main  # noqa: E402
from ipp_bench.policies.checkpoint import (  # noqa: E402
    SHIPPED_CHECKPOINT,
    CheckpointError,
    load_checkpoint,
)


def _shipped_payload():
    return torch.load(SHIPPED_CHECKPOINT, map_location="cpu", weights_only=True)


def _nan_weight(p):
    name = next(k for k, v in p["state_dict"].items() if v.is_floating_point())
    p["state_dict"][name] = p["state_dict"][name].clone()
    p["state_dict"][name].view(-1)[0] = float("nan")


def _huge(p):
    p["net_config"] = {**p["net_config"], "embed_dim": 1_000_000, "ff_dim": 4_000_000}


def _wrong_shape(p):
    name = next(iter(p["state_dict"]))
    p["state_dict"][name] = torch.zeros(3, 3)


CASES = {
    "state_dict-int": (lambda p: p.update(state_dict=5), "state_dict is int, expected a dict of named tensors"),
    "meta-int": (lambda p: p.update(meta=5), "meta is int, expected a dict"),
    "net_config-int": (lambda p: p.update(net_config=5), "net_config is int"),
    "net_config-bad-field": (lambda p: p["net_config"].update(n_heads=0), "NetConfig.n_heads = 0 is invalid"),
    "huge-embed_dim": (_huge, "more than the"),
    "wrong-shape": (_wrong_shape, "does not fit AttentionNet"),
    "missing-tensor": (lambda p: p["state_dict"].pop(next(iter(p["state_dict"]))), "missing"),
    "non-finite": (_nan_weight, "non-finite weights (NaN or inf)"),
    "not-a-dict": (lambda p: None, "has format 'list'"),
    # a network that would add greedy's score to its logits: the suite has no such network
    "needs-rate_skip": (lambda p: p["net_config"].update(rate_skip=True),
                        "NetConfig.rate_skip = True is not supported"),
    "needs-skip_teacher": (lambda p: p["net_config"].update(skip_teacher="far"),
                           "NetConfig.skip_teacher = 'far' is not supported"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_every_malformed_checkpoint_is_a_checkpoint_error(case, tmp_path):
    edit, message = CASES[case]
    payload = _shipped_payload()
    edit(payload)
    path = tmp_path / "bad.pt"
    torch.save([1, 2] if case == "not-a-dict" else payload, path)
    with pytest.raises(CheckpointError, match=message.replace("(", r"\(").replace(")", r"\)")):
        load_checkpoint(path)


def test_a_malformed_checkpoint_on_the_command_line_is_one_line(tmp_path, capsys):
    payload = _shipped_payload()
    payload["state_dict"] = 5
    path = tmp_path / "bad.pt"
    torch.save(payload, path)
    rc = main(["evaluate", "--task", "Grid15Eval-v1", "--planner", f"attention:checkpoint={path}"])
    err = capsys.readouterr().err
    assert rc == 2 and "state_dict is int" in err and len(err.strip().splitlines()) == 1


def test_the_shipped_checkpoints_inert_keys_load_as_the_plain_network(tmp_path):
    """The shipped checkpoint's net_config carries the inert keys at their values: it loads, as the network
    without them, and a copy saved again no longer writes them."""
    from ipp_bench.policies.checkpoint import save_checkpoint
    from ipp_bench.policies.network import INERT_FIELDS, NetConfig

    cfg = _shipped_payload()["net_config"]
    carried = {k: cfg[k] for k in INERT_FIELDS if k in cfg}
    assert carried == {k: INERT_FIELDS[k] for k in carried}
    net, _ = load_checkpoint(SHIPPED_CHECKPOINT)
    assert net.cfg == NetConfig(**{k: v for k, v in cfg.items() if k not in INERT_FIELDS})
    again, _ = load_checkpoint(save_checkpoint(net, tmp_path / "again.pt"))
    assert set(INERT_FIELDS).isdisjoint(torch.load(tmp_path / "again.pt", weights_only=True)["net_config"])
    for a, b in zip(net.state_dict().values(), again.state_dict().values()):
        assert torch.equal(a, b)


def test_a_checkpoint_that_needs_a_planners_score_as_input_is_one_line_on_the_command_line(tmp_path, capsys):
    payload = _shipped_payload()
    payload["net_config"]["rate_skip"] = True
    path = tmp_path / "rate.pt"
    torch.save(payload, path)
    rc = main(["evaluate", "--task", "Grid15Eval-v1", "--planner", f"attention:checkpoint={path}"])
    err = capsys.readouterr().err
    assert rc == 2 and "NetConfig.rate_skip = True is not supported" in err and "rate_skip = False" in err
    assert len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("device, message", [
    ("nope", "attention.device = 'nope' is invalid: expected 'cpu', 'cuda', 'cuda:N' or 'mps'"),
    ("cuda:99", "attention.device = 'cuda:99' is unavailable"),
    ("meta", "attention.device = 'meta' is invalid"),
])
def test_a_bad_or_unavailable_device_is_one_line(device, message, capsys):
    rc = main(["evaluate", "--task", "Grid15Eval-v1", "--planner", f"attention:device={device}"])
    err = capsys.readouterr().err
    assert rc == 2 and message in err and len(err.strip().splitlines()) == 1, err
