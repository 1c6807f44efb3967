"""The quadrotor: physical parameters, its MjSpec body, and the rotor mixer.

An X-configuration quadrotor of 1.5 kg (the class of the AscTec/Firefly-type
research platforms used in the lineage's Gazebo experiments). Four site
actuators push along the body z axis; each also applies the rotor's reaction
torque ``+-k_m * thrust`` about that axis (gear ``0 0 1 0 0 +-k_m``), so yaw is
controlled by spinning pairs faster or slower, as on a real airframe.

Two rotor models (``QuadrotorParams.rotor_model``):

* ``"thrust"`` (v0, v1 default): a first-order lag on each rotor's thrust, MuJoCo's own activation
  (``dyntype="filterexact"``, ``gain = 1``).
* ``"speed"``: each rotor's speed omega is a state with a first-order lag towards the commanded
  speed, and thrust = k_f omega^2 (:class:`RotorSpeeds`, stepped with the physics by
  :class:`~ipp_bench.sim.flight.Flight`). MuJoCo's actuator gains are fixed, affine in the
  actuator's length and velocity, muscle or user callbacks, never quadratic in an activation, so
  the speed is integrated here (exactly, omega_{k+1} = omega_c + (omega_k - omega_c) e^{-dt / tau})
  and k_f omega_k^2 written to the ``ctrl`` of a gain-1 actuator without dynamics; as with
  ``filterexact``, the thrust during a step is the state at its start.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ipp_bench.sim.gl import mujoco

GRAVITY = 9.81  # [m/s^2]
ROTOR_MODELS = ("thrust", "speed")


@dataclass(frozen=True)
class QuadrotorParams:
    """Airframe parameters (SI units)."""

    mass: float = 1.5  # [kg]
    inertia: tuple[float, float, float] = (0.029, 0.029, 0.055)  # [kg m^2] about body x, y, z
    arm_length: float = 0.22  # [m] centre to rotor axis
    max_thrust: float = 10.0  # [N] per rotor (thrust/weight 2.7)
    yaw_moment_coeff: float = 0.016  # [m] reaction torque per newton of thrust
    motor_time_constant: float = 0.03  # [s] first-order rotor lag (of the thrust, or of the speed)
    rotor_model: str = "thrust"  # "thrust": lag on thrust (MuJoCo filterexact); "speed": omega state, k_f omega^2
    thrust_coeff: float = 8.5e-6  # [N s^2/rad^2] k_f of the "speed" model (10 N at 1085 rad/s, 10 400 rpm)
    camera_fovy_deg: float = 60.0  # [deg] downward camera, square image
    camera_offset_z: float = -0.06  # [m] below the body origin, under every geom

    def __post_init__(self) -> None:
        for name in ("mass", "arm_length", "max_thrust", "yaw_moment_coeff", "motor_time_constant", "thrust_coeff"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"QuadrotorParams.{name} must be a finite number > 0, got {v!r}")
        if self.rotor_model not in ROTOR_MODELS:
            raise ValueError(f"QuadrotorParams.rotor_model must be one of {ROTOR_MODELS}, got {self.rotor_model!r}")
        if len(self.inertia) != 3 or min(self.inertia) <= 0.0:
            raise ValueError(f"QuadrotorParams.inertia must be 3 positive values, got {self.inertia}")
        if not 0.0 < self.camera_fovy_deg < 180.0:
            raise ValueError(f"QuadrotorParams.camera_fovy_deg must be in (0, 180), got {self.camera_fovy_deg}")
        if 4 * self.max_thrust <= 1.2 * self.mass * GRAVITY:
            raise ValueError("QuadrotorParams.max_thrust: four rotors must lift 1.2 x the weight")

    @cached_property
    def rotor_positions(self) -> np.ndarray:
        """(4, 2) rotor x, y in the body frame: front-left, front-right, rear-right, rear-left."""
        d = self.arm_length / np.sqrt(2.0)
        return np.array([[d, d], [d, -d], [-d, -d], [-d, d]])

    @cached_property
    def spin(self) -> np.ndarray:
        """(4,) +1 where the rotor's reaction torque is +z (clockwise rotor), else -1."""
        return np.array([1.0, -1.0, 1.0, -1.0])

    @cached_property
    def allocation(self) -> np.ndarray:
        """(4, 4) A with [collective thrust, tau_x, tau_y, tau_z] = A @ rotor thrusts."""
        x, y = self.rotor_positions.T
        return np.stack([np.ones(4), y, -x, self.spin * self.yaw_moment_coeff])

    @cached_property
    def mixer(self) -> np.ndarray:
        """(4, 4) inverse of :attr:`allocation`."""
        return np.linalg.inv(self.allocation)

    @property
    def hover_thrust(self) -> float:
        """Per-rotor thrust that balances gravity [N]."""
        return self.mass * GRAVITY / 4.0


class RotorSpeeds:
    """The four rotor speeds of the ``"speed"`` model: omega' = (omega_c - omega) / tau, thrust k_f omega^2.

    ``step(commanded thrusts)`` returns the thrusts to apply during the coming physics step (from the
    speeds at its start) and advances the speeds by ``dt`` exactly towards omega_c = sqrt(T_c / k_f)
    (T_c clipped to [0, max_thrust]). No MuJoCo in here.
    """

    def __init__(self, params: QuadrotorParams, dt: float) -> None:
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"RotorSpeeds dt must be a finite number > 0 [s], got {dt}")
        self.k_f = float(params.thrust_coeff)
        self.max_thrust = float(params.max_thrust)
        self.decay = math.exp(-dt / params.motor_time_constant)
        self.omega = np.zeros(4)
        self.reset(params.hover_thrust)

    def reset(self, thrust: float) -> None:
        """Every rotor at the speed of ``thrust`` [N]."""
        self.omega[:] = math.sqrt(min(max(float(thrust), 0.0), self.max_thrust) / self.k_f)

    @property
    def thrust(self) -> np.ndarray:
        """(4,) thrusts k_f omega^2 [N] of the current speeds."""
        return self.k_f * self.omega * self.omega

    def step(self, thrust_cmd) -> np.ndarray:
        applied = self.thrust
        target = np.sqrt(np.clip(np.asarray(thrust_cmd, dtype=np.float64), 0.0, self.max_thrust) / self.k_f)
        self.omega = target + (self.omega - target) * self.decay
        return applied


def add_quadrotor(spec: mujoco.MjSpec, params: QuadrotorParams, pos=(0.0, 0.0, 1.0),
                  name: str = "quad") -> mujoco.MjsBody:
    """Adds the quadrotor (free body, rotor sites and actuators, downward camera) to ``spec``.

    Names: body ``quad``, camera ``quad/down``, sites and actuators ``quad/rotor{i}``.
    """
    body = spec.worldbody.add_body(name=name, pos=list(pos))
    body.add_freejoint(name=f"{name}/free")
    body.explicitinertial = True
    body.mass = params.mass
    body.inertia = list(params.inertia)
    body.ipos = [0.0, 0.0, 0.0]

    visual = dict(contype=0, conaffinity=0, density=0.0, group=1)
    body.add_geom(name=f"{name}/hull", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.09, 0.07, 0.035],
                  rgba=[0.15, 0.15, 0.18, 1.0], contype=1, conaffinity=1, density=0.0)
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.04, 0.04, 0.012], pos=[0.0, 0.0, 0.045],
                  rgba=[0.9, 0.45, 0.1, 1.0], **visual)
    colours = ([0.85, 0.1, 0.1, 1.0], [0.85, 0.1, 0.1, 1.0], [0.9, 0.9, 0.9, 1.0], [0.9, 0.9, 0.9, 1.0])
    for i, ((x, y), rgba) in enumerate(zip(params.rotor_positions, colours)):
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[0.012, 0.0, 0.0],
                      fromto=[0.0, 0.0, 0.0, x, y, 0.0], rgba=[0.2, 0.2, 0.22, 1.0], **visual)
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[0.11, 0.004, 0.0], pos=[x, y, 0.03],
                      rgba=[rgba[0], rgba[1], rgba[2], 0.55], **visual)
        body.add_site(name=f"{name}/rotor{i}", pos=[x, y, 0.03], size=[0.01, 0.0, 0.0])
        act = spec.add_actuator(name=f"{name}/rotor{i}", target=f"{name}/rotor{i}",
                                trntype=mujoco.mjtTrn.mjTRN_SITE)
        act.gear = [0.0, 0.0, 1.0, 0.0, 0.0, float(params.spin[i] * params.yaw_moment_coeff)]
        act.ctrllimited = True
        act.ctrlrange = [0.0, params.max_thrust]
        if params.rotor_model == "thrust":
            act.dyntype = mujoco.mjtDyn.mjDYN_FILTEREXACT
            act.dynprm[0] = params.motor_time_constant
        else:  # "speed": the thrust k_f omega^2 comes from RotorSpeeds
            act.dyntype = mujoco.mjtDyn.mjDYN_NONE
        act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        act.gainprm[0] = 1.0
        act.biastype = mujoco.mjtBias.mjBIAS_NONE
    body.add_camera(name=f"{name}/down", pos=[0.0, 0.0, params.camera_offset_z], fovy=params.camera_fovy_deg)
    return body


def quadrotor_spec(params: QuadrotorParams = QuadrotorParams(), timestep: float = 0.005,
                   air_density: float = 1.225) -> mujoco.MjSpec:
    """The airframe alone, hovering 1 m above the origin (what ``assets/quadrotor.xml`` holds)."""
    spec = mujoco.MjSpec()
    spec.modelname = "ipp_bench_quadrotor"
    spec.option.timestep = timestep
    spec.option.density = air_density
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    add_quadrotor(spec, params)
    return spec


def export_xml(path: str, params: QuadrotorParams = QuadrotorParams()) -> None:
    """Writes the airframe as MJCF (for MuJoCo's viewer: ``python -m mujoco.viewer --mjcf PATH``)."""
    spec = quadrotor_spec(params)
    spec.compile()
    header = ("<!-- The ipp-bench quadrotor, generated from ipp_bench/sim/quadrotor.py by\n"
              "     `python -m ipp_bench.sim.quadrotor assets/quadrotor.xml`; edit the code, not this file.\n"
              "     The simulation composes it into the weed-field scene with MjSpec at run time. -->\n")
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(header + spec.to_xml())


if __name__ == "__main__":
    import sys

    export_xml(sys.argv[1] if len(sys.argv) > 1 else "assets/quadrotor.xml")
