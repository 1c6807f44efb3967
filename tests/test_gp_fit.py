"""The prior fit against the maths: the log marginal likelihood formula, reproducible fits, and a
fitted prior that explains held-out maps better than the paper's constants."""

import math

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from ipp_bench.core import gp_fit
from ipp_bench.core.belief import GPBelief, cell_centres, prior_covariance
from ipp_bench.core.config import IPPConfig
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


def test_fitted_mean_is_the_likelihood_maximising_constant():
    """The profiled (GLS) mean beats every other constant mean under the same covariance."""
    rng = np.random.default_rng(3)
    xy = cell_centres((5, 6), 2.5)
    K = prior_covariance(xy, 5.0, 0.05, 0.001)
    maps = 0.07 + rng.multivariate_normal(np.zeros(30), K, size=8)
    m = gp_fit.gls_mean(maps, xy, 5.0, 0.05, 0.001)
    lml = gp_fit.log_marginal_likelihood(maps, xy, 5.0, 0.05, 0.001, m)
    for other in (m - 0.02, m - 1e-3, m + 1e-3, m + 0.02, 0.5):
        assert gp_fit.log_marginal_likelihood(maps, xy, 5.0, 0.05, 0.001, other) < lml
    # closed form against a dense solve: m = 1^T K^-1 sum_j x_j / (J 1^T K^-1 1)
    Kinv = np.linalg.inv(K)
    ones = np.ones(30)
    assert m == pytest.approx(ones @ Kinv @ maps.sum(axis=0) / (8 * ones @ Kinv @ ones), rel=1e-10)


@pytest.mark.parametrize("task", ["ipp_bench/Hotspots15Eval-v2",
                                  pytest.param("ipp_bench/Hotspots30Train-v2", marks=pytest.mark.slow)])
def test_v2_task_files_reproduce_from_the_fit_with_the_mean(task):
    """``ipp-bench fit-prior --task T --fit-mean`` gives the values written in the v2 task files,
    and the fitted mean explains held-out maps better than the paper's 0.5 refitted."""
    cfg = task_spec(task).config
    fit = gp_fit.fit_prior(cfg, fit_mean=True)
    assert fit.mean_fitted and fit.prior_mean == pytest.approx(cfg.gp.prior_mean, rel=2e-3)
    assert fit.length_scale == pytest.approx(cfg.gp.length_scale, rel=2e-3)
    assert fit.signal_variance == pytest.approx(cfg.gp.signal_variance, rel=2e-3)
    assert fit.nugget == pytest.approx(cfg.gp.nugget, rel=5e-3, abs=1e-9)
    half = gp_fit.fit_prior(cfg.replace(prior_mean=0.5))
    fitted = gp_fit.held_out_lml(cfg, cfg.gp.length_scale, cfg.gp.signal_variance, cfg.gp.nugget)
    fixed = gp_fit.held_out_lml(cfg, half.length_scale, half.signal_variance, half.nugget, prior_mean=0.5)
    assert fitted > fixed + 5.0  # nats per map


def test_gp_section_records_a_fitted_mean():
    fit = gp_fit.PriorFit("weed_patches", (3, 3), 40, 7, 6.9, 0.018, 0.00068, 0.036971234, 1.0, True)
    text = gp_fit.gp_section(fit, "ipp-bench fit-prior --task X --fit-mean --write")
    assert "mean fitted (generalised least squares)" in text and "prior_mean = 0.03697  # [field units]" in text


def test_a_fit_too_large_for_memory_is_refused_before_any_map_is_drawn():
    """128 x 128 cells: 5 covariances of 16384^2 floats (10 GiB) would end in SIGSEGV; refused first, with
    the estimate checked against the measured peak on a map that fits."""
    import tracemalloc

    from ipp_bench.core.limits import FIT_ARRAYS, fit_prior_bytes

    big = task_spec("ipp_bench/Hotspots128Eval-v2").config
    tracemalloc.start()
    for fit in (lambda: gp_fit.fit_prior(big, 40), lambda: gp_fit.held_out_lml(big, 5.0, 0.1, 1e-3)):
        with pytest.raises(ValueError, match=r"128 x 128 cells is too large to fit a prior on: .* 10 GiB \(limit"):
            fit()
    assert tracemalloc.get_traced_memory()[1] < 20 * 2**20
    tracemalloc.stop()
    small = IPPConfig().replace(rows=20, cols=20)
    maps = gp_fit.sample_maps(small, 40, 1)
    xy = cell_centres((20, 20), 2.5)
    tracemalloc.start()
    gp_fit.log_marginal_likelihood(maps, xy, 5.0, 0.1, 1e-3)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert FIT_ARRAYS * 400**2 * 8 <= fit_prior_bytes(small, 40) and peak <= fit_prior_bytes(small, 40)
