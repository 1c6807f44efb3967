"""The v0 camera pipeline, kept so that ``ipp_bench/MuJoCoWeed15-v0`` behaves as it always did.

Hand-written per-pixel numpy: HSV threshold and ground projection (v1 uses OpenCV, ``vision``).
Also the baseline of ``benchmarks/bench_vision.py``.

No segmentation rendering and no ground truth: each pixel of the RGB frame is
classified by colour (:class:`HSVThreshold`), cast as a ray through the pinhole
camera (intrinsics from the vertical field of view and the image size) from the
camera's actual pose, intersected with the ground plane z = 0, and binned into
the grid cell it hits (:class:`GroundProjector`). A cell's weed fraction is the
share of its pixels classified as weed; cells with too few pixels (at the edge
of the image, or cut off by the drone's tilt) are reported unseen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class HSVThreshold:
    """A pixel is weed when its hue, saturation and value fall in these ranges (hue in degrees)."""

    hue_min: float = 72.0  # [deg] above straw/soil yellows and green-brown mixed pixels
    hue_max: float = 170.0  # [deg] below cyan
    sat_min: float = 0.35  # greyish moss and stones stay out
    val_min: float = 0.12  # too dark to judge

    def __post_init__(self) -> None:
        if not 0.0 <= self.hue_min < self.hue_max <= 360.0:
            raise ValueError(f"HSVThreshold hue range must satisfy 0 <= hue_min < hue_max <= 360, "
                             f"got {self.hue_min}, {self.hue_max}")
        for name in ("sat_min", "val_min"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"HSVThreshold.{name} must be in [0, 1], got {getattr(self, name)}")

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        """Boolean weed mask (H, W) of a uint8 RGB image (H, W, 3)."""
        img = rgb.astype(np.int16)
        r, g, b = img[..., 0], img[..., 1], img[..., 2]
        mx = np.maximum(np.maximum(r, g), b)
        mn = np.minimum(np.minimum(r, g), b)
        chroma = mx - mn
        # green-dominant hues lie in [60, 180): max channel is g, hue = 60 * (2 + (b - r) / chroma)
        # (hues above 180 are not weeds; a non-green max means a hue outside (60, 180))
        ok = (g == mx) & (chroma > 0)
        ok &= chroma >= self.sat_min * mx  # saturation = chroma / max
        ok &= mx >= self.val_min * 255.0
        # hue = 120 + 60 (b - r) / chroma; test hue_min <= hue <= hue_max without dividing
        lo = max(self.hue_min, 60.0)
        hi = min(self.hue_max, 180.0)
        br = (b - r).astype(np.float32) * 60.0
        c = chroma.astype(np.float32)
        ok &= br >= (lo - 120.0) * c
        ok &= br <= (hi - 120.0) * c
        return ok


class GroundProjector:
    """Projects camera pixels to grid cells on the ground plane z = 0.

    Args:
        rows, cols, resolution: the grid (cells, metres per cell); the map spans
            [0, cols*res] x [0, rows*res] and cell (r, c) has flat index r*cols + c.
        width, height: image size [px].
        fovy_deg: vertical field of view [deg] (MuJoCo's camera ``fovy``).
        min_coverage: a cell counts as seen when its pixels cover at least this
            share of its area (judged from the pixel count a full cell would get).
    """

    def __init__(self, rows: int, cols: int, resolution: float, width: int, height: int,
                 fovy_deg: float = 60.0, min_coverage: float = 0.5) -> None:
        if not 0.0 < min_coverage <= 1.0:
            raise ValueError(f"min_coverage must be in (0, 1], got {min_coverage}")
        self.rows, self.cols, self.resolution = int(rows), int(cols), float(resolution)
        self.width, self.height = int(width), int(height)
        self.min_coverage = float(min_coverage)
        self.focal = (self.height / 2.0) / math.tan(math.radians(fovy_deg) / 2.0)  # [px], square pixels
        u = (np.arange(self.width) + 0.5 - self.width / 2.0) / self.focal
        v = (np.arange(self.height) + 0.5 - self.height / 2.0) / self.focal
        uu, vv = np.meshgrid(u, v)
        # camera frame (MuJoCo/OpenGL): x right, y up, looking along -z; image row 0 is the top
        self.rays_camera = np.stack([uu.ravel(), -vv.ravel(), -np.ones(uu.size)], axis=1)
        self.n_cells = self.rows * self.cols

    def pixel_cells(self, cam_pos: np.ndarray, cam_mat: np.ndarray) -> np.ndarray:
        """Flat cell index hit by each pixel's ray (H*W,), -1 off the map or above the horizon.

        Args:
            cam_pos: (3,) camera position [m] in the world.
            cam_mat: (3, 3) camera orientation, columns = camera axes in the world (``data.cam_xmat``).
        """
        d = self.rays_camera @ np.asarray(cam_mat, dtype=np.float64).reshape(3, 3).T
        pz = float(cam_pos[2])
        dz = d[:, 2]
        down = dz < -1e-9
        t = np.where(down, -pz / np.where(down, dz, -1.0), 0.0)
        x = cam_pos[0] + t * d[:, 0]
        y = cam_pos[1] + t * d[:, 1]
        c = np.floor(x / self.resolution).astype(np.int64)
        r = np.floor(y / self.resolution).astype(np.int64)
        inside = down & (pz > 0) & (c >= 0) & (c < self.cols) & (r >= 0) & (r < self.rows)
        return np.where(inside, r * self.cols + c, -1)

    def expected_pixels(self, altitude: float) -> float:
        """Pixels a whole cell gets straight below the camera at ``altitude`` [m]."""
        return (self.resolution * self.focal / max(altitude, 1e-6)) ** 2

    def cell_fractions(self, weed: np.ndarray, cam_pos, cam_mat) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Weed fraction per cell from a boolean weed mask.

        Returns:
            (fraction, seen, counts): (n,) float64 fraction (0 where unseen), (n,) bool, (n,) pixel counts.
        """
        cells = self.pixel_cells(cam_pos, cam_mat)
        valid = cells >= 0
        idx = cells[valid]
        counts = np.bincount(idx, minlength=self.n_cells).astype(np.float64)
        hits = np.bincount(idx, weights=weed.ravel()[valid].astype(np.float64), minlength=self.n_cells)
        seen = counts >= self.min_coverage * self.expected_pixels(float(cam_pos[2]))
        fraction = np.where(seen, hits / np.maximum(counts, 1.0), 0.0)
        return fraction, seen, counts
