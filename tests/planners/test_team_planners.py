"""Team planners: team-greedy's score against the batch GP posterior, the coverage bands, the team
episode loop (determinism, every single-UAV planner per UAV) and the refusals."""

import numpy as np
import pytest

from ipp_bench.core import metrics as M
from ipp_bench.core.belief import GPBelief
from ipp_bench.envs.registry import make_env
from ipp_bench.planners import make_planner, view_for
from ipp_bench.planners.episode import fly_episode, fly_team_episode
from ipp_bench.planners.team import TeamGreedyPlanner

TEAM2 = "ipp_bench/Hotspots30Team2Eval-v2"


def _posterior_variance(prior: GPBelief, observations) -> np.ndarray:
    """diag(P0 - P0 H^T (H P0 H^T + R)^-1 H P0) over every read-out at once."""
    if not observations:
        return np.diag(prior.cov).copy()
    H = np.zeros((sum(o.m for o in observations), prior.n))
    row = 0
    for o in observations:
        H[row:row + o.m, o.cells] = o.weights
        row += o.m
    S = H @ prior.cov @ H.T + np.diag(np.concatenate([o.var for o in observations]))
    return np.diag(prior.cov - prior.cov @ H.T @ np.linalg.solve(S, H @ prior.cov))


def test_team_greedy_scores_each_leg_by_the_posterior_after_its_teammates_committed_read_outs():
    """score(leg) = [Tr_ROI P(taken + teammates' pending) - Tr_ROI P(taken + pending + leg)] / flight time,
    every P the batch GP posterior; the ROI the live belief's."""
    env = make_env(TEAM2, budget_s=40)
    prior = GPBelief.prior(env.config.grid, env.config.gp)
    rng = np.random.default_rng(0)
    env.reset(seed=4)
    checked = 0
    for agent in env.agent_iter():
        obs, _, terminated, _, _ = env.last()
        if terminated:
            env.step(None)
            continue
        seat = env.seats[env.uav_index(agent)]
        planner = TeamGreedyPlanner()
        planner.reset(view_for(planner, seat), 0)
        view = planner.view
        if view.teammates_pending() and checked < 3:
            planner.act(obs)
            scores = planner.scores(obs)
            taken = [env.sensor.observe(np.array(p[1:])) for p in env.mission.world.measurement_log]
            taken = [o for o in taken if o is not None]  # every read-out taken or committed, all UAVs
            roi = view.belief_roi()
            before = _posterior_variance(prior, taken)[roi].sum()
            node = seat.current_node
            for a in np.flatnonzero(obs["action_mask"])[:5]:
                end = env.roadmap.positions[env.roadmap.neighbours[node, a]]
                leg = view.leg_observations(view.position, end)
                after = _posterior_variance(prior, taken + leg)[roi].sum()
                duration = view.leg_durations(view.position, end[None])[0]
                assert scores[a] == pytest.approx((before - after) / duration, rel=1e-7, abs=1e-12)
            checked += 1
        env.step(int(rng.choice(np.flatnonzero(obs["action_mask"]))))
    assert checked == 3


def test_team_coverage_flies_each_uav_in_its_own_band():
    env = make_env("ipp_bench/Hotspots30Team4Eval-v2", budget_s=80)
    result = fly_team_episode(env, "team-coverage", 3)
    height = env.config.grid.size_m[1]
    for seat in env.seats:
        ys = [p[2] for p in seat.mission.path[1:]]
        low, high = seat.index * height / 4, (seat.index + 1) * height / 4
        assert ys and all(low - 1e-9 <= y <= high + 1e-9 for y in ys), (seat.index, ys)
    assert result.report[0]["uncertainty_reduction_pct"] > 0


@pytest.mark.parametrize("spec", ["random", "greedy", "team-greedy", "team-oracle"])
def test_the_team_loop_is_deterministic_and_every_spec_flies_each_uav(spec):
    env = make_env(TEAM2, budget_s=60)
    one = fly_team_episode(env, spec, 9)
    two = fly_episode(env, spec, 9)  # the one episode loop hands a team env to the team loop
    assert one.report == two.report and one.decisions == two.decisions > 4
    assert len({s.current_node for s in env.seats}) == 2
    assert all(len(s.mission.path) > 2 for s in env.seats)


def test_attention_flies_each_uav_of_a_team():
    pytest.importorskip("torch")
    env = make_env(TEAM2, budget_s=60)
    result = fly_team_episode(env, "attention", 1)
    assert result.decisions > 4 and all(len(s.mission.path) > 2 for s in env.seats)


@pytest.mark.parametrize("team, single", [("team-greedy", "greedy"), ("team-coverage", "coverage"),
                                          ("team-oracle", "oracle")])
def test_on_one_uav_a_team_aware_planner_flies_as_its_single_uav_counterpart(team, single):
    env = make_env("ipp_bench/Hotspots30Eval-v2", budget_s=80, report_times=[40, 80])
    alone = fly_episode(env, single, 5)
    assert fly_episode(env, team, 5).report == alone.report
    one = make_env(TEAM2, budget_s=80, report_times=[40, 80], team={"size": 1, "starts": None})
    in_team = fly_episode(one, team, 5)  # the team env of one UAV too, to the end of the budget
    assert in_team.report == alone.report and in_team.decisions == alone.decisions


def test_only_the_team_oracle_reads_the_truth():
    env = make_env(TEAM2)
    env.reset(seed=0)
    assert hasattr(view_for(make_planner("team-oracle"), env.seats[0]), "true_roi")
    assert not hasattr(view_for(make_planner("team-greedy"), env.seats[0]), "true_roi")
    assert not hasattr(view_for(make_planner("greedy"), env.seats[0]), "true_roi")


def test_team_greedy_reward_sum_is_the_team_trace_reduction():
    env = make_env(TEAM2, budget_s=30)
    result = fly_team_episode(env, "team-greedy", 2)
    assert result.total_reward > 0
    assert result.final["measurements"] == env.mission.world.n_measurements > 0
    assert M.trace_roi(env.mission.belief.variance, env.mission.eval_roi) == pytest.approx(
        env.mission.history[-1].trace_roi)
