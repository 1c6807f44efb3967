"""A team deployed in MuJoCo: several quadrotors in one scene, each camera a sensor, one shared belief."""

import warnings

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("dm_control")

from ipp_bench.envs import make_env  # noqa: E402
from ipp_bench.planners.episode import fly_episode  # noqa: E402

TEAM = "ipp_bench/MuJoCoWeed15Team2-v1"
SINGLE = "ipp_bench/MuJoCoWeed15-v1"


def test_a_team_of_one_flies_the_single_drone_deployment_exactly():
    """The team's machinery (one scene, legs committed then flown with the physics, read-outs taken as
    they come and fused in time order) with one drone is the single-drone deployment: the same legs,
    the same read-outs at the same times and places, the same belief."""
    team = make_env(TEAM, budget_s=40.0, team={"size": 1, "starts": [[2, 2, 14.0]]})
    single = make_env(SINGLE, budget_s=40.0)
    try:
        a = fly_episode(team, "greedy", 3)
        b = fly_episode(single, "greedy", 3)
        assert team.mission.paths[0] == single.mission.path
        assert team.mission.world.measurement_log == single.mission.measurement_log
        np.testing.assert_array_equal(team.mission.belief.mean, single.mission.belief.mean)
        np.testing.assert_array_equal(team.mission.belief.variance, single.mission.belief.variance)
        assert a.final["uncertainty_reduction_pct"] == b.final["uncertainty_reduction_pct"]
    finally:
        team.close()
        single.close()


def test_the_drones_fly_together_in_one_wind_with_their_own_estimators():
    env = make_env(TEAM, budget_s=30.0)
    try:
        scene = env.world.scene
        assert scene.drones == 2 and len({ids.camera_id for ids in scene.drones_ids}) == 2
        assert scene.model.nexclude == 1  # the drones' bodies never touch each other
        result = fly_episode(env, "team-greedy", 5)
        f0, f1 = env.world.flights
        assert f0.time_s == f1.time_s  # one physics
        np.testing.assert_array_equal(f0.wind, f1.wind)
        assert np.linalg.norm(f0.wind) > 0.0
        assert not np.allclose(f0.estimated_position() - f0.position, f1.estimated_position() - f1.position)
        for uav, flight in enumerate(env.world.flights):  # each drone ended where its path says, within tracking
            assert np.linalg.norm(flight.position - np.array(env.mission.paths[uav][-1][1:])) < 1.0
            assert len(env.mission.paths[uav]) > 3
        assert result.final["time_s"] == pytest.approx(30.0, abs=3.0)
    finally:
        env.close()


def test_a_teammates_committed_leg_is_predicted_as_it_is_then_flown():
    """What a team-aware planner fuses in advance: the read-outs a teammate's committed leg will take,
    predicted from its reference. Flown in the physics (wind, tracking error), the same number of
    read-outs is taken, each within a metre of where it was predicted; and the belief a UAV decides
    on holds every read-out taken up to its time and none after."""
    env = make_env(TEAM, budget_s=60.0)
    taken: list[tuple[int, float, np.ndarray]] = []
    env.reset(seed=7)
    sim = env.sim_team
    read = sim.read

    def logged(uav, time_s):
        taken.append((uav, time_s, env.world.flights[uav].position))
        return read(uav, time_s)

    sim.read = logged
    checked = 0
    try:
        for agent in env.agent_iter(400):
            if env.terminations[agent]:
                env.step(None)
                continue
            mission = env.mission
            assert all(p[0] > mission.fused_s - 1e-9 for p in mission._pending)
            assert all(t <= mission.fused_s + 0.01 for _, t, _ in taken)
            i = env.uav_index(agent)
            other = 1 - i
            c = sim.legs[other]
            if c is not None and c.whole and checked < 12:
                predicted = sim.ahead_points(other)
                now, end = float(env.world.scene.data.time), c.limit
                mask = env.uav_mask(i)
                env.step(int(np.flatnonzero(mask)[0]))
                while sim.legs[other] is c:  # fly on (the acting UAV's next legs) until the teammate's leg ends
                    nxt = env.agent_selection
                    if env.terminations[nxt]:
                        env.step(None)
                        continue
                    env.step(int(np.flatnonzero(env.uav_mask(env.uav_index(nxt)))[0]))
                got = [p for u, t, p in taken if u == other and now < t <= end + 1e-9]
                assert abs(len(got) - len(predicted)) <= 1
                for p, q in zip(predicted[::-1], got[::-1]):  # matched from the arrival back
                    assert np.linalg.norm(np.asarray(p) - q) < 1.0
                checked += 1
                continue
            env.step(int(np.flatnonzero(env.uav_mask(i))[0]))
        assert checked >= 5
    finally:
        env.close()


def test_same_seed_same_team_episode():
    env = make_env(TEAM, budget_s=30.0)
    try:
        a = fly_episode(env, "team-greedy", 11)
        log_a = list(env.mission.world.measurement_log)
        b = fly_episode(env, "team-greedy", 11)
        assert a.final == b.final and env.mission.world.measurement_log == log_a
    finally:
        env.close()


def test_pettingzoo_api_test_passes_on_the_mujoco_team():
    from pettingzoo.test import api_test

    env = make_env(TEAM, budget_s=20.0)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            api_test(env, num_cycles=20)
    finally:
        env.close()


def test_stop_and_go_flight_is_refused_in_one_line():
    with pytest.raises(ValueError, match=r"sim.flight.mode = 'stop' is invalid: expected 'continuous'") as err:
        make_env(TEAM, mode="stop")
    assert "\n" not in str(err.value)


def test_the_team_demo_video_is_the_same_bytes_for_the_same_seed(tmp_path):
    pytest.importorskip("imageio_ffmpeg")
    pytest.importorskip("matplotlib")
    from ipp_bench.eval.demo import record
    from ipp_bench.sim.video import expected_frames

    outs = [tmp_path / "a.mp4", tmp_path / "b.mp4"]
    for out in outs:
        log, frames = record(TEAM, "team-greedy", 2, str(out), budget=6.0, size=(320, 192), fps=5, speedup=1.0,
                             hold_s=0.4, progress=False)
    assert outs[0].read_bytes() == outs[1].read_bytes()
    end = log.final["time_s"]
    assert frames == expected_frames(end, fps=5, speedup=1.0, hold_s=0.4)


def test_the_dm_control_view_of_a_team_task_is_refused_in_one_line():
    from ipp_bench.sim import load

    with pytest.raises(ValueError, match="is a team .*a dm_control Environment flies one drone") as err:
        load(TEAM)
    assert "\n" not in str(err.value)


def test_render_shows_a_chase_view_of_every_drone_above_the_maps():
    env = make_env(TEAM, render=True, budget_s=10.0)
    try:
        env.reset(seed=0)
        frame = env.render()
        half = (frame.shape[1] - 4) // 2
        assert frame.dtype == np.uint8 and frame.shape[1] >= 2 * half
        top = frame[: half // 2]
        assert not np.array_equal(top[:, :half], top[:, half + 4: 2 * half + 4])  # each view follows its drone
    finally:
        env.close()
