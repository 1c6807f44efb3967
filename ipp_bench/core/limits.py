"""Size limits of an IPP problem, checked from its config before anything is built.

Every field of :mod:`ipp_bench.core.config` is valid on its own; some combinations are not affordable:
a map so large that the roadmap's positional encoding or the dense belief's covariance does not
fit in memory, a measurement spacing or altitude range that puts hundreds of thousands of
measurements into one leg's update, or a budget and speed that make an episode of millions of
legs. :func:`check_sizes` estimates each from the config alone and refuses the config with one
line naming the fields, what it would need and the limit, so that the mistake costs nothing (the
env calls it first, before the roadmap is built).

The limits are far above every task of the suite (the largest, 30 x 30 cells, needs ~0.1 GiB for
its Laplacian and at most a few MiB per leg update) and well below what a workstation has. A
128 x 128 map passes the roadmap and encoding check (the sparse eigensolver, ~0.2 GB)
and is refused by the dense belief's, which names the scalable belief,
:class:`ipp_bench.core.belief_window.WindowBelief`; a task that holds the window belief
(``gp.belief = "window"``) is checked against the window belief's memory instead.
"""

from __future__ import annotations

import math

from .belief_window import DEFAULT_GROUP_SPAN, MASK_CACHE, task_window
from .config import IPPConfig
from .roadmap import DENSE_ENCODING_MAX_NODES
from .sensor import Sensor

#: [bytes] the most memory an estimate may reach (the encoding's solver, the dense belief's prior, a leg update)
ARRAY_LIMIT_BYTES = 2 * 2**30
#: decisions after which an episode that has not ended is a planner bug (the episode loop's limit)
MAX_DECISIONS = 100_000
#: the most cell widths an episode may fly (budget_s x speed / resolution): about its most legs,
#: so that an episode of short legs stays within :data:`MAX_DECISIONS`
MAX_FLIGHT_CELLS = MAX_DECISIONS

_FLOAT = 8  # bytes of a float64
#: [-] float64 arrays of n x n that building the dense prior holds at once (distances, the Matern
#: kernel's temporaries, the belief's copy): tracemalloc's peak of ``GPBelief.from_grid`` is 5.00 n^2
#: floats on 30 x 30 and 50 x 50 cells
DENSE_BELIEF_ARRAYS = 5
#: the sparse encoding's LU: ~``_LU_FILL`` k N^0.25 factor entries per node (SuperLU, minimum degree
#: on A + A^T, symmetric mode), fitted on grid roadmaps of 48 x 48 to 181 x 181 cells x 2 levels
#: (180 to 337 per node at k = 20); on 3 levels, k = 40 and uniform sampling the fill is below the fit
_LU_FILL = 1.1
#: [-] float64 arrays of N x N the dense encoding holds at its peak (adjacency, its transpose's maximum,
#: the scaled products, the identity, L): 4.1 N^2 floats measured at 1 800 nodes (102 MB)
_DENSE_LAPLACIAN_ARRAYS = 5
_LU_ENTRY = 16  # [bytes] per factor entry: value, index and SuperLU's own (peak RSS 174 MB at 128 x 128)
_SPARSE_FIXED = 8 * 2**20  # [bytes] the sparse solver's fixed workspace (measured peaks 16-40 MB at 40-64 cells square)


def _gib(n_bytes: float) -> str:
    return f"{n_bytes / 2**30:.3g} GiB"


def roadmap_nodes(config: IPPConfig) -> int:
    """Nodes of the task's roadmap: a node per cell and level (``grid``), or ``n_samples``."""
    g = config.graph
    return config.grid.n_cells * len(g.altitudes) if g.sampling == "grid" else g.n_samples


def belief_states(config: IPPConfig) -> int:
    """States of the belief: a cell each, plus a persistent camera error per cell and resolution
    factor when the task models it (:class:`~ipp_bench.core.belief.PersistentErrorBelief`)."""
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
    across = math.ceil(side / grid.resolution) + 1  # cells a look spans along one axis, at most
    cells = min(grid.cols, across) * min(grid.rows, across)
    return samples * cells, longest, cells


def encoding_bytes(config: IPPConfig) -> int:
    """[bytes] the roadmap and its positional encoding at their peak, by the solver the roadmap uses.

    Up to :data:`~ipp_bench.core.roadmap.DENSE_ENCODING_MAX_NODES` nodes, the dense N x N Laplacian's arrays; above
    it the sparse solver: its LU (an empirical fill, see ``_LU_FILL``), ARPACK's 2 pe_dim + 1 Lanczos
    vectors, the k-NN arrays and a fixed workspace. The estimate is 5-50 % above the measured peak
    (``benchmarks/bench_roadmap_scale.py``) on roadmaps of 40 x 40 to 256 x 256 cells, 2 and 3
    levels, k = 20 and 40, grid and uniform sampling.
    """
    return _encoding_bytes(roadmap_nodes(config), config.graph.k, config.graph.pe_dim)


def _encoding_bytes(nodes: int, k: int, dim: int) -> int:
    if nodes <= DENSE_ENCODING_MAX_NODES:
        return _DENSE_LAPLACIAN_ARRAYS * nodes**2 * _FLOAT
    per_node = _LU_ENTRY * _LU_FILL * k * nodes**0.25 + _FLOAT * (2 * dim + 1 + 8) + _FLOAT * 3 * k
    return int(nodes * per_node) + _SPARSE_FIXED


def dense_belief_bytes(config: IPPConfig) -> int:
    """[bytes] building the dense belief (:class:`~ipp_bench.core.belief.GPBelief`): its prior's peak."""
    return DENSE_BELIEF_ARRAYS * belief_states(config) ** 2 * _FLOAT


def window_belief_bytes(config: IPPConfig) -> int:
    """[bytes] the window belief (:class:`~ipp_bench.core.belief_window.WindowBelief`) at its largest: the
    band of n (2w + 1)^2 floats and the mean, the downdate's scratch for the largest fused group
    (``group_span`` + 2w cells square, its Gram matrix) and the cache of window masks at that size.
    95 MB measured at 128 x 128, w = 12 (``benchmarks/bench_belief_scale.py``); this gives 110 MB."""
    n, w = config.grid.n_cells, task_window(config.grid, config.gp)
    side = 2 * w + 1
    rect = min(config.grid.rows, DEFAULT_GROUP_SPAN + 2 * w) * min(config.grid.cols, DEFAULT_GROUP_SPAN + 2 * w)
    return n * side**2 * _FLOAT + n * _FLOAT + rect**2 * _FLOAT + MASK_CACHE * rect * side**2


def _most(fn, limit: float) -> int:
    """The largest n with fn(n) <= limit, fn increasing (bisection)."""
    lo, hi = 1, 1
    while fn(hi) <= limit:
        lo, hi = hi, hi * 2
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if fn(mid) <= limit else (lo, mid)
    return lo


def check_sizes(config: IPPConfig) -> None:
    """Refuse a config whose episodes would not fit in memory or would not end.

    Raises:
        ValueError: one line naming the fields, the memory (or legs) needed and the limit.
    """
    grid, graph, mission = config.grid, config.graph, config.mission
    nodes = roadmap_nodes(config)
    need = encoding_bytes(config)
    if need > ARRAY_LIMIT_BYTES:
        most = _most(lambda n: _encoding_bytes(n, graph.k, graph.pe_dim), ARRAY_LIMIT_BYTES)
        what = (f"grid.rows x grid.cols x len(graph.altitudes) = {grid.rows} x {grid.cols} x {len(graph.altitudes)}"
                if graph.sampling == "grid" else f"graph.n_samples = {graph.n_samples}")
        raise ValueError(f"{what} = {nodes} roadmap nodes is too large: the positional encoding's sparse "
                         f"eigensolver (k = {graph.k}) needs about {_gib(need)} (limit {_gib(ARRAY_LIMIT_BYTES)}, "
                         f"at most {most} nodes)")
    states = belief_states(config)
    if config.gp.belief == "window":
        need = window_belief_bytes(config)
        if need > ARRAY_LIMIT_BYTES:
            raise ValueError(
                f"grid.rows x grid.cols = {grid.rows} x {grid.cols} cells is too large for the window belief: its "
                f"band of {states} x {(2 * task_window(config.grid, config.gp) + 1) ** 2} covariances needs "
                f"{_gib(need)} "
                f"(limit {_gib(ARRAY_LIMIT_BYTES)}); lower gp.belief_window or the map's size")
    elif (need := dense_belief_bytes(config)) > ARRAY_LIMIT_BYTES:
        most = _most(lambda n: DENSE_BELIEF_ARRAYS * n**2 * _FLOAT, ARRAY_LIMIT_BYTES)
        raise ValueError(
            f"grid.rows x grid.cols = {grid.rows} x {grid.cols} cells is too large for the dense belief: its "
            f"covariance of {states} states needs {_gib(states**2 * _FLOAT)}, {_gib(need)} while its prior is built "
            f"(limit {_gib(ARRAY_LIMIT_BYTES)}, at most {most} states); a map this large needs the scalable belief "
            "ipp_bench.core.belief_window.WindowBelief: set gp.belief = 'window' (--env belief=window)")
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
            f"{mission.budget_s * mission.speed:.4g} m of flight, {flight_cells:.4g} cell widths of "
            f"grid.resolution = {grid.resolution:g} m: more than the {MAX_FLIGHT_CELLS} an episode may fly (its "
            f"legs would not end); valid: budget_s x speed <= {MAX_FLIGHT_CELLS * grid.resolution:g} m "
            "at this resolution")


#: [-] float64 arrays of n x n (n cells) that one evaluation of the log marginal likelihood of
#: ``ipp-bench fit-prior`` holds at once (the kernel's temporaries, K, its Cholesky factor):
#: tracemalloc's peak of ``gp_fit._lml_and_mean`` is 5.00 n^2 floats on 20 x 20 and 40 x 40 cells
FIT_ARRAYS = 5


def fit_prior_bytes(config: IPPConfig, maps: int) -> int:
    """[bytes] fitting the prior of ``config``'s field family on ``maps`` maps (:mod:`ipp_bench.core.gp_fit`):
    the likelihood's n x n arrays and three copies of the maps."""
    n = config.grid.n_cells
    return FIT_ARRAYS * n**2 * _FLOAT + 3 * int(maps) * n * _FLOAT


def check_fit_size(config: IPPConfig, maps: int) -> None:
    """Refuse a prior fit that would not fit in memory, before any map is drawn.

    Raises:
        ValueError: one line naming the map's size, the memory needed and the limit.
    """
    need = fit_prior_bytes(config, maps)
    if need <= ARRAY_LIMIT_BYTES:
        return
    grid, n = config.grid, config.grid.n_cells
    most = _most(lambda m: FIT_ARRAYS * m**2 * _FLOAT + 3 * int(maps) * m * _FLOAT, ARRAY_LIMIT_BYTES)
    raise ValueError(
        f"grid.rows x grid.cols = {grid.rows} x {grid.cols} cells is too large to fit a prior on: the log marginal "
        f"likelihood of {maps} maps holds {FIT_ARRAYS} covariances of {n} x {n} cells, {_gib(need)} (limit "
        f"{_gib(ARRAY_LIMIT_BYTES)}, at most {most} cells); fit on a task of the same field family with a smaller "
        "map")


__all__ = ["ARRAY_LIMIT_BYTES", "DENSE_BELIEF_ARRAYS", "FIT_ARRAYS", "MAX_DECISIONS", "MAX_FLIGHT_CELLS",
           "belief_states", "check_fit_size", "check_sizes", "dense_belief_bytes", "encoding_bytes", "fit_prior_bytes",
           "leg_update_rows", "roadmap_nodes", "window_belief_bytes"]
