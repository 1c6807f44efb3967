"""The scene's airframe is replaceable: another quadrotor MJCF, attached with PyMJCF, flies a mission."""

import math

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("dm_control")

import gymnasium as gym  # noqa: E402
from dm_control import mjcf  # noqa: E402

import ipp_bench.envs  # noqa: E402,F401
from ipp_bench.sim.quadrotor import GRAVITY  # noqa: E402
from ipp_bench.sim.scene import WeedScene  # noqa: E402

# A different airframe, written by hand: 2.2 kg, 0.30 m arms, 14 N rotors, a sphere hull and a
# static payload body (fused into the free body by the scene's compiler settings).
HEAVY_QUAD = """
<mujoco model="heavy_quad">
  <worldbody>
    <body name="frame">
      <freejoint name="root"/>
      <inertial pos="0 0 0" mass="2.2" diaginertia="0.05 0.05 0.09"/>
      <geom type="sphere" size="0.12" density="0" rgba="0.2 0.4 0.8 1"/>
      <body name="payload" pos="0 0 -0.1">
        <geom type="box" size="0.05 0.05 0.02" density="0" contype="0" conaffinity="0"/>
      </body>
      <site name="rotor0" pos="0.212132 0.212132 0.04"/>
      <site name="rotor1" pos="0.212132 -0.212132 0.04"/>
      <site name="rotor2" pos="-0.212132 -0.212132 0.04"/>
      <site name="rotor3" pos="-0.212132 0.212132 0.04"/>
      <camera name="down" pos="0 0 -0.15" fovy="60"/>
    </body>
  </worldbody>
  <actuator>
    <general name="rotor0" site="rotor0" ctrllimited="true" ctrlrange="0 14" gear="0 0 1 0 0 0.02"
             dyntype="filterexact" dynprm="0.04"/>
    <general name="rotor1" site="rotor1" ctrllimited="true" ctrlrange="0 14" gear="0 0 1 0 0 -0.02"
             dyntype="filterexact" dynprm="0.04"/>
    <general name="rotor2" site="rotor2" ctrllimited="true" ctrlrange="0 14" gear="0 0 1 0 0 0.02"
             dyntype="filterexact" dynprm="0.04"/>
    <general name="rotor3" site="rotor3" ctrllimited="true" ctrlrange="0 14" gear="0 0 1 0 0 -0.02"
             dyntype="filterexact" dynprm="0.04"/>
  </actuator>
</mujoco>
"""


def test_parameters_are_read_from_the_attached_mjcf():
    scene = WeedScene(15, 15, 2.5, airframe=mjcf.from_xml_string(HEAVY_QUAD))
    q = scene.quad
    assert q.mass == pytest.approx(2.2) and q.arm_length == pytest.approx(0.3, abs=1e-6)
    assert q.inertia == pytest.approx((0.05, 0.05, 0.09)) and q.max_thrust == 14.0
    assert q.yaw_moment_coeff == pytest.approx(0.02) and q.motor_time_constant == pytest.approx(0.04)
    assert q.camera_offset_z == pytest.approx(-0.15)
    assert q.hover_thrust == pytest.approx(2.2 * GRAVITY / 4)
    assert scene.physics.named.model.body_mass["quad/frame"] == pytest.approx(2.2)


def test_another_airframe_flies_a_mission_and_hovers_on_its_own_weight():
    env = gym.make("ipp_bench/MuJoCoWeed15-v1", airframe=mjcf.from_xml_string(HEAVY_QUAD), budget_s=30.0).unwrapped
    obs, _ = env.reset(seed=0)
    legs = 0
    while True:
        mask = obs["action_mask"]
        if not mask.any():
            break
        obs, _, terminated, _, _ = env.step(int(np.flatnonzero(mask)[0]))
        legs += 1
        if terminated:
            break
    mission = env.mission
    assert legs >= 3 and mission.time_s == pytest.approx(mission.budget_s, abs=3.0)
    assert mission.n_measurements > 0
    # the drone followed the waypoints (estimator and wind errors of v1: within a metre)
    assert np.linalg.norm(env.world.flight.position - mission.position) < 1.5
    # hovering in calm air, the rotors carry this airframe's weight: sum of thrusts = m g
    flight = env.world.flight
    flight.disturbances = None
    env.world.scene.physics.model.opt.wind[:] = 0.0
    env.world.scene.data.xfrc_applied[:] = 0.0
    flight.hover(6.0)
    thrust = env.world.scene.data.actuator_force[env.world.scene.actuator_ids].sum()
    assert thrust == pytest.approx(2.2 * GRAVITY, rel=2e-3)
    assert math.isfinite(float(env.world.scene.data.qvel.sum()))
    env.close()


def test_an_airframe_without_the_names_is_refused_in_one_line():
    bad = HEAVY_QUAD.replace('name="down"', 'name="nadir"')
    with pytest.raises(ValueError, match="no camera named 'down'"):
        WeedScene(15, 15, 2.5, airframe=mjcf.from_xml_string(bad))
    wide = HEAVY_QUAD.replace('fovy="60"', 'fovy="75"')
    with pytest.raises(ValueError, match="fovy 75.0 deg"):
        gym.make("ipp_bench/MuJoCoWeed15-v1", airframe=mjcf.from_xml_string(wide))
