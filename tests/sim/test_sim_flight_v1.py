"""v1 flight: velocity-continuous legs, wind, state estimation (checked against formulas)."""

import dataclasses
import math

import numpy as np
import pytest

pytest.importorskip("mujoco")

from ipp_bench.sim.controller import ContinuousLeg, ControllerGains, continuous_durations  # noqa: E402
from ipp_bench.sim.disturbance import DisturbanceConfig, Disturbances, perturb_quat, quat_to_mat  # noqa: E402
from ipp_bench.sim.flight import Flight, FlightConfig  # noqa: E402
from ipp_bench.sim.quadrotor import GRAVITY  # noqa: E402
from ipp_bench.sim.scene import WeedScene  # noqa: E402

CALM = DisturbanceConfig.none()


@pytest.fixture(scope="module")
def scene():
    return WeedScene(15, 15, 2.5)


def test_leg_durations_match_the_closed_forms():
    v, ramp = 2.0, 1.0
    L = 10.0
    end = [[L, 0.0, 0.0]]
    # from cruise straight on: length / speed; from rest: + ramp / 2; straight back: + 2 ramp
    assert continuous_durations([0, 0, 0], [2, 0, 0], end, v, ramp)[0] == pytest.approx(L / v)
    assert continuous_durations([0, 0, 0], [0, 0, 0], end, v, ramp)[0] == pytest.approx(L / v + ramp / 2)
    assert continuous_durations([0, 0, 0], [-2, 0, 0], end, v, ramp)[0] == pytest.approx(L / v + 2 * ramp)
    assert continuous_durations([0, 0, 0], None, end, v, ramp)[0] == pytest.approx(L / v + 2 * ramp)
    # the upper bound holds for every incoming velocity of magnitude <= speed and every length
    rng = np.random.default_rng(0)
    for _ in range(200):
        v0 = rng.normal(size=3)
        v0 *= rng.uniform(0, v) / np.linalg.norm(v0)
        ends = rng.uniform(-8, 8, (5, 3))
        exact = continuous_durations([0, 0, 0], v0, ends, v, ramp)
        assert np.all(exact <= continuous_durations([0, 0, 0], None, ends, v, ramp) + 1e-12)
        for e, t in zip(ends, exact):
            leg = ContinuousLeg([0, 0, 0], v0, e, v, ramp)
            assert leg.duration == pytest.approx(t)
            ts = np.linspace(0.0, leg.duration, 50)
            np.testing.assert_allclose(leg.sample(leg.duration)[0], e, atol=1e-9)  # ends on the waypoint
            assert max(np.linalg.norm(leg.sample(t)[1]) for t in ts) <= v + 1e-9  # never above the speed


def test_reference_is_smooth_and_ends_at_the_waypoint_at_cruise_speed():
    leg = ContinuousLeg([0, 0, 8], [0, 2, 0], [10, 0, 8], 2.0, 1.0)  # 90 deg turn at full speed
    ts = np.linspace(0, leg.duration, 4001)
    p = np.array([leg.sample(t)[0] for t in ts])
    vel = np.array([leg.sample(t)[1] for t in ts])
    acc = np.array([leg.sample(t)[2] for t in ts])
    np.testing.assert_allclose(p[0], [0, 0, 8], atol=1e-12)
    np.testing.assert_allclose(p[-1], [10, 0, 8], atol=1e-9)
    np.testing.assert_allclose(vel[0], [0, 2, 0], atol=1e-12)  # continuous with the incoming velocity
    assert np.linalg.norm(vel[-1]) == pytest.approx(2.0)  # arrives at cruise speed ...
    assert vel[-1][0] > 1.9  # ... heading along the new leg (after the blend, straight at the waypoint)
    # derivatives (central differences, interior points)
    np.testing.assert_allclose(np.gradient(p, ts, axis=0)[1:-1], vel[1:-1], atol=2e-3)
    np.testing.assert_allclose(np.gradient(vel, ts, axis=0)[1:-1], acc[1:-1], atol=2e-3)
    np.testing.assert_allclose(acc[0], 0.0, atol=1e-9)  # no acceleration jump where the legs join
    assert np.linalg.norm(acc, axis=1).max() <= math.pi * 2.0 / (2 * 1.0) * math.sqrt(2) + 1e-6  # pi |dv| / (2 T_r)
    assert np.linalg.norm(vel, axis=1).max() <= 2.0 + 1e-6


def _flight(scene, disturbances=CALM, seed=0):
    f = Flight(scene, 2.0, FlightConfig(), ControllerGains(), disturbances)
    f.disturbance_seed = seed
    return f


def test_no_stop_at_a_straight_waypoint(scene):
    flight = _flight(scene)
    flight.reset([5.0, 10.0, 8.0])
    speeds = []
    log = lambda f: speeds.append(float(np.linalg.norm(f.velocity)))  # noqa: E731
    first = flight.follow([15.0, 10.0, 8.0], on_step=log)
    n_first = len(speeds)
    second = flight.follow([25.0, 10.0, 8.0], on_step=log)
    assert first.duration == pytest.approx(10.0 / 2.0 + 0.5)  # from rest: + ramp / 2
    assert second.duration == pytest.approx(10.0 / 2.0)  # through the waypoint at cruise speed
    assert flight.ref_time == pytest.approx(10.5)
    around = speeds[n_first - 200: n_first + 200]  # one second either side of the waypoint
    assert min(around) > 1.9
    assert np.linalg.norm(flight.position - [25.0, 10.0, 8.0]) < 0.3


def test_turning_back_stops_along_the_leg(scene):
    flight = _flight(scene)
    flight.reset([5.0, 10.0, 8.0])
    flight.follow([15.0, 10.0, 8.0])
    vx = []
    leg = flight.follow([8.0, 10.0, 8.0], on_step=lambda f: vx.append(float(f.velocity[0])))
    assert leg.duration == pytest.approx(2 * 1.0 + 7.0 / 2.0)  # reverse: + 2 ramp
    assert vx[0] > 1.5 and min(vx) < -1.9  # it really reverses, through zero


def test_steady_wind_tilts_the_drone_and_offsets_it_as_the_formulas_say(scene):
    cfg = dataclasses.replace(CALM, rotor_drag=0.35)
    flight = _flight(scene, cfg)
    home = np.array([18.0, 18.0, 8.0])
    flight.reset(home)
    wind = 4.0
    # a steady 4 m/s wind along +x (the episode's draw replaced; no gusts)
    flight.disturbances = Disturbances(cfg, 0)
    flight.disturbances.wind_mean = (wind, 0.0)
    flight.hover(12.0, at=home)
    d, m = scene.data, scene.model
    # total horizontal air force: rotor drag (applied) + MuJoCo's inertia-box drag on the airspeed
    force = d.xfrc_applied[scene.body_id, 0] + d.qfrc_passive[scene.qvel_adr]
    assert force > 0.35 * wind * 0.95  # pushes downwind
    q = d.qpos[scene.qpos_adr + 3: scene.qpos_adr + 7]
    R = quat_to_mat(q)
    tilt = math.degrees(math.atan2(-R[0, 2], R[2, 2]))  # thrust axis leans into the wind (-x)
    assert tilt == pytest.approx(math.degrees(math.atan2(force, scene.quad.mass * GRAVITY)), abs=0.3)
    # PD position loop without integral action: steady offset F / (m k_p) downwind
    kp = ControllerGains().pos_omega_xy ** 2
    assert flight.position[0] - home[0] == pytest.approx(force / (scene.quad.mass * kp), abs=0.02)
    assert m.opt.wind[0] == pytest.approx(wind)


def test_gusts_and_estimator_errors_have_the_configured_statistics():
    cfg = DisturbanceConfig(wind_max=0.0, gust_std=0.7, gust_time_s=2.0, pos_noise_std=0.1, pos_noise_time_s=1.0,
                            att_noise_std_deg=0.3, update_hz=50.0)
    d = Disturbances(cfg, 3)
    n = 60_000
    gust, pos = np.empty(n), np.empty(n)
    for i in range(n):
        d.advance()
        gust[i] = d.wind[0]
        pos[i] = d.position_error()[0] - d.pos_bias[0]
    assert np.std(gust) == pytest.approx(0.7, rel=0.15)
    assert np.std(pos) == pytest.approx(0.1, rel=0.1)
    lag1 = np.corrcoef(pos[:-1], pos[1:])[0, 1]
    assert lag1 == pytest.approx(math.exp(-1.0 / (50.0 * 1.0)), abs=0.005)
    # bias: per episode, with the configured spread across episodes
    biases = np.array([Disturbances(cfg, s).pos_bias for s in range(400)])
    assert np.std(biases[:, 0]) == pytest.approx(cfg.pos_bias_std, rel=0.15)
    assert np.std(biases[:, 2]) == pytest.approx(cfg.pos_bias_std_z, rel=0.15)


def test_controller_flies_the_estimate_so_a_position_bias_moves_the_drone(scene):
    cfg = dataclasses.replace(CALM, pos_bias_std=0.3)
    flight = _flight(scene, cfg, seed=5)
    home = np.array([18.0, 18.0, 8.0])
    flight.reset(home)
    bias = np.array(flight.disturbances.pos_bias)
    assert np.linalg.norm(bias[:2]) > 0.05
    flight.hover(8.0, at=home)
    # the estimate (true + bias) sits on the target, so the true position is target - bias
    np.testing.assert_allclose(flight.position, home - bias, atol=0.01)
    np.testing.assert_allclose(flight.estimated_position(), home, atol=0.01)
    # the camera is georeferenced with the estimated pose
    est_body, est_cam, _ = flight.estimated_camera_pose()
    np.testing.assert_allclose(est_body, flight.position + bias, atol=1e-12)


def test_attitude_error_is_a_small_body_rotation():
    q = (math.cos(0.2), 0.0, 0.0, math.sin(0.2))  # yaw 0.4 rad
    p = perturb_quat(q, (0.01, 0.0, 0.0))
    R, Rp = quat_to_mat(q), quat_to_mat(p)
    rel = R.T @ Rp
    assert math.acos(max(-1.0, min(1.0, (np.trace(rel) - 1) / 2))) == pytest.approx(0.01, rel=1e-6)
    assert rel[2, 1] == pytest.approx(math.sin(0.01), rel=1e-6)  # about body x


def test_same_seed_same_disturbed_flight(scene):
    out = []
    for seed in (4, 4, 5):
        flight = _flight(scene, DisturbanceConfig(), seed)
        flight.reset([5.0, 5.0, 8.0])
        flight.follow([15.0, 9.0, 14.0])
        out.append(scene.data.qpos.copy())
    np.testing.assert_array_equal(out[0], out[1])
    assert not np.array_equal(out[0], out[2])
