"""The figure of one episode (``ipp-bench evaluate --render out.png``): what a newcomer can read.

Three map panels with titles and colour bars: the ground truth with its evaluation ROI outlined,
the belief mean, and the belief standard deviation with the flown path coloured by mission time
(its own colour bar), waypoints marked by altitude level, start and end in the legend. Drawn on
matplotlib's Agg canvas through :class:`matplotlib.figure.Figure` (no pyplot, no display); needs
the ``eval`` extra. ``env.render()`` stays the numpy-only ``rgb_array`` of the gymnasium API.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..core.config import cell_centre
from ..core.data import write_atomically

FIGURE_EXTRA_MESSAGE = 'the --render figure needs matplotlib: pip install "ipp-bench[eval]"'


def require_figure() -> None:
    """Raise ImportError (naming the extra) now if :func:`save_episode_figure` could not draw."""
    try:
        import matplotlib.figure  # noqa: F401
    except ImportError:
        raise ImportError(FIGURE_EXTRA_MESSAGE) from None


def save_episode_figure(mission, path: str | Path, title: str = "") -> Path:
    """Write the figure of ``mission`` (after its episode) to ``path`` (PNG)."""
    try:
        from matplotlib import colormaps
        from matplotlib.collections import LineCollection
        from matplotlib.figure import Figure
        from matplotlib.lines import Line2D
    except ImportError:
        raise ImportError(FIGURE_EXTRA_MESSAGE) from None
    cfg = mission.config
    g = cfg.grid
    width, height = g.size_m
    extent = (0.0, width, 0.0, height)
    shape = (g.rows, g.cols)
    std = np.sqrt(np.maximum(mission.belief.variance, 0.0)).reshape(shape)
    prior_std = math.sqrt(cfg.gp.signal_variance + getattr(cfg.gp, "nugget", 0.0))
    fig = Figure(figsize=(15.5, 4.8), layout="constrained")
    axes = fig.subplots(1, 3)
    panels = [
        (mission.truth, "ground truth (ROI: truth >= mu_th outlined)", "field value", 0.0, 1.0, "viridis"),
        (mission.belief.mean.reshape(shape), "belief mean", "field value", 0.0, 1.0, "viridis"),
        (std, "belief standard deviation and the path", "standard deviation", 0.0, prior_std, "magma"),
    ]
    for ax, (data, name, label, lo, hi, cmap) in zip(axes, panels):
        im = ax.imshow(data, origin="lower", extent=extent, vmin=lo, vmax=hi, cmap=cmap)
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02, label=label)
    res = g.resolution
    xs, ys = cell_centre(np.arange(g.cols), res), cell_centre(np.arange(g.rows), res)
    axes[0].contour(xs, ys, mission.truth >= cfg.mission.mu_th, levels=[0.5], colors="white", linewidths=1.2)
    ax = axes[2]
    handles = []
    altitudes = cfg.graph.altitudes
    markers = ["o", "^", "s", "D"]
    paths = getattr(mission, "paths", None) or [mission.path]  # a team: one path per UAV
    for k, flown in enumerate(paths):
        way = np.asarray(flown, dtype=float)  # (t, x, y, z) per waypoint
        if len(way) > 1:
            segments = np.stack([way[:-1, 1:3], way[1:, 1:3]], axis=1)
            lines = LineCollection(segments, cmap=colormaps["plasma"], linewidths=2.2)
            lines.set_array(way[1:, 0])
            lines.set_clim(0.0, mission.budget_s)
            ax.add_collection(lines)
            if k == 0:
                fig.colorbar(lines, ax=ax, fraction=0.046, pad=0.08, label="mission time [s] (path colour)")
        for i, alt in enumerate(altitudes):
            level = np.abs(way[:, 3][:, None] - np.asarray(altitudes)[None, :]).argmin(axis=1) == i
            m = markers[i % len(markers)]
            ax.scatter(way[level, 1], way[level, 2], marker=m, s=18, facecolor="none", edgecolor="cyan",
                       linewidths=1.0)
            if k == 0:
                handles.append(Line2D([], [], ls="", marker=m, mfc="none", mec="cyan",
                                      label=f"waypoint at ~{alt:g} m"))
        ax.plot(*way[0, 1:3], "o", ms=8, mfc="lime", mec="black")
        ax.plot(*way[-1, 1:3], "X", ms=9, mfc="red", mec="black")
    handles += [Line2D([], [], ls="", marker="o", mfc="lime", mec="black", label="start"),
                Line2D([], [], ls="", marker="X", mfc="red", mec="black", label="end")]
    ax.legend(handles=handles, fontsize=7, loc="upper right", framealpha=0.8)
    m = mission.metrics()
    fig.suptitle(f"{title}   t = {m['time_s']:.1f} of {mission.budget_s:g} s, uncertainty reduction "
                 f"{m['uncertainty_reduction_pct']:.1f} %, RMSE reduction {m['rmse_reduction_pct']:.1f} %",
                 fontsize=11)
    out = Path(path)
    write_atomically(out, lambda tmp: fig.savefig(tmp, dpi=100, format="png"))
    return out
