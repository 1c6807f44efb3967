"""The quadrotor: physical parameters, its MjSpec body, and the rotor mixer.

An X-configuration quadrotor of 1.5 kg (the class of the AscTec/Firefly-type
research platforms used in the lineage's Gazebo experiments). Four site
actuators push along the body z axis; each also applies the rotor's reaction
torque ``+-k_m * thrust`` about that axis (gear ``0 0 1 0 0 +-k_m``), so yaw is
controlled by spinning pairs faster or slower, as on a real airframe. Rotor
speed-up is a first-order lag (``dyntype="filterexact"``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ipp_bench.sim.gl import mujoco

GRAVITY = 9.81  # [m/s^2]


@dataclass(frozen=True)
class QuadrotorParams:
    """Airframe parameters (SI units)."""

    mass: float = 1.5  # [kg]
    inertia: tuple[float, float, float] = (0.029, 0.029, 0.055)  # [kg m^2] about body x, y, z
    arm_length: float = 0.22  # [m] centre to rotor axis
    max_thrust: float = 10.0  # [N] per rotor (thrust/weight 2.7)
    yaw_moment_coeff: float = 0.016  # [m] reaction torque per newton of thrust
    motor_time_constant: float = 0.03  # [s] first-order rotor lag
    camera_fovy_deg: float = 60.0  # [deg] downward camera, square image
    camera_offset_z: float = -0.06  # [m] below the body origin, under every geom

    def __post_init__(self) -> None:
        for name in ("mass", "arm_length", "max_thrust", "yaw_moment_coeff", "motor_time_constant"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"QuadrotorParams.{name} must be > 0, got {getattr(self, name)}")
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
        act.dyntype = mujoco.mjtDyn.mjDYN_FILTEREXACT
        act.dynprm[0] = params.motor_time_constant
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
