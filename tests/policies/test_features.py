"""The look-gain node feature: exact where its assumption holds, cheap, and wired into training and the planner."""

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

import ipp_bench.envs  # noqa: F401
from ipp_bench import metrics as M
from ipp_bench.belief import GPBelief
from ipp_bench.planners import make_planner
from ipp_bench.planners.base import RobotView
from ipp_bench.policies.features import LookGain, add_gain_feature, gain_feature_wrapper


def test_single_cell_read_outs_of_an_uncorrelated_belief_are_exact():
    env = gym.make("ipp_bench/Grid15Eval-v1").unwrapped
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    n = env.config.grid.n_cells
    belief = GPBelief(np.full(n, 0.5), np.diag(rng.uniform(0.01, 0.1, n)))
    roi = rng.random(n) < 0.5
    gain = LookGain.of(env)(belief.variance, roi)
    low = np.flatnonzero(env.roadmap.positions[:, 2] < 10.0)  # 8 m: one read-out per cell
    for i in low[:: max(len(low) // 10, 1)]:
        obs = env.sensor.observe(env.roadmap.positions[i])
        post = RobotView.predict_variance(belief, [obs])
        before = M.trace_roi(belief.variance, roi)
        exact = 10 * (before - M.trace_roi(post, roi)) / before
        assert gain[i] == pytest.approx(exact, rel=1e-4)


def test_wrapper_adds_one_column_and_the_planner_adds_the_same():
    env = gain_feature_wrapper(gym.make("ipp_bench/Grid15Train-v1"))
    assert env.observation_space["node_features"].shape == (450, 6)
    obs, _ = env.reset(seed=1)
    assert obs["node_features"].shape == (450, 6) and np.all(obs["node_features"][:, 5] >= 0)
    base = env.unwrapped._observation()
    again = add_gain_feature(base, RobotView(env.unwrapped))
    np.testing.assert_array_equal(again["node_features"], obs["node_features"])
    assert env.action_masks().any()


def test_planner_with_a_gain_feature_checkpoint_runs_on_15_and_30(tmp_path):
    import torch

    from ipp_bench.policies.checkpoint import save_checkpoint
    from ipp_bench.policies.network import AttentionNet, NetConfig

    torch.manual_seed(0)
    path = tmp_path / "gain.pt"
    save_checkpoint(AttentionNet(NetConfig(node_dim=6, embed_dim=16, n_heads=2, ff_dim=32)), path)
    for task in ("ipp_bench/Grid15Eval-v1", "ipp_bench/Grid30Eval-v1"):
        env = gym.make(task)
        obs, _ = env.reset(seed=0)
        planner = make_planner(f"attention:checkpoint={path}")
        planner.reset(RobotView(env.unwrapped), 0)
        for _ in range(5):
            a = planner.act(obs)
            assert env.unwrapped.action_masks()[a]
            obs, *_ = env.step(a)
