"""UAV teams: the shared belief against the batch GP posterior, the turn order, PettingZoo's API test,
the team tasks' files and their refusals."""

import warnings

import numpy as np
import pytest

from ipp_bench.core.belief import GPBelief
from ipp_bench.core.team import TeamConfig
from ipp_bench.envs.registry import TASKS, make_env, tagged

TEAM2 = "ipp_bench/Hotspots30Team2Eval-v2"


def batch_cov(prior: GPBelief, observations) -> np.ndarray:
    """P0 - P0 H^T (H P0 H^T + R)^-1 H P0 over every read-out at once (the GP posterior's covariance)."""
    P0 = prior.cov
    if not observations:
        return P0
    H = np.zeros((sum(o.m for o in observations), prior.n))
    row = 0
    for o in observations:
        H[row:row + o.m, o.cells] = o.weights
        row += o.m
    R = np.concatenate([o.var for o in observations])
    S = H @ P0 @ H.T + np.diag(R)
    return P0 - P0 @ H.T @ np.linalg.solve(S, H @ P0)


def logged_observations(env, until_s=np.inf):
    """The read-outs every UAV has taken or committed up to ``until_s``, from the team's log."""
    out = []
    for t, x, y, z in env.mission.world.measurement_log:
        if t <= until_s + 1e-9:
            obs = env.sensor.observe(np.array([x, y, z]))
            if obs is not None:
                out.append(obs)
    return out


def _random_episode(env, seed, on_decision):
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    for agent in env.agent_iter():
        obs, _, terminated, _, _ = env.last()
        if terminated:
            env.step(None)
            continue
        on_decision(agent)
        env.step(int(rng.choice(np.flatnonzero(obs["action_mask"]))))


def test_the_shared_belief_holds_exactly_the_read_outs_taken_by_the_acting_uavs_clock():
    """At every decision the belief's covariance is the batch posterior of every UAV's read-outs taken up
    to the acting UAV's clock (not those its teammates' legs take later), and the acting UAV is the one
    whose leg ended first; at the end the mean and covariance are the batch posterior of all read-outs."""
    env = make_env(TEAM2, budget_s=50)
    prior = GPBelief.prior(env.config.grid, env.config.gp)
    checked = []

    def check(agent):
        clock = env.seats[env.uav_index(agent)].mission.time_s
        live = [env.seats[env.uav_index(a)].mission.time_s for a in env.agents if not env.terminations[a]]
        assert clock == min(live)
        np.testing.assert_allclose(env.mission.belief.cov, batch_cov(prior, logged_observations(env, clock)),
                                   atol=1e-10)
        pending = logged_observations(env)
        checked.append(len(pending) > len(logged_observations(env, clock)))

    _random_episode(env, 7, check)
    assert sum(checked) >= 3  # decisions made while a teammate's leg was still being read
    np.testing.assert_allclose(env.mission.belief.cov, batch_cov(prior, logged_observations(env)), atol=1e-10)


def test_the_mean_is_the_batch_posterior_and_the_report_reads_the_belief_at_each_report_time():
    env = make_env(TEAM2, budget_s=60, measure_at_start=False, report_times=[20, 40, 60])
    fused = []
    env.reset(seed=3)
    env.mission.world.update_hooks.append(lambda obs, zs, t: fused.append((t, obs, zs)))
    rng = np.random.default_rng(3)
    for _ in env.agent_iter():
        obs, _, terminated, _, _ = env.last()
        env.step(None if terminated else int(rng.choice(np.flatnonzero(obs["action_mask"]))))
    assert [t for t, _, _ in fused] == sorted(t for t, _, _ in fused)  # fused in time order
    prior = GPBelief.prior(env.config.grid, env.config.gp)
    observations = [o for _, obs, _ in fused for o in obs]
    H = np.zeros((sum(o.m for o in observations), prior.n))
    row = 0
    for o in observations:
        H[row:row + o.m, o.cells] = o.weights
        row += o.m
    z = np.concatenate([v for _, _, zs in fused for v in zs])
    R = np.concatenate([o.var for o in observations])
    gain = prior.cov @ H.T @ np.linalg.inv(H @ prior.cov @ H.T + np.diag(R))
    np.testing.assert_allclose(env.mission.belief.mean, prior.mean + gain @ (z - H @ prior.mean), atol=1e-9)
    roi = env.mission.eval_roi
    for row_ in env.mission.report():
        cov = batch_cov(prior, logged_observations(env, row_["time_s"]))
        assert row_["trace_roi"] == pytest.approx(float(np.diag(cov)[roi].sum()), rel=1e-9)


def test_belief_ahead_is_the_posterior_covariance_with_the_teammates_committed_legs():
    from ipp_bench.planners import TeamRobotView

    env = make_env(TEAM2, budget_s=50)
    prior = GPBelief.prior(env.config.grid, env.config.gp)
    seen = []

    def check(agent):
        view = TeamRobotView(env.seats[env.uav_index(agent)])
        ahead = view.belief_ahead()
        np.testing.assert_allclose(ahead.cov, batch_cov(prior, logged_observations(env)), atol=1e-10)
        np.testing.assert_allclose(ahead.mean, view.belief.mean, atol=0)
        seen.append(len(view.teammates_pending()))

    _random_episode(env, 11, check)
    assert max(seen) > 0


def test_the_same_seed_plays_the_single_uav_tasks_field_first_start_and_first_noise():
    team, single = make_env(TEAM2), make_env("ipp_bench/Hotspots30Eval-v2")
    for seed in (0, 5):
        team.reset(seed=seed)
        single.reset(seed=seed)
        np.testing.assert_array_equal(team.mission.truth, single.mission.truth)
        assert team.seats[0].current_node == single.current_node
        single.mission.fly_to(single.roadmap.positions[single.roadmap.neighbours[single.current_node, 0]])
        seat = team.seats[0]
        seat.mission.fly_to(team.roadmap.positions[team.roadmap.neighbours[seat.current_node, 0]])
        team.mission.finish()
        assert team.mission.world.measurement_log[:1] == single.mission.measurement_log[:1]


def test_pettingzoo_api_test_passes_on_the_team_tasks():
    from pettingzoo.test import api_test

    for task in ("ipp_bench/Hotspots30Team2Eval-v2", "ipp_bench/Hotspots30Team4Train-v2"):
        env = make_env(task, budget_s=30)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # its advice for Box observations: ours is the single-UAV Dict
            api_test(env, num_cycles=50)


def test_uavs_never_share_a_node_and_every_uav_flies_its_own_budget():
    env = make_env("ipp_bench/Hotspots30Team4Eval-v2", budget_s=40)

    def check(agent):
        nodes = [s.current_node for s, a in zip(env.seats, env.possible_agents) if a in env.agents]
        assert len(set(nodes)) == len(nodes)

    _random_episode(env, 2, check)
    assert not env.agents
    for seat in env.seats:
        assert 40 - 8 < seat.mission.time_s <= 40 + 1e-9  # spent to within one leg


def test_team_tasks_are_data_tagged_team_with_train_and_eval_seeds():
    roadmap = "ipp_bench.envs.team:TeamGraphEnv"
    teams = [t for t in tagged("team") if TASKS[t].entry_point == roadmap]  # the roadmap's teams
    assert {"ipp_bench/Hotspots30Team2Eval-v2", "ipp_bench/Hotspots30Team4Eval-v2",
            "ipp_bench/Hotspots30Team2Train-v2", "ipp_bench/Hotspots30Team4Train-v2"} <= set(teams)
    single = TASKS["ipp_bench/Hotspots30Eval-v2"].config
    for task in teams:
        spec = TASKS[task]
        train = "train" in spec.tags
        assert spec.config.mission.episode_seeds == ((2**31, 2**32) if train else (0, 2**31))
        assert spec.config.replace(episode_seeds=single.mission.episode_seeds) == single
        assert TeamConfig.from_dict(spec.team).size in (2, 4)


@pytest.mark.parametrize("team, message", [
    ({"size": 0}, r"team.size = 0 is invalid: expected an integer in \[1, 16\]"),
    ({"size": 2, "starts": [[2, 2, 14.0]]}, "team.starts = .* is invalid: expected 2 positions"),
    ({"size": 2, "starts": [[2, 2, 14.0], [40, 2, 14.0]]}, r"team.starts\[1\] = \(40.0, 2.0, 14.0\) is invalid"),
    ({"size": 2, "starts": [[2, 2, 14.0], [2, 2, 14.0]]}, "starts on different roadmap nodes"),
    ({"size": 2, "budgets_s": [100, -1]}, "team.budgets_s = .* is invalid: expected budgets > 0"),
    ({"size": 2, "share_nodes": "no"}, "team.share_nodes = 'no' is invalid"),
    ({"size": 2, "nosuch": 1}, r"unknown fields \['nosuch'\] in section 'team'"),
    ({"size": 2, "budgets_s": [100, 0.5]}, "the budget of UAV 1 .0.5 s. pays for no move"),
])
def test_a_team_that_does_not_fit_is_one_line_before_work(team, message):
    with pytest.raises(ValueError, match=message) as err:
        env = make_env(TEAM2, team=team)
        env.reset(seed=0)
    assert "\n" not in str(err.value)


def test_a_task_file_with_a_team_table_is_checked_and_needs_the_team_env(tmp_path):
    from ipp_bench.envs.registry import TaskFileError, load_task_file

    text = (TASKS[TEAM2].source and open(TASKS[TEAM2].source).read())
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("size = 2", "size = 3"))
    with pytest.raises(TaskFileError, match="team.starts = .* is invalid: expected 3 positions"):
        load_task_file(bad)
    bad.write_text(text.replace("ipp_bench.envs.team:TeamGraphEnv", "ipp_bench.envs.graph:GraphIPPEnv")
                   .replace("Team2Eval", "Team2Bad"))
    from ipp_bench.envs.registry import load_task

    with pytest.raises(ValueError, match="a \\[team\\] table needs a team environment as its entry_point"):
        make_env(load_task(bad))
    single = tmp_path / "single.toml"
    head, _, rest = text.replace("Team2Eval", "Team2NoTable").partition("[team]")
    single.write_text(head + rest[rest.index("[config"):])
    with pytest.raises(ValueError, match="is a team environment: a team task needs a \\[team\\] table"):
        make_env(load_task(single))


def test_a_team_renders_every_uavs_path(tmp_path):
    from ipp_bench.eval.figure import save_episode_figure
    from ipp_bench.planners.episode import fly_team_episode

    env = make_env(TEAM2, budget_s=30, report_times=[30], render=True)
    fly_team_episode(env, "greedy", 0)
    frame = env.render()
    assert frame.ndim == 3 and frame.dtype == np.uint8
    single = make_env(TEAM2, budget_s=30, report_times=[30], render=True, team={"size": 1, "starts": None})
    fly_team_episode(single, "greedy", 0)
    assert not np.array_equal(frame, single.render())  # the second UAV's path is drawn too
    assert save_episode_figure(env.mission, tmp_path / "team.png").stat().st_size > 10_000


@pytest.mark.parametrize("argv, message", [
    (["--tasks", "Hotspots30Team2Eval-v2", "--planners", "greedy", "--env", 'team={"size": 0}'],
     r"team.size = 0 is invalid: expected an integer in \[1, 16\]"),
    (["--tasks", "Hotspots30Team2Eval-v2", "--planners", "greedy", "--env", 'team={"budgets_s": [200, 0.1]}'],
     r"task ipp_bench/Hotspots30Team2Eval-v2: the budget of UAV 1 \(0.1 s\) pays for no move"),
    (["--tasks", "Hotspots30Eval-v2", "--planners", "greedy", "--env", 'team={"size": 2}'],
     "unknown config field 'team'"),
])
def test_the_leaderboard_refuses_a_team_that_does_not_fit_in_one_line_writing_nothing(tmp_path, capsys, argv,
                                                                                        message):
    import re

    from ipp_bench.cli import main

    out = tmp_path / "board"
    assert main(["leaderboard", *argv, "--episodes", "2", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert re.search(message, err) and err.count("\n") == 1, err
    assert not out.exists()


def test_a_team_board_flies_every_planner_per_uav_and_team_aware_ones(tmp_path):
    import csv

    from ipp_bench.cli import main

    out = tmp_path / "board"
    assert main(["leaderboard", "--tasks", "Hotspots30Team2Eval-v2", "--planners", "random,team-greedy,team-coverage",
                 "--episodes", "2", "--env", "budget_s=30", "--env", "report_times=[15,30]", "--out", str(out)]) == 0
    rows = list(csv.DictReader(open(out / "results.csv")))
    assert {r["planner"] for r in rows} == {"random", "team-greedy", "team-coverage"} and len(rows) == 12
    assert "team-greedy" in (out / "leaderboard.md").read_text()


def test_the_report_pairs_a_team_with_its_single_uav_task_at_equal_flight_and_mission_time():
    from ipp_bench.eval.markdown import team_section
    from ipp_bench.eval.tables import EpisodeTable, team_pairs

    single, team = "ipp_bench/Hotspots30Eval-v2", TEAM2
    assert team_pairs([single, team, "ipp_bench/Grid30Eval-v1"]) == [(single, team, 2)]
    rows = []
    for seed in range(4):
        for task, t, value in [(single, 50.0, 10.0 + seed), (single, 100.0, 20.0 + seed),
                               (team, 50.0, 25.0 + 2 * seed), (team, 100.0, 30.0)]:
            row = {"task": task, "planner": "greedy", "seed": seed, "time_s": t, "decision_time_mean_s": 0.01}
            row.update({k: value for k in ("trace_roi", "rmse_roi", "uncertainty_reduction_pct",
                                           "rmse_reduction_pct")})
            rows.append(row)
    text = team_section(EpisodeTable(rows))
    assert "| Method | 2 UAVs at 50 s - one at 100 s | 2 UAVs - one, at 50 s | 2 UAVs - one, at 100 s |" in text
    line = next(ln for ln in text.splitlines() if ln.startswith("| `greedy`"))
    cells = [c.strip() for c in line.strip("|").split("|")][1:]
    # team at 50 minus single at 100: 25 + 2s - (20 + s) = 5 + s, mean 6.5; at 50: 15 + s, mean 16.5;
    # at 100: 30 - (20 + s) = 10 - s, mean 8.5
    assert [c.split(" ")[0] for c in cells] == ["+6.5", "+16.5", "+8.5"]
    assert all(c.endswith("won 4/4") for c in cells)
    assert team_section(EpisodeTable([r for r in rows if r["task"] == team])) == ""


# -- one observation, one resolution of the team's config, PettingZoo's conventions ------------------------
def test_a_uav_of_a_team_of_one_observes_exactly_what_the_single_uav_env_observes():
    """The same state gives the same observation, bit for bit: a team of one on the single-UAV task's
    config and seed is that task's episode, observed through the one GraphObservation both envs hold."""
    team = make_env(TEAM2, budget_s=60, team={"size": 1, "starts": None})
    single = make_env("ipp_bench/Hotspots30Eval-v2", budget_s=60)
    assert type(team.seats[0]).__mro__[1:] == (object,)  # a seat holds the env's parts, it is no env itself
    for seed in (0, 3):
        obs, _ = single.reset(seed=seed)
        team.reset(seed=seed)
        rng = np.random.default_rng(seed)
        steps = 0
        for _ in team.agent_iter():
            seen, _, terminated, _, _ = team.last()
            if terminated:
                team.step(None)
                continue
            assert seen.keys() == obs.keys()
            for key in obs:
                assert seen[key].dtype == obs[key].dtype and seen[key].tobytes() == obs[key].tobytes(), key
            action = int(rng.choice(np.flatnonzero(obs["action_mask"])))
            obs, reward, _, _, _ = single.step(action)
            team.step(action)
            assert team.rewards.get("uav_0", reward) == reward
            steps += 1
        assert steps > 10 and team.seats[0].mission.time_s == single.mission.time_s


def test_the_team_builds_its_parts_once_and_each_uav_walks_its_own_budget(monkeypatch):
    """One config, roadmap, camera and observation (one footprint per node) for the whole team, shared by
    every seat; each UAV's budget is resolved when the env is built, never again per reset, and its
    observation's budget fraction walks down its own budget."""
    from ipp_bench.core.config import IPPConfig
    from ipp_bench.core.sensor import Sensor

    looks = []
    observe = Sensor.observe
    monkeypatch.setattr(Sensor, "observe", lambda self, p: looks.append(1) or observe(self, p))
    env = make_env(TEAM2, budget_s=40, team={"budgets_s": [30.0, 40.0]})
    assert len(looks) == env.roadmap.n_nodes  # the footprints, once for the team
    assert all(seat.observer is env.observer and seat.config is env.config for seat in env.seats)
    assert [c.mission.budget_s for c in env.member_configs] == [30.0, 40.0]
    assert env.world_config.mission.budget_s == 40.0
    replaced = []
    replace = IPPConfig.replace
    monkeypatch.setattr(IPPConfig, "replace", lambda self, **kw: replaced.append(kw) or replace(self, **kw))
    env.reset(seed=1)
    assert not [kw for kw in replaced if "budget_s" in kw]
    fractions = {a: [] for a in env.possible_agents}
    rng = np.random.default_rng(1)
    for agent in env.agent_iter():
        obs, _, terminated, _, _ = env.last()
        if terminated:
            env.step(None)
            continue
        mission = env.seats[env.uav_index(agent)].mission
        own = (30.0, 40.0)[env.uav_index(agent)]
        assert obs["budget"][0] == np.float32(mission.remaining_s / own)
        fractions[agent].append(float(obs["budget"][0]))
        env.step(int(rng.choice(np.flatnonzero(obs["action_mask"]))))
    for walk in fractions.values():
        assert walk[0] == pytest.approx(1.0, abs=1e-6) and walk == sorted(walk, reverse=True) and walk[-1] < 0.5


def test_env_and_raw_env_follow_pettingzoos_conventions():
    from pettingzoo.test import api_test
    from pettingzoo.utils.wrappers import AssertOutOfBoundsWrapper, OrderEnforcingWrapper

    from ipp_bench.envs import team as team_module

    raw = team_module.raw_env(TEAM2, budget_s=30)
    assert isinstance(raw, team_module.TeamGraphEnv) and raw.task_id == TEAM2
    wrapped = team_module.env(TEAM2, budget_s=30)
    assert isinstance(wrapped, OrderEnforcingWrapper) and isinstance(wrapped.env, AssertOutOfBoundsWrapper)
    assert wrapped.unwrapped.config.mission.budget_s == 30
    with pytest.raises(AttributeError, match="agent_selection cannot be accessed before reset"):
        _ = wrapped.agent_selection
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # its advice for Box observations: ours is the single-UAV Dict
        api_test(wrapped, num_cycles=50)
    wrapped.reset(seed=0)
    with pytest.raises(AssertionError, match="action is not in action space"):
        wrapped.step(raw.roadmap.k)
    with pytest.raises(ValueError, match="flies one UAV"):
        team_module.raw_env("ipp_bench/Hotspots30Eval-v2")
    with pytest.raises(ValueError, match=r"render_mode='human' is invalid"):
        team_module.raw_env(TEAM2, render_mode="human")


def test_there_is_no_parallel_view_because_a_uav_may_act_twice_in_a_row():
    """aec_to_parallel steps every agent once per cycle; here the UAV whose leg ends first acts, again and
    again while a teammate flies a long leg, so the env says it is not parallelizable."""
    from pettingzoo.utils.conversions import aec_to_parallel

    env = make_env(TEAM2, budget_s=60)
    assert env.metadata["is_parallelizable"] is False
    with pytest.raises(AssertionError):
        aec_to_parallel(env)
    env.reset(seed=0)
    order = []
    for agent in env.agent_iter():
        obs, _, terminated, _, _ = env.last()
        if terminated:
            env.step(None)
            continue
        order.append(agent)
        mask = obs["action_mask"].astype(bool)
        # uav_0 hops to its nearest neighbours, uav_1 to its farthest: uav_0 decides more often
        costs = np.where(mask, env.roadmap.costs[env.seats[env.uav_index(agent)].current_node], np.nan)
        env.step(int(np.nanargmin(costs) if agent == "uav_0" else np.nanargmax(costs)))
    assert any(a == b for a, b in zip(order, order[1:]))
