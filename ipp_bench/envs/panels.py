"""The ``rgb_array`` of a graph env, numpy only: truth, belief mean, belief std and the path by time.

(The MuJoCo views, chase camera and downward camera, are :mod:`ipp_bench.sim.render`; the annotated
figure of ``ipp-bench evaluate --render`` is :mod:`ipp_bench.eval.figure`.)
"""

from __future__ import annotations

import numpy as np

# Anchors of matplotlib's viridis and plasma maps (public colour data), linearly interpolated.
_VIRIDIS = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], float)
_PLASMA = np.array([[13, 8, 135], [126, 3, 168], [204, 71, 120], [248, 149, 64], [240, 249, 33]], float)


def colormap(values: np.ndarray, lo: float, hi: float, anchors: np.ndarray = _VIRIDIS) -> np.ndarray:
    """Map ``values`` to uint8 RGB through piecewise-linear ``anchors`` over [lo, hi]."""
    t = np.clip((np.asarray(values, float) - lo) / max(hi - lo, 1e-12), 0.0, 1.0) * (len(anchors) - 1)
    i = np.minimum(t.astype(int), len(anchors) - 2)
    f = (t - i)[..., None]
    return ((1 - f) * anchors[i] + f * anchors[i + 1]).astype(np.uint8)


def _panel(grid: np.ndarray, px: int, lo: float, hi: float) -> np.ndarray:
    img = colormap(grid, lo, hi)
    return np.repeat(np.repeat(img, px, axis=0), px, axis=1)[::-1]  # y up


def _draw_path(img: np.ndarray, path: np.ndarray, res: float, px: int, t_max: float) -> None:
    """Draw waypoints (t, x, y, z) as a polyline coloured by time; dots grow with altitude."""
    h = img.shape[0]
    scale = px / res
    if len(path) == 0:
        return
    pts = []
    for a, b in zip(path[:-1], path[1:]):
        n = max(int(np.linalg.norm(b[1:3] - a[1:3]) * scale), 1)
        pts.append(a + np.linspace(0, 1, n, endpoint=False)[:, None] * (b - a))
    pts.append(path[-1:])
    pts = np.concatenate(pts)
    cols = colormap(pts[:, 0], 0.0, t_max, _PLASMA)
    u = np.clip((pts[:, 1] * scale).astype(int), 0, img.shape[1] - 1)
    v = np.clip(h - 1 - (pts[:, 2] * scale).astype(int), 0, h - 1)
    for du in (-1, 0, 1):
        for dv in (-1, 0, 1):
            img[np.clip(v + dv, 0, h - 1), np.clip(u + du, 0, img.shape[1] - 1)] = cols
    for t, x, y, z in path:
        r = max(2, int(round(z / 4)))
        cu, cv = int(x * scale), h - 1 - int(y * scale)
        img[max(cv - r, 0):cv + r + 1, max(cu - r, 0):cu + r + 1] = colormap(t, 0.0, t_max, _PLASMA)
    cu, cv = int(path[-1, 1] * scale), h - 1 - int(path[-1, 2] * scale)
    img[max(cv - 3, 0):cv + 4, max(cu - 3, 0):cu + 4] = (255, 0, 0)


def render_mission(mission, size: int = 240) -> np.ndarray:
    """(H, W, 3) uint8: ground truth | belief mean | belief std with the path coloured by time."""
    g = mission.config.grid
    px = max(2, size // max(g.rows, g.cols))
    shape = (g.rows, g.cols)
    std = np.sqrt(mission.belief.variance).reshape(shape)
    prior_std = np.sqrt(mission.config.gp.signal_variance + mission.config.gp.nugget)
    panels = [
        _panel(mission.truth, px, 0.0, 1.0),
        _panel(mission.belief.mean.reshape(shape), px, 0.0, 1.0),
        _panel(std, px, 0.0, prior_std),
    ]
    for path in getattr(mission, "paths", None) or [mission.path]:  # a team: one path per UAV
        for p in panels[1:]:
            _draw_path(p, np.asarray(path, dtype=float), g.resolution, px, mission.budget_s)
    gap = np.full((panels[0].shape[0], 4, 3), 255, np.uint8)
    row = [panels[0]]
    for p in panels[1:]:
        row += [gap, p]
    return np.ascontiguousarray(np.concatenate(row, axis=1))
