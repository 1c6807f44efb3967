"""The training vec env: positional encoding held by the policy, masks from the observation, and
environments in worker processes giving the same transitions as in this process."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("sb3_contrib")
gym = pytest.importorskip("gymnasium")

from sb3_contrib import MaskablePPO
from stable_baselines3.common.monitor import Monitor

import ipp_bench.envs  # noqa: F401
from ipp_bench.policies.sb3 import AttentionPolicy
from ipp_bench.train.vec import ShardedSubprocVecEnv, make_vec_env, roadmap_pos_encoding

TASK = "ipp_bench/Grid15-v0"
NET = {"embed_dim": 16, "n_heads": 2, "ff_dim": 32}


def _make():
    return Monitor(gym.make(TASK))


def _pe():
    env = gym.make(TASK)
    pe = roadmap_pos_encoding(env)
    env.close()
    return pe


def _params(model) -> list[torch.Tensor]:
    return [p.detach().clone() for p in model.policy.parameters()]


def test_policy_with_the_encoding_in_its_kwargs_equals_the_policy_reading_it_from_the_observation():
    env = gym.make(TASK)
    full = MaskablePPO(AttentionPolicy, env, n_steps=16, batch_size=16, seed=0, policy_kwargs={"net_config": NET})
    venv = make_vec_env(_make, 1, "dummy")
    assert "pos_encoding" not in venv.observation_space.spaces
    held = MaskablePPO(AttentionPolicy, venv, n_steps=16, batch_size=16, seed=0,
                       policy_kwargs={"net_config": NET, "pos_encoding": _pe()})
    held.policy.load_state_dict(full.policy.state_dict())
    obs, _ = env.reset(seed=3)
    venv.seed(3)
    vobs = venv.reset()
    t_full, _ = full.policy.obs_to_tensor(obs)
    t_held, _ = held.policy.obs_to_tensor(vobs)
    with torch.no_grad():
        torch.testing.assert_close(held.policy.get_distribution(t_held).distribution.logits,
                                   full.policy.get_distribution(t_full).distribution.logits)
        torch.testing.assert_close(held.policy.predict_values(t_held), full.policy.predict_values(t_full))
    venv.close()


def test_a_policy_without_the_encoding_anywhere_is_refused_in_one_line():
    venv = make_vec_env(_make, 1, "dummy")
    with pytest.raises(ValueError, match="lacks \\['pos_encoding'\\].*policy_kwargs"):
        MaskablePPO(AttentionPolicy, venv, policy_kwargs={"net_config": NET})
    with pytest.raises(ValueError, match="rows"):
        MaskablePPO(AttentionPolicy, venv, policy_kwargs={"net_config": NET, "pos_encoding": np.zeros((7, 32))})
    venv.close()


def test_masks_come_from_the_observation_and_equal_the_envs_own():
    venv = make_vec_env(_make, 3, "dummy")
    venv.seed(1)
    obs = venv.reset()
    for _ in range(40):
        asked = np.stack(venv.env_method("action_masks"))  # answered by the wrapper
        own = np.stack(venv.venv.env_method("action_masks"))  # asked of the environments
        np.testing.assert_array_equal(asked, own)
        np.testing.assert_array_equal(asked, obs["action_mask"].astype(bool))
        actions = np.array([np.flatnonzero(m)[0] for m in asked])
        obs, *_ = venv.step(actions)
    venv.close()


def test_workers_give_the_same_training_as_this_process_and_save_load_keeps_the_encoding(tmp_path):
    """Same seed -> same weights, whether the environments step here or in worker processes."""
    weights = {}
    for kind in ("dummy", "subproc"):
        venv = make_vec_env(_make, 3, kind)
        model = MaskablePPO(AttentionPolicy, venv, n_steps=16, batch_size=24, n_epochs=2, seed=0,
                            policy_kwargs={"net_config": NET, "pos_encoding": _pe()})
        model.learn(96)
        weights[kind] = _params(model)
        if kind == "subproc":
            assert isinstance(venv.venv, ShardedSubprocVecEnv)
            model.save(tmp_path / "m.zip")
            loaded = MaskablePPO.load(tmp_path / "m.zip", env=venv)
            np.testing.assert_array_equal(loaded.policy.pos_encoding, _pe())
            obs = venv.reset()
            a1, _ = model.predict(obs, action_masks=obs["action_mask"].astype(bool), deterministic=True)
            a2, _ = loaded.predict(obs, action_masks=obs["action_mask"].astype(bool), deterministic=True)
            np.testing.assert_array_equal(a1, a2)
        venv.close()
    for a, b in zip(weights["dummy"], weights["subproc"], strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_sharded_workers_answer_attribute_calls_in_the_order_asked():
    venv = ShardedSubprocVecEnv([_make] * 5, n_workers=2)
    try:
        venv.set_attr("tag", 7, indices=[4, 1])
        assert venv.get_attr("tag", indices=[4, 1]) == [7, 7]
        venv.seed(0)
        venv.reset()
        nodes = venv.get_attr("current_node")
        assert venv.get_attr("current_node", indices=[3, 0]) == [nodes[3], nodes[0]]
        assert venv.has_attr("action_masks") and not venv.has_attr("no_such_attribute")
        with pytest.raises(AttributeError, match="no_such_attribute"):
            venv.get_attr("no_such_attribute")
        assert all(venv.env_is_wrapped(Monitor))
    finally:
        venv.close()


def test_bad_vec_env_kind_is_refused():
    with pytest.raises(ValueError, match="subproc"):
        make_vec_env(_make, 1, "threads")


_RSS_AFTER_FREE = """
import json, os, sys
import numpy as np
from ipp_bench.core._threads import keep_freed_memory
applied = keep_freed_memory() if sys.argv[1] == "keep" else None
def rss():
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
block = np.ones(64 << 17)  # 64 MiB, every page touched
held = rss()
del block
print(json.dumps({"applied": applied, "released": held - rss()}))
"""


@pytest.mark.skipif(not Path("/proc/self/statm").exists(), reason="reads the resident size from /proc (Linux)")
def test_keep_freed_memory_keeps_a_freed_block_in_the_process():
    """glibc returns a freed 64 MiB block to the OS at once (it was mmap'ed); after keep_freed_memory
    the block comes from the heap and stays there for reuse: the resident size does not drop."""

    def run(mode):
        out = subprocess.run([sys.executable, "-c", _RSS_AFTER_FREE, mode], capture_output=True, text=True,
                             timeout=60, check=True)
        return json.loads(out.stdout)

    default, kept = run("default"), run("keep")
    if not kept["applied"]:
        pytest.skip("the C library is not glibc: keep_freed_memory changes nothing and says so")
    assert default["released"] > 48 << 20  # the block went back to the OS
    assert kept["released"] < 8 << 20  # the block stayed


def test_metric_reward_sums_to_the_episodes_report_mean():
    """An episode's rewards add up to its report: the mean ROI uncertainty reduction over the report
    times, over 10, less what the start's read-out (before the first action) gave."""
    from ipp_bench.planners import make_planner
    from ipp_bench.planners.base import RobotView
    from ipp_bench.train.vec import MetricReward

    env = MetricReward(gym.make("ipp_bench/Hotspots15Eval-v2", budget_s=120.0))
    obs, _ = env.reset(seed=4)
    at_start = np.mean([row["uncertainty_reduction_pct"] for row in env.unwrapped.mission.report()]) / 10
    greedy = make_planner("greedy")
    greedy.reset(RobotView(env.unwrapped), 4)
    total, done, steps = 0.0, False, 0
    while not done:
        obs, r, term, trunc, _ = env.step(greedy.act(obs))
        total += r
        done = term or trunc
        steps += 1
    report = env.unwrapped.mission.report()
    assert len(report) == 2 and steps > 20  # 50 and 100 s fit the 120 s budget
    want = np.mean([row["uncertainty_reduction_pct"] for row in report]) / 10 - at_start
    assert 0 < at_start < 1 and total == pytest.approx(want, rel=1e-9)
    assert want > 1  # the test cannot pass on an empty episode


@pytest.mark.parametrize("layout", ["v2", "v1"])
def test_a_run_starts_no_more_workers_than_its_cpu_quota(tmp_path, monkeypatch, layout):
    """The README's tiny run (16 environments by default) in a container limited to 2 CPUs whose
    affinity mask shows the host's 16: two worker processes, not 16."""
    import multiprocessing as mp
    import os

    from ipp_bench.core import _threads
    from ipp_bench.train.args import TrainArgs

    if layout == "v2":
        (tmp_path / "cpu.max").write_text("200000 100000\n")
    else:
        (tmp_path / "cpu").mkdir()
        (tmp_path / "cpu" / "cpu.cfs_quota_us").write_text("150000\n")
        (tmp_path / "cpu" / "cpu.cfs_period_us").write_text("100000\n")
    monkeypatch.setattr(_threads, "CGROUP_ROOT", str(tmp_path))
    monkeypatch.setattr(_threads.os, "sched_getaffinity", lambda pid: set(range(16)))
    before = set(mp.active_children())
    venv = make_vec_env(_make, TrainArgs().n_envs, "subproc")
    try:
        started = set(mp.active_children()) - before
        assert TrainArgs().n_envs == 16
        assert len(started) == len(venv.venv.processes) == 2
        assert venv.num_envs == 16
    finally:
        venv.close()
    # without a quota, the affinity mask decides, and never more workers than CPUs
    assert _threads.cgroup_cpu_quota(str(tmp_path / "none")) is None
    monkeypatch.undo()  # this machine's own affinity mask and quota
    venv = make_vec_env(_make, 16, "subproc")
    try:
        assert len(set(mp.active_children()) - before) <= len(os.sched_getaffinity(0))
    finally:
        venv.close()


def test_no_cpu_quota_reads_as_none(tmp_path):
    from ipp_bench.core._threads import cgroup_cpu_quota

    (tmp_path / "cpu.max").write_text("max 100000\n")
    assert cgroup_cpu_quota(str(tmp_path)) is None
    (tmp_path / "cpu.max").unlink()
    (tmp_path / "cpu").mkdir()
    (tmp_path / "cpu" / "cpu.cfs_quota_us").write_text("-1\n")
    (tmp_path / "cpu" / "cpu.cfs_period_us").write_text("100000\n")
    assert cgroup_cpu_quota(str(tmp_path)) is None
