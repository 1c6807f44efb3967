"""The rotor-speed model: thrust = k_f omega^2 with a first-order lag on omega, against its formulas."""

import math

import numpy as np
import pytest

pytest.importorskip("mujoco")

from ipp_bench.sim.flight import Flight  # noqa: E402
from ipp_bench.sim.quadrotor import QuadrotorParams, RotorSpeeds  # noqa: E402
from ipp_bench.sim.scene import WeedScene  # noqa: E402
from ipp_bench.sim.world import SimConfig  # noqa: E402

SPEED = QuadrotorParams(rotor_model="speed")


@pytest.mark.parametrize("kwargs, name", [({"thrust_coeff": 0.0}, "thrust_coeff"),
                                          ({"thrust_coeff": float("nan")}, "thrust_coeff"),
                                          ({"motor_time_constant": -0.03}, "motor_time_constant"),
                                          ({"rotor_model": "rpm"}, "rotor_model")])
def test_bad_rotor_parameters_are_refused_in_one_line(kwargs, name):
    with pytest.raises(ValueError, match=name) as err:
        QuadrotorParams(**kwargs)
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match="rotor_model"):
        SimConfig(rotor_model="omega")


def test_speed_lag_is_the_analytic_first_order_step_response():
    """omega(t) = omega_c + (omega_0 - omega_c) e^{-t / tau} at every step, thrust k_f omega^2."""
    dt, p = 0.005, SPEED
    rotors = RotorSpeeds(p, dt)
    w0 = math.sqrt(p.hover_thrust / p.thrust_coeff)
    np.testing.assert_allclose(rotors.omega, w0)
    cmd = np.array([1.0, 3.0, 6.0, 9.5])  # [N] down and up from hover (3.68 N)
    wc = np.sqrt(cmd / p.thrust_coeff)
    for k in range(200):
        applied = rotors.step(cmd)
        w = wc + (w0 - wc) * math.exp(-k * dt / p.motor_time_constant)  # the speed at the step's start
        np.testing.assert_allclose(applied, p.thrust_coeff * w ** 2, rtol=1e-12)
    # after 1 s (33 tau): the steady state is the commanded thrust, k_f omega_c^2
    np.testing.assert_allclose(rotors.thrust, cmd, rtol=1e-12)
    # thrust itself is not a first-order lag: from hover to 9.5 N it reaches 63 % of the step at
    # t = -tau ln((omega_63 - omega_c) / (omega_0 - omega_c)) = 1.147 tau, not at tau
    rotors.reset(p.hover_thrust)
    t63_thrust = p.hover_thrust + (1 - math.exp(-1)) * (9.5 - p.hover_thrust)
    wc = math.sqrt(9.5 / p.thrust_coeff)
    t63 = -p.motor_time_constant * math.log((math.sqrt(t63_thrust / p.thrust_coeff) - wc) / (w0 - wc))
    assert t63 == pytest.approx(1.147 * p.motor_time_constant, rel=1e-3)
    first = next(k for k in range(100) if rotors.step(np.full(4, 9.5))[0] >= t63_thrust)
    assert first == math.ceil(t63 / dt)
    # commands outside [0, max_thrust] are clipped, as the actuator's ctrlrange does for "thrust"
    for _ in range(400):
        rotors.step(np.array([-1.0, 20.0, 0.0, 5.0]))
    np.testing.assert_allclose(rotors.thrust, [0.0, p.max_thrust, 0.0, 5.0], atol=1e-9)


def test_speed_model_in_mujoco_applies_k_f_omega_squared_and_hovers():
    scene = WeedScene(15, 15, 2.5, SPEED)
    assert scene.model.na == 0  # no MuJoCo activation: the speed is the Python state
    flight = Flight(scene)
    home = np.array([18.0, 18.0, 8.0])
    flight.reset(home)
    errors, forces = [], []

    def check(f):
        errors.append(np.linalg.norm(f.position - home))
        forces.append(f.scene.data.actuator_force[f.scene.actuator_ids].copy())

    before = []
    orig = flight.rotors.step
    flight.rotors.step = lambda cmd: before.append(flight.rotors.thrust) or orig(cmd)
    flight.hover(3.0, at=home, on_step=check)
    np.testing.assert_allclose(forces, before, rtol=1e-12)  # the force MuJoCo applied is k_f omega^2
    assert max(errors) < 0.01
