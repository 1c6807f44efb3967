"""Image formation of the downward camera: what the sensor does to the rendered irradiance.

MuJoCo renders the scene as the lens would see it under the episode's sun; :class:`CameraModel`
then applies, in the order a camera does:

1. optics (on the 8-bit frame): a Gaussian point-spread function (lens + demosaicing, ``psf_sigma_px``) and, where the
   image moves by at least half a pixel during the exposure, a linear motion-blur kernel along the
   image-plane motion (translation over the ground and rotation of the airframe);
2. pixel binning above the sensor's binning altitude (``cv2.resize(..., INTER_AREA)`` by the
   binning factor: the read-out at half resolution that the sensor model's binning stands for);
3. exposure and white balance of the episode (auto-exposure error, per-channel gains);
4. shot noise (variance proportional to the signal) and read noise, then 8-bit quantisation.

Per-episode conditions (:class:`EpisodeConditions`: sun direction, exposure and white-balance
error) are drawn from the episode's generator; pixel noise from a generator seeded by the episode
too, so the same seed gives the same frames bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class CameraModel:
    """Sensor and optics of the downward camera (defaults: a small machine-vision camera)."""

    image_size: int = 320  # [px] side of the square image at full resolution
    psf_sigma_px: float = 0.6  # [px] Gaussian blur of lens and demosaicing
    exposure_s: float = 0.004  # [s] shutter time (motion blur)
    read_noise_dn: float = 2.0  # [DN] read-noise std on the 0-255 scale
    shot_noise_gain: float = 0.5  # [DN] shot-noise variance per DN of signal
    exposure_jitter: float = 0.12  # [-] std of the log auto-exposure error per episode
    white_balance_jitter: float = 0.05  # [-] std of each channel's gain error per episode
    sun_zenith_deg: tuple[float, float] = (15.0, 60.0)  # [deg] range of the sun's zenith angle per episode

    def __post_init__(self) -> None:
        if not (isinstance(self.image_size, int) and 32 <= self.image_size <= 1280):
            raise ValueError(f"CameraModel.image_size must be an integer in [32, 1280] px, got {self.image_size!r}")
        for name, hi in (("psf_sigma_px", 5.0), ("exposure_s", 0.1), ("read_noise_dn", 50.0),
                         ("shot_noise_gain", 10.0), ("exposure_jitter", 1.0), ("white_balance_jitter", 0.5)):
            v = getattr(self, name)
            if not 0.0 <= v <= hi:
                raise ValueError(f"CameraModel.{name} must be in [0, {hi}], got {v}")
        lo, hi = self.sun_zenith_deg
        if not 0.0 <= lo <= hi < 85.0:
            raise ValueError(f"CameraModel.sun_zenith_deg must satisfy 0 <= low <= high < 85 [deg], "
                             f"got {self.sun_zenith_deg}")

    @property
    def ideal(self) -> bool:
        """No optics, noise or per-episode variation: the rendered frame is the image (v0)."""
        return (self.psf_sigma_px == 0 and self.exposure_s == 0 and self.read_noise_dn == 0
                and self.shot_noise_gain == 0 and self.exposure_jitter == 0 and self.white_balance_jitter == 0)


@dataclass(frozen=True)
class EpisodeConditions:
    """What changes from one episode to the next: sun, exposure error, white balance."""

    sun_dir: tuple[float, float, float]  # unit vector the sunlight travels along (towards the ground)
    exposure_gain: float  # [-] auto-exposure error (1 = perfect)
    white_balance: tuple[float, float, float]  # [-] per-channel gains (R, G, B)

    @staticmethod
    def draw(model: CameraModel, rng: np.random.Generator) -> EpisodeConditions:
        lo, hi = model.sun_zenith_deg
        zenith = math.radians(rng.uniform(lo, hi))
        azimuth = rng.uniform(0.0, 2.0 * math.pi)
        s = math.sin(zenith)
        sun = (-s * math.cos(azimuth), -s * math.sin(azimuth), -math.cos(zenith))
        gain = math.exp(model.exposure_jitter * rng.standard_normal())
        wb = 1.0 + model.white_balance_jitter * rng.standard_normal(3)
        wb = np.clip(wb, 0.5, 1.5)
        return EpisodeConditions(tuple(float(v) for v in sun), float(gain), tuple(float(v) for v in wb))

    @staticmethod
    def nominal() -> EpisodeConditions:
        return EpisodeConditions((0.0, 0.0, -1.0), 1.0, (1.0, 1.0, 1.0))


def motion_blur_px(model: CameraModel, altitude: float, vel_world, omega_body, focal_px: float) -> tuple[float, float]:
    """Image-plane motion during one exposure (dx, dy) [px] of the central pixel.

    Translation over the ground moves the image by v h^-1 f; a rotation rate w about the body x / y
    axes moves it by w f (small angles). Signs are irrelevant for a symmetric kernel.
    """
    h = max(float(altitude), 1e-3)
    t = model.exposure_s
    dx = (float(vel_world[0]) / h + float(omega_body[1])) * focal_px * t
    dy = (float(vel_world[1]) / h - float(omega_body[0])) * focal_px * t
    return dx, dy


def _motion_kernel(dx: float, dy: float) -> np.ndarray:
    """Normalised line kernel of length |(dx, dy)| px along that direction."""
    length = math.hypot(dx, dy)
    n = int(math.ceil(length)) | 1  # odd size
    k = np.zeros((n, n), np.float32)
    c = n // 2
    steps = max(2, int(math.ceil(length * 4)))
    for s in np.linspace(-0.5, 0.5, steps):
        x, y = c + s * dx, c + s * dy
        k[int(round(y)), int(round(x))] += 1.0
    return k / k.sum()


def form_image(frame: np.ndarray, model: CameraModel, cond: EpisodeConditions, rng: np.random.Generator,
               binning: int = 1, blur_px: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """The camera's uint8 image of a rendered frame (see the module docstring for the steps).

    Args:
        frame: (S, S, 3) uint8 rendered irradiance at full resolution.
        model, cond: the camera and the episode's conditions.
        rng: pixel-noise generator (advanced).
        binning: read-out binning factor (1 or the sensor's factor above its binning altitude).
        blur_px: image-plane motion during the exposure [px] (:func:`motion_blur_px`).

    Returns:
        (S / binning, S / binning, 3) uint8.
    """
    img = frame
    if model.psf_sigma_px > 0.0:
        img = cv2.GaussianBlur(img, (0, 0), model.psf_sigma_px)
    if math.hypot(*blur_px) >= 0.5:
        img = cv2.filter2D(img, -1, _motion_kernel(*blur_px), borderType=cv2.BORDER_REFLECT)
    img = img.astype(np.float32)
    if binning > 1:
        s = img.shape[0] // binning
        img = cv2.resize(img, (s, s), interpolation=cv2.INTER_AREA)
    img *= np.asarray(cond.white_balance, np.float32) * np.float32(cond.exposure_gain)
    # shot + read noise: var = g * signal + r^2 (per pixel and channel), in place
    var = np.maximum(img, 0.0)
    var *= np.float32(model.shot_noise_gain)
    var += np.float32(model.read_noise_dn ** 2)
    np.sqrt(var, out=var)
    # OpenCV's generator, seeded per frame from ``rng`` (3x faster than numpy's normals at 320 px)
    noise = np.empty(img.shape, np.float32)
    cv2.setRNGSeed(int(rng.integers(0, 2**31 - 1)))
    cv2.randn(noise, 0.0, 1.0)
    var *= noise
    img += var
    np.clip(img, 0.0, 255.0, out=img)
    img += 0.5
    return img.astype(np.uint8)
