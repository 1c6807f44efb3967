"""Every configuration field rejects a bad value with an error naming it and its valid range."""

import dataclasses

import pytest

from ipp_bench.config import GPConfig, GraphConfig, GridConfig, IPPConfig, MissionConfig, SensorConfig

BAD = [
    (GridConfig, "rows", 1), (GridConfig, "rows", 2.5), (GridConfig, "cols", 0),
    (GridConfig, "resolution", 0.0), (GridConfig, "resolution", float("nan")),
    (GPConfig, "length_scale", -1.0), (GPConfig, "signal_variance", 0.0), (GPConfig, "prior_mean", float("inf")),
    (GPConfig, "nugget", -1e-3), (GPConfig, "belief", "sparse"), (GPConfig, "belief_window", -1),
    (GPConfig, "belief_window", 2.5), (SensorConfig, "binning_noise_exponent", -7.0),
    (SensorConfig, "binning_noise_exponent", float("nan")),
    (SensorConfig, "persistent_var", -1e-4), (SensorConfig, "persistent_var_binned", float("nan")),
    (SensorConfig, "persistent_corr", 1.5), (SensorConfig, "persistent_neighbour_corr", 1.0),
    (SensorConfig, "persistent_neighbour_corr", -0.1), (SensorConfig, "noise_floor", 0.0), (SensorConfig, "noise_floor", 1.2),
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
