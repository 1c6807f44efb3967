"""Everything simulated for one grid: scene, flight, camera and its image processing.

:class:`WeedWorld` is built once per environment (the model is compiled once);
:meth:`WeedWorld.load_field` paints a new ground texture for each episode and
:meth:`WeedWorld.read_camera` turns the current frame into a sensor read-out:
the nominal footprint of :class:`~ipp_bench.sensor.Sensor` at the drone's actual
position, restricted to the cells the camera really saw (tilt can cut edge cells
off), with each cell's value the weed fraction of its pixels, then the sensor's
binning and altitude noise (``Sensor.noisy_from_cell_values``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ipp_bench.config import GridConfig, SensorConfig
from ipp_bench.sensor import Observation, Sensor
from ipp_bench.sim.controller import ControllerGains
from ipp_bench.sim.flight import Flight
from ipp_bench.sim.quadrotor import QuadrotorParams
from ipp_bench.sim.render import SceneRenderer
from ipp_bench.sim.scene import SceneConfig, WeedScene
from ipp_bench.sim.texture import weed_texture
from ipp_bench.sim.vision import GroundProjector, HSVThreshold


@dataclass(frozen=True)
class SimConfig:
    """Settings of the MuJoCo deployment that are not part of the IPP problem."""

    image_size: int = 128  # [px] side of the square measurement image
    ramp_s: float = 1.0  # [s] velocity ramp at both ends of a leg
    arrive_tol: float = 0.15  # [m] waypoint reached within this distance ...
    settle_speed: float = 0.3  # [m/s] ... and below this speed
    min_coverage: float = 0.5  # share of a cell the image must cover for the cell to count as seen
    scene: SceneConfig = SceneConfig()
    gains: ControllerGains = ControllerGains()
    threshold: HSVThreshold = HSVThreshold()

    def __post_init__(self) -> None:
        if not 16 <= self.image_size <= min(self.scene.max_render_size):
            raise ValueError(f"SimConfig.image_size must be in [16, {min(self.scene.max_render_size)}] px, "
                             f"got {self.image_size}")
        for name in ("ramp_s", "arrive_tol", "settle_speed"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"SimConfig.{name} must be > 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class CameraReading:
    """One camera frame and what was made of it."""

    frame: np.ndarray  # (H, W, 3) uint8
    weed_mask: np.ndarray  # (H, W) bool
    fraction: np.ndarray  # (n,) weed fraction per cell (0 where unseen)
    seen: np.ndarray  # (n,) bool
    body_xyz: np.ndarray  # (3,) drone position when the frame was taken [m]


class WeedWorld:
    """Scene + flight + renderer + image processing over one grid.

    Args:
        grid: the map (same grid as the belief).
        sensor: camera model; its ``fov_deg`` is the MuJoCo camera's field of view.
        speed: cruise speed [m/s].
        cfg: deployment settings.
    """

    def __init__(self, grid: GridConfig, sensor: SensorConfig, speed: float = 2.0,
                 cfg: SimConfig = SimConfig()) -> None:
        self.grid, self.cfg = grid, cfg
        self.quad = QuadrotorParams(camera_fovy_deg=sensor.fov_deg)
        self.scene = WeedScene(grid.rows, grid.cols, grid.resolution, self.quad, cfg.scene)
        self.flight = Flight(self.scene, speed=speed, ramp_s=cfg.ramp_s, arrive_tol=cfg.arrive_tol,
                             settle_speed=cfg.settle_speed, gains=cfg.gains)
        self.renderer = SceneRenderer(self.scene)
        self.projector = GroundProjector(grid.rows, grid.cols, grid.resolution, cfg.image_size, cfg.image_size,
                                         sensor.fov_deg, cfg.min_coverage)
        self.weed_mask_truth: np.ndarray | None = None
        self._texture_key: tuple | None = None
        self.last_reading: CameraReading | None = None

    def load_field(self, truth: np.ndarray, seed: int) -> None:
        """Paints the ground for ground truth ``truth`` (rows, cols); ``seed`` draws the texture.

        The same (truth, seed) as the previous call keeps the texture already painted.
        """
        truth = np.asarray(truth, dtype=np.float64)
        key = (truth.shape, truth.tobytes(), int(seed))
        if key != self._texture_key:
            rgb, mask = weed_texture(truth, np.random.default_rng(int(seed)), self.cfg.scene.texels_per_cell)
            self.scene.set_ground(rgb)
            self.weed_mask_truth = mask
            self._texture_key = key
        self.last_reading = None

    def camera(self) -> CameraReading:
        """Renders the downward camera at the drone's current pose and estimates per-cell weed fractions."""
        size = self.cfg.image_size
        frame = self.renderer.render(None, size, size)
        weed = self.cfg.threshold(frame)
        d, cam = self.scene.data, self.scene.camera_id
        fraction, seen, _ = self.projector.cell_fractions(weed, d.cam_xpos[cam], d.cam_xmat[cam])
        reading = CameraReading(frame, weed, fraction, seen, self.flight.position)
        self.last_reading = reading
        return reading

    def read_camera(self, sensor: Sensor, rng: np.random.Generator) -> tuple[Observation | None, np.ndarray | None]:
        """A sensor read-out from the camera: (Observation, z), or (None, None) when nothing usable was seen."""
        reading = self.camera()
        obs = sensor.observe(reading.body_xyz)
        if obs is None:
            return None, None
        obs = restrict(obs, reading.seen)
        if obs is None:
            return None, None
        return obs, sensor.noisy_from_cell_values(obs, reading.fraction, rng)

    def close(self) -> None:
        self.renderer.close()


def restrict(obs: Observation, seen: np.ndarray) -> Observation | None:
    """``obs`` without the measurements (rows of H) that involve an unseen cell; None if none is left."""
    cell_seen = seen[obs.cells]
    if cell_seen.all():
        return obs
    rows = ~np.any((obs.weights > 0) & ~cell_seen[None, :], axis=1)
    if not rows.any():
        return None
    W = obs.weights[rows]
    cols = np.any(W > 0, axis=0)
    return Observation(cells=obs.cells[cols], weights=W[:, cols], var=obs.var[rows], altitude=obs.altitude)
