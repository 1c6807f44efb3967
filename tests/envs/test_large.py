"""The large tasks: 128 x 128 cells on the window belief, registered apart from the benchmark.

Each env builds a 32 768-node roadmap (2-4 s), so the tests share one env and fly short budgets.
"""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from ipp_bench import envs
from ipp_bench.core.belief import GPBelief
from ipp_bench.core.belief_window import WindowBelief
from ipp_bench.envs import tagged

EVAL, TRAIN = "ipp_bench/Hotspots128Eval-v2", "ipp_bench/Hotspots128Train-v2"
SHORT = {"budget_s": 40.0, "report_times": (20.0, 40.0)}  # [s] a few legs


@pytest.fixture(scope="module")
def env():
    e = gym.make(EVAL, **SHORT).unwrapped
    yield e
    e.close()


def test_registered_tagged_large_not_benchmark():
    assert {EVAL, TRAIN} <= set(tagged("large"))
    # the default leaderboard leaves them out
    assert EVAL not in tagged("benchmark") and TRAIN not in tagged("benchmark")
    assert TRAIN in tagged("train")
    cfg, train = envs.TASKS[EVAL].config, envs.TASKS[TRAIN].config
    assert (cfg.grid.rows, cfg.grid.cols, cfg.grid.resolution) == (128, 128, 2.5)
    assert cfg.gp.belief == "window" and cfg.mission.field == "weed_patches"
    v2 = envs.TASKS["ipp_bench/Hotspots30Eval-v2"].config
    assert (cfg.gp.length_scale, cfg.gp.signal_variance, cfg.gp.nugget, cfg.gp.prior_mean) == (
        v2.gp.length_scale, v2.gp.signal_variance, v2.gp.nugget, v2.gp.prior_mean)  # v2's fitted prior
    assert cfg.sensor == v2.sensor and cfg.graph == v2.graph
    assert train.replace(episode_seeds=cfg.mission.episode_seeds) == cfg  # the same task on other seeds
    assert cfg.mission.episode_seeds[1] <= train.mission.episode_seeds[0]


def test_the_budget_keeps_hotspots30s_share_of_the_map():
    """A lawnmower at the lowest level covers the same share of the map in the budget (66 % on 30 x 30)."""
    from ipp_bench.core.sensor import Sensor

    def share(task):
        c = envs.TASKS[task].config
        swath = Sensor(c.grid, c.sensor).footprint_side(c.graph.altitudes[0])
        width, height = c.grid.size_m
        return c.mission.budget_s * c.mission.speed * swath / (width * height)

    assert share(EVAL) == pytest.approx(share("ipp_bench/Hotspots30Eval-v2"), abs=0.02)
    assert share(EVAL) < 1.0


@pytest.mark.slow  # builds the 128 x 128 env (roadmap and encoding about 2.5 s, the env check 3 s)
def test_an_env_step_on_the_window_belief(env):
    check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    belief = env.mission.belief
    assert isinstance(belief, WindowBelief) and not isinstance(belief, GPBelief) and belief.window == 12
    assert obs["node_features"].shape == (32768, 5) and env.observation_space.contains(obs)
    before = belief.variance.sum()
    a = int(np.flatnonzero(obs["action_mask"])[0])
    obs, reward, *_ = env.step(a)
    assert np.isfinite(reward) and reward > 0 and belief.variance.sum() < before
    assert env.observation_space.contains(obs)


@pytest.mark.slow  # the 128 x 128 env
def test_a_greedy_episode_runs_and_the_dense_only_planners_refuse(env):
    from ipp_bench.planners.episode import fly_episode

    result = fly_episode(env, "greedy", 0)
    assert result.decisions > 3 and result.report[-1]["uncertainty_reduction_pct"] >= 0
    assert result.final["time_s"] <= SHORT["budget_s"] + 1e-9
    for planner in ("mcts", "oracle"):
        with pytest.raises(ValueError, match=rf"planner '{planner}' cannot run on {EVAL} \(gp.belief = 'window'\): "):
            fly_episode(env, planner, 0)


def test_the_window_belief_is_checked_by_its_own_estimate():
    from ipp_bench.core.limits import ARRAY_LIMIT_BYTES, check_sizes, window_belief_bytes

    cfg = envs.TASKS[EVAL].config
    check_sizes(cfg)
    assert 82e6 < window_belief_bytes(cfg) < 150e6  # 95 MB measured (w = 12)
    with pytest.raises(ValueError, match="too large for the dense belief.*set gp.belief = 'window'"):
        check_sizes(cfg.replace(belief="dense"))
    huge = cfg.replace(rows=256, cols=256, belief_window=40)  # the encoding fits (~1 GB)
    assert window_belief_bytes(huge) > ARRAY_LIMIT_BYTES
    with pytest.raises(ValueError, match=r"256 x 256 cells is too large for the window belief: .* GiB"):
        check_sizes(huge)


def test_the_window_belief_refuses_the_camera_error_states():
    cfg = envs.TASKS[EVAL].config
    with pytest.raises(ValueError, match="gp.belief = 'window' is invalid: expected 'dense' with the camera's error"):
        cfg.replace(persistent_var=0.01)
