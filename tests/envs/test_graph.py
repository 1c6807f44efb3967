"""The graph env over every registered graph task: check_env, determinism, masks, the clock, errors,
long-run numerical health."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import ipp_bench.envs as envs
from ipp_bench.envs import GraphIPPEnv

#: the large tasks (128 x 128 cells, a 2-4 s roadmap per env) have their own, shorter tests: test_large.py
GRAPH_TASKS = [t for t, s in envs.TASKS.items()
               if s.entry_point.endswith("graph:GraphIPPEnv") and "large" not in s.tags]


def rollout(env, seed, steps=25):
    obs, info = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    out = [obs["node_features"].copy()]
    rewards = []
    for _ in range(steps):
        a = int(rng.choice(np.flatnonzero(obs["action_mask"])))
        obs, r, term, trunc, info = env.step(a)
        out.append(obs["node_features"].copy())
        rewards.append(r)
        if term:
            break
    return np.stack(out), np.array(rewards), info


@pytest.mark.parametrize("task", GRAPH_TASKS)
def test_check_env(task):
    """Without a warning: every Box has finite bounds (the belief mean's: any finite float32)."""
    import warnings

    env = gym.make(task)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=True)
    assert [str(w.message) for w in caught] == []


def test_node_feature_bounds_are_the_real_ones():
    env = gym.make("ipp_bench/Grid15Eval-v1").unwrapped
    box = env.observation_space["node_features"]
    gp = env.config.gp
    np.testing.assert_array_equal(box.low[0], [0, 0, 0, np.finfo(np.float32).min, 0])
    assert box.high[0, :3].tolist() == [1, 1, 1] and box.high[0, 4] == pytest.approx(np.sqrt(gp.signal_variance
                                                                                            + gp.nugget), rel=1e-4)
    obs, _ = env.reset(seed=0)
    feats = [obs["node_features"]]
    while obs["action_mask"].any():
        obs, *_ = env.step(int(np.flatnonzero(obs["action_mask"])[0]))
        feats.append(obs["node_features"])
    assert all(box.contains(f) for f in feats)
    assert max(f[:, 4].max() for f in feats) <= box.high[0, 4]


@pytest.mark.parametrize("task", GRAPH_TASKS)
def test_same_seed_same_episode(task):
    a = rollout(gym.make(task), seed=3)
    b = rollout(gym.make(task), seed=3)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert a[2] == b[2]
    c = rollout(gym.make(task), seed=4)
    assert not np.array_equal(a[0][0], c[0][0]) or not np.array_equal(a[1], c[1])


@pytest.mark.parametrize("task", GRAPH_TASKS)
def test_observation_in_space_and_render(task):
    env = gym.make(task, render_mode="rgb_array")
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    img = env.render()
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    for key in ("trace_roi", "rmse_roi", "uncertainty_reduction_pct", "time_s", "reward_info_gain"):
        assert key in info


def test_overrides_through_gym_make():
    env = gym.make("ipp_bench/Grid15Eval-v0", budget_s=50.0, rows=12, cols=10)
    obs, _ = env.reset(seed=0)
    assert obs["node_features"].shape == (240, 5)
    assert env.unwrapped.config.mission.budget_s == 50.0
    with pytest.raises(ValueError, match="budget_s"):
        gym.make("ipp_bench/Grid15Eval-v0", budget_s=-5.0)


def test_start_and_random_start():
    env = gym.make("ipp_bench/Grid15Eval-v0")
    env.reset(seed=0)
    np.testing.assert_allclose(env.unwrapped.mission.position, [6.25, 6.25, 14.0])
    train = gym.make("ipp_bench/Grid15-v0")
    starts = {train.reset(seed=s)[0]["current_node"][0] for s in range(8)}
    assert len(starts) > 1


def test_invalid_actions_name_the_valid_ones():
    env = gym.make("ipp_bench/Grid15Eval-v0", budget_s=2.0)
    obs, _ = env.reset(seed=0)
    mask = env.unwrapped.action_masks()
    assert mask.any() and not mask.all()  # 2 s affords only the nearest neighbours
    masked = int(np.flatnonzero(~mask)[0])
    with pytest.raises(ValueError, match=r"valid actions now are \["):
        env.step(masked)
    with pytest.raises(ValueError, match="out of range"):
        env.step(20)
    with pytest.raises(ValueError, match="one integer"):
        env.step(1.5)


def test_mask_and_termination_follow_the_budget():
    env = gym.make("ipp_bench/Grid15Eval-v0", budget_s=6.0)
    obs, _ = env.reset(seed=0)
    uenv = env.unwrapped
    term = False
    while not term:
        costs = uenv.roadmap.costs[uenv.current_node]
        np.testing.assert_array_equal(obs["action_mask"].astype(bool), costs <= uenv.mission.remaining_s + 1e-9)
        obs, r, term, trunc, info = env.step(int(np.flatnonzero(obs["action_mask"])[0]))
        assert not trunc
    assert not obs["action_mask"].any()
    assert info["time_s"] <= 6.0 + 1e-9


@pytest.mark.parametrize("task", sorted(t for t, s in envs.TASKS.items() if "large" not in s.tags))
def test_the_core_clock_gives_the_roadmap_edge_costs_bit_for_bit(task):
    """The masks and look-ahead planners once read ``roadmap.costs``; they now ask the mission.
    On every registered task's roadmap the core mission's durations are those costs, bit for bit
    (so the committed baselines do not move)."""
    from ipp_bench.core.mission import Mission
    from ipp_bench.core.roadmap import Roadmap

    cfg = envs.task_spec(task).config
    rm = Roadmap.build(cfg.grid, cfg.graph, cfg.mission.speed)
    mission = Mission(cfg, np.zeros((cfg.grid.rows, cfg.grid.cols)), np.random.default_rng(0), rm.positions[0])
    got = np.stack([mission.leg_durations(rm.positions[i], rm.positions[rm.neighbours[i]])
                    for i in range(rm.n_nodes)])
    assert got.tobytes() == rm.costs.tobytes()


def test_each_env_builds_one_sensor():
    env = gym.make("ipp_bench/Grid15Eval-v0").unwrapped
    env.reset(seed=0)
    assert env.mission.sensor is env.sensor


def test_reward_is_relative_belief_roi_trace_reduction():
    env = gym.make("ipp_bench/Grid15Eval-v0")
    env.reset(seed=1)
    m = env.unwrapped.mission
    roi = m.belief_roi()
    before = m.belief.variance[roi].sum()
    _, r, _, _, info = env.step(0)
    after = m.belief.variance[roi].sum()
    assert r == pytest.approx(10 * (before - after) / before)
    assert info["reward_info_gain"] == r and r > 0


def test_node_features_are_footprint_averages():
    env = gym.make("ipp_bench/Grid15Eval-v0")
    obs, _ = env.reset(seed=2)
    uenv = env.unwrapped
    i = 225 + 7 * 15 + 7  # centre node at 14 m
    cells = uenv.sensor.observe(uenv.roadmap.positions[i]).cells
    f = obs["node_features"][i]
    assert f[3] == pytest.approx(uenv.mission.belief.mean[cells].mean(), rel=1e-5)
    assert f[4] == pytest.approx(np.sqrt(uenv.mission.belief.variance[cells]).mean(), rel=1e-5)
    np.testing.assert_allclose(f[:3], [0.5, 0.5, 1.0])


def test_uniform_roadmap_env():
    env = GraphIPPEnv(sampling="uniform", n_samples=200, field="regions", budget_s=40.0)
    obs, _ = env.reset(seed=0)
    assert obs["node_features"].shape == (200, 5)
    rollout(env, 0, steps=5)


def test_2000_random_steps_stay_finite_symmetric_psd():
    env = gym.make("ipp_bench/Grid15-v0", budget_s=1e5, rows=8, cols=8)
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(2000):
        obs, r, term, _, _ = env.step(int(rng.choice(np.flatnonzero(obs["action_mask"]))))
        assert np.isfinite(r)
    P = env.unwrapped.mission.belief.cov
    assert np.all(np.isfinite(P)) and np.all(np.isfinite(env.unwrapped.mission.belief.mean))
    assert np.abs(P - P.T).max() <= 1e-12 * np.abs(P).max()
    assert np.linalg.eigvalsh(P).min() > -1e-10
    assert np.all(np.isfinite(obs["node_features"]))
