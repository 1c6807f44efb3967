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


def test_rate_feature_is_greedys_score_over_the_best_and_an_untrained_rate_skip_net_is_greedy(tmp_path):
    import torch

    from ipp_bench.policies.checkpoint import save_checkpoint
    from ipp_bench.policies.features import RATE_NODE_DIM, add_rate_feature
    from ipp_bench.policies.network import AttentionNet, NetConfig

    torch.manual_seed(0)
    path = tmp_path / "rate.pt"
    save_checkpoint(AttentionNet(NetConfig(node_dim=RATE_NODE_DIM, rate_skip=True, embed_dim=16, n_heads=2,
                                           ff_dim=32)), path)
    for task in ("ipp_bench/Grid15Eval-v1", "ipp_bench/Grid30Eval-v1"):
        env = gym.make(task).unwrapped
        obs, _ = env.reset(seed=3)
        view = RobotView(env)
        greedy, policy = make_planner("greedy"), make_planner(f"attention:checkpoint={path}")
        greedy.reset(view, 3)
        policy.reset(view, 3)
        for _ in range(8):
            scores = greedy.scores(obs)
            ext = add_rate_feature(obs, view)
            rate = ext["node_features"][obs["neighbours"], -1]
            allowed = obs["action_mask"].astype(bool)
            # greedy's score (an independent computation: the planner's own) divided by the best allowed one
            np.testing.assert_allclose(rate[allowed], scores[allowed] / scores[allowed].max(), rtol=1e-6)
            assert np.all(rate[~allowed] == 0)
            others = np.setdiff1d(np.arange(env.roadmap.n_nodes), obs["neighbours"])
            assert np.all(ext["node_features"][others, -1] == 0)
            # W^Q starts at zero: the untrained network decides as greedy does
            a = greedy.act(obs)
            assert policy.act(obs) == a
            obs, *_ = env.step(a)


def test_rate_skip_sb3_policy_matches_its_attention_net():
    import torch
    from sb3_contrib import MaskablePPO

    from ipp_bench.policies.features import gain_feature_wrapper
    from ipp_bench.policies.sb3 import AttentionPolicy

    env = gain_feature_wrapper(gym.make("ipp_bench/Grid15Train-v1"), rate=True)
    model = MaskablePPO(AttentionPolicy, env, n_steps=16, batch_size=16, n_epochs=1, seed=0, policy_kwargs={
        "net_config": {"node_dim": 7, "rate_skip": True, "embed_dim": 16, "n_heads": 2, "ff_dim": 32}})
    model.learn(16)  # moves W^Q off zero, so both terms of the logits are at work
    obs, _ = env.reset(seed=5)
    t, _ = model.policy.obs_to_tensor(obs)
    with torch.no_grad():
        logits, value = model.policy.attention_net().forward_obs(t)
        ref = model.policy.get_distribution(t).distribution.logits
        ref_value = model.policy.predict_values(t)
    torch.testing.assert_close(torch.softmax(logits, -1), torch.softmax(ref, -1))
    torch.testing.assert_close(value, ref_value[:, 0])
    assert model.policy.action_net.pointer.w_q.weight.abs().sum() > 0


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
    with pytest.raises(ValueError, match="NetConfig.invariant needs node_dim = 6 without rate_skip"):
        NetConfig(node_dim=7, rate_skip=True, invariant=True)


def _error_belief(env, neighbour_corr: float = 0.0):
    """A camera-error belief on ``env``'s grid: an uncorrelated field prior, the task's error constants
    (``neighbour_corr`` for the persistent errors' spatial correlation), after a few 8 m looks."""
    import dataclasses

    from ipp_bench.belief import PersistentErrorBelief

    rng = np.random.default_rng(4)
    n = env.config.grid.n_cells
    sensor = dataclasses.replace(env.sensor.cfg, persistent_neighbour_corr=neighbour_corr)
    belief = PersistentErrorBelief(GPBelief(rng.uniform(0.2, 0.8, n), np.diag(rng.uniform(0.02, 0.15, n))), sensor)
    low = np.flatnonzero(env.roadmap.positions[:, 2] < 10.0)
    for i in rng.choice(low, 12, replace=False):  # some cells seen, a few of them several times
        obs = env.sensor.observe(env.roadmap.positions[i])
        belief.update([obs], [rng.uniform(0.0, 1.0, obs.m)])
    return belief


def test_camera_error_look_gain_is_the_augmented_kalman_formula_for_single_cell_read_outs():
    """On the deployment's sensor (persistent per-cell error states), with an uncorrelated belief and
    independent cells' errors, an 8 m read-out's rows are single cells: the feature equals the exact
    reduction of the batch formula on the augmented state [x, u_1, u_2] (the white noise at the
    predicted value's scale), and the white-noise formula overstates it where cells were seen before."""
    from ipp_bench.belief import value_scale

    env = gym.make("ipp_bench/Weed15Twin-v1").unwrapped
    env.reset(seed=0)
    belief = _error_belief(env)
    n, P = env.config.grid.n_cells, belief.state.cov
    roi = np.random.default_rng(5).random(n) < 0.6
    var = belief.field.variance
    gain = LookGain.of(env)(var, roi, belief)
    white = LookGain.of(env)(var, roi)
    before = var[roi].sum()
    low = np.flatnonzero(env.roadmap.positions[:, 2] < 10.0)
    checked = repeated = 0
    for i in low:
        obs = env.sensor.observe(env.roadmap.positions[i])
        off = belief.offset[obs.factor]
        sd = np.where(belief.seen[obs.cells], belief.sd[obs.factor][obs.cells],
                      np.sqrt(belief.variances[obs.factor] * value_scale(belief.field.mean[obs.cells], belief.floor)))
        H = np.zeros((obs.m, P.shape[0]))
        H[np.arange(obs.m), obs.cells] = 1.0  # W = I at 8 m
        H[np.arange(obs.m), obs.cells + off] = sd
        R = (obs.var - obs.persistent) * value_scale(belief.field.mean[obs.cells], belief.floor)
        S = H @ P @ H.T + np.diag(R)
        K = P[:n] @ H.T
        exact = 10 * np.einsum("ij,jk,ik->i", K, np.linalg.inv(S), K)[roi].sum() / before
        assert gain[i] == pytest.approx(exact, rel=1e-5)
        checked += 1
        if belief.seen[obs.cells].all():
            repeated += 1
            assert white[i] > 2 * gain[i]  # white noise: another look would pin the error again
    assert checked > 20 and repeated > 0


def test_camera_error_states_feed_the_planners_feature_and_white_noise_tasks_keep_theirs():
    from ipp_bench.belief import error_states

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


def test_tasks_that_share_a_roadmap_keep_their_own_cameras_feature():
    """Grid15Eval-v1 and the deployment's twin share one roadmap object but not their camera: the
    feature of each is the one built from its own camera, whichever task built its feature first."""
    grid, twin = gym.make("ipp_bench/Grid15Eval-v1").unwrapped, gym.make("ipp_bench/Weed15Twin-v1").unwrapped
    grid.reset(seed=0)
    twin.reset(seed=0)
    assert grid.roadmap is twin.roadmap and grid.sensor.cfg != twin.sensor.cfg
    var, roi = twin.mission.belief.variance, twin.mission.belief_roi()
    LookGain.of(grid)(var, roi)  # built first, from the other camera
    own = LookGain(twin.roadmap.positions, twin.sensor, twin.config.grid.n_cells)
    np.testing.assert_array_equal(LookGain.of(twin)(var, roi), own(var, roi))
    np.testing.assert_array_equal(LookGain.of(twin).noise, own.noise)
    assert not np.array_equal(LookGain.of(grid).noise, own.noise)
