"""Planners on the window belief: one look-gain method on both beliefs, the dense one's numbers
unchanged, greedy's scores the dense ones' where both fit, and the planners that need the full covariance
refusing a window task in one line."""

import gymnasium as gym
import numpy as np
import pytest

from ipp_bench.core.belief import GPBelief, LegBatch, trace_reductions
from ipp_bench.core.belief_window import WindowBelief
from ipp_bench.core.sensor import stack
from ipp_bench.planners import RobotView
from ipp_bench.planners import greedy as G

TASK = "ipp_bench/Hotspots30Eval-v2"


def _env(**overrides):
    env = gym.make(TASK, budget_s=40.0, report_times=(40.0,), **overrides).unwrapped
    env.reset(seed=3)
    return env


def test_the_dense_beliefs_look_gain_method_is_the_function_bit_for_bit():
    env = _env()
    view = RobotView(env)
    node, roi = env.current_node, view.belief_roi()
    batch = G.leg_batch(view, node)
    assert isinstance(batch, LegBatch) and isinstance(view.belief, GPBelief)
    expected = trace_reductions(view.belief.cov, batch, roi)
    assert view.belief.trace_reductions(batch, roi).tobytes() == expected.tobytes()
    legs = []
    for target in env.roadmap.neighbours[node]:
        obs = view.leg_observations(env.roadmap.positions[node], env.roadmap.positions[target])
        legs.append(stack(obs) if obs else None)
    assert view.belief.trace_reductions(legs, roi).tobytes() == expected.tobytes()  # the per-leg list, batched


def test_greedy_on_the_window_belief_scores_as_the_dense_one():
    dense, window = _env(), _env(belief="window")
    assert isinstance(window.mission.belief, WindowBelief) and window.mission.belief.window == 12
    vd, vw = RobotView(dense), RobotView(window)
    for _ in range(6):  # the same legs flown in both (dense greedy's), scored by both after each
        node = dense.current_node
        sd, sw = G.greedy_scores(vd, node), G.greedy_scores(vw, node)
        assert isinstance(G.leg_batch(vw, node), list)
        np.testing.assert_allclose(sw, sd, rtol=0.02, atol=1e-9 * sd.max())
        mask = dense.action_masks()
        a = int(np.argmax(np.where(mask, sd, -np.inf)))
        assert a == int(np.argmax(np.where(mask, sw, -np.inf)))
        dense.step(a)
        window.step(a)


def test_the_window_beliefs_leg_cache_is_bounded(monkeypatch):
    monkeypatch.setattr(G, "WINDOW_LEG_CACHE_NODES", 3)
    env = _env(belief="window")
    view = RobotView(env)
    for node in range(8):
        G.leg_batch(view, node)
    cache = G._LEGS[env.roadmap][1]
    assert list(cache) == [5, 6, 7]
    G.leg_batch(view, 5)
    assert list(cache) == [6, 7, 5]  # the most recently used kept last


@pytest.mark.parametrize("planner", ["mcts", "oracle"])
def test_planners_that_need_the_full_covariance_refuse_a_window_task(planner):
    from ipp_bench.planners.episode import start_episode

    env = gym.make(TASK, belief="window").unwrapped
    with pytest.raises(ValueError, match=rf"^planner '{planner}' cannot run on {TASK} \(gp.belief = 'window'\): .+"):
        start_episode(env, planner, 0)


def test_cmaes_runs_on_the_window_belief():
    pytest.importorskip("cma")
    from ipp_bench.planners.episode import fly_episode

    env = gym.make(TASK, belief="window", budget_s=20.0, report_times=(20.0,)).unwrapped
    result = fly_episode(env, "cmaes:max_evals=24", 0)
    assert result.decisions >= 1 and np.isfinite(result.report[-1]["trace_roi"])
