"""Size limits of an IPP problem, checked from its config before anything is built.

Every field of :mod:`ipp_bench.config` is valid on its own; some combinations are not affordable:
a map so large that the roadmap's dense Laplacian (the positional encoding) or the belief's
covariance does not fit in memory, a measurement spacing or altitude range that puts hundreds of
thousands of measurements into one leg's update, or a budget and speed that make an episode of
millions of legs. :func:`check_sizes` estimates each from the config alone and refuses the
config with one line naming the fields, what it would need and the limit, so that the mistake
costs nothing (the env calls it first, before the roadmap is built).

The limits are far above every task of the suite (the largest, 30 x 30 cells, needs ~26 MiB for
its Laplacian and at most a few MiB per leg update) and well below what a workstation has.
"""

from __future__ import annotations

import math

from .config import IPPConfig
from .sensor import Sensor

#: [bytes] the largest single array an estimate may reach (dense Laplacian, covariance, leg update)
ARRAY_LIMIT_BYTES = 2 * 2**30
#: the most cell widths an episode may fly (budget_s x speed / resolution): about the most legs
MAX_FLIGHT_CELLS = 20_000

_FLOAT = 8  # bytes of a float64


def _gib(n_bytes: float) -> str:
    return f"{n_bytes / 2**30:.3g} GiB"


def roadmap_nodes(config: IPPConfig) -> int:
    """Nodes of the task's roadmap: a node per cell and level (``grid``), or ``n_samples``."""
    g = config.graph
    return config.grid.n_cells * len(g.altitudes) if g.sampling == "grid" else g.n_samples


def belief_states(config: IPPConfig) -> int:
    """States of the belief: a cell each, plus a persistent camera error per cell and resolution
    factor when the task models it (:class:`~ipp_bench.belief.PersistentErrorBelief`)."""
    n = config.grid.n_cells
    s = config.sensor
    if not s.camera_error_states:
        return n
    factors = (s.persistent_var > 0 or s.noise_floor < 1.0) + (s.persistent_var_binned > 0 or s.noise_floor < 1.0)
    return n * (1 + max(int(factors), 1))


def leg_update_rows(config: IPPConfig) -> tuple[int, float, int]:
    """(rows, longest leg [m], cells per look) of the largest leg update: the measurements along
    the longest leg across the map and its altitude range, times the cells of the widest look."""
    grid, graph, mission = config.grid, config.graph, config.mission
    width, height = grid.size_m
    longest = math.sqrt(width**2 + height**2 + (graph.altitudes[-1] - graph.altitudes[0]) ** 2)
    samples = int(longest / mission.measurement_spacing) + 1
    side = Sensor(grid, config.sensor).footprint_side(graph.altitudes[-1])
    per_axis = min(grid.cols, math.ceil(side / grid.resolution) + 1), min(grid.rows, math.ceil(side / grid.resolution) + 1)
    cells = per_axis[0] * per_axis[1]
    return samples * cells, longest, cells


def check_sizes(config: IPPConfig) -> None:
    """Refuse a config whose episodes would not fit in memory or would not end.

    Raises:
        ValueError: one line naming the fields, the memory (or legs) needed and the limit.
    """
    grid, graph, mission = config.grid, config.graph, config.mission
    nodes = roadmap_nodes(config)
    need = nodes**2 * _FLOAT
    if need > ARRAY_LIMIT_BYTES:
        most = int(math.sqrt(ARRAY_LIMIT_BYTES / _FLOAT))
        what = (f"grid.rows x grid.cols x len(graph.altitudes) = {grid.rows} x {grid.cols} x {len(graph.altitudes)}"
                if graph.sampling == "grid" else f"graph.n_samples = {graph.n_samples}")
        raise ValueError(f"{what} = {nodes} roadmap nodes is too large: the positional encoding's dense "
                         f"Laplacian needs {_gib(need)} (limit {_gib(ARRAY_LIMIT_BYTES)}, at most {most} nodes)")
    states = belief_states(config)
    need = states**2 * _FLOAT
    if need > ARRAY_LIMIT_BYTES:
        raise ValueError(f"grid.rows x grid.cols = {grid.rows} x {grid.cols} cells is too large: the belief's "
                         f"covariance of {states} states needs {_gib(need)} (limit {_gib(ARRAY_LIMIT_BYTES)})")
    rows, longest, cells = leg_update_rows(config)
    need = rows**2 * _FLOAT
    if need > ARRAY_LIMIT_BYTES:
        most_rows = math.sqrt(ARRAY_LIMIT_BYTES / _FLOAT)
        spacing = longest / max(most_rows / cells - 1, 1e-12)
        raise ValueError(
            f"mission.measurement_spacing = {mission.measurement_spacing:g} m with graph.altitudes = "
            f"{list(graph.altitudes)} is too fine: a leg of {longest:.4g} m (across the map and its altitude "
            f"range) takes {rows // cells} measurements of up to {cells} cells, whose update needs {_gib(need)} "
            f"(limit {_gib(ARRAY_LIMIT_BYTES)}); raise measurement_spacing to at least {spacing:.3g} m or "
            "lower the highest altitude")
    flight_cells = mission.budget_s * mission.speed / grid.resolution
    if flight_cells > MAX_FLIGHT_CELLS:
        raise ValueError(
            f"mission.budget_s x mission.speed = {mission.budget_s:g} s x {mission.speed:g} m/s is "
            f"{mission.budget_s * mission.speed:.4g} m of flight, {flight_cells:.4g} cell widths: more than the "
            f"{MAX_FLIGHT_CELLS} an episode may fly (its legs would not end); valid: budget_s x speed <= "
            f"{MAX_FLIGHT_CELLS * grid.resolution:g} m on this grid")


__all__ = ["ARRAY_LIMIT_BYTES", "MAX_FLIGHT_CELLS", "belief_states", "check_sizes", "leg_update_rows",
           "roadmap_nodes"]
