"""Quadrotor model and flight control: the model, hover, a 10 m waypoint, the leg reference."""

import math

import numpy as np
import pytest

pytest.importorskip("mujoco")

from ipp_bench.sim.controller import Leg  # noqa: E402
from ipp_bench.sim.flight import Flight  # noqa: E402
from ipp_bench.sim.gl import mujoco  # noqa: E402
from ipp_bench.sim.quadrotor import GRAVITY, QuadrotorParams  # noqa: E402
from ipp_bench.sim.scene import SceneConfig, WeedScene  # noqa: E402


@pytest.fixture(scope="module")
def scene():
    return WeedScene(15, 15, 2.5)


def test_model_loads_with_a_real_airframe(scene):
    m, p = scene.model, scene.quad
    assert m.nu == 4 and m.opt.timestep == SceneConfig().timestep
    assert m.body_mass[scene.body_id] == pytest.approx(p.mass)
    np.testing.assert_allclose(m.body_inertia[scene.body_id], p.inertia)
    gear = m.actuator_gear[scene.actuator_ids]
    np.testing.assert_array_equal(gear[:, 2], 1.0)  # thrust along body z
    np.testing.assert_allclose(gear[:, 5], p.spin * p.yaw_moment_coeff)  # rotor reaction torques
    assert sorted(np.sign(gear[:, 5])) == [-1, -1, 1, 1]
    np.testing.assert_array_equal(m.actuator_ctrlrange[scene.actuator_ids], [[0, p.max_thrust]] * 4)
    assert m.cam_fovy[scene.camera_id] == pytest.approx(60.0)
    assert m.vis.quality.shadowsize == 0 and m.vis.quality.offsamples == 0


def test_mixer_inverts_the_allocation():
    p = QuadrotorParams()
    np.testing.assert_allclose(p.allocation @ p.mixer, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(p.mixer @ [p.mass * GRAVITY, 0, 0, 0], [p.hover_thrust] * 4)
    with pytest.raises(ValueError, match="mass"):
        QuadrotorParams(mass=-1.0)


def test_hover_within_10cm_for_10s_from_idle_rotors(scene):
    flight = Flight(scene)
    home = np.array([18.0, 18.0, 8.0])
    flight.reset(home)
    scene.data.act[:] = 0.0  # rotors idle at the start: the controller has to catch the drop
    scene.data.qvel[:3] = [0.2, -0.1, 0.0]  # and a gust of 0.22 m/s
    errors = []
    flight.hover(10.0, at=home, on_step=lambda f: errors.append(np.linalg.norm(f.position - home)))
    assert flight.time_s == pytest.approx(10.0, abs=scene.model.opt.timestep)
    assert max(errors) < 0.1
    assert errors[-1] < 0.01


def test_reaches_a_waypoint_10m_away(scene):
    flight = Flight(scene)
    flight.reset([5.0, 5.0, 8.0])
    target = np.array([15.0, 5.0, 8.0])
    speeds, tilts = [], []

    def log(f):
        speeds.append(np.linalg.norm(f.velocity))
        q = scene.data.qpos[3:7]
        tilts.append(math.degrees(math.acos(1 - 2 * (q[1] ** 2 + q[2] ** 2))))

    assert flight.fly_to(target, on_step=log)
    assert np.linalg.norm(flight.position - target) < 0.3
    assert flight.time_s == pytest.approx(Leg(np.zeros(3), [10, 0, 0]).duration, abs=0.5)
    assert max(speeds) < 2.1  # "up to 2 m/s"
    assert 3.0 < max(tilts) < 35.0  # it really tilts to accelerate; within the tilt limit


def test_climb_and_diagonal_legs(scene):
    flight = Flight(scene)
    flight.reset([6.25, 6.25, 14.0])
    for target in ([6.25, 6.25, 8.0], [20.0, 11.0, 14.0], [3.75, 31.25, 8.0]):
        assert flight.fly_to(target)
        assert np.linalg.norm(flight.position - target) < 0.3


def test_flight_is_deterministic(scene):
    out = []
    for _ in range(2):
        flight = Flight(scene)
        flight.reset([5.0, 5.0, 8.0])
        flight.fly_to([12.0, 9.0, 14.0])
        out.append(scene.data.qpos.copy())
    np.testing.assert_array_equal(out[0], out[1])


def test_time_limit_stops_the_leg(scene):
    flight = Flight(scene)
    flight.reset([5.0, 5.0, 8.0])
    assert not flight.fly_to([30.0, 5.0, 8.0], time_limit_s=3.0)
    assert flight.time_s == pytest.approx(3.0, abs=scene.model.opt.timestep)


def test_leg_reference_profile():
    leg = Leg([0, 0, 0], [10, 0, 0], speed=2.0, ramp_s=1.0)
    assert leg.duration == pytest.approx(6.0)
    assert Leg.duration_for(10.0, 2.0, 1.0) == pytest.approx(6.0)
    ts = np.linspace(0, leg.duration, 601)
    s = np.array([leg.sample(t)[0][0] for t in ts])
    v = np.array([leg.sample(t)[1][0] for t in ts])
    assert s[0] == 0.0 and s[-1] == pytest.approx(10.0)
    assert v.max() == pytest.approx(2.0) and v[0] == 0.0 and v[-1] == pytest.approx(0.0, abs=1e-12)
    assert np.all(np.diff(s) >= -1e-12)
    np.testing.assert_allclose(np.gradient(s, ts), v, atol=0.02)  # velocity is the derivative
    short = Leg([0, 0, 0], [0, 0, 1.0], speed=2.0, ramp_s=1.0)  # too short to reach 2 m/s
    assert short.cruise_speed == pytest.approx(1.0) and short.duration == pytest.approx(2.0)


def test_exported_airframe_matches_the_code():
    from ipp_bench.core.data import data_dir
    from ipp_bench.sim.quadrotor import airframe_xml

    shipped = mujoco.MjModel.from_xml_path(str(data_dir("assets") / "quadrotor.xml"))
    code = mujoco.MjModel.from_xml_string(airframe_xml())
    for name in ("body_mass", "body_inertia", "actuator_gear", "actuator_ctrlrange", "actuator_dynprm",
                 "geom_size", "geom_pos", "site_pos", "cam_fovy", "cam_pos"):
        np.testing.assert_allclose(getattr(shipped, name), getattr(code, name), rtol=1e-5, err_msg=name)
