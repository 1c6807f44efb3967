"""Field families: seeded, in [0, 1], with the structure each promises."""

import numpy as np
import pytest

from ipp_bench.core.config import FIELD_GUARANTEED_MAX, GridConfig
from ipp_bench.core.fields import FIELDS, make_field


@pytest.mark.parametrize("name", sorted(FIELDS))
def test_fields_are_seeded_and_in_unit_range(name):
    g = GridConfig(15, 15)
    a = make_field(name, g, np.random.default_rng(1))
    b = make_field(name, g, np.random.default_rng(1))
    c = make_field(name, g, np.random.default_rng(2))
    assert a.shape == (15, 15)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert a.min() >= 0 and a.max() <= 1 and a.max() >= 0.5


def test_regions_field_has_high_and_low_regions():
    f = make_field("regions", GridConfig(15, 15), np.random.default_rng(0))
    high = f >= 0.6
    assert 0.15 <= high.mean() <= 0.45
    assert np.all(f[~high] <= 0.3 + 1e-12)


def test_unknown_field_names_the_valid_ones():
    with pytest.raises(ValueError, match="bernoulli"):
        make_field("gas", GridConfig(), np.random.default_rng(0))


@pytest.mark.parametrize("name", sorted(FIELDS))
def test_every_family_reaches_the_guaranteed_maximum_mu_th_relies_on(name):
    grid = GridConfig(15, 15, 2.5)
    for seed in range(50):
        assert make_field(name, grid, np.random.default_rng(seed)).max() >= FIELD_GUARANTEED_MAX
