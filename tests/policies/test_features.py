"""The look-gain node feature wired into training and the planner (its maths: tests/test_gains.py)."""

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

import ipp_bench.envs  # noqa: F401
from ipp_bench.core.gains import LookGain
from ipp_bench.planners import make_planner
from ipp_bench.planners.base import RobotView
from ipp_bench.policies.features import add_gain_feature, gain_feature_wrapper


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


def test_invariant_inputs_follow_their_formulas_and_mean_the_same_on_15_and_30():
    """Columns: metres from the current node / 25, the env's z, (mean - mu_th) / sigma_0, std / sigma_0,
    and the look gain over the mean ROI cell variance / 10; on two map sizes with one prior, a node at
    the same place gets (nearly) the same inputs, where the v1 look-gain feature differs 4x."""
    from ipp_bench.policies.features import INVARIANT_LENGTH_M, invariant_features

    prior = dict(length_scale=5.0, signal_variance=0.1, nugget=0.001, prior_mean=0.5)
    sigma0 = np.sqrt(0.1 + 0.001)
    got = {}
    for task in ("ipp_bench/Grid15Eval-v1", "ipp_bench/Grid30Eval-v1"):
        env = gym.make(task, **prior).unwrapped
        obs, _ = env.reset(seed=1)
        view = RobotView(env)
        inv = invariant_features(obs, view)["node_features"]
        v1 = add_gain_feature(obs, view)["node_features"]
        pos, cur = env.roadmap.positions, int(obs["current_node"][0])
        np.testing.assert_allclose(inv[:, :2], (pos[:, :2] - pos[cur, :2]) / INVARIANT_LENGTH_M, rtol=1e-6)
        np.testing.assert_array_equal(inv[:, 2], obs["node_features"][:, 2])
        np.testing.assert_allclose(inv[:, 3], (obs["node_features"][:, 3] - env.config.mission.mu_th) / sigma0,
                                   rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(inv[:, 4], obs["node_features"][:, 4] / sigma0, rtol=1e-5)
        roi = env.mission.belief_roi()
        var = env.mission.belief.variance
        # the v1 column is 10 x reduction / Tr_ROI; the invariant one reduction / mean ROI variance / 10
        np.testing.assert_allclose(inv[:, 5], v1[:, 5] / 10 * var[roi].sum() / var[roi].mean() / 10, rtol=1e-5)
        nodes = [int(np.argmin(np.linalg.norm(pos - np.array(p), axis=1))) for p in ((25, 25, 8), (20, 30, 14))]
        got[task] = (inv[nodes], v1[nodes, 5])
    (inv15, g15), (inv30, g30) = got.values()
    np.testing.assert_allclose(inv15[:, [0, 1, 2, 4]], inv30[:, [0, 1, 2, 4]], rtol=1e-3, atol=1e-3)
    np.testing.assert_allclose(inv15[:, 5], inv30[:, 5], rtol=0.06)  # the start's read-out differs a little
    assert np.all(g15 / g30 > 3)  # the v1 feature: divided by a 4x larger map's trace


def test_invariant_network_runs_as_a_planner_on_every_size(tmp_path):
    import torch

    from ipp_bench.policies.checkpoint import save_checkpoint
    from ipp_bench.policies.network import AttentionNet, NetConfig

    torch.manual_seed(0)
    path = tmp_path / "inv.pt"
    save_checkpoint(AttentionNet(NetConfig(node_dim=6, invariant=True, embed_dim=16, n_heads=2, ff_dim=32)), path)
    for task in ("ipp_bench/Grid15Eval-v1", "ipp_bench/Hotspots30Eval-v2"):
        env = gym.make(task).unwrapped
        obs, _ = env.reset(seed=2)
        planner = make_planner(f"attention:checkpoint={path}")
        planner.reset(RobotView(env), 2)
        for _ in range(3):
            a = planner.act(obs)
            assert obs["action_mask"][a]
            obs, *_ = env.step(a)
    with pytest.raises(ValueError, match="NetConfig.invariant needs node_dim = 6"):
        NetConfig(node_dim=5, invariant=True)


def test_camera_error_states_feed_the_planners_feature_and_white_noise_tasks_keep_theirs():
    from ipp_bench.core.belief import error_states

    twin = gym.make("ipp_bench/Weed15Twin-v1").unwrapped
    obs, _ = twin.reset(seed=1)
    view = RobotView(twin)
    assert view.error_states() is twin.mission.belief_model is error_states(twin.mission)
    got = add_gain_feature(obs, view)["node_features"][:, 5]
    want = LookGain.of(twin)(twin.mission.belief.variance, twin.mission.belief_roi(), twin.mission.belief_model)
    np.testing.assert_array_equal(got, want)
    grid = gym.make("ipp_bench/Grid15Eval-v1").unwrapped
    obs, _ = grid.reset(seed=1)
    assert RobotView(grid).error_states() is None
    np.testing.assert_array_equal(add_gain_feature(obs, RobotView(grid))["node_features"][:, 5],
                                  LookGain.of(grid)(grid.mission.belief.variance, grid.mission.belief_roi()))
