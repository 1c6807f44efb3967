"""The MuJoCo scene: textured weed field, lighting, and the quadrotor.

Composed with MuJoCo's own ``MjSpec`` rather than an MJCF string or dm_control's
PyMJCF: the ground texture is a per-seed numpy array that goes straight into
``MjsTexture.data`` (no temporary PNG, no base64 in XML), the map size comes
from the task's grid at run time, the airframe from a frozen dataclass, and it
needs nothing beyond the ``mujoco`` package (dm_control would add a dependency
and its own GL handling). The model is compiled once per grid; a new episode
only rewrites ``model.tex_data`` and the renderers re-upload that texture.

Rendering is set for fast, stable colours in software rendering: no shadows
(``<quality shadowsize="0"/>``), no multisampling (``offsamples=0``), no
headlight, one straight-down directional light whose ambient + diffuse sum to
1, and a matte ground (no specular, no reflectance), so a texel's rendered
colour is its texture colour from every camera pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ipp_bench.sim.gl import mujoco

from ipp_bench.sim.quadrotor import QuadrotorParams, add_quadrotor


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


def build_spec(rows: int, cols: int, resolution: float, quad: QuadrotorParams = QuadrotorParams(),
               cfg: SceneConfig = SceneConfig()) -> mujoco.MjSpec:
    """Composes the scene; the ground texture starts blank (see :meth:`WeedScene.set_ground`)."""
    spec = mujoco.MjSpec()
    spec.modelname = "ipp_bench_weed_field"
    spec.option.timestep = cfg.timestep
    spec.option.density = cfg.air_density
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST

    width_m, height_m = cols * resolution, rows * resolution
    vis = spec.visual
    vis.quality.shadowsize = 0
    vis.quality.offsamples = 0
    vis.global_.offwidth, vis.global_.offheight = cfg.max_render_size
    vis.headlight.active = 0
    vis.map.znear = 0.005  # x extent: 0.3 m near plane for a 60 m scene
    vis.map.zfar = 10.0
    spec.stat.extent = max(width_m, height_m) * 1.6
    spec.stat.center = [width_m / 2, height_m / 2, 5.0]

    sky = spec.add_texture(name="sky", type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
                           builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
                           rgb1=[0.55, 0.7, 0.9], rgb2=[0.95, 0.97, 1.0], width=64, height=64)
    del sky
    p = cfg.texels_per_cell
    tex = spec.add_texture(name="weed_field", type=mujoco.mjtTexture.mjTEXTURE_2D,
                           width=cols * p, height=rows * p, nchannel=3)
    tex.data = bytes(rows * p * cols * p * 3)
    ground = spec.add_material(name="weed_field", texrepeat=[1.0, 1.0], texuniform=False,
                               specular=0.0, shininess=0.0, reflectance=0.0)
    ground.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "weed_field"

    world = spec.worldbody
    world.add_light(name="sun", type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
                    pos=[width_m / 2, height_m / 2, 50.0], dir=[0.0, 0.0, -1.0], castshadow=False,
                    ambient=[0.4, 0.4, 0.4], diffuse=[0.6, 0.6, 0.6], specular=[0.0, 0.0, 0.0])
    # Thin boxes, not planes: MuJoCo draws a plane as a fine grid, which costs ~10x more
    # per frame in software rendering; a box's top face carries the whole 2D texture.
    world.add_geom(name="field", type=mujoco.mjtGeom.mjGEOM_BOX, material="weed_field",
                   size=[width_m / 2, height_m / 2, 0.05], pos=[width_m / 2, height_m / 2, -0.05])
    world.add_geom(name="outer_soil", type=mujoco.mjtGeom.mjGEOM_BOX, rgba=list(SOIL_RGBA),
                   size=[cfg.outer_ground, cfg.outer_ground, 0.05],
                   pos=[width_m / 2, height_m / 2, -0.13], contype=0, conaffinity=0)
    add_quadrotor(spec, quad, pos=(width_m / 2, height_m / 2, 10.0))
    return spec


class WeedScene:
    """Compiled scene: model, data, ids looked up once, and the ground texture.

    Args:
        rows, cols, resolution: the task's grid (cells and metres per cell).
        quad: airframe parameters.
        cfg: simulation and rendering settings.
    """

    def __init__(self, rows: int, cols: int, resolution: float,
                 quad: QuadrotorParams = QuadrotorParams(), cfg: SceneConfig = SceneConfig()) -> None:
        self.rows, self.cols, self.resolution = int(rows), int(cols), float(resolution)
        self.quad, self.cfg = quad, cfg
        self.spec = build_spec(self.rows, self.cols, self.resolution, quad, cfg)
        self.model = self.spec.compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.body_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "quad")
        self.camera_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, "quad/down")
        self.light_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_LIGHT, "sun")
        self.texture_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TEXTURE, "weed_field")
        joint = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "quad/free")
        self.qpos_adr = int(m.jnt_qposadr[joint])
        self.qvel_adr = int(m.jnt_dofadr[joint])
        self.actuator_ids = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, f"quad/rotor{i}")
                                      for i in range(4)])
        adr, h, w = m.tex_adr[self.texture_id], m.tex_height[self.texture_id], m.tex_width[self.texture_id]
        self._tex_view = m.tex_data[adr: adr + h * w * 3].reshape(h, w, 3)
        self.texture_version = 0  # bumped on every set_ground; renderers re-upload when it changes

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
        """Puts the drone at rest at ``xyz`` [m] with rotors at hover thrust."""
        mujoco.mj_resetData(self.model, self.data)
        q = self.data.qpos[self.qpos_adr: self.qpos_adr + 7]
        q[:3] = xyz
        q[3:] = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
        self.data.act[:] = self.quad.hover_thrust
        self.data.ctrl[self.actuator_ids] = self.quad.hover_thrust
        mujoco.mj_forward(self.model, self.data)

    @property
    def position(self) -> np.ndarray:
        return self.data.qpos[self.qpos_adr: self.qpos_adr + 3].copy()

    @property
    def velocity(self) -> np.ndarray:
        """World-frame linear velocity [m/s]."""
        return self.data.qvel[self.qvel_adr: self.qvel_adr + 3].copy()
