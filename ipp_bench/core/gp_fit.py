"""Fit the GP prior to a field family by log marginal likelihood (the paper's Section V-A procedure).

The paper fitted its Matern 3/2 hyper-parameters "by maximizing log marginal likelihood over
independent maps" of its data. Here the maps are draws of a task's field family on the task's
grid, treated as exact observations of every cell: with ``y_j`` the j-th map minus the prior mean
``m`` and ``K = k(l, s2) + nugget I`` over the cell centres,

    log p(Y) = sum_j [ -1/2 y_j^T K^-1 y_j - 1/2 log |K| - n/2 log 2 pi ].

Length scale, signal variance and nugget are free, optimised in log space by L-BFGS-B. The nugget
is the part of the field with no spatial correlation at the scale of a cell; a family without
spatial structure (``bernoulli``) puts almost all its variance there.

The prior mean is the task's (the paper's 0.5) unless it is fitted too (``fit_mean=True``,
``ipp-bench fit-prior --fit-mean``): then it is profiled out in closed form, the generalised
least-squares mean ``m(K) = 1^T K^-1 sum_j x_j / (J 1^T K^-1 1)`` of the maps ``x_j`` under each
candidate ``K``, which is the value maximising the likelihood for that ``K``. Sparse fields need
it: weed patches cover a few percent of the map and average about 0.05, so a mean fixed at 0.5
puts the prior next to the patch values and far from the bare soil that is most of the map (the
fit then spends its variance explaining the offset, and every measurement of bare soil pulls the
estimate of the unseen patches down).

Run it as ``ipp-bench fit-prior --task ipp_bench/Grid15Eval-v1 --write``.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from .belief import cell_centres, prior_covariance
from .config import IPPConfig
from .fields import make_field

FIT_SEED = 20_251_123  # [-] seed of the fitting maps (drawn apart from any episode's field stream)
HELD_OUT_SEED = 91_000_001  # [-] seed of held-out maps used to compare priors
DEFAULT_MAPS = 40
#: likelihood evaluations of a fit, for :func:`estimate_seconds` (two L-BFGS-B starts of three
#: parameters with numerical gradients: 108 on Grid15Eval-v1)
TYPICAL_EVALUATIONS = 120
# log-space bounds: length scale [m], signal variance and nugget [field units^2]
_BOUNDS = ((math.log(0.3), math.log(200.0)), (math.log(1e-4), math.log(20.0)), (math.log(1e-7), math.log(1.0)))


@dataclass(frozen=True)
class PriorFit:
    """Fitted hyper-parameters and the log marginal likelihood per map that they reach."""

    family: str
    grid: tuple[int, int]
    maps: int
    seed: int
    length_scale: float  # [m]
    signal_variance: float  # [field units^2]
    nugget: float  # [field units^2]
    prior_mean: float  # [field units] the task's (fixed) or, with ``mean_fitted``, the fitted one
    lml_per_map: float  # [nats]
    mean_fitted: bool = False  # whether ``prior_mean`` was fitted (generalised least squares)


def sample_maps(config: IPPConfig, maps: int, seed: int) -> np.ndarray:
    """(maps, n_cells) independent draws of the task's field family (row-major cells)."""
    if maps < 2:
        raise ValueError(f"maps = {maps} is invalid: expected an integer >= 2")
    children = np.random.SeedSequence(int(seed)).spawn(int(maps))
    return np.stack([make_field(config.mission.field, config.grid, np.random.default_rng(c)).reshape(-1)
                     for c in children])


def _lml_and_mean(maps: np.ndarray, xy: np.ndarray, length_scale: float, signal_variance: float,
                  nugget: float, prior_mean: float | None) -> tuple[float, float]:
    """(log marginal likelihood, mean): the mean given, or (None) the GLS mean under this K."""
    X = np.atleast_2d(maps)
    K = prior_covariance(xy, length_scale, signal_variance, nugget)
    try:
        L = np.linalg.cholesky(K)
    except np.linalg.LinAlgError:
        return -math.inf, math.nan
    n_maps, n = X.shape
    if prior_mean is None:
        a = np.linalg.solve(L, np.ones(n))  # L^-1 1
        b = np.linalg.solve(L, X.sum(axis=0))  # L^-1 sum_j x_j
        prior_mean = float(a.dot(b) / (n_maps * a.dot(a)))
    Z = np.linalg.solve(L, (X - prior_mean).T)  # (n, maps): L^-1 y_j
    lml = -0.5 * np.sum(Z * Z) - n_maps * np.sum(np.log(np.diag(L))) - 0.5 * n_maps * n * math.log(2 * math.pi)
    return float(lml), float(prior_mean)


def log_marginal_likelihood(maps: np.ndarray, xy: np.ndarray, length_scale: float, signal_variance: float,
                            nugget: float, prior_mean: float = 0.5) -> float:
    """Sum over maps of log N(map | prior_mean, k(length_scale, signal_variance) + nugget I)."""
    return _lml_and_mean(maps, xy, length_scale, signal_variance, nugget, prior_mean)[0]


def gls_mean(maps: np.ndarray, xy: np.ndarray, length_scale: float, signal_variance: float, nugget: float) -> float:
    """The constant mean that maximises the likelihood of ``maps`` under this covariance (GLS)."""
    return _lml_and_mean(maps, xy, length_scale, signal_variance, nugget, None)[1]


def minimise_lml(maps: np.ndarray, xy: np.ndarray, prior_mean: float | None,
                 resolution: float, progress: Callable[[str], None] | None = None) -> tuple[float, float, float]:
    """(length scale, signal variance, nugget) maximising the log marginal likelihood of ``maps``;
    with ``prior_mean=None`` the mean is profiled out (:func:`gls_mean` of the result is the fitted one).
    ``progress`` (if given) gets one line per optimiser start."""
    Y = np.atleast_2d(maps)
    calls = [0]

    def objective(theta: np.ndarray) -> float:
        calls[0] += 1
        value = _lml_and_mean(Y, xy, *np.exp(theta), prior_mean=prior_mean)[0]
        return -value / Y.size if math.isfinite(value) else 1e6

    centre = float(Y.mean()) if prior_mean is None else prior_mean
    variance = max(float(np.mean((Y - centre) ** 2)), 1e-3)
    starts = [np.log([ls, 0.9 * variance, 0.1 * variance]) for ls in (2.0 * resolution, 5.0 * resolution)]
    results = []
    for i, x0 in enumerate(starts, 1):
        t0, calls[0] = time.perf_counter(), 0
        results.append(minimize(objective, x0, method="L-BFGS-B", bounds=_BOUNDS))
        if progress is not None:
            progress(f"likelihood maximised from start {i}/{len(starts)} (length scale {math.exp(x0[0]):.3g} m): "
                     f"{calls[0]} evaluations in {time.perf_counter() - t0:.1f} s")
    best = min(results, key=lambda r: r.fun)
    ls, s2, nugget = (float(v) for v in np.exp(best.x))
    return ls, s2, nugget


def estimate_seconds(config: IPPConfig, maps: int = DEFAULT_MAPS, seed: int = FIT_SEED) -> float:
    """A rough wall time [s] of :func:`fit_prior`: one likelihood evaluation on its maps, timed here,
    times :data:`TYPICAL_EVALUATIONS` (for the progress line before a fit)."""
    from .limits import check_fit_size

    check_fit_size(config, maps)
    g = config.grid
    t0 = time.perf_counter()
    Y = sample_maps(config, maps, seed)
    xy = cell_centres((g.rows, g.cols), g.resolution)
    sampling = time.perf_counter() - t0
    variance = max(float(np.var(Y)), 1e-3)
    times = []
    for length_scale in (2.0, 3.5, 5.0):  # the median of three, as the fit's first steps
        t0 = time.perf_counter()
        _lml_and_mean(Y, xy, length_scale * g.resolution, 0.9 * variance, 0.1 * variance, config.gp.prior_mean)
        times.append(time.perf_counter() - t0)
    return sampling + float(np.median(times)) * TYPICAL_EVALUATIONS


def fit_prior(config: IPPConfig, maps: int = DEFAULT_MAPS, seed: int = FIT_SEED, fit_mean: bool = False,
              progress: Callable[[str], None] | None = None) -> PriorFit:
    """Maximise the log marginal likelihood of ``maps`` draws of the task's field family; the prior
    mean is the task's, or with ``fit_mean`` fitted too (profiled: the GLS mean). ``progress`` (if
    given) gets one line per stage.

    Raises:
        ValueError: the map is too large for the fit's n x n arrays (:func:`ipp_bench.core.limits.check_fit_size`).
    """
    from .limits import check_fit_size

    check_fit_size(config, maps)
    g = config.grid
    xy = cell_centres((g.rows, g.cols), g.resolution)
    Y = sample_maps(config, maps, seed)
    if progress is not None:
        progress(f"drew {maps} maps of {g.rows} x {g.cols} cells")
    ls, s2, nugget = minimise_lml(Y, xy, None if fit_mean else config.gp.prior_mean, g.resolution, progress)
    lml, mean = _lml_and_mean(Y, xy, ls, s2, nugget, None if fit_mean else config.gp.prior_mean)
    return PriorFit(config.mission.field, (g.rows, g.cols), maps, seed, ls, s2, nugget, mean, lml / maps, fit_mean)


def held_out_lml(config: IPPConfig, length_scale: float, signal_variance: float, nugget: float,
                 maps: int = 20, seed: int = HELD_OUT_SEED, prior_mean: float | None = None) -> float:
    """Log marginal likelihood per map of a prior on ``maps`` held-out draws of the task's family
    (prior mean: ``prior_mean``, default the task's)."""
    from .limits import check_fit_size

    check_fit_size(config, maps)
    g = config.grid
    xy = cell_centres((g.rows, g.cols), g.resolution)
    Y = sample_maps(config, maps, seed)
    mean = config.gp.prior_mean if prior_mean is None else prior_mean
    return log_marginal_likelihood(Y, xy, length_scale, signal_variance, nugget, mean) / maps


def _significant(x: float, digits: int = 4) -> str:
    return f"{float(f'{x:.{digits}g}'):g}" if x >= 1e-4 else f"{x:.{digits - 1}e}"


def gp_section(fit: PriorFit, command: str) -> str:
    """The ``[config.gp]`` section of a task file holding ``fit``, with the command that made it."""
    return (
        "[config.gp]\n"
        f"# fitted by `{command}`:\n"
        f"# Matern 3/2 log marginal likelihood over {fit.maps} {fit.family} maps of {fit.grid[0]} x {fit.grid[1]} "
        f"cells (seed {fit.seed}), " + ("mean fitted (generalised least squares)" if fit.mean_fitted else "mean fixed")
        + "\n"
        f"length_scale = {_significant(fit.length_scale)}  # [m]\n"
        f"signal_variance = {_significant(fit.signal_variance)}  # [field units^2]\n"
        f"nugget = {_significant(fit.nugget)}  # [field units^2]\n"
        f"prior_mean = {_significant(fit.prior_mean) if fit.mean_fitted else f'{fit.prior_mean:g}'}  # [field units]\n")


_SECTION = re.compile(r"^\[config\.gp\]\n(?:(?!\[).*\n?)*", re.MULTILINE)


def write_gp_section(path: str | Path, fit: PriorFit, command: str) -> None:
    """Replace (or append) the ``[config.gp]`` section of the task file at ``path``."""
    path = Path(path)
    text = path.read_text()
    section = gp_section(fit, command) + "\n"
    if _SECTION.search(text):
        text = _SECTION.sub(lambda _: section, text, count=1)
    else:
        text = text.rstrip("\n") + "\n\n" + section
    path.write_text(text.rstrip("\n") + "\n")
