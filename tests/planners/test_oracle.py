"""The ``oracle`` reference: greedy's rule on the true ROI, which it alone can read."""

import numpy as np
import pytest

from ipp_bench.envs import make_env
from ipp_bench.planners import (
    REFERENCE_PLANNERS,
    RobotView,
    TruthView,
    is_reference,
    is_team_planner,
    make_planner,
    planner_names,
    view_for,
)
from ipp_bench.planners.base import GraphPlanner
from ipp_bench.planners.episode import fly_episode
from ipp_bench.planners.greedy import greedy_scores

TASK = "ipp_bench/Hotspots30Eval-v2"
# cheap settings of the planners that would take long on 30 x 30 (the view they get is what is tested)
CHEAP = {"mcts": "mcts:simulations=2,horizon_s=4", "cmaes": "cmaes:max_evals=12"}


def _corner_mission(env, corner):
    """Replace the episode's world by a field whose only ROI is a 3 x 3 patch at ``corner`` (col, row)."""
    truth = np.zeros((env.config.grid.rows, env.config.grid.cols))
    c, r = corner
    truth[r - 1:r + 2, c - 1:c + 2] = 0.9
    env.mission = env._make_mission(truth, np.random.default_rng(0), env.mission.position)
    return truth


def _track(planner, corner, seconds=60.0):
    """Positions after each decision of ``planner`` over ``seconds`` of mission time, and the mission
    time at which a ROI cell was first in view (inf: not within the flight)."""
    env = make_env(TASK, budget_s=seconds, report_times=[seconds])
    positions = []
    fly_episode(env, planner, 3, on_reset=lambda e: _corner_mission(e, corner),
                on_decision=lambda d: positions.append(env.mission.position.copy()))
    roi = env.mission.eval_roi
    first = np.inf
    for t, *p in env.mission.measurement_log:
        obs = env.sensor.observe(p)
        if obs is not None and roi[obs.cells].any():
            first = t
            break
    return np.array(positions), first


def test_oracle_flies_to_the_only_roi_first_and_greedy_cannot_know_where_it_is():
    corner = (27, 27)  # the far corner from the start above cell (2, 2)
    target = np.array([(corner[0] + 0.5) * 2.5, (corner[1] + 0.5) * 2.5])
    positions, first = _track("oracle", corner)
    dist = np.linalg.norm(positions[:, :2] - target, axis=1)
    reached = int(np.argmax(dist < 8.0))  # first decision that ends within a footprint of the ROI
    assert dist[reached] < 8.0
    assert np.all(np.diff(dist[:reached + 1]) < 0)  # every leg until then closes in on it
    assert first < 60.0
    # greedy, blind to the truth, spends that time on the belief ROI (the whole map at first)
    _, g_first = _track("greedy", corner)
    assert g_first > first
    # and the oracle's path follows the truth: the ROI in the other far corner sends it elsewhere
    other, _ = _track("oracle", (27, 2))
    assert not np.allclose(other[:3], positions[:3])


def test_oracle_is_greedy_scored_on_the_true_roi():
    env = make_env(TASK)
    obs, _ = env.reset(seed=5)
    oracle = make_planner("oracle")
    oracle.reset(view_for(oracle, env), 5)
    for _ in range(3):
        obs, *_ = env.step(oracle.act(obs))
    node = int(obs["current_node"][0])
    mask = obs["action_mask"].astype(bool)
    expected = greedy_scores(RobotView(env), node, env.mission.eval_roi)
    np.testing.assert_array_equal(oracle.scores(obs)[mask], expected[mask])
    assert not np.array_equal(env.mission.eval_roi, env.mission.belief_roi())


@pytest.mark.parametrize("name", [n for n in planner_names()
                                  if n not in REFERENCE_PLANNERS and not is_team_planner(n)])
def test_no_other_registered_planner_gets_the_truth_view(name):
    seen = []
    env = make_env("ipp_bench/Hotspots15Eval-v2", budget_s=12.0, report_times=[12.0])
    agent = make_planner(CHEAP.get(name, name))
    fly_episode(env, agent, 0, on_reset=lambda e: seen.append(agent.view))
    assert type(seen[0]) is RobotView and not hasattr(seen[0], "true_roi")
    assert not is_reference(name)


def test_only_the_suites_references_read_the_truth():
    env = make_env(TASK)
    env.reset(seed=0)
    oracle = make_planner("oracle")
    assert is_reference("oracle") and isinstance(view_for(oracle, env), TruthView)
    roi = view_for(oracle, env).true_roi()
    np.testing.assert_array_equal(roi, env.mission.eval_roi)
    roi[:] = True  # a copy: the planner cannot change what the metrics use
    assert not env.mission.eval_roi.all()

    class Sneaky(GraphPlanner):  # a plugin that claims the truth, even under the oracle's name
        name = "oracle"
        reads_truth = True

        def act(self, obs):
            return 0

    with pytest.raises(ValueError, match="only the suite's reference planners"):
        view_for(Sneaky(), env)
