"""Run archives (SB3 ``.zip``) are read without unpickling: a pickled payload in any entry never runs."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from sb3_contrib import MaskablePPO

import ipp_bench.envs  # noqa: F401
from ipp_bench.policies.checkpoint import CheckpointError, load_checkpoint
from ipp_bench.policies.sb3 import AttentionPolicy
from ipp_bench.train.archive import load_objects, pickled_entries, read_archive
from ipp_bench.train.export import export_zip
from ipp_bench.train.vec import roadmap_pos_encoding

NET = {"embed_dim": 16, "n_heads": 2, "ff_dim": 32}


@pytest.fixture
def archive(tmp_path):
    """A real archive as training writes it: the positional encoding in policy_kwargs, after learning."""
    env = gym.make("ipp_bench/Grid15-v0")
    kwargs = {"net_config": NET, "pos_encoding": roadmap_pos_encoding(env)}
    model = MaskablePPO(AttentionPolicy, env, n_steps=16, batch_size=16, n_epochs=1, seed=0, policy_kwargs=kwargs)
    model.learn(16)
    model.save(tmp_path / "latest.zip")
    return tmp_path / "latest.zip", model, env, kwargs


def test_an_archive_has_pickled_entries_and_export_reads_none_of_them(archive, tmp_path, poison):
    path, model, _, _ = archive
    data, _ = read_archive(path)
    # What SB3 would unpickle: the policy class, the spaces, the schedules, policy_kwargs, ...
    assert {"policy_class", "policy_kwargs", "observation_space", "lr_schedule"} <= set(pickled_entries(data))
    marker = tmp_path / "ran"
    for key in pickled_entries(data):
        poison(path, key, marker)
    out = export_zip(path, tmp_path / "export.pt")
    assert not marker.exists()
    net, meta = load_checkpoint(out)
    assert meta["ppo_steps"] == model.num_timesteps == 16
    for name, value in model.policy.attention_net().state_dict().items():
        assert torch.equal(net.state_dict()[name], value), name


def test_export_refuses_an_archive_of_another_policy_class(archive, tmp_path):
    import json
    import zipfile

    path, *_ = archive
    with zipfile.ZipFile(path) as zf:
        members = {name: zf.read(name) for name in zf.namelist()}
    data = json.loads(members["data"])
    data["policy_class"]["__module__"] = "somewhere.else"
    members["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(path, "w") as zf:
        for name, blob in members.items():
            zf.writestr(name, blob)
    with pytest.raises(CheckpointError, match="not ipp_bench's AttentionPolicy .module 'somewhere.else'"):
        export_zip(path, tmp_path / "x.pt")


def test_loading_for_resume_substitutes_every_pickled_entry(archive, tmp_path, poison):
    path, model, env, kwargs = archive
    marker = tmp_path / "ran"
    data, _ = read_archive(path)
    for key in pickled_entries(data):
        poison(path, key, marker)
    known = {"policy_class": AttentionPolicy, "policy_kwargs": kwargs, "observation_space": env.observation_space,
             "action_space": env.action_space, "lr_schedule": None, "clip_range": 0.2, "rollout_buffer_class": None,
             "_last_obs": None, "_last_episode_starts": None, "_last_original_obs": None, "ep_info_buffer": None,
             "ep_success_buffer": None}
    loaded = MaskablePPO.load(path, env=env, custom_objects=load_objects(path, known))
    assert not marker.exists()
    obs, _ = env.reset(seed=3)
    mask = obs["action_mask"].astype(bool)
    assert np.array_equal(model.predict(obs, action_masks=mask, deterministic=True)[0],
                          loaded.predict(obs, action_masks=mask, deterministic=True)[0])
    loaded.learn(16, reset_num_timesteps=False)  # and it trains on
    # A pickled entry this package never writes is refused unread.
    poison(path, "evil", marker)
    with pytest.raises(CheckpointError, match=r"pickled entries this package never writes \(evil\)"):
        load_objects(path, known)
    assert not marker.exists()


def test_validate_refuses_a_crafted_archive_in_one_line_before_any_episode(tmp_path, capsys, monkeypatch, poison):
    """``--validate evil.zip``: the archive is checked first, so a crafted one is refused at once (in one
    line, its payload never run), before greedy's reference or any env is built."""
    import io
    import json
    import zipfile

    from ipp_bench.train import validation
    from ipp_bench.train.command import main

    evil = tmp_path / "evil.zip"
    blob = io.BytesIO()
    torch.save({}, blob)
    with zipfile.ZipFile(evil, "w") as zf:
        zf.writestr("data", json.dumps({"policy_class": {":type:": "<class 'abc.ABCMeta'>", "__module__": "evil"}}))
        zf.writestr("policy.pth", blob.getvalue())
    marker = tmp_path / "ran"
    poison(evil, "policy_class", marker)

    def built(*_args, **_kwargs):
        raise AssertionError("an env or episode was built before the archive was checked")

    for name in ("make_env", "evaluate_planner", "evaluate_net", "_fly"):
        monkeypatch.setattr(validation, name, built)
    assert main(["--validate", str(evil), "--val-task", "ipp_bench/Grid15-v0", "--eval-episodes", "1"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1
    assert "--validate" in err and "not ipp_bench's AttentionPolicy (module 'evil')" in err
    assert not marker.exists()
