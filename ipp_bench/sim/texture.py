"""Ground texture of the weed field: weed green on soil, generated per seed.

Pure numpy/scipy (no MuJoCo). Every grid cell is ``texels_per_cell`` texels
square; the weed mask inside a cell covers exactly ``round(value * texels^2)``
texels, so the ground truth the belief is scored against is the fraction the
camera could at best recover. Plants are smooth noise blobs (several scales, so
they cross cell borders naturally); colours vary per plant and per texel, and
soil carries moisture patches, straw, greenish moss and grey stones that sit
near, but outside, the weed colour range: the threshold has work to do.

Texture rows follow grid rows: texel row ``i`` lies at y = (i + 0.5) / texels_per_cell
* resolution, column ``j`` at x likewise (the scene flips it for OpenGL).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage


@dataclass(frozen=True)
class TexturePalette:
    """HSV colour statistics (hue in degrees, saturation and value in [0, 1])."""

    soil_hsv: tuple[float, float, float] = (26.0, 0.48, 0.42)
    soil_jitter: tuple[float, float, float] = (4.0, 0.07, 0.06)
    weed_hsv: tuple[float, float, float] = (102.0, 0.62, 0.52)
    weed_jitter: tuple[float, float, float] = (12.0, 0.10, 0.12)
    straw_hsv: tuple[float, float, float] = (46.0, 0.42, 0.68)  # dry residue: yellow, not green
    moss_hsv: tuple[float, float, float] = (75.0, 0.16, 0.45)  # greenish tint, too grey to count
    stone_hsv: tuple[float, float, float] = (30.0, 0.05, 0.62)
    straw_fraction: float = 0.05  # of soil texels
    moss_fraction: float = 0.04
    stone_fraction: float = 0.02


def hsv_to_rgb(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectorised HSV (hue in degrees) to RGB in [0, 1], shape (..., 3)."""
    h = np.mod(h, 360.0) / 60.0
    i = np.floor(h).astype(np.int64) % 6
    f = h - np.floor(h)
    p = v * (1.0 - s)
    q = v * (1.0 - s * f)
    t = v * (1.0 - s * (1.0 - f))
    r = np.choose(i, [v, q, p, p, t, v])
    g = np.choose(i, [t, v, v, q, p, p])
    b = np.choose(i, [p, p, t, v, v, q])
    return np.stack([r, g, b], axis=-1)


def _noise(rng: np.random.Generator, shape: tuple[int, int], sigma: float) -> np.ndarray:
    """Zero-mean, unit-std Gaussian-smoothed white noise (sigma in texels).

    Wide kernels are applied on a coarser grid and upsampled bilinearly (same look, ~10x faster).
    """
    factor = max(1, int(sigma // 4))
    while shape[0] % factor or shape[1] % factor:
        factor -= 1
    coarse = (shape[0] // factor, shape[1] // factor)
    field = ndimage.gaussian_filter(rng.standard_normal(coarse), sigma=sigma / factor, mode="wrap")
    if factor > 1:
        field = ndimage.zoom(field, factor, order=1, mode="grid-wrap", grid_mode=True)
    return (field - field.mean()) / (field.std() + 1e-12)


def _upsample_field(field: np.ndarray, p: int) -> np.ndarray:
    """Bilinear interpolation of cell values at texel centres (edge cells held constant)."""
    rows, cols = field.shape
    y = (np.arange(rows * p) + 0.5) / p - 0.5
    x = (np.arange(cols * p) + 0.5) / p - 0.5
    yy, xx = np.meshgrid(y, x, indexing="ij")
    return ndimage.map_coordinates(field, [yy, xx], order=1, mode="nearest")


def _blocks(image: np.ndarray, rows: int, cols: int, p: int) -> np.ndarray:
    return image.reshape(rows, p, cols, p).transpose(0, 2, 1, 3).reshape(rows * cols, p * p)


def _unblocks(blocks: np.ndarray, rows: int, cols: int, p: int) -> np.ndarray:
    return blocks.reshape(rows, cols, p, p).transpose(0, 2, 1, 3).reshape(rows * p, cols * p)


def weed_mask(field: np.ndarray, rng: np.random.Generator, texels_per_cell: int = 64) -> np.ndarray:
    """Boolean weed mask with exactly ``round(field[r, c] * texels_per_cell**2)`` texels per cell."""
    field = np.asarray(field, dtype=np.float64)
    if field.ndim != 2 or np.any(field < 0.0) or np.any(field > 1.0):
        raise ValueError(f"field must be a 2D array with values in [0, 1], got shape {field.shape}")
    if texels_per_cell < 4:
        raise ValueError(f"texels_per_cell must be >= 4, got {texels_per_cell}")
    rows, cols = field.shape
    p = texels_per_cell
    shape = (rows * p, cols * p)
    # plants: clumps (~0.25 cell) with leaves (~0.05 cell) on top, drawn towards weedy
    # neighbours (the interpolated field) so patches do not end in straight cell borders
    score = _noise(rng, shape, 0.09 * p) + 0.45 * _noise(rng, shape, 0.025 * p)
    score += 3.0 * _upsample_field(field, p)
    blocks = _blocks(score, rows, cols, p)
    order = np.argsort(blocks, axis=1, kind="stable")
    ranks = np.empty_like(order)
    np.put_along_axis(ranks, order, np.broadcast_to(np.arange(p * p), order.shape), axis=1)
    n_weed = np.rint(field.ravel() * p * p).astype(np.int64)
    mask = ranks >= (p * p - n_weed)[:, None]
    return _unblocks(mask, rows, cols, p)


def weed_texture(
    field: np.ndarray,
    rng: np.random.Generator,
    texels_per_cell: int = 64,
    palette: TexturePalette = TexturePalette(),
) -> tuple[np.ndarray, np.ndarray]:
    """Generates the ground texture of a weed field.

    Args:
        field: (rows, cols) weed fraction per cell in [0, 1] (the ground truth).
        rng: generator; the same state gives the same texture.
        texels_per_cell: texture resolution, texels per cell side.
        palette: colour statistics.

    Returns:
        (rgb, mask): (rows*p, cols*p, 3) uint8 texture in grid-row order and the boolean weed mask.
    """
    mask = weed_mask(field, rng, texels_per_cell)
    shape = mask.shape
    p = texels_per_cell
    pal = palette

    # per-texel HSV of soil: moisture (large patches) and grain (fine)
    moisture = _noise(rng, shape, 0.6 * p)
    grain = rng.standard_normal(shape)
    h = pal.soil_hsv[0] + pal.soil_jitter[0] * _noise(rng, shape, 0.3 * p)
    s = pal.soil_hsv[1] + pal.soil_jitter[1] * (0.6 * moisture + 0.4 * grain)
    v = pal.soil_hsv[2] + pal.soil_jitter[2] * (-0.8 * moisture + 0.6 * grain)

    # soil clutter: straw, moss and stones in small clumps (never on weeds)
    clutter = _noise(rng, shape, 0.04 * p)
    kind = _noise(rng, shape, 0.15 * p)
    soil = ~mask
    lo = np.quantile(clutter[soil], 1.0 - (pal.straw_fraction + pal.moss_fraction + pal.stone_fraction)) if soil.any() else np.inf
    cluttered = soil & (clutter >= lo)
    edges = np.quantile(kind, [pal.straw_fraction / (pal.straw_fraction + pal.moss_fraction + pal.stone_fraction),
                               (pal.straw_fraction + pal.moss_fraction) / (pal.straw_fraction + pal.moss_fraction + pal.stone_fraction)])
    for hsv, sel in (
        (pal.straw_hsv, cluttered & (kind < edges[0])),
        (pal.moss_hsv, cluttered & (kind >= edges[0]) & (kind < edges[1])),
        (pal.stone_hsv, cluttered & (kind >= edges[1])),
    ):
        h[sel] = hsv[0] + 3.0 * grain[sel]
        s[sel] = hsv[1] + 0.03 * grain[sel]
        v[sel] = hsv[2] + 0.05 * grain[sel]

    # weeds: hue per plant (mid-scale), shading of leaves (fine scale)
    leaf = _noise(rng, shape, 0.02 * p)
    plant = _noise(rng, shape, 0.12 * p)
    h[mask] = pal.weed_hsv[0] + pal.weed_jitter[0] * plant[mask]
    s[mask] = pal.weed_hsv[1] + pal.weed_jitter[1] * (0.5 * plant[mask] + 0.5 * grain[mask])
    v[mask] = pal.weed_hsv[2] + pal.weed_jitter[2] * (0.8 * leaf[mask] + 0.3 * grain[mask])

    rgb = hsv_to_rgb(h, np.clip(s, 0.0, 1.0), np.clip(v, 0.04, 1.0))
    return np.round(rgb * 255.0).astype(np.uint8), mask
