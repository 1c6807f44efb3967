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
    margin_texels: int = 1  # [texels] ring of every plant whose colour mixes with the soil's (0: none, v0)
    margin_weed_share: tuple[float, float] = (0.5, 1.0)  # [-] range of the weed colour's share in that ring
    fine_structure: float = 1.0  # [-] weight of texel-scale structure in the plant score (0: none, v0)

    def __post_init__(self) -> None:
        if not (isinstance(self.margin_texels, int) and 0 <= self.margin_texels <= 8):
            raise ValueError(f"TexturePalette.margin_texels must be an integer in [0, 8], got {self.margin_texels!r}")
        if not 0.0 <= self.fine_structure <= 5.0:
            raise ValueError(f"TexturePalette.fine_structure must be in [0, 5], got {self.fine_structure}")
        lo, hi = self.margin_weed_share
        if not 0.0 <= lo <= hi <= 1.0:
            raise ValueError(f"TexturePalette.margin_weed_share must satisfy 0 <= low <= high <= 1, "
                             f"got {self.margin_weed_share}")

    @staticmethod
    def v0() -> TexturePalette:
        """The v0 texture: plant margins keep the weed colour."""
        return TexturePalette(margin_texels=0, fine_structure=0.0)


def hsv_to_rgb(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectorised HSV (hue in degrees) to RGB in [0, 1], shape (..., 3)."""
    h6 = np.mod(h, 360.0) / 60.0
    out = []
    for n in (5.0, 3.0, 1.0):  # r, g, b: v - v s clip(min(k, 4 - k), 0, 1), k = (n + h/60) mod 6
        k = np.mod(n + h6, 6.0)
        out.append(v - v * s * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0))
    return np.stack(out, axis=-1)


def _interp_matrix(n_out: int, n_in: int, wrap: bool) -> np.ndarray:
    """(n_out, n_in) linear interpolation from ``n_in`` cell centres to ``n_out`` finer centres."""
    x = (np.arange(n_out) + 0.5) * n_in / n_out - 0.5
    i0 = np.floor(x).astype(np.int64)
    f = (x - i0).astype(np.float32)
    i1 = i0 + 1
    if wrap:
        i0, i1 = i0 % n_in, i1 % n_in
    else:
        i0, i1 = np.clip(i0, 0, n_in - 1), np.clip(i1, 0, n_in - 1)
    m = np.zeros((n_out, n_in), dtype=np.float32)
    rows = np.arange(n_out)
    np.add.at(m, (rows, i0), 1.0 - f)
    np.add.at(m, (rows, i1), f)
    return m


def _upsample(coarse: np.ndarray, shape: tuple[int, int], wrap: bool) -> np.ndarray:
    """Separable bilinear upsampling of ``coarse`` to ``shape`` (two small matrix products)."""
    ay = _interp_matrix(shape[0], coarse.shape[0], wrap)
    ax = _interp_matrix(shape[1], coarse.shape[1], wrap)
    return (ay @ coarse.astype(np.float32)) @ ax.T


def _noise(rng: np.random.Generator, shape: tuple[int, int], sigma: float) -> np.ndarray:
    """Zero-mean, unit-std Gaussian-smoothed white noise (sigma in texels), float32.

    Wide kernels are applied on a coarser grid and upsampled bilinearly (same look, ~10x faster).
    """
    factor = max(1, int(sigma // 2.5))
    while shape[0] % factor or shape[1] % factor:
        factor -= 1
    coarse = (shape[0] // factor, shape[1] // factor)
    field = ndimage.gaussian_filter(rng.standard_normal(coarse, dtype=np.float32), sigma=sigma / factor, mode="wrap")
    if factor > 1:
        field = _upsample(field, shape, wrap=True)
    field -= field.mean()
    field /= field.std() + 1e-12
    return field


def _upsample_field(field: np.ndarray, p: int) -> np.ndarray:
    """Bilinear interpolation of cell values at texel centres (edge cells held constant)."""
    return _upsample(field, (field.shape[0] * p, field.shape[1] * p), wrap=False)


def _blocks(image: np.ndarray, rows: int, cols: int, p: int) -> np.ndarray:
    return image.reshape(rows, p, cols, p).transpose(0, 2, 1, 3).reshape(rows * cols, p * p)


def _unblocks(blocks: np.ndarray, rows: int, cols: int, p: int) -> np.ndarray:
    return blocks.reshape(rows, cols, p, p).transpose(0, 2, 1, 3).reshape(rows * p, cols * p)


def _check(field: np.ndarray, texels_per_cell: int) -> np.ndarray:
    field = np.asarray(field, dtype=np.float64)
    if field.ndim != 2 or np.any(field < 0.0) or np.any(field > 1.0):
        raise ValueError(f"field must be a 2D array with values in [0, 1], got shape {field.shape}")
    if texels_per_cell < 4:
        raise ValueError(f"texels_per_cell must be >= 4, got {texels_per_cell}")
    return field


def _mask_from_score(field: np.ndarray, score: np.ndarray, p: int) -> np.ndarray:
    """The round(value * p^2) highest-scoring texels of every cell."""
    rows, cols = field.shape
    blocks = _blocks(score, rows, cols, p)
    order = np.argsort(blocks, axis=1)
    n_weed = np.rint(field.ravel() * p * p).astype(np.int64)
    ranks = np.empty_like(order)
    np.put_along_axis(ranks, order, np.broadcast_to(np.arange(p * p), order.shape), axis=1)
    return _unblocks(ranks >= (p * p - n_weed)[:, None], rows, cols, p)


def _plant_score(field: np.ndarray, rng: np.random.Generator, p: int, fine: float):
    """Score whose top texels per cell are weeds, and the clump and leaf noise it was built from.

    Clumps (~0.25 cell) with leaves (~0.05 cell) on top, drawn towards weedy neighbours (the
    interpolated field) so that patches do not end in straight cell borders; ``fine`` > 0 adds
    texel-scale structure (ragged leaf margins, seedlings of a few texels) that a coarse image
    cannot resolve.
    """
    shape = (field.shape[0] * p, field.shape[1] * p)
    clumps, leaves = _noise(rng, shape, 0.09 * p), _noise(rng, shape, 0.025 * p)
    score = clumps + 0.45 * leaves + 3.0 * _upsample_field(field, p)
    if fine > 0.0:
        score = score + fine * _noise(rng, shape, 0.6)
    return score, clumps, leaves


def weed_mask(field: np.ndarray, rng: np.random.Generator, texels_per_cell: int = 64,
              palette: TexturePalette | None = None) -> np.ndarray:
    """Boolean weed mask with exactly ``round(field[r, c] * texels_per_cell**2)`` texels per cell."""
    field = _check(field, texels_per_cell)
    fine = palette.fine_structure if palette is not None else 0.0
    return _mask_from_score(field, _plant_score(field, rng, texels_per_cell, fine)[0], texels_per_cell)


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
    field = _check(field, texels_per_cell)
    p = texels_per_cell
    pal = palette
    shape = (field.shape[0] * p, field.shape[1] * p)
    # plants: clumps (~0.25 cell) with leaves (~0.05 cell) on top, drawn towards weedy
    # neighbours (the interpolated field) so patches do not end in straight cell borders
    score, clumps, leaves = _plant_score(field, rng, p, pal.fine_structure)
    mask = _mask_from_score(field, score, p)

    moisture = _noise(rng, shape, 0.6 * p)  # large damp/dry patches of soil
    patch = _noise(rng, shape, 0.15 * p)  # mid-scale: plant hue, clutter kind
    clutter = _noise(rng, shape, 0.04 * p)  # small clumps of straw, moss, stones
    grain = rng.standard_normal(shape, dtype=np.float32)

    h = pal.soil_hsv[0] + pal.soil_jitter[0] * (0.7 * moisture - 0.7 * patch)
    s = pal.soil_hsv[1] + pal.soil_jitter[1] * (0.6 * moisture + 0.4 * grain)
    v = pal.soil_hsv[2] + pal.soil_jitter[2] * (-0.8 * moisture + 0.6 * grain)

    # soil clutter: straw, moss and stones (never on weeds)
    soil = ~mask
    total = pal.straw_fraction + pal.moss_fraction + pal.stone_fraction
    if soil.any() and total > 0:
        cluttered = soil & (clutter >= np.quantile(clutter[soil], 1.0 - total))
        edges = np.quantile(patch, [pal.straw_fraction / total, (pal.straw_fraction + pal.moss_fraction) / total])
        for hsv, sel in (
            (pal.straw_hsv, cluttered & (patch < edges[0])),
            (pal.moss_hsv, cluttered & (patch >= edges[0]) & (patch < edges[1])),
            (pal.stone_hsv, cluttered & (patch >= edges[1])),
        ):
            g = grain[sel]
            h[sel] = hsv[0] + 3.0 * g
            s[sel] = hsv[1] + 0.03 * g
            v[sel] = hsv[2] + 0.05 * g

    # weeds: hue per plant (mid scale), shading of leaves (fine scale)
    plant, leaf, g = patch[mask], leaves[mask], grain[mask]
    h[mask] = pal.weed_hsv[0] + pal.weed_jitter[0] * plant
    s[mask] = pal.weed_hsv[1] + pal.weed_jitter[1] * (0.5 * plant + 0.5 * g)
    v[mask] = pal.weed_hsv[2] + pal.weed_jitter[2] * (0.8 * leaf + 0.3 * g)

    rgb = hsv_to_rgb(h, np.clip(s, 0.0, 1.0), np.clip(v, 0.04, 1.0))
    if pal.margin_texels > 0 and mask.any() and (~mask).any():
        # plant margins: leaf edges over soil, colours mixed (the weed/soil colour ranges overlap there)
        depth = ndimage.distance_transform_cdt(mask, metric="chessboard")
        ring = mask & (depth <= pal.margin_texels)
        lo, hi = pal.margin_weed_share
        share = lo + (hi - lo) * (0.5 + 0.5 * np.tanh(grain[ring]))
        soil_rgb = hsv_to_rgb(np.full(share.shape, pal.soil_hsv[0]), np.full(share.shape, pal.soil_hsv[1]),
                              np.full(share.shape, pal.soil_hsv[2]))
        rgb[ring] = share[:, None] * rgb[ring] + (1.0 - share[:, None]) * soil_rgb
    return (rgb * 255.0 + 0.5).astype(np.uint8), mask
