"""From a camera frame to per-cell weed fractions, with OpenCV.

No segmentation rendering and no ground truth: the RGB frame is

1. converted to HSV and thresholded (``cv2.cvtColor`` + ``cv2.inRange``, :class:`WeedSegmenter`),
2. cleaned up by a morphological opening (``cv2.morphologyEx``: isolated noisy pixels out),
3. projected onto the ground plane z = 0 (:class:`GroundProjector`): the four image corners are
   cast as rays through the pinhole camera from the camera's pose (the *estimated* pose in the
   deployment, so misregistration is part of the error), the plane homography between image and
   ground comes from ``cv2.getPerspectiveTransform`` (exact for a pinhole camera and a plane), and
   ``cv2.warpPerspective`` resamples the weed mask and the image's coverage onto a ground raster of
   whole cells at about the image's ground sampling distance;
4. reduced to cells by area resampling (``cv2.resize(..., INTER_AREA)`` by an integer factor is the
   exact mean over each cell's raster pixels).

A cell's weed fraction is its weed share of the covered raster; cells covered less than
``min_coverage`` (image edge, tilt) are reported unseen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ipp_bench.core.sensor import rays_on_ground


@dataclass(frozen=True)
class WeedSegmenter:
    """A pixel is weed when its hue, saturation and value fall in these ranges; then an opening.

    OpenCV's 8-bit HSV holds hue / 2 (0-179) and saturation, value times 255; the bounds are
    rounded inwards to that raster.
    """

    hue_min: float = 72.0  # [deg] above straw/soil yellows and green-brown mixed pixels
    hue_max: float = 170.0  # [deg] below cyan
    sat_min: float = 0.35  # [-] greyish moss and stones stay out
    val_min: float = 0.12  # [-] too dark to judge
    open_px: int = 0  # [px] side of the elliptic opening kernel (isolated pixels out; 3 px measured to erase
    #                   sub-pixel weeds: bias -0.07 against -0.03 without it); 0 or 1: none
    close_px: int = 3  # [px] side of the elliptic closing kernel after it (gaps inside plants filled); 0 or 1: none

    def __post_init__(self) -> None:
        if not 0.0 <= self.hue_min < self.hue_max <= 360.0:
            raise ValueError(f"WeedSegmenter hue range must satisfy 0 <= hue_min < hue_max <= 360 [deg], "
                             f"got {self.hue_min}, {self.hue_max}")
        for name in ("sat_min", "val_min"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"WeedSegmenter.{name} must be in [0, 1], got {getattr(self, name)}")
        for name in ("open_px", "close_px"):
            v = getattr(self, name)
            if not (isinstance(v, int) and 0 <= v <= 15):
                raise ValueError(f"WeedSegmenter.{name} must be an integer in [0, 15] px, got {v!r}")

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) inclusive bounds for ``cv2.inRange`` on OpenCV's 8-bit HSV."""
        lo = np.array([math.ceil(self.hue_min / 2.0), math.ceil(self.sat_min * 255.0),
                       math.ceil(self.val_min * 255.0)], dtype=np.uint8)
        hi = np.array([min(math.floor(self.hue_max / 2.0), 179), 255, 255], dtype=np.uint8)
        return lo, hi

    @staticmethod
    def _kernel(size: int) -> np.ndarray | None:
        return None if size <= 1 else cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        """Weed mask (H, W) uint8 (1 weed, 0 not) of a uint8 RGB image (H, W, 3)."""
        lo, hi = self.bounds
        hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
        mask = cv2.inRange(hsv, lo, hi)
        for op, size in ((cv2.MORPH_OPEN, self.open_px), (cv2.MORPH_CLOSE, self.close_px)):
            k = self._kernel(size)
            if k is not None:
                mask = cv2.morphologyEx(mask, op, k)
        return (mask >> 7).astype(np.uint8, copy=False)


def rgb_to_hsv(rgb: np.ndarray) -> np.ndarray:
    """Reference conversion of uint8 RGB to HSV (hue in degrees, s and v in [0, 1]), for tests."""
    x = rgb.astype(np.float64) / 255.0
    r, g, b = x[..., 0], x[..., 1], x[..., 2]
    mx, mn = x.max(axis=-1), x.min(axis=-1)
    c = mx - mn
    safe = np.where(c > 0, c, 1.0)
    h = np.where(mx == r, ((g - b) / safe) % 6.0, np.where(mx == g, (b - r) / safe + 2.0, (r - g) / safe + 4.0))
    h = np.where(c > 0, 60.0 * h, 0.0)
    s = np.where(mx > 0, c / np.where(mx > 0, mx, 1.0), 0.0)
    return np.stack([h, s, mx], axis=-1)


def corner_rays(width: int, height: int, fovy_deg: float) -> np.ndarray:
    """(4, 3) camera-frame rays through the centres of the four corner pixels.

    Camera frame of MuJoCo/OpenGL: x right, y up, looking along -z; image row 0 is the top.
    Order: top-left, top-right, bottom-right, bottom-left (OpenCV pixel coordinates (0, 0),
    (W-1, 0), (W-1, H-1), (0, H-1)).
    """
    focal = (height / 2.0) / math.tan(math.radians(fovy_deg) / 2.0)
    us = np.array([0.5, width - 0.5, width - 0.5, 0.5]) - width / 2.0
    vs = np.array([0.5, 0.5, height - 0.5, height - 0.5]) - height / 2.0
    return np.stack([us / focal, -vs / focal, -np.ones(4)], axis=1)


class GroundProjector:
    """Projects an image-sized mask onto the grid's cells through the plane homography.

    Args:
        rows, cols, resolution: the grid (cells, metres per cell); the map spans
            [0, cols*res] x [0, rows*res] and cell (r, c) has flat index r*cols + c.
        width, height: image size [px].
        fovy_deg: vertical field of view [deg] (MuJoCo's camera ``fovy``; square pixels).
        min_coverage: a cell counts as seen when the image covers at least this share of it.
        max_raster: largest raster pixels per cell side (bounds the work at low altitude).
    """

    def __init__(self, rows: int, cols: int, resolution: float, width: int, height: int,
                 fovy_deg: float = 60.0, min_coverage: float = 0.5, max_raster: int = 64) -> None:
        if not 0.0 < min_coverage <= 1.0:
            raise ValueError(f"GroundProjector min_coverage must be in (0, 1], got {min_coverage}")
        self.rows, self.cols, self.resolution = int(rows), int(cols), float(resolution)
        self.width, self.height = int(width), int(height)
        self.fovy_deg = float(fovy_deg)
        self.min_coverage = float(min_coverage)
        self.max_raster = int(max_raster)
        self.focal = (self.height / 2.0) / math.tan(math.radians(fovy_deg) / 2.0)  # [px]
        self.n_cells = self.rows * self.cols
        self._rays = corner_rays(self.width, self.height, self.fovy_deg)
        self._src = np.array([[0, 0], [self.width - 1, 0], [self.width - 1, self.height - 1],
                              [0, self.height - 1]], dtype=np.float32)

    def ground_sampling_distance(self, altitude: float) -> float:
        """Ground size of one pixel straight below the camera [m]."""
        return max(float(altitude), 1e-6) / self.focal

    def corners_on_ground(self, cam_pos, cam_mat) -> np.ndarray | None:
        """(4, 2) ground points (x, y) [m] of the corner pixels, None when a corner misses the ground."""
        return rays_on_ground(self._rays, cam_pos, cam_mat)

    def to_image(self, points, cam_pos, cam_mat) -> np.ndarray:
        """(K, 2) OpenCV pixel coordinates (x right, y down) of world points (K, 3) [m]; NaN behind the camera."""
        R = np.asarray(cam_mat, dtype=np.float64).reshape(3, 3)
        pc = (np.asarray(points, dtype=np.float64) - np.asarray(cam_pos, dtype=np.float64)) @ R  # camera frame
        depth = -pc[:, 2]
        ok = depth > 1e-9
        d = np.where(ok, depth, 1.0)
        u = self.focal * pc[:, 0] / d + self.width / 2.0 - 0.5
        v = -self.focal * pc[:, 1] / d + self.height / 2.0 - 0.5
        return np.where(ok[:, None], np.stack([u, v], axis=1), np.nan)

    def cell_fractions(self, mask: np.ndarray, cam_pos, cam_mat) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Weed fraction per cell from a weed mask (H, W) of 0/1 (any numeric dtype).

        Args:
            mask: the segmented frame.
            cam_pos: (3,) camera position [m]; cam_mat: (3, 3) orientation, columns = camera axes
                in the world (``data.cam_xmat``), either true or estimated.

        Returns:
            (fraction, seen, coverage): (n,) float64 fraction (0 where unseen), (n,) bool, and the
            (n,) share of each cell the image covers.
        """
        n = self.n_cells
        fraction, coverage = np.zeros(n), np.zeros(n)
        ground = self.corners_on_ground(cam_pos, cam_mat)
        if ground is None:
            return fraction, np.zeros(n, bool), coverage
        res = self.resolution
        c0 = max(0, int(math.floor(ground[:, 0].min() / res)))
        c1 = min(self.cols - 1, int(math.floor(ground[:, 0].max() / res)))
        r0 = max(0, int(math.floor(ground[:, 1].min() / res)))
        r1 = min(self.rows - 1, int(math.floor(ground[:, 1].max() / res)))
        if c1 < c0 or r1 < r0:
            return fraction, np.zeros(n, bool), coverage
        # raster at about the image's ground sampling distance, a whole number of pixels per cell
        ppc = int(min(self.max_raster, max(2, round(res / self.ground_sampling_distance(float(cam_pos[2]))))))
        nr, nc = r1 - r0 + 1, c1 - c0 + 1
        # OpenCV pixel (i, j) of the raster has its centre at x = x0 + (j + 0.5) res / ppc
        dst = np.empty((4, 2), dtype=np.float32)
        dst[:, 0] = (ground[:, 0] - c0 * res) * (ppc / res) - 0.5
        dst[:, 1] = (ground[:, 1] - r0 * res) * (ppc / res) - 0.5
        H = cv2.getPerspectiveTransform(self._src, dst)
        both = np.empty((self.height, self.width, 2), dtype=np.float32)
        both[..., 0] = mask
        both[..., 1] = 1.0
        raster = cv2.warpPerspective(both, H, (nc * ppc, nr * ppc), flags=cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        cells = cv2.resize(raster, (nc, nr), interpolation=cv2.INTER_AREA).reshape(nr, nc, 2)
        weed, cover = cells[..., 0].astype(np.float64), cells[..., 1].astype(np.float64)
        seen_block = cover >= self.min_coverage
        idx = (np.arange(r0, r1 + 1)[:, None] * self.cols + np.arange(c0, c1 + 1)[None, :]).ravel()
        coverage[idx] = cover.ravel()
        fraction[idx] = np.where(seen_block, np.clip(weed / np.maximum(cover, 1e-9), 0.0, 1.0), 0.0).ravel()
        seen = np.zeros(n, bool)
        seen[idx] = seen_block.ravel()
        return fraction, seen, coverage
