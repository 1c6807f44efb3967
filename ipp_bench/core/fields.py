"""Ground-truth field families, seeded, values in [0, 1] on the grid.

- ``bernoulli``: independent cells, each 1 with a per-map probability (the paper's training maps).
- ``regions``: a smooth random field split into high- and low-value regions (evaluation maps).
- ``weed_patches``: a few clustered weed patches on bare soil (the MuJoCo deployment).

Every family gives at least one cell above 0.5 so that the evaluation ROI is never empty.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.ndimage import gaussian_filter

from .config import FIELD_FAMILIES, GridConfig, cell_centre


def bernoulli(grid: GridConfig, rng: np.random.Generator) -> np.ndarray:
    """Independent Bernoulli cells; the occupancy probability is drawn per map from U(0.2, 0.5)."""
    p = rng.uniform(0.2, 0.5)
    field = (rng.random((grid.rows, grid.cols)) < p).astype(np.float64)
    if not field.any():
        field[rng.integers(grid.rows), rng.integers(grid.cols)] = 1.0
    return field


def _smooth_noise(grid: GridConfig, rng: np.random.Generator, sigma_m: float) -> np.ndarray:
    noise = rng.standard_normal((grid.rows, grid.cols))
    s = gaussian_filter(noise, sigma=sigma_m / grid.resolution, mode="wrap")
    return (s - s.min()) / max(s.max() - s.min(), 1e-12)


def regions(grid: GridConfig, rng: np.random.Generator) -> np.ndarray:
    """Smooth field thresholded at a random quantile: high regions in [0.6, 1], low in [0, 0.3].

    The high fraction of the map is drawn from U(0.2, 0.4); the structure has a correlation length
    of a few metres, like the GP prior, so a belief can learn it from neighbouring measurements.
    """
    s = _smooth_noise(grid, rng, sigma_m=rng.uniform(3.0, 5.0))
    high_fraction = rng.uniform(0.2, 0.4)
    th = np.quantile(s, 1.0 - high_fraction)
    high = s >= th
    field = np.empty_like(s)
    field[high] = 0.6 + 0.4 * (s[high] - th) / max(s.max() - th, 1e-12)
    field[~high] = 0.3 * s[~high] / max(th, 1e-12)
    return np.clip(field, 0.0, 1.0)


def weed_patches(grid: GridConfig, rng: np.random.Generator) -> np.ndarray:
    """Weed density: 3-6 elliptic Gaussian patches (radius 2-5 m, peak 0.6-1) over sparse weeds."""
    width, height = grid.size_m
    x = cell_centre(np.arange(grid.cols), grid.resolution)
    y = cell_centre(np.arange(grid.rows), grid.resolution)
    X, Y = np.meshgrid(x, y)
    field = np.zeros((grid.rows, grid.cols))
    for _ in range(int(rng.integers(3, 7))):
        cx, cy = rng.uniform(0.1, 0.9) * width, rng.uniform(0.1, 0.9) * height
        rx, ry = rng.uniform(2.0, 5.0, size=2)
        angle = rng.uniform(0, np.pi)
        dx, dy = X - cx, Y - cy
        u = (np.cos(angle) * dx + np.sin(angle) * dy) / rx
        v = (-np.sin(angle) * dx + np.cos(angle) * dy) / ry
        field = np.maximum(field, rng.uniform(0.6, 1.0) * np.exp(-0.5 * (u * u + v * v)))
    scattered = rng.random((grid.rows, grid.cols)) < 0.03
    field[scattered] = np.maximum(field[scattered], rng.uniform(0.1, 0.3, scattered.sum()))
    field[field < 0.02] = 0.0
    return np.clip(field, 0.0, 1.0)


FIELDS: dict[str, Callable[[GridConfig, np.random.Generator], np.ndarray]] = {
    "bernoulli": bernoulli,
    "regions": regions,
    "weed_patches": weed_patches,
}
assert tuple(FIELDS) == FIELD_FAMILIES


def make_field(name: str, grid: GridConfig, rng: np.random.Generator) -> np.ndarray:
    """A (rows, cols) ground truth of family ``name`` drawn with ``rng``."""
    try:
        fn = FIELDS[name]
    except KeyError:
        raise ValueError(f"unknown field family {name!r}: valid are {sorted(FIELDS)}") from None
    return fn(grid, rng)
