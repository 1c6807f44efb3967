"""The MuJoCo scene: textured weed field, lighting, and an attached quadrotor airframe.

Composed with dm_control's PyMJCF and compiled into a :class:`DeploymentPhysics` (a
``dm_control.mujoco.Physics``): the weed field, the sun and the sky are this module's; the
airframe is a separate MJCF model (:func:`~ipp_bench.sim.quadrotor.airframe_mjcf` by default)
attached under the prefix ``quad/`` with a free joint, so a user replaces it with their own MJCF
(``WeedScene(..., airframe=mjcf.from_path("my_quad.xml"))``; the names it must provide are
:data:`~ipp_bench.sim.quadrotor.AIRFRAME_NAMES`). A team scene (``drones=n``) attaches n copies,
under ``quad/``, ``quad1/``, ``quad2/``, ...; they do not collide with each other (the planners keep
them on different roadmap nodes, but two legs may cross: collision avoidance is not modelled).
The controller's parameters (mass, inertia, arm length, thrust limits, rotor lag, camera) are read
back from the compiled model (:func:`~ipp_bench.sim.quadrotor.airframe_params`), never assumed.

The ground texture is a per-seed numpy array written straight into the compiled model's
``tex_data`` (no temporary PNG, no base64 in XML; the MJCF declares a blank texture of the right
size); the map size comes from the task's grid at run time. The model is compiled once per
grid; a new episode only rewrites ``tex_data`` and the renderers re-upload that texture.

Rendering is set for fast, stable colours in software rendering: no shadows
(``<quality shadowsize="0"/>``), no multisampling (``offsamples=0``), no
headlight, one straight-down directional light whose ambient + diffuse sum to
1, and a matte ground (no specular, no reflectance), so a texel's rendered
colour is its texture colour from every camera pose.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from ipp_bench.sim.gl import mujoco  # chooses MUJOCO_GL before dm_control imports mujoco

# isort: split
from dm_control import mjcf

from ipp_bench.sim.quadrotor import QuadrotorParams, airframe_mjcf, airframe_params, free_joint


@dataclass(frozen=True)
class SceneConfig:
    """Simulation and rendering settings of the deployment scene."""

    timestep: float = 0.005  # [s] fixed physics step (200 Hz; the controller runs every step)
    air_density: float = 1.225  # [kg/m^3] MuJoCo inertia-box drag on the airframe
    texels_per_cell: int = 64  # ground texture resolution (64 -> 3.9 cm texels on 2.5 m cells)
    max_render_size: tuple[int, int] = (1280, 1280)  # [px] (width, height) of the off-screen buffer
    outer_ground: float = 120.0  # [m] half-size of the untextured soil around the map

    def __post_init__(self) -> None:
        if not 0.0 < self.timestep <= 0.02:
            raise ValueError(f"SceneConfig.timestep must be in (0, 0.02] s, got {self.timestep}")
        if self.air_density < 0.0:
            raise ValueError(f"SceneConfig.air_density must be >= 0, got {self.air_density}")
        if not 4 <= self.texels_per_cell <= 256:
            raise ValueError(f"SceneConfig.texels_per_cell must be in [4, 256], got {self.texels_per_cell}")
        if min(self.max_render_size) < 16:
            raise ValueError(f"SceneConfig.max_render_size must be >= 16 px, got {self.max_render_size}")


SOIL_RGBA = (0.42, 0.33, 0.24, 1.0)
AIRFRAME_PREFIX = "quad/"
#: the most quadrotors one scene holds
MAX_DRONES = 16


def drone_prefix(drone: int) -> str:
    """Name prefix of drone ``drone``'s airframe: ``quad/`` for the first, ``quad1/``, ``quad2/``, ... after it."""
    return AIRFRAME_PREFIX if drone == 0 else f"{AIRFRAME_PREFIX.rstrip('/')}{drone}/"


@dataclass(frozen=True)
class DroneIds:
    """Where one drone lives in the compiled model."""

    joint_name: str  # its free joint
    body_id: int
    camera_id: int  # its downward camera
    qpos_adr: int
    qvel_adr: int
    actuator_ids: np.ndarray  # (4,) rotor actuators


class DeploymentPhysics(mjcf.Physics):
    """The deployment's ``dm_control.mujoco.Physics`` (model, data, named access, ``render``).

    One time step of the dm_control environment (:func:`ipp_bench.sim.load`) is a planner
    decision: the task's ``before_step`` flies the chosen leg through the mission, which steps
    this physics under the cascaded controller every ``timestep`` (:class:`~ipp_bench.sim.flight.Flight`)
    and reads the camera on the way. The environment's own sub-stepping (``physics.step`` after
    ``before_step``) would add a physics step without the controller, so :meth:`step` advances
    nothing; fly the drone through ``Flight`` (``WeedScene.flight``) instead.
    """

    def step(self, nstep: int = 1) -> None:  # noqa: D401 - see the class docstring
        """No physics of its own: the leg was flown in the task's ``before_step``."""
        del nstep


def build_mjcf(rows: int, cols: int, resolution: float, airframe: mjcf.RootElement | None = None,
               cfg: SceneConfig = SceneConfig(), drones: int = 1) -> mjcf.RootElement:
    """Composes the scene with ``airframe`` attached (default: the shipped quadrotor), ``drones`` times.

    Returns:
        The scene's root. The ground texture starts blank (see :meth:`WeedScene.set_ground`).
        ``airframe`` is attached as it is (its model renamed ``quad``), its free body placed at
        (centre of the map, 10 m); further drones are copies of it (``quad1``, ...), 2 m apart along
        x, with no contacts between any two of them.
    """
    if isinstance(drones, bool) or not isinstance(drones, int) or not 1 <= drones <= MAX_DRONES:
        raise ValueError(f"drones = {drones!r} is invalid: expected an integer in [1, {MAX_DRONES}]")
    width_m, height_m = cols * resolution, rows * resolution
    root = mjcf.RootElement(model="ipp_bench_weed_field")
    root.option.timestep = cfg.timestep
    root.option.density = cfg.air_density
    root.option.integrator = "implicitfast"
    # the attachment frame (a static body) fuses into the world, and static parts of the airframe
    # into its free body: one rigid body carries the airframe's mass and inertia
    root.compiler.fusestatic = True
    vis = root.visual
    vis.quality.shadowsize = 0
    vis.quality.offsamples = 0
    gl_global = getattr(vis, "global")
    gl_global.offwidth, gl_global.offheight = cfg.max_render_size
    vis.headlight.active = 0
    vis.map.znear = 0.005  # x extent: 0.3 m near plane for a 60 m scene
    vis.map.zfar = 10.0
    root.statistic.extent = max(width_m, height_m) * 1.6
    root.statistic.center = [width_m / 2, height_m / 2, 5.0]

    root.asset.add("texture", name="sky", type="skybox", builtin="gradient", rgb1=[0.55, 0.7, 0.9],
                   rgb2=[0.95, 0.97, 1.0], width=64, height=64)
    p = cfg.texels_per_cell
    # blank: the episode's texture is written into the compiled model's tex_data (WeedScene.set_ground)
    root.asset.add("texture", name="weed_field", type="2d", builtin="flat", rgb1=[0.0, 0.0, 0.0],
                   width=cols * p, height=rows * p)
    root.asset.add("material", name="weed_field", texture="weed_field", texrepeat=[1.0, 1.0], texuniform=False,
                   specular=0.0, shininess=0.0, reflectance=0.0)

    world = root.worldbody
    world.add("light", name="sun", type="directional", pos=[width_m / 2, height_m / 2, 50.0],
              dir=[0.0, 0.0, -1.0], castshadow=False, ambient=[0.4, 0.4, 0.4], diffuse=[0.6, 0.6, 0.6],
              specular=[0.0, 0.0, 0.0])
    # Thin boxes, not planes: MuJoCo draws a plane as a fine grid, which costs ~10x more
    # per frame in software rendering; a box's top face carries the whole 2D texture.
    world.add("geom", name="field", type="box", material="weed_field",
              size=[width_m / 2, height_m / 2, 0.05], pos=[width_m / 2, height_m / 2, -0.05])
    world.add("geom", name="outer_soil", type="box", rgba=list(SOIL_RGBA),
              size=[cfg.outer_ground, cfg.outer_ground, 0.05],
              pos=[width_m / 2, height_m / 2, -0.13], contype=0, conaffinity=0)
    airframe = airframe if airframe is not None else airframe_mjcf()
    frames = [airframe] + [copy.deepcopy(airframe) for _ in range(1, drones)]
    free_bodies = []
    for i, af in enumerate(frames):
        af.model = drone_prefix(i).rstrip("/")
        frame = root.attach(af)
        frame.pos = [width_m / 2 + 2.0 * i, height_m / 2, 10.0]
        free_bodies += [b for b in af.find_all("body") if b.freejoint is not None]
    for i, a in enumerate(free_bodies):
        for b in free_bodies[i + 1:]:
            root.contact.add("exclude", body1=a, body2=b)
    return root


class WeedScene:
    """Compiled scene: the dm_control physics, ids looked up once, and the ground texture.

    Args:
        rows, cols, resolution: the task's grid (cells and metres per cell).
        quad: airframe parameters of the shipped airframe (ignored when ``airframe`` is given,
            except ``thrust_coeff``, which no MJCF holds).
        cfg: simulation and rendering settings.
        airframe: a PyMJCF model to fly instead of the shipped one (see the module docstring).

    ``quad`` is then what the compiled model says (:func:`~ipp_bench.sim.quadrotor.airframe_params`).
    ``model`` and ``data`` are the raw ``MjModel`` / ``MjData`` of ``physics`` (the control loop
    steps them directly; named reads go through ``physics.named``). ``drones`` > 1 builds a team
    scene: ``drones_ids[i]`` holds drone i's ids; the attributes ``joint_name``, ``body_id``,
    ``camera_id``, ``qpos_adr``, ``qvel_adr`` and ``actuator_ids`` are the first drone's.
    """

    def __init__(self, rows: int, cols: int, resolution: float,
                 quad: QuadrotorParams = QuadrotorParams(), cfg: SceneConfig = SceneConfig(),  # noqa: B008 (frozen)
                 airframe: mjcf.RootElement | None = None, drones: int = 1) -> None:
        self.rows, self.cols, self.resolution = int(rows), int(cols), float(resolution)
        self.cfg = cfg
        self.mjcf_model = build_mjcf(self.rows, self.cols, self.resolution,
                                     airframe if airframe is not None else airframe_mjcf(quad), cfg, drones)
        self.physics = DeploymentPhysics.from_mjcf_model(self.mjcf_model)
        self.model = self.physics.model.ptr
        self.data = self.physics.data.ptr
        m = self.model
        self.quad = airframe_params(m, AIRFRAME_PREFIX, quad.thrust_coeff)
        self.light_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_LIGHT, "sun")
        self.texture_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TEXTURE, "weed_field")
        self.drones_ids = [self._drone_ids(i) for i in range(drones)]
        first = self.drones_ids[0]
        self.joint_name, self.body_id, self.camera_id = first.joint_name, first.body_id, first.camera_id
        self.qpos_adr, self.qvel_adr, self.actuator_ids = first.qpos_adr, first.qvel_adr, first.actuator_ids
        adr, h, w = m.tex_adr[self.texture_id], m.tex_height[self.texture_id], m.tex_width[self.texture_id]
        if int(m.tex_nchannel[self.texture_id]) != 3:
            raise RuntimeError(f"the weed_field texture compiled with {m.tex_nchannel[self.texture_id]} "
                               "channels, not 3")
        self._tex_view = m.tex_data[adr: adr + h * w * 3].reshape(h, w, 3)
        self.texture_version = 0  # bumped on every set_ground; renderers re-upload when it changes

    def _drone_ids(self, drone: int) -> DroneIds:
        m, prefix = self.model, drone_prefix(drone)
        named = self.physics.named.model
        joint = free_joint(m, prefix)
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, joint)
        camera = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, prefix + "down")
        return DroneIds(name, int(m.jnt_bodyid[joint]), camera,
                        int(named.jnt_qposadr[name]), int(named.jnt_dofadr[name]),
                        np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, f"{prefix}rotor{i}")
                                  for i in range(4)]))

    @property
    def drones(self) -> int:
        """Number of quadrotors in the scene."""
        return len(self.drones_ids)

    @property
    def texture_shape(self) -> tuple[int, int]:
        return self._tex_view.shape[:2]

    def set_ground(self, rgb: np.ndarray) -> None:
        """Replaces the ground texture; ``rgb`` is (rows*p, cols*p, 3) uint8 in grid-row order."""
        rgb = np.asarray(rgb)
        if rgb.shape != self._tex_view.shape or rgb.dtype != np.uint8:
            raise ValueError(f"ground texture must be uint8 of shape {self._tex_view.shape}, "
                             f"got {rgb.dtype} {rgb.shape}")
        self._tex_view[...] = rgb[::-1]  # OpenGL: texture row 0 is the far (max y) edge
        self.texture_version += 1

    def reset(self, xyz, yaw: float = 0.0) -> None:
        """Puts the (first) drone at rest at ``xyz`` [m] with rotors at hover thrust."""
        self.reset_team([xyz], [yaw])

    def reset_team(self, xyzs, yaws=None) -> None:
        """Puts drones 0, 1, ... at rest at ``xyzs`` [m] (one each, in order; yaws [rad] default 0) with
        rotors at hover thrust; drones not named stay where the model puts them."""
        mujoco.mj_resetData(self.model, self.data)
        yaws = [0.0] * len(xyzs) if yaws is None else yaws
        for ids, xyz, yaw in zip(self.drones_ids, xyzs, yaws):
            q = self.data.qpos[ids.qpos_adr: ids.qpos_adr + 7]
            q[:3] = xyz
            q[3:] = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
        self.data.act[:] = self.quad.hover_thrust
        for ids in self.drones_ids:
            self.data.ctrl[ids.actuator_ids] = self.quad.hover_thrust
        mujoco.mj_forward(self.model, self.data)

    @property
    def position(self) -> np.ndarray:
        """True position [m] (named read of the free joint)."""
        return np.array(self.physics.named.data.qpos[self.joint_name][:3])

    @property
    def velocity(self) -> np.ndarray:
        """World-frame linear velocity [m/s] (named read of the free joint)."""
        return np.array(self.physics.named.data.qvel[self.joint_name][:3])
