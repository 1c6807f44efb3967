"""The prior fit against the maths: the log marginal likelihood formula, reproducible fits, and a
fitted prior that explains held-out maps better than the paper's constants."""

import math

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from ipp_bench import gp_fit
from ipp_bench.belief import GPBelief, cell_centres, prior_covariance
from ipp_bench.config import IPPConfig
from ipp_bench.envs import task_spec


def test_log_marginal_likelihood_equals_the_gaussian_density():
    rng = np.random.default_rng(0)
    xy = cell_centres((4, 5), 2.5)
    maps = rng.random((3, 20))
    K = prior_covariance(xy, 6.0, 0.2, 0.01)
    expected = sum(multivariate_normal(np.full(20, 0.5), K).logpdf(m) for m in maps)
    assert gp_fit.log_marginal_likelihood(maps, xy, 6.0, 0.2, 0.01, 0.5) == pytest.approx(expected, rel=1e-10)


def test_prior_covariance_is_kernel_plus_nugget():
    b = GPBelief.from_grid((3, 3), 2.5, 4.0, 0.3, 0.5, nugget=0.02)
    plain = GPBelief.from_grid((3, 3), 2.5, 4.0, 0.3, 0.5)
    np.testing.assert_allclose(b.cov - plain.cov, 0.02 * np.eye(9), atol=1e-15)
    assert b.variance == pytest.approx(np.full(9, 0.32))


def test_fit_recovers_the_hyper_parameters_of_gp_draws():
    """Maps drawn from a known GP give back its length scale and variance (the fit is a real MLE)."""
    cfg = IPPConfig().replace(rows=12, cols=12)
    xy = cell_centres((12, 12), 2.5)
    K = prior_covariance(xy, 7.0, 0.1, 0.002)
    rng = np.random.default_rng(1)
    maps = 0.5 + rng.multivariate_normal(np.zeros(144), K, size=60)
    fit = gp_fit.minimise_lml(maps, xy, 0.5, cfg.grid.resolution)
    assert fit[0] == pytest.approx(7.0, rel=0.15)
    assert fit[1] == pytest.approx(0.1, rel=0.3)
    assert fit[2] == pytest.approx(0.002, rel=0.3)


@pytest.mark.parametrize("task", ["ipp_bench/Grid15Eval-v1", "ipp_bench/Grid15Train-v1"])
def test_task_file_values_reproduce_from_the_fit_seeds(task):
    """``ipp-bench fit-prior --task T`` from its own seeds gives the values written in the task file."""
    cfg = task_spec(task).config
    fit = gp_fit.fit_prior(cfg)
    assert fit.length_scale == pytest.approx(cfg.gp.length_scale, rel=2e-3)
    assert fit.signal_variance == pytest.approx(cfg.gp.signal_variance, rel=2e-3)
    assert fit.nugget == pytest.approx(cfg.gp.nugget, rel=5e-3)


def test_fitted_prior_beats_the_papers_constants_on_held_out_maps():
    cfg = task_spec("ipp_bench/Grid15Eval-v1").config
    gp = cfg.gp
    fitted = gp_fit.held_out_lml(cfg, gp.length_scale, gp.signal_variance, gp.nugget)
    paper = gp_fit.held_out_lml(cfg, 3.67, 1.82, 1e-9)
    assert math.isfinite(paper) and fitted > paper + 100.0  # nats per map


def test_bernoulli_maps_fit_to_a_nugget():
    """No spatial structure: the variance goes to the nugget (the reason v1 does not train on them)."""
    cfg = IPPConfig().replace(field="bernoulli", rows=10, cols=10)
    fit = gp_fit.fit_prior(cfg, maps=20)
    assert fit.nugget > 5 * fit.signal_variance


def test_write_gp_section_replaces_only_that_section(tmp_path):
    path = tmp_path / "t.toml"
    path.write_text('id = "x"\n\n[config.gp]\nlength_scale = 1.0\n\n[config.mission]\nbudget_s = 5.0\n')
    fit = gp_fit.PriorFit("regions", (3, 3), 40, 7, 8.123456, 0.0987654, 0.00123456, 0.5, 1.0)
    gp_fit.write_gp_section(path, fit, "ipp-bench fit-prior --task X --write")
    text = path.read_text()
    assert "length_scale = 8.123  # [m]" in text and "nugget = 0.001235" in text
    assert "ipp-bench fit-prior --task X --write" in text
    assert text.count("[config.gp]") == 1 and "budget_s = 5.0" in text and "length_scale = 1.0" not in text
