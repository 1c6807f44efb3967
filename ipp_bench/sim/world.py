"""Everything simulated for one grid: scene, flight, camera and its image processing.

:class:`WeedWorld` is built once per environment (the model is compiled once);
:meth:`WeedWorld.begin_episode` paints a new ground texture and draws the episode's conditions
(sun, exposure, white balance, wind, state-estimation errors) from the episode's seed, and
:meth:`WeedWorld.read_camera` turns the current frame into a sensor read-out: the nominal footprint
of :class:`~ipp_bench.core.sensor.Sensor` at the drone's *estimated* position, restricted to the cells the
camera really saw, with z the pipeline's estimate of each measurement (cell or binned block) and
no synthetic noise on top (``SimConfig.measurement = "camera"``, v1). The v0 task keeps its
behaviour: ideal camera, the sensor model's noise added (``"camera+noise"``), stop-and-go flight.
``"truth"`` replaces the camera's values by the ground truth (the ablation that shows the camera
matters).

One module on purpose (over 400 lines): the scene, the flight and the camera pipeline of one grid
share the compiled model and the episode's conditions.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ipp_bench.core.config import GridConfig, SensorConfig
from ipp_bench.core.sensor import Observation, Sensor, restrict
from ipp_bench.sim import vision_v0
from ipp_bench.sim.camera import CameraModel, EpisodeConditions, form_image, motion_blur_px
from ipp_bench.sim.controller import ControllerGains
from ipp_bench.sim.disturbance import DisturbanceConfig
from ipp_bench.sim.flight import Flight, FlightConfig
from ipp_bench.sim.quadrotor import ROTOR_MODELS, QuadrotorParams
from ipp_bench.sim.render import SceneRenderer
from ipp_bench.sim.scene import SceneConfig, WeedScene
from ipp_bench.sim.texture import TexturePalette, weed_texture
from ipp_bench.sim.vision import GroundProjector, WeedSegmenter

MEASUREMENTS = ("camera", "camera+noise", "truth")

#: the v0 camera: ideal optics and sensor, 128 px, no per-episode variation
V0_CAMERA = CameraModel(image_size=128, psf_sigma_px=0.0, exposure_s=0.0, read_noise_dn=0.0, shot_noise_gain=0.0,
                        exposure_jitter=0.0, white_balance_jitter=0.0, sun_zenith_deg=(0.0, 0.0))


@dataclass(frozen=True)
class SimConfig:
    """Settings of the MuJoCo deployment that are not part of the IPP problem (defaults: v1)."""

    camera: CameraModel = CameraModel()
    segmenter: WeedSegmenter = WeedSegmenter()
    palette: TexturePalette = TexturePalette()
    flight: FlightConfig = FlightConfig()
    disturbances: DisturbanceConfig = DisturbanceConfig()
    measurement: str = "camera"  # "camera" (v1) | "camera+noise" (v0) | "truth" (ablation)
    pipeline: str = "opencv"  # "opencv" (v1) | "v0" (the v0 per-pixel numpy code, ipp_bench.sim.vision_v0)
    pixel_binning: bool = True  # above the binning altitude the image is read out binned (v1)
    min_coverage: float = 0.5  # [-] share of a cell the image must cover for the cell to count as seen
    rotor_model: str = "thrust"  # "thrust": lag on thrust; "speed": rotor speed state, thrust k_f omega^2
    scene: SceneConfig = SceneConfig()
    gains: ControllerGains = ControllerGains()

    def __post_init__(self) -> None:
        if self.camera.image_size > min(self.scene.max_render_size):
            raise ValueError(f"SimConfig.camera.image_size must be <= {min(self.scene.max_render_size)} px "
                             f"(SceneConfig.max_render_size), got {self.camera.image_size}")
        if self.pipeline not in ("opencv", "v0"):
            raise ValueError(f"SimConfig.pipeline must be 'opencv' or 'v0', got {self.pipeline!r}")
        if self.measurement not in MEASUREMENTS:
            raise ValueError(f"SimConfig.measurement must be one of {MEASUREMENTS}, got {self.measurement!r}")
        if self.rotor_model not in ROTOR_MODELS:
            raise ValueError(f"SimConfig.rotor_model must be one of {ROTOR_MODELS}, got {self.rotor_model!r}")
        if not 0.0 < self.min_coverage <= 1.0:
            raise ValueError(f"SimConfig.min_coverage must be in (0, 1], got {self.min_coverage}")

    @property
    def image_size(self) -> int:
        return self.camera.image_size

    def with_image_size(self, size: int) -> SimConfig:
        return dataclasses.replace(self, camera=dataclasses.replace(self.camera, image_size=int(size)))

    @staticmethod
    def from_dict(section: dict) -> SimConfig:
        """The ``[sim]`` section of a task file: top-level fields, and one table per sub-section
        (``[sim.camera]``, ``[sim.flight]``, ...); what a table leaves out keeps its default.

        Raises:
            ValueError: an unknown key (the valid ones listed) or a bad value (field and range named).
        """
        if not isinstance(section, dict):
            raise ValueError(f"[sim] must be a table, got {section!r}")
        base = SimConfig()
        top, subs = {}, {}
        for key, value in section.items():
            if key in SIM_SECTIONS:
                if not isinstance(value, dict):
                    raise ValueError(f"[sim.{key}] must be a table, got {value!r}")
                sub = getattr(base, key)
                names = [f.name for f in dataclasses.fields(sub)]
                for k in value:
                    if k not in names:
                        raise ValueError(f"unknown [sim.{key}] field {k!r}: valid are {names}")
                subs[key] = dataclasses.replace(
                    sub, **{k: _coerce(getattr(sub, k), v, f"sim.{key}.{k}") for k, v in value.items()})
            elif key in sim_field_owners() and sim_field_owners()[key] == "":
                top[key] = _coerce(getattr(base, key), value, f"sim.{key}")
            else:
                top_level = sorted(k for k, o in sim_field_owners().items() if o == "")
                raise ValueError(f"unknown [sim] key {key!r}: valid are {top_level} and the tables "
                                 f"{list(SIM_SECTIONS)}")
        return dataclasses.replace(base, **subs, **top)

    def replace(self, **overrides) -> SimConfig:
        """A copy with leaf fields set by their (unique) names: ``replace(image_size=480, wind_max=2.0)``.

        Raises:
            ValueError: an unknown name (the valid ones listed) or a bad value (field and range named).
        """
        owners = sim_field_owners()
        top, subs = {}, {}
        for name, value in overrides.items():
            if name not in owners:
                raise ValueError(f"unknown sim field {name!r}: valid are {sorted(owners)}")
            owner = owners[name]
            if owner:
                subs.setdefault(owner, {})[name] = _coerce(getattr(getattr(self, owner), name), value, name)
            else:
                top[name] = _coerce(getattr(self, name), value, name)
        new_subs = {k: dataclasses.replace(getattr(self, k), **v) for k, v in subs.items()}
        return dataclasses.replace(self, **new_subs, **top)

    @staticmethod
    def v0() -> SimConfig:
        """The v0 deployment: ideal 128 px camera plus the sensor model's noise, stop at every waypoint."""
        return SimConfig(camera=V0_CAMERA, segmenter=WeedSegmenter(open_px=0, close_px=0), palette=TexturePalette.v0(),
                         flight=FlightConfig.v0(), disturbances=DisturbanceConfig.none(),
                         measurement="camera+noise", pixel_binning=False, pipeline="v0")


#: the sub-sections of ``[sim]`` (nested dataclasses of :class:`SimConfig`)
SIM_SECTIONS = ("camera", "segmenter", "palette", "flight", "disturbances", "scene", "gains")


def sim_field_owners() -> dict[str, str]:
    """Every leaf field of :class:`SimConfig` -> its sub-section ("" for the top level); names are unique."""
    owners: dict[str, str] = {}
    for f in dataclasses.fields(SimConfig):
        if f.name in SIM_SECTIONS:
            for g in dataclasses.fields(type(getattr(SimConfig(), f.name))):
                assert g.name not in owners, f"sim field {g.name} is not unique"
                owners[g.name] = f.name
        else:
            assert f.name not in owners, f"sim field {f.name} is not unique"
            owners[f.name] = ""
    return owners


def split_sim_settings(init: Callable[[dict[str, Any]], None], overrides: dict[str, Any], sim: SimConfig | None,
                       sim_section: dict | None) -> SimConfig:
    """A deployment env's settings: ``overrides`` that name a :class:`SimConfig` leaf field set it (on
    ``sim``, else the task file's ``sim_section``, else the defaults); ``init`` is called with the rest
    (the problem's fields), and an unknown name is said once, with both lists of valid names."""
    names = sim_field_owners()
    sim_overrides = {k: v for k, v in overrides.items() if k in names}
    try:
        init({k: v for k, v in overrides.items() if k not in names})
    except ValueError as err:
        if str(err).startswith("unknown config field"):
            raise ValueError(f"{err}; or a sim field: {sorted(names)}") from None
        raise
    if sim is None:
        sim = SimConfig.from_dict(sim_section) if sim_section is not None else SimConfig()
    return sim.replace(**sim_overrides) if sim_overrides else sim


def _coerce(default, value, where: str):
    """A TOML / JSON value in the type of the field's default (lists -> tuples), or a one-line error."""
    if isinstance(default, tuple):
        if not isinstance(value, (list, tuple)) or len(value) != len(default):
            raise ValueError(f"{where} = {value!r} is invalid: expected {len(default)} numbers, e.g. {list(default)}")
        return tuple(_coerce(d, v, where) for d, v in zip(default, value))
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ValueError(f"{where} = {value!r} is invalid: expected true or false")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{where} = {value!r} is invalid: expected an integer")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{where} = {value!r} is invalid: expected a number")
        return float(value)
    if isinstance(default, str) and not isinstance(value, str):
        raise ValueError(f"{where} = {value!r} is invalid: expected a string")
    return value


@dataclass(frozen=True)
class CameraReading:
    """One camera frame and what was made of it."""

    frame: np.ndarray  # (h, w, 3) uint8 image as the camera delivered it (binned above the binning altitude)
    weed_mask: np.ndarray  # (h, w) uint8 0/1
    fraction: np.ndarray  # (n,) weed fraction per cell (0 where unseen)
    seen: np.ndarray  # (n,) bool
    body_xyz: np.ndarray  # (3,) true drone position when the frame was taken [m]
    estimated_xyz: np.ndarray  # (3,) estimated drone position used for georeferencing [m]
    binning: int  # read-out binning factor of the frame
    footprint: np.ndarray | None = None  # (4, 2) ground corners of the frame from the estimated pose [m]
    cell_pixels: dict | None = None  # seen cell -> (x, y) pixel of its centre in ``frame`` (estimated pose)
    drone: int = 0  # whose camera (a team scene)


class WeedWorld:
    """Scene + flight + renderer + image processing over one grid.

    Args:
        grid: the map (same grid as the belief).
        sensor: camera model of the belief; its ``fov_deg`` is the MuJoCo camera's field of view,
            its binning altitude and factor decide the read-out binning.
        speed: cruise speed [m/s].
        cfg: deployment settings.
        airframe: a PyMJCF quadrotor to fly instead of the shipped one (see :mod:`ipp_bench.sim.scene`);
            its camera's field of view must equal the sensor model's.
        drones: quadrotors in the scene (a team): ``flights[i]`` flies drone i, ``camera(drone=i)``
            reads its camera; ``flight`` is the first drone's loop.
    """

    def __init__(self, grid: GridConfig, sensor: SensorConfig, speed: float = 2.0,
                 cfg: SimConfig = SimConfig(), airframe=None, drones: int = 1) -> None:
        self.grid, self.cfg, self.sensor_cfg = grid, cfg, sensor
        # one OpenCV thread per process, as for BLAS (ipp_bench.core._threads): on 2 shared cores a second
        # thread only waits for the first; parallelism comes from worker processes
        cv2.setNumThreads(1)
        shipped = QuadrotorParams(camera_fovy_deg=sensor.fov_deg, rotor_model=cfg.rotor_model)
        self.scene = WeedScene(grid.rows, grid.cols, grid.resolution, shipped, cfg.scene, airframe=airframe,
                               drones=drones)
        self.quad = self.scene.quad
        if abs(self.quad.camera_fovy_deg - sensor.fov_deg) > 1e-9:
            raise ValueError(f"airframe: camera 'down' has fovy {self.quad.camera_fovy_deg} deg, the sensor model "
                             f"{sensor.fov_deg} deg (fov_deg): they must be equal")
        if self.quad.rotor_model != cfg.rotor_model:
            raise ValueError(f"airframe: its rotor actuators are the {self.quad.rotor_model!r} model, "
                             f"SimConfig.rotor_model is {cfg.rotor_model!r} (filterexact dynamics: 'thrust'; "
                             "none: 'speed')")
        self.flights = [Flight(self.scene, speed=speed, cfg=cfg.flight, gains=cfg.gains, disturbances=cfg.disturbances,
                               drone=i, wind_owner=i == 0) for i in range(self.scene.drones)]
        self.flight = self.flights[0]
        self.renderer = SceneRenderer(self.scene)
        size = cfg.camera.image_size
        self._projectors: dict[int, GroundProjector] = {}
        self._size = size
        self._fov = sensor.fov_deg
        self.conditions = EpisodeConditions.nominal()
        self._v0_threshold = vision_v0.HSVThreshold()
        self._pixel_rng = np.random.default_rng(0)
        self.weed_mask_truth: np.ndarray | None = None
        self._texture_key: tuple | None = None
        self.last_reading: CameraReading | None = None  # the latest read-out, of any drone
        self.last_readings: list[CameraReading | None] = [None] * self.scene.drones  # each drone's latest
        self._sun0 = (self.scene.model.light_dir[self.scene.light_id].copy(),
                      self.scene.model.light_diffuse[self.scene.light_id].copy(),
                      self.scene.model.light_ambient[self.scene.light_id].copy())

    def _v0_projector(self, shape) -> vision_v0.GroundProjector:
        key = ("v0", shape[:2])
        p = self._projectors.get(key)
        if p is None:
            p = vision_v0.GroundProjector(self.grid.rows, self.grid.cols, self.grid.resolution, shape[1], shape[0],
                                          self._fov, self.cfg.min_coverage)
            self._projectors[key] = p
        return p

    def projector(self, binning: int) -> GroundProjector:
        p = self._projectors.get(binning)
        if p is None:
            s = self._size // binning
            p = GroundProjector(self.grid.rows, self.grid.cols, self.grid.resolution, s, s, self._fov,
                                self.cfg.min_coverage)
            self._projectors[binning] = p
        return p

    # -- episodes ---------------------------------------------------------------------------------
    def load_field(self, truth: np.ndarray, seed: int) -> None:
        """Paints the ground for ground truth ``truth`` (rows, cols); ``seed`` draws the texture.

        The same (truth, seed) as the previous call keeps the texture already painted.
        """
        truth = np.asarray(truth, dtype=np.float64)
        key = (truth.shape, truth.tobytes(), int(seed))
        if key != self._texture_key:
            rgb, mask = weed_texture(truth, np.random.default_rng(int(seed)), self.cfg.scene.texels_per_cell,
                                     self.cfg.palette)
            self.scene.set_ground(rgb)
            self.weed_mask_truth = mask
            self._texture_key = key
        self.last_reading = None
        self.last_readings = [None] * self.scene.drones

    def begin_episode(self, truth: np.ndarray, seed: int) -> None:
        """Texture, conditions (sun, exposure, white balance), wind and estimator errors of one episode.

        Everything is drawn from ``seed``: the same seed gives the same episode, frame for frame.
        """
        ss = np.random.SeedSequence(int(seed))
        tex_seed, cond_seed, pix_seed, dist_seed = (int(s.generate_state(1, np.uint64)[0]) for s in ss.spawn(4))
        self.load_field(truth, tex_seed)
        self.conditions = EpisodeConditions.draw(self.cfg.camera, np.random.default_rng(cond_seed))
        self._pixel_rng = np.random.default_rng(pix_seed)
        self._apply_sun()
        self.flight.disturbance_seed = dist_seed
        for i, flight in enumerate(self.flights[1:], start=1):  # a team's other drones: their own estimators
            flight.disturbance_seed = int(np.random.SeedSequence([dist_seed, i]).generate_state(1, np.uint64)[0])

    def _apply_sun(self) -> None:
        """Sun direction into the scene's light; the auto-exposure normalises the ground's irradiance."""
        m, i = self.scene.model, self.scene.light_id
        d0, diff0, amb0 = self._sun0
        sun = np.asarray(self.conditions.sun_dir)
        m.light_dir[i] = sun
        m.light_diffuse[i] = diff0
        m.light_ambient[i] = amb0

    def _exposure(self) -> float:
        """Gain that an ideal auto-exposure applies: ground irradiance back to its overhead-sun value."""
        _, diff0, amb0 = self._sun0
        cos_z = max(-float(self.conditions.sun_dir[2]), 0.05)
        return float((amb0[0] + diff0[0]) / (amb0[0] + diff0[0] * cos_z))

    # -- camera -----------------------------------------------------------------------------------
    def binning_at(self, altitude: float) -> int:
        s = self.sensor_cfg
        return s.binning if (self.cfg.pixel_binning and altitude > s.binning_altitude and s.binning > 1) else 1

    def camera(self, binning: int | None = None, drone: int = 0) -> CameraReading:
        """Renders the downward camera, forms the image, segments it and projects it with the estimated pose.

        ``binning`` forces the read-out's binning factor (calibration); default: the sensor's rule
        at the estimated altitude. ``drone``: whose camera (a team scene).
        """
        size = self.cfg.camera.image_size
        flight = self.flights[drone]
        raw = self.renderer.render(None if drone == 0 else self.renderer.down_camera(drone), size, size)
        est_pos, est_cam_pos, est_cam_mat = flight.estimated_camera_pose()
        if binning is None:
            binning = self.binning_at(float(est_pos[2]))
        cam = self.cfg.camera
        if cam.ideal:
            frame = raw
        else:
            cond = dataclasses.replace(self.conditions, exposure_gain=self.conditions.exposure_gain * self._exposure())
            proj = self.projector(1)
            blur = motion_blur_px(cam, float(flight.position[2]), flight.velocity,
                                  flight.angular_velocity, proj.focal) if cam.exposure_s > 0 else (0.0, 0.0)
            frame = form_image(raw, cam, cond, self._pixel_rng, binning, blur)
        proj = self.projector(binning)
        if self.cfg.pipeline == "v0":
            weed = self._v0_threshold(frame)
            fraction, seen, _ = self._v0_projector(frame.shape).cell_fractions(weed, est_cam_pos, est_cam_mat)
            weed = weed.astype(np.uint8)
        else:
            weed = self.cfg.segmenter(frame)
            fraction, seen, _ = proj.cell_fractions(weed, est_cam_pos, est_cam_mat)
        reading = CameraReading(frame, weed, fraction, seen, flight.position, est_pos, binning,
                                proj.corners_on_ground(est_cam_pos, est_cam_mat),
                                self._cell_pixels(seen, proj, est_cam_pos, est_cam_mat), drone)
        self.last_reading = reading
        self.last_readings[drone] = reading
        return reading

    def _cell_pixels(self, seen: np.ndarray, proj: GroundProjector, cam_pos, cam_mat) -> dict:
        """Seen cell -> (x, y) pixel of its centre in the frame (the demo writes the fractions there)."""
        cells = np.flatnonzero(seen)
        res = self.grid.resolution
        pts = np.stack([(cells % self.grid.cols + 0.5) * res, (cells // self.grid.cols + 0.5) * res,
                        np.zeros(cells.size)], axis=1)
        uv = proj.to_image(pts, cam_pos, cam_mat)
        return {int(c): (float(u), float(v)) for c, (u, v) in zip(cells, uv) if np.isfinite(u)}


    def read_camera(self, sensor: Sensor, rng: np.random.Generator,
                    truth: np.ndarray | None = None, drone: int = 0) -> tuple[Observation | None, np.ndarray | None]:
        """A sensor read-out from the camera: (Observation, z), or (None, None) when nothing usable was seen.

        The read-out's layout (cells, H, R) is the sensor model's at the estimated position; z is
        H times the camera's per-cell fractions ("camera"), plus the sensor model's noise
        ("camera+noise", v0), or H times the ground truth ``truth`` ("truth"). ``drone``: whose camera.
        """
        reading = self.camera(drone=drone)
        obs = sensor.observe(reading.estimated_xyz)
        if obs is None:
            return None, None
        obs = restrict(obs, reading.seen)
        if obs is None:
            return None, None
        mode = self.cfg.measurement
        if mode == "camera":
            return obs, obs.weights @ reading.fraction[obs.cells]
        if mode == "truth":
            if truth is None:
                raise ValueError("SimConfig.measurement = 'truth' needs the ground truth")
            return obs, obs.weights @ np.asarray(truth, dtype=np.float64).reshape(-1)[obs.cells]
        return obs, sensor.noisy_from_cell_values(obs, reading.fraction, rng)

    def close(self) -> None:
        self.renderer.close()
