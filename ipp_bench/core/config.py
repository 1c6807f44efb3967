"""Typed, frozen configuration of an IPP problem, validated at construction.

Every field carries its unit in a comment. A bad value raises ``ValueError`` naming the field,
the value and the valid range, so a wrong ``gym.make(..., **overrides)`` fails at once and says
how to fix it. Numbers of any numeric type are accepted (``numpy.int64(20)`` for an integer
field, an int for a float field) and stored as Python numbers; strings and booleans are refused
where a number is expected. ``IPPConfig.replace(**flat)`` sets fields by name across the sections.

One module on purpose (over 400 lines): every section of a task's configuration with its checks, so
that ``IPPConfig.replace`` and the task files see one list of fields.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass, field
from typing import Any, NoReturn

FIELD_FAMILIES = ("bernoulli", "regions", "weed_patches")
#: [s] the one tolerance of mission-time comparisons: a leg that overruns the remaining budget by
#: less than this still fits, a record at most this after a report time counts "at or before" it
TIME_TOL_S = 1e-9
SAMPLING_MODES = ("grid", "uniform")
#: the field beliefs a task can hold: "dense", :class:`~ipp_bench.core.belief.GPBelief` (the n x n
#: covariance; every task up to 30 x 30), "window", :class:`~ipp_bench.core.belief_window.WindowBelief`
#: (the covariance within a window of cells; large maps)
BELIEF_KINDS = ("dense", "window")
#: every field family has at least one cell at or above this value (``ipp_bench.core.fields``), so an
#: evaluation ROI ``truth >= mu_th`` with ``mu_th`` up to it is never empty
FIELD_GUARANTEED_MAX = 0.5


def cell_centre(index: Any, resolution: float) -> Any:
    """[m] coordinate of the centre of cell ``index`` along one axis (elementwise on index arrays):
    the one cell-centre formula of the suite."""
    return (index + 0.5) * resolution


# -- the validation helpers of every config (task sections, planner settings) ---------------------
#: the longest value an error message quotes (a longer one is cut, so that the message stays one line)
MAX_QUOTED_CHARS = 120


def quoted(value: Any) -> str:
    """``repr(value)``, cut to :data:`MAX_QUOTED_CHARS` (a value nested too deeply to print is named so)."""
    try:
        text = repr(value)
    except RecursionError:
        return f"<a {type(value).__name__} nested too deeply to print>"
    return text if len(text) <= MAX_QUOTED_CHARS else text[:MAX_QUOTED_CHARS - 4] + " ..."


def invalid(where: str, value: Any, valid: str) -> NoReturn:
    """Raise the suite's one error for a bad setting: ``where = value is invalid: expected valid``."""
    raise ValueError(f"{where} = {quoted(value)} is invalid: expected {valid}")


def _range_text(low: float | None, high: float | None, low_open: bool, high_open: bool) -> str:
    if low is not None and high is not None:
        return f"in {'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
    if low is not None:
        return f"{'>' if low_open else '>='} {low:g}"
    if high is not None:
        return f"{'<' if high_open else '<='} {high:g}"
    return ""


def check_number(where: str, value: Any, low: float | None = None, high: float | None = None, *,
                 low_open: bool = False, high_open: bool = False, unit: str = "") -> float:
    """``value`` as a float if it is a finite real number within the bounds (open or closed), else
    :func:`invalid` naming the range. Strings and booleans are refused."""
    rng = _range_text(low, high, low_open, high_open)
    valid = f"a finite number {rng}".rstrip() + (f" [{unit}]" if unit else "")
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        invalid(where, value, valid + " (not a string or a bool)")
    v = float(value)
    if (not math.isfinite(v) or (low is not None and (v <= low if low_open else v < low))
            or (high is not None and (v >= high if high_open else v > high))):
        invalid(where, value, valid)
    return v


def check_integer(where: str, value: Any, low: int, high: int | None = None) -> int:
    """``value`` as an int if it is an integer (not a bool) in [low, high], else :func:`invalid`."""
    ok = isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if not ok or value < low or (high is not None and value > high):
        invalid(where, value, f"an integer {_range_text(low, high, False, False)}")
    return int(value)


def _fail(section: str, name: str, value: Any, valid: str) -> None:
    invalid(f"{section}.{name}", value, valid)


def _finite(section: str, name: str, value: Any) -> float:
    return check_number(f"{section}.{name}", value)


def _plain(obj: Any, *names: str) -> None:
    """Store numpy numbers of fields ``names`` of frozen ``obj`` as Python numbers (after checks)."""
    for name in names:
        value = getattr(obj, name)
        if isinstance(value, numbers.Number) and type(value) not in (int, float):
            object.__setattr__(obj, name, int(value) if isinstance(value, numbers.Integral) else float(value))


def _positive(section: str, name: str, value: Any) -> None:
    check_number(f"{section}.{name}", value, 0.0, low_open=True)


def _integer(section: str, name: str, value: Any, low: int, high: int | None = None) -> None:
    check_integer(f"{section}.{name}", value, low, high)


def _bounded(section: str, name: str, value: Any, bounds: tuple[float, float], unit: str) -> None:
    check_number(f"{section}.{name}", value, *bounds, unit=unit)


# The numerical range of the prior and the camera noise. Within it, every update of the belief is
# well conditioned (the innovation covariance H P H^T + R stays positive definite in float64, checked
# at the range's corners by tests/test_config.py); beyond it the Cholesky factorisations fail
# ("Matrix is not positive definite") or the metrics overflow. The field is in [0, 1]: the range is
# wide around every sensible value.
LENGTH_SCALE_RANGE = (1e-3, 1e3)  # [m] gp.length_scale
VARIANCE_RANGE = (1e-6, 1e3)  # [field units^2] gp.signal_variance, sensor.noise_a
NUGGET_RANGE = (0.0, 1e3)  # [field units^2] gp.nugget
PRIOR_MEAN_RANGE = (-1e3, 1e3)  # [field units] gp.prior_mean
NOISE_B_RANGE = (1e-3, 1e3)  # [1/m] sensor.noise_b


@dataclass(frozen=True)
class GridConfig:
    """The mapped area: a rows x cols grid of square cells."""

    rows: int = 15  # [cells] along y
    cols: int = 15  # [cells] along x
    resolution: float = 2.5  # [m] cell side

    def __post_init__(self) -> None:
        _integer("grid", "rows", self.rows, 2)
        _integer("grid", "cols", self.cols, 2)
        _positive("grid", "resolution", self.resolution)
        _plain(self, "rows", "cols", "resolution")

    @property
    def n_cells(self) -> int:
        return self.rows * self.cols

    @property
    def size_m(self) -> tuple[float, float]:
        """(width along x, height along y) in metres."""
        return self.cols * self.resolution, self.rows * self.resolution


@dataclass(frozen=True)
class GPConfig:
    """Gaussian-process prior: Matern 3/2 over cell centres (paper Section IV-D)."""

    length_scale: float = 3.67  # [m]
    signal_variance: float = 1.82  # [field units^2]
    prior_mean: float = 0.5  # [field units]
    nugget: float = 0.0  # [field units^2] independent per-cell variance added to the prior diagonal
    belief: str = "dense"  # one of BELIEF_KINDS: "dense" (GPBelief) or "window" (WindowBelief, large maps)
    belief_window: int = 0  # [cells] the window belief's window w; 0: ceil(4 length scales / cell side)

    def __post_init__(self) -> None:
        _bounded("gp", "length_scale", self.length_scale, LENGTH_SCALE_RANGE, "m")
        _bounded("gp", "signal_variance", self.signal_variance, VARIANCE_RANGE, "field units^2")
        _bounded("gp", "prior_mean", self.prior_mean, PRIOR_MEAN_RANGE, "field units")
        _bounded("gp", "nugget", self.nugget, NUGGET_RANGE, "field units^2")
        if self.belief not in BELIEF_KINDS:
            _fail("gp", "belief", self.belief, f"one of {BELIEF_KINDS}")
        _integer("gp", "belief_window", self.belief_window, 0)
        _plain(self, "length_scale", "signal_variance", "prior_mean", "nugget", "belief_window")


@dataclass(frozen=True)
class SensorConfig:
    """Downward square camera with altitude-dependent noise f^e a (1 - exp(-b h)).

    f is the resolution factor of the read-out (``binning`` above ``binning_altitude``, else 1) and
    e is ``binning_noise_exponent``: 0 in the v0 tasks (the paper states no such factor), 3 in v1
    (the lineage's code, ipp-rl ``measurement_variance_matrix``: a 2 x 2 block mean is 8x noisier).
    """

    fov_deg: float = 60.0  # [deg] full field of view of the square image
    noise_a: float = 0.05  # [field units^2]
    noise_b: float = 0.2  # [1/m]
    binning_altitude: float = 10.0  # [m] above this, measurements average binning x binning cells
    binning: int = 2  # [cells] block side of the coarse read-out
    binning_noise_exponent: float = 0.0  # [-] e in f^e: noise growth of a binned read-out
    # the camera's persistent error: a per-cell error that every look at the same resolution factor
    # repeats (the same texture misread the same way), carried by the belief as one extra state per
    # cell and factor (:class:`~ipp_bench.core.belief.PersistentErrorBelief`); 0: none (v0, graph tasks)
    persistent_var: float = 0.0  # [field units^2] per cell, full-resolution read-outs (f = 1), at t = 0.5
    persistent_var_binned: float = 0.0  # [field units^2] per cell, binned read-outs (f = binning), at t = 0.5
    persistent_corr: float = 0.0  # [-] correlation of a cell's persistent errors at the two factors
    # the persistent errors of neighbouring cells correlate (the cells of a binned block share much of
    # theirs): corr = r^(d^2), d the distance in cells (a squared-exponential field whose edge-neighbour
    # value is r); 0: independent cells
    persistent_neighbour_corr: float = 0.0  # [-] r in [0, 1)
    # camera errors shrink where a cell is empty or full (no plant margins to misread): with the
    # persistent states, every variance is scaled by k + (1 - k) 4 t (1 - t), t the read-out's value
    noise_floor: float = 1.0  # [-] k in (0, 1]: variance at t = 0 or 1 relative to t = 0.5; 1: same everywhere

    def __post_init__(self) -> None:
        v = _finite("sensor", "fov_deg", self.fov_deg)
        if not 0.0 < v < 180.0:
            _fail("sensor", "fov_deg", self.fov_deg, "a number in (0, 180) degrees")
        _bounded("sensor", "noise_a", self.noise_a, VARIANCE_RANGE, "field units^2")
        _bounded("sensor", "noise_b", self.noise_b, NOISE_B_RANGE, "1/m")
        _positive("sensor", "binning_altitude", self.binning_altitude)
        _integer("sensor", "binning", self.binning, 1)
        e = _finite("sensor", "binning_noise_exponent", self.binning_noise_exponent)
        if not -6.0 <= e <= 6.0:
            _fail("sensor", "binning_noise_exponent", self.binning_noise_exponent, "a number in [-6, 6]")
        for name in ("persistent_var", "persistent_var_binned"):
            if _finite("sensor", name, getattr(self, name)) < 0:
                _fail("sensor", name, getattr(self, name), "a finite number >= 0 [field units^2]")
        if not 0.0 <= _finite("sensor", "persistent_corr", self.persistent_corr) <= 1.0:
            _fail("sensor", "persistent_corr", self.persistent_corr, "a number in [0, 1]")
        if not 0.0 <= _finite("sensor", "persistent_neighbour_corr", self.persistent_neighbour_corr) < 1.0:
            _fail("sensor", "persistent_neighbour_corr", self.persistent_neighbour_corr, "a number in [0, 1)")
        if not 0.0 < _finite("sensor", "noise_floor", self.noise_floor) <= 1.0:
            _fail("sensor", "noise_floor", self.noise_floor, "a number in (0, 1]")
        _plain(self, "fov_deg", "noise_a", "noise_b", "binning_altitude", "binning", "binning_noise_exponent",
               "persistent_var", "persistent_var_binned", "persistent_corr", "persistent_neighbour_corr",
               "noise_floor")

    def persistent(self, factor: int) -> float:
        """Persistent per-cell error variance of read-outs at resolution factor ``factor`` (at t = 0.5)."""
        return self.persistent_var_binned if factor > 1 else self.persistent_var

    @property
    def camera_error_states(self) -> bool:
        """Whether the belief carries the camera's error model
        (:class:`~ipp_bench.core.belief.PersistentErrorBelief`)."""
        return self.persistent_var > 0 or self.persistent_var_binned > 0 or self.noise_floor < 1.0


@dataclass(frozen=True)
class GraphConfig:
    """3D probabilistic roadmap: candidate measurement positions and their k-NN edges."""

    altitudes: tuple[float, ...] = (8.0, 14.0)  # [m] flight levels, strictly increasing
    k: int = 20  # [-] neighbours per node, k / len(altitudes) on each level
    sampling: str = "grid"  # "grid": cell centres at every level; "uniform": random PRM
    n_samples: int = 450  # [-] nodes in "uniform" mode, split equally over the levels
    pe_dim: int = 32  # [-] Laplacian eigenvectors in the positional encoding
    roadmap_seed: int = 0  # [-] seed of the "uniform" sampling (the roadmap is fixed per task)

    def __post_init__(self) -> None:
        alts = tuple(self.altitudes) if isinstance(self.altitudes, (list, tuple)) else None
        if not alts:
            _fail("graph", "altitudes", self.altitudes, "a non-empty sequence of altitudes > 0 [m]")
        for a in alts:
            if _finite("graph", "altitudes", a) <= 0:
                _fail("graph", "altitudes", self.altitudes, "altitudes > 0 [m]")
        if any(b <= a for a, b in zip(alts, alts[1:])):
            _fail("graph", "altitudes", self.altitudes, "strictly increasing altitudes")
        object.__setattr__(self, "altitudes", tuple(float(a) for a in alts))
        _integer("graph", "k", self.k, len(alts))
        if self.k % len(alts):
            _fail("graph", "k", self.k, f"a multiple of the number of altitude levels ({len(alts)})")
        if self.sampling not in SAMPLING_MODES:
            _fail("graph", "sampling", self.sampling, f"one of {SAMPLING_MODES}")
        _integer("graph", "n_samples", self.n_samples, 2 * len(alts))
        _integer("graph", "pe_dim", self.pe_dim, 1)
        _integer("graph", "roadmap_seed", self.roadmap_seed, 0)
        _plain(self, "k", "n_samples", "pe_dim", "roadmap_seed")


@dataclass(frozen=True)
class MissionConfig:
    """Budget, flight and evaluation settings of one mission."""

    budget_s: float = 150.0  # [s] flight-time budget
    speed: float = 2.0  # [m/s] cruise speed; travel time = length / speed
    measurement_spacing: float = 7.5  # [m] travelled between measurements (0.2 map units)
    # (col, row [cells], altitude [m]); None or "random": a random node
    start: tuple[float, float, float] | None = (2, 2, 14.0)
    field: str = "bernoulli"  # ground-truth family
    mu_th: float = 0.4  # [field units] ROI threshold
    beta: float = 1.0  # [-] belief ROI: mu + beta sigma >= mu_th
    report_times: tuple[float, ...] = (50.0, 100.0, 150.0, 200.0)  # [s] metrics read-out times
    measure_at_start: bool = True  # take one measurement at the start position at t = 0
    # [-] half-open range [lo, hi) of this task's episode seeds: reset(seed=s) plays episode seed
    # lo + s mod (hi - lo). Evaluation tasks use [0, 2^31) (every seed the leaderboard draws),
    # training tasks [2^31, 2^32), so no training episode is ever an evaluation episode
    episode_seeds: tuple[int, int] = (0, 2**63)

    def __post_init__(self) -> None:
        _positive("mission", "budget_s", self.budget_s)
        _positive("mission", "speed", self.speed)
        _positive("mission", "measurement_spacing", self.measurement_spacing)
        if self.start == "random":
            object.__setattr__(self, "start", None)
        if self.start is not None:
            if not isinstance(self.start, (list, tuple)) or len(self.start) != 3:
                _fail("mission", "start", self.start, "None / 'random' or (col, row, altitude)")
            for v in self.start:
                _finite("mission", "start", v)
            if self.start[2] <= 0:
                _fail("mission", "start", self.start, "an altitude > 0 [m]")
            object.__setattr__(self, "start", tuple(float(v) for v in self.start))
        if self.field not in FIELD_FAMILIES:
            _fail("mission", "field", self.field, f"one of {FIELD_FAMILIES}")
        if not 0.0 <= _finite("mission", "mu_th", self.mu_th) <= FIELD_GUARANTEED_MAX:
            _fail("mission", "mu_th", self.mu_th,
                  f"a number in [0, {FIELD_GUARANTEED_MAX}] (every field family has a cell at or above "
                  f"{FIELD_GUARANTEED_MAX}, so the evaluation ROI truth >= mu_th is never empty)")
        if _finite("mission", "beta", self.beta) < 0:
            _fail("mission", "beta", self.beta, "a finite number >= 0")
        times = self.report_times
        if not isinstance(times, (list, tuple)) or not times:
            _fail("mission", "report_times", times, "a non-empty sequence of times > 0 [s]")
        for t in times:
            if _finite("mission", "report_times", t) <= 0:
                _fail("mission", "report_times", times, "times > 0 [s]")
        if any(b <= a for a, b in zip(times, times[1:])):
            _fail("mission", "report_times", times, "strictly increasing times")
        object.__setattr__(self, "report_times", tuple(float(t) for t in times))
        if not isinstance(self.measure_at_start, bool):
            _fail("mission", "measure_at_start", self.measure_at_start, "True or False")
        seeds = self.episode_seeds
        if (not isinstance(seeds, (list, tuple)) or len(seeds) != 2
                or not all(isinstance(v, numbers.Integral) and not isinstance(v, bool) for v in seeds)
                or not 0 <= seeds[0] < seeds[1] <= 2**63):
            _fail("mission", "episode_seeds", seeds, "two integers lo < hi in [0, 2^63]")
        object.__setattr__(self, "episode_seeds", (int(seeds[0]), int(seeds[1])))
        _plain(self, "budget_s", "speed", "measurement_spacing", "mu_th", "beta")

    @property
    def report_times_in_budget(self) -> tuple[float, ...]:
        """[s] the report times an episode reports its metrics at: those within the budget."""
        return tuple(t for t in self.report_times if t <= self.budget_s + TIME_TOL_S)


_SECTIONS = ("grid", "gp", "sensor", "graph", "mission")


@dataclass(frozen=True)
class IPPConfig:
    """One IPP problem: the map, the prior, the camera, the roadmap and the mission."""

    grid: GridConfig = field(default_factory=GridConfig)
    gp: GPConfig = field(default_factory=GPConfig)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    graph: GraphConfig = field(default_factory=GraphConfig)
    mission: MissionConfig = field(default_factory=MissionConfig)

    def __post_init__(self) -> None:
        for name, cls in _SECTION_CLASSES.items():
            value = getattr(self, name)
            if isinstance(value, dict):
                object.__setattr__(self, name, _build(cls, name, value))
            elif not isinstance(value, cls):
                _fail("config", name, value, f"a {cls.__name__} or a dict of its fields")
        if self.gp.belief == "window" and self.sensor.camera_error_states:
            _fail("gp", "belief", self.gp.belief,
                  "'dense' with the camera's error states (sensor.persistent_var, persistent_var_binned, "
                  "noise_floor): the window belief has white read-out noise only")
        start = self.mission.start
        if start is not None:
            c, r, h = start
            low, high = self.altitude_range
            if not (0 <= c <= self.grid.cols - 1 and 0 <= r <= self.grid.rows - 1 and low <= h <= high):
                _fail("mission", "start", start,
                      f"(col in [0, {self.grid.cols - 1}], row in [0, {self.grid.rows - 1}], altitude in "
                      f"[{low:g}, {high:g}] m, the range of graph.altitudes)")

    @property
    def altitude_range(self) -> tuple[float, float]:
        """[m] (lowest, highest) altitude of the task's flight envelope: its roadmap's levels."""
        return self.graph.altitudes[0], self.graph.altitudes[-1]

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> IPPConfig:
        """Build from ``{"grid": {...}, "mission": {...}, ...}``; unknown keys are errors."""
        unknown = set(data) - set(_SECTIONS)
        if unknown:
            raise ValueError(f"unknown config sections {sorted(unknown)}: valid are {list(_SECTIONS)}")
        return cls(**{k: v for k, v in data.items()})

    def to_dict(self) -> dict[str, dict[str, Any]]:
        return {name: dataclasses.asdict(getattr(self, name)) for name in _SECTIONS}

    def replace(self, **overrides: Any) -> IPPConfig:
        """A copy with fields set by their (unique) names, e.g. ``replace(budget_s=200, rows=20)``."""
        sections: dict[str, dict[str, Any]] = {}
        owners = field_owners()
        for name, value in overrides.items():
            if name in _SECTIONS:  # a whole section, e.g. grid={"rows": 20}
                if not isinstance(value, dict):
                    invalid(name, value, f"a dict of the {name} section's fields, e.g. "
                                         f"{name}={{{_section_fields(name)[0]!r}: ...}}")
                _check_section_keys(name, value)
                sections.setdefault(name, {}).update(value)
                continue
            if name not in owners:
                raise ValueError(
                    f"unknown config field {name!r}: valid fields are {sorted(owners)}")
            sections.setdefault(owners[name], {})[name] = value
        updated = {
            s: dataclasses.replace(getattr(self, s), **_normalise(sections[s])) if s in sections
            else getattr(self, s) for s in _SECTIONS}
        return IPPConfig(**updated)


def _normalise(values: dict[str, Any]) -> dict[str, Any]:
    """TOML and JSON give lists where the dataclasses hold tuples."""
    return {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}


def _section_fields(section: str) -> list[str]:
    return [f.name for f in dataclasses.fields(_SECTION_CLASSES[section])]


def _check_section_keys(section: str, values: dict[str, Any]) -> None:
    """Raise naming the section and its valid fields if ``values`` has a key it does not hold."""
    names = set(_section_fields(section))
    unknown = sorted(map(str, set(values) - names))
    if unknown:
        raise ValueError(f"unknown fields {unknown} in section {section!r}: valid are {sorted(names)}")


def _build(cls: type, section: str, values: dict[str, Any]) -> Any:
    _check_section_keys(section, values)
    return cls(**_normalise(values))


_SECTION_CLASSES = {"grid": GridConfig, "gp": GPConfig, "sensor": SensorConfig,
                    "graph": GraphConfig, "mission": MissionConfig}


def field_owners() -> dict[str, str]:
    """Map every config field name to the section that holds it."""
    owners: dict[str, str] = {}
    for section, cls in _SECTION_CLASSES.items():
        for f in dataclasses.fields(cls):
            assert f.name not in owners, f"config field {f.name} is not unique"
            owners[f.name] = section
    return owners
