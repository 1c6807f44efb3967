"""The quadrotor: physical parameters, its PyMJCF airframe, and the rotor mixer.

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
from typing import TYPE_CHECKING

import numpy as np

from ipp_bench.sim.gl import mujoco

if TYPE_CHECKING:  # imported where it is used (dm_control loads MuJoCo's GL backend)
    from dm_control import mjcf

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


#: what an airframe MJCF provides (its model is attached to the scene under the prefix ``quad/``)
AIRFRAME_NAMES = ("one body with a free joint (its centre of mass at its origin)",
                  "rotor0..rotor3: sites and actuators (front-left, front-right, rear-right, rear-left)",
                  "down: the downward camera")


def airframe_mjcf(params: QuadrotorParams = QuadrotorParams()) -> mjcf.RootElement:  # noqa: B008 (frozen)
    """The shipped airframe as a PyMJCF model (what ``assets/quadrotor.xml`` holds).

    The model is what :class:`~ipp_bench.sim.scene.WeedScene` attaches (``airframe=``): one free
    body (``<freejoint/>``; static sub-bodies are fused into it) carrying the mass and inertia with
    its centre of mass at the body origin, four sites
    ``rotor0..rotor3`` with site actuators pushing along body z (gear ``0 0 1 0 0 +-k_m``,
    ``ctrlrange`` 0..max thrust; ``dyntype="filterexact"`` for the thrust lag, none for the
    ``"speed"`` rotor model) and a camera ``down``. Any MJCF with those names can replace it;
    :func:`airframe_params` reads the controller's parameters back from the compiled model.
    """
    from dm_control import mjcf

    root = mjcf.RootElement(model="quad")
    body = root.worldbody.add("body", name="airframe")
    body.add("freejoint", name="free")
    body.add("inertial", pos=[0.0, 0.0, 0.0], mass=params.mass, diaginertia=list(params.inertia))
    visual = dict(contype=0, conaffinity=0, density=0.0, group=1)
    body.add("geom", name="hull", type="box", size=[0.09, 0.07, 0.035], rgba=[0.15, 0.15, 0.18, 1.0],
             contype=1, conaffinity=1, density=0.0)
    body.add("geom", type="box", size=[0.04, 0.04, 0.012], pos=[0.0, 0.0, 0.045], rgba=[0.9, 0.45, 0.1, 1.0],
             **visual)
    colours = ([0.85, 0.1, 0.1, 1.0], [0.85, 0.1, 0.1, 1.0], [0.9, 0.9, 0.9, 1.0], [0.9, 0.9, 0.9, 1.0])
    for i, ((x, y), rgba) in enumerate(zip(params.rotor_positions, colours)):
        body.add("geom", type="capsule", size=[0.012], fromto=[0.0, 0.0, 0.0, x, y, 0.0],
                 rgba=[0.2, 0.2, 0.22, 1.0], **visual)
        body.add("geom", type="cylinder", size=[0.11, 0.004], pos=[x, y, 0.03],
                 rgba=[rgba[0], rgba[1], rgba[2], 0.55], **visual)
        site = body.add("site", name=f"rotor{i}", pos=[x, y, 0.03], size=[0.01])
        dyn = (dict(dyntype="filterexact", dynprm=[params.motor_time_constant]) if params.rotor_model == "thrust"
               else dict(dyntype="none"))
        root.actuator.add("general", name=f"rotor{i}", site=site, ctrllimited=True,
                          ctrlrange=[0.0, params.max_thrust],
                          gear=[0.0, 0.0, 1.0, 0.0, 0.0, float(params.spin[i] * params.yaw_moment_coeff)],
                          gaintype="fixed", gainprm=[1.0], biastype="none", **dyn)
    body.add("camera", name="down", pos=[0.0, 0.0, params.camera_offset_z], fovy=params.camera_fovy_deg)
    return root


def airframe_params(model, prefix: str = "quad/", thrust_coeff: float = QuadrotorParams.thrust_coeff
                    ) -> QuadrotorParams:
    """The controller's :class:`QuadrotorParams`, read from a compiled model holding an airframe.

    Args:
        model: ``mujoco.MjModel`` (e.g. ``physics.model.ptr``) of a scene with an attached airframe.
        prefix: the airframe's name prefix.
        thrust_coeff: k_f of the ``"speed"`` rotor model (not an MJCF quantity).

    Raises:
        ValueError: a name of :data:`AIRFRAME_NAMES` is missing, or the airframe is not an X
            quadrotor with its centre of mass at its frame (naming what is wrong).
    """
    def need(kind, name):
        i = mujoco.mj_name2id(model, kind, prefix + name)
        if i < 0:
            raise ValueError(f"airframe: no {kind.name[6:].lower()} named {name!r} (an airframe provides "
                             f"{'; '.join(AIRFRAME_NAMES)})")
        return i

    body = int(model.jnt_bodyid[free_joint(model, prefix)])
    mass = float(model.body_subtreemass[body])
    if mass != float(model.body_mass[body]):
        raise ValueError("airframe: bodies below the free body must be static (no joints), so that they fuse into it")
    if np.abs(model.body_ipos[body]).max() > 1e-9:
        raise ValueError("airframe: the centre of mass must be at the airframe's origin (body pos and inertial pos 0)")
    sites = [need(mujoco.mjtObj.mjOBJ_SITE, f"rotor{i}") for i in range(4)]
    acts = [need(mujoco.mjtObj.mjOBJ_ACTUATOR, f"rotor{i}") for i in range(4)]
    xy = np.array([model.site_pos[s][:2] for s in sites])
    arm = float(np.hypot(*xy[0]))
    expected = QuadrotorParams(arm_length=max(arm, 1e-9)).rotor_positions
    if not np.allclose(xy, expected, atol=1e-6):
        raise ValueError(f"airframe: rotor sites at {xy.round(4).tolist()} are not an X of arm {arm:.4f} m "
                         "(front-left, front-right, rear-right, rear-left)")
    gear = np.array([model.actuator_gear[a] for a in acts])
    k_m = float(abs(gear[0, 5]))
    if not (np.allclose(gear[:, :3], [0.0, 0.0, 1.0]) and np.allclose(gear[:, 5], QuadrotorParams().spin * k_m)):
        raise ValueError(f"airframe: rotor actuators need gear 0 0 1 0 0 +-k_m with spins {QuadrotorParams().spin}, "
                         f"got {gear.round(4).tolist()}")
    filt = [int(model.actuator_dyntype[a]) == int(mujoco.mjtDyn.mjDYN_FILTEREXACT) for a in acts]
    if len(set(filt)) != 1:
        raise ValueError("airframe: the four rotor actuators must share one dyntype")
    cam = need(mujoco.mjtObj.mjOBJ_CAMERA, "down")
    tau = float(model.actuator_dynprm[acts[0]][0]) if filt[0] else QuadrotorParams.motor_time_constant
    return QuadrotorParams(
        mass=mass, inertia=tuple(float(v) for v in model.body_inertia[body]), arm_length=arm,
        max_thrust=float(model.actuator_ctrlrange[acts[0]][1]), yaw_moment_coeff=k_m,
        motor_time_constant=tau,
        rotor_model="thrust" if filt[0] else "speed", thrust_coeff=thrust_coeff,
        camera_fovy_deg=float(model.cam_fovy[cam]), camera_offset_z=float(model.cam_pos[cam][2]))


def free_joint(model, prefix: str = "quad/") -> int:
    """Id of the airframe's free joint (the one free joint of a body named ``prefix...``)."""
    free = [j for j in range(model.njnt) if int(model.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_FREE)
            and (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.jnt_bodyid[j])) or "").startswith(prefix)]
    if len(free) != 1:
        raise ValueError(f"airframe: needs exactly one body with a free joint, found {len(free)} ("
                         f"an airframe provides {'; '.join(AIRFRAME_NAMES)})")
    return free[0]


def airframe_xml(params: QuadrotorParams = QuadrotorParams()) -> str:
    """The airframe alone as an MJCF document (``assets/quadrotor.xml``)."""
    header = ("<!-- The ipp-bench quadrotor, generated from ipp_bench/sim/quadrotor.py by\n"
              "     `python -m ipp_bench.sim.quadrotor assets/quadrotor.xml`; edit the code, not this file.\n"
              "     The scene attaches it with PyMJCF (ipp_bench/sim/scene.py, airframe=...); an MJCF\n"
              "     with the same names (sites and actuators rotor0..rotor3, camera down) can replace it. -->\n")
    return header + airframe_mjcf(params).to_xml_string(precision=6)


def export_xml(path: str, params: QuadrotorParams = QuadrotorParams()) -> None:
    """Writes the airframe as MJCF (look at it: ``python -m mujoco.viewer --mjcf PATH``)."""
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(airframe_xml(params))


if __name__ == "__main__":
    import sys

    export_xml(sys.argv[1] if len(sys.argv) > 1 else "assets/quadrotor.xml")
