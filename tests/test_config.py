"""Every configuration field rejects a bad value with an error naming it and its valid range."""

import dataclasses

import pytest

from ipp_bench.core.config import GPConfig, GraphConfig, GridConfig, IPPConfig, MissionConfig, SensorConfig

BAD = [
    (GridConfig, "rows", 1), (GridConfig, "rows", 2.5), (GridConfig, "cols", 0),
    (GridConfig, "resolution", 0.0), (GridConfig, "resolution", float("nan")),
    (GPConfig, "length_scale", -1.0), (GPConfig, "signal_variance", 0.0), (GPConfig, "prior_mean", float("inf")),
    (GPConfig, "nugget", -1e-3), (GPConfig, "belief", "sparse"), (GPConfig, "belief_window", -1),
    (GPConfig, "belief_window", 2.5), (SensorConfig, "binning_noise_exponent", -7.0),
    (SensorConfig, "binning_noise_exponent", float("nan")),
    (SensorConfig, "persistent_var", -1e-4), (SensorConfig, "persistent_var_binned", float("nan")),
    (SensorConfig, "persistent_corr", 1.5), (SensorConfig, "persistent_neighbour_corr", 1.0),
    (SensorConfig, "persistent_neighbour_corr", -0.1), (SensorConfig, "noise_floor", 0.0),
    (SensorConfig, "noise_floor", 1.2),
    (SensorConfig, "fov_deg", 0.0), (SensorConfig, "fov_deg", 180.0), (SensorConfig, "noise_a", 0.0),
    (SensorConfig, "noise_b", -0.2), (SensorConfig, "binning_altitude", 0.0), (SensorConfig, "binning", 0),
    (GraphConfig, "altitudes", ()), (GraphConfig, "altitudes", (14.0, 8.0)), (GraphConfig, "altitudes", (0.0, 8.0)),
    (GraphConfig, "altitudes", (8.0, 8.0)), (GraphConfig, "k", 1), (GraphConfig, "k", 21),
    (GraphConfig, "sampling", "hex"), (GraphConfig, "n_samples", 3), (GraphConfig, "pe_dim", 0),
    (GraphConfig, "roadmap_seed", -1),
    (MissionConfig, "budget_s", 0.0), (MissionConfig, "speed", -2.0), (MissionConfig, "measurement_spacing", 0.0),
    (MissionConfig, "start", (1, 2)), (MissionConfig, "start", (1, 2, 0.0)), (MissionConfig, "field", "gas"),
    (MissionConfig, "mu_th", float("nan")), (MissionConfig, "beta", -1.0), (MissionConfig, "report_times", ()),
    (MissionConfig, "report_times", (100.0, 50.0)), (MissionConfig, "measure_at_start", 1),
    # strings and booleans are not numbers, whatever they spell
    (GridConfig, "rows", "20"), (GridConfig, "resolution", "2.5"), (GridConfig, "rows", True),
    (MissionConfig, "budget_s", "100"), (MissionConfig, "budget_s", True), (GraphConfig, "altitudes", ("8", 14.0)),
    (MissionConfig, "report_times", ("50",)), (SensorConfig, "noise_a", False),
    # outside the fields' range, the evaluation ROI could be empty (NaN metrics)
    (MissionConfig, "mu_th", 0.9), (MissionConfig, "mu_th", -0.1),
    (MissionConfig, "episode_seeds", (5, 5)), (MissionConfig, "episode_seeds", (-1, 3)),
    (MissionConfig, "episode_seeds", (0.0, 3)),
    # beyond the numerical range of the prior and the noise: a Cholesky that fails ("Singular matrix",
    # "not positive definite") or metrics that overflow (inf RMSE, nan %)
    (GPConfig, "prior_mean", 1e300), (GPConfig, "signal_variance", 1e300), (GPConfig, "signal_variance", 1e-300),
    (GPConfig, "nugget", 1e300), (GPConfig, "length_scale", 1e300), (GPConfig, "length_scale", 1e-300),
    (SensorConfig, "noise_a", 1e-300), (SensorConfig, "noise_a", 1e300), (SensorConfig, "noise_b", 1e-300),
]


def test_every_field_is_covered():
    covered = {(cls, name) for cls, name, _ in BAD}
    for cls in (GridConfig, GPConfig, SensorConfig, GraphConfig, MissionConfig):
        for f in dataclasses.fields(cls):
            assert (cls, f.name) in covered, f"no bad-value test for {cls.__name__}.{f.name}"


@pytest.mark.parametrize("cls, name, value", BAD, ids=[f"{c.__name__}.{n}={v!r}" for c, n, v in BAD])
def test_bad_value_names_field_and_range(cls, name, value):
    with pytest.raises(ValueError) as err:
        cls(**{name: value})
    msg = str(err.value)
    assert name in msg and "expected" in msg


def test_defaults_are_the_paper_values():
    c = IPPConfig()
    assert (c.grid.rows, c.grid.cols, c.grid.resolution) == (15, 15, 2.5)
    assert (c.gp.length_scale, c.gp.signal_variance, c.gp.prior_mean) == (3.67, 1.82, 0.5)
    assert (c.sensor.fov_deg, c.sensor.noise_a, c.sensor.noise_b) == (60.0, 0.05, 0.2)
    assert c.graph.altitudes == (8.0, 14.0) and c.graph.k == 20
    assert c.mission.start == (2.0, 2.0, 14.0) and c.mission.speed == 2.0 and c.mission.mu_th == 0.4


def test_replace_by_flat_names_and_errors():
    c = IPPConfig().replace(budget_s=200, rows=20, altitudes=[6.0, 10.0, 14.0], k=21)
    assert c.mission.budget_s == 200 and c.grid.rows == 20 and c.graph.altitudes == (6.0, 10.0, 14.0)
    with pytest.raises(ValueError, match="unknown config field 'budget'.*budget_s"):
        IPPConfig().replace(budget=3)
    with pytest.raises(ValueError, match="budget_s"):
        IPPConfig().replace(budget_s=-1)
    with pytest.raises(ValueError, match="mission.start"):
        IPPConfig().replace(start=(20, 2, 14.0))  # off a 15 x 15 grid
    assert IPPConfig().replace(start="random").mission.start is None


def test_round_trip_dict():
    c = IPPConfig().replace(field="regions", rows=17)
    assert IPPConfig.from_dict(c.to_dict()) == c
    with pytest.raises(ValueError, match="unknown config sections"):
        IPPConfig.from_dict({"grids": {}})


def test_numbers_of_any_numeric_type_are_accepted_and_stored_as_python_numbers():
    np = pytest.importorskip("numpy")
    c = IPPConfig().replace(rows=np.int64(20), resolution=np.float32(2.5), budget_s=np.int32(100), k=np.int64(10))
    assert c.grid.rows == 20 and type(c.grid.rows) is int
    assert c.grid.resolution == 2.5 and type(c.grid.resolution) is float
    assert c.mission.budget_s == 100 and type(c.mission.budget_s) is int
    assert type(c.graph.k) is int
    assert IPPConfig().replace(budget_s=100).to_dict() == IPPConfig().replace(budget_s=np.int64(100)).to_dict()


@pytest.mark.parametrize("name, value, valid", [
    ("prior_mean", 1e300, "in [-1000, 1000] [field units]"), ("noise_a", 1e-300, "in [1e-06, 1000] [field units^2]"),
    ("signal_variance", 1e300, "in [1e-06, 1000] [field units^2]"), ("nugget", 1e300, "in [0, 1000] [field units^2]"),
], ids=["prior_mean", "noise_a", "signal_variance", "nugget"])
def test_the_numerical_range_is_named_with_its_bounds(name, value, valid):
    with pytest.raises(ValueError) as err:
        IPPConfig().replace(**{name: value})
    assert f"{name} = {value!r} is invalid: expected a finite number {valid}" in str(err.value)


def test_the_corners_of_the_numerical_range_give_finite_metrics():
    """Every update stays well conditioned and every metric finite at the range's corners (with the
    lowest altitude's noise, the smallest there is, against the largest prior variance)."""
    np = pytest.importorskip("numpy")
    from ipp_bench.core.config import LENGTH_SCALE_RANGE, NOISE_B_RANGE, NUGGET_RANGE, PRIOR_MEAN_RANGE, VARIANCE_RANGE
    from ipp_bench.core.mission import Mission, cell_to_xyz

    truth = np.random.default_rng(0).random((15, 15))
    corners = [dict(length_scale=ls, signal_variance=VARIANCE_RANGE[1], noise_a=VARIANCE_RANGE[0],
                    noise_b=NOISE_B_RANGE[0], nugget=NUGGET_RANGE[0], prior_mean=pm)
               for ls in LENGTH_SCALE_RANGE for pm in PRIOR_MEAN_RANGE]
    corners += [dict(signal_variance=VARIANCE_RANGE[0], noise_a=VARIANCE_RANGE[1], noise_b=NOISE_B_RANGE[1],
                     nugget=NUGGET_RANGE[1], length_scale=LENGTH_SCALE_RANGE[1])]
    for corner in corners:
        cfg = IPPConfig().replace(budget_s=60.0, **corner)
        m = Mission(cfg, truth, np.random.default_rng(1), cell_to_xyz(cfg, 2, 2, 8.0))
        for target in ((20.0, 5.0, 8.0), (20.0, 20.0, 14.0), (5.0, 20.0, 8.0), (30.0, 30.0, 8.0)):
            m.fly_to(target)
        for record in m.history:
            assert all(np.isfinite([record.trace_roi, record.rmse_roi, record.uncertainty_reduction_pct,
                                    record.rmse_reduction_pct])), corner


@pytest.mark.parametrize("section, value", [("grid", {"nosuch": 5}), ("mission", {"foo": 1})], ids=["grid", "mission"])
def test_an_unknown_key_in_a_whole_section_is_named(section, value):
    with pytest.raises(ValueError) as err:
        IPPConfig().replace(**{section: value})
    assert f"unknown fields {list(value)} in section {section!r}: valid are" in str(err.value)
    with pytest.raises(ValueError, match=rf"{section} = 5 is invalid: expected a dict of the {section} section"):
        IPPConfig().replace(**{section: 5})


@pytest.mark.parametrize("start", [(10, 10, 1e9), (10, 10, 0.001), (10, 10, 7.0)], ids=["1e9", "0.001", "7"])
def test_a_start_outside_the_altitudes_is_refused_naming_the_range(start):
    """Unchecked, the start snaps to the nearest node: 1e9 m would start at 14 m without a word."""
    with pytest.raises(ValueError) as err:
        IPPConfig().replace(start=start)
    assert "mission.start" in str(err.value) and "altitude in [8, 14] m" in str(err.value)


def test_a_value_nested_too_deeply_to_print_is_still_one_line():
    deep = []
    for _ in range(100_000):
        deep = [deep]
    with pytest.raises(ValueError) as err:
        GridConfig(rows=deep)
    assert "grid.rows = <a list nested too deeply to print> is invalid" in str(err.value)
    with pytest.raises(ValueError) as err:
        GridConfig(rows=list(range(10_000)))
    assert len(str(err.value)) < 300
