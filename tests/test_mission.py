"""Mission clock, measurement spacing, budget refusal and time-stamped metrics."""

import numpy as np
import pytest

from ipp_bench.core.config import IPPConfig
from ipp_bench.core.mission import BudgetExceededError, Mission, cell_to_xyz


def make(budget=100.0, **kw):
    cfg = IPPConfig().replace(budget_s=budget, **kw)
    truth = np.random.default_rng(0).random((15, 15))
    return Mission(cfg, truth, np.random.default_rng(1), cell_to_xyz(cfg, 2, 2, 14.0))


def test_start_measurement_and_prior_record():
    m = make()
    assert m.history[0].time_s == 0 and m.history[0].uncertainty_reduction_pct == 0
    assert m.n_measurements == 9  # 6 x 6 clipped footprint at 14 m, 2 x 2 binned
    assert make(measure_at_start=False).n_measurements == 0


def test_measures_every_spacing_and_on_arrival():
    m = make(measure_at_start=False)
    start = m.position.copy()
    leg = m.fly_to(start + [20.0, 0.0, 0.0])  # 20 m: at 7.5, 15 and arrival
    assert [round(p[1] - start[0], 6) for p in m.measurement_log] == [7.5, 15.0, 20.0]
    assert leg.duration_s == pytest.approx(10.0) and m.time_s == pytest.approx(10.0)
    m.fly_to(m.position + [0.0, 10.0, 0.0])  # spacing restarts at arrival: at 7.5 and 10
    assert len(m.measurement_log) == 5
    np.testing.assert_allclose([t for t, *_ in m.measurement_log], [3.75, 7.5, 10.0, 13.75, 15.0])


def test_budget_refusal_is_clear_and_loses_nothing():
    m = make(budget=10.0)
    before = (m.time_s, m.position.copy(), m.belief.cov.copy())
    with pytest.raises(BudgetExceededError, match=r"takes 12.50 s but only 10.00 s"):
        m.fly_to(m.position + [25.0, 0.0, 0.0])
    assert m.time_s == before[0]
    np.testing.assert_array_equal(m.position, before[1])
    np.testing.assert_array_equal(m.belief.cov, before[2])
    m.fly_to(m.position + [20.0, 0.0, 0.0])  # exactly the budget is fine
    assert m.remaining_s == 0.0


def test_invalid_targets():
    m = make()
    with pytest.raises(ValueError, match="outside the map"):
        m.fly_to((50.0, 5.0, 8.0))
    with pytest.raises(ValueError, match="expected three finite numbers"):
        m.fly_to("up")
    with pytest.raises(ValueError, match="already there"):
        m.fly_to(m.position)


@pytest.mark.parametrize("target, where", [
    ((20.0, 20.0, 60.0), "above the highest level"), ((20.0, 20.0, 0.001), "below the lowest level"),
    ((20.0, 20.0, 7.9), "just below the lowest level"), ((37.6, 20.0, 8.0), "beyond the map's edge"),
], ids=["z=60", "z=0.001", "z=7.9", "x=37.6"])
def test_a_waypoint_outside_the_flight_envelope_is_refused_whatever_planner_asks(target, where):
    """The task's altitudes (8 and 14 m) bound the flight as the map does: a planner that asks for 60 m
    (a wider footprint the task never offers) or 1 mm is refused with one line naming the range."""
    m = make()
    with pytest.raises(ValueError) as err:
        m.fly_to(target)
    assert "valid is x in [0, 37.5], y in [0, 37.5], z in [8, 14] [m]" in str(err.value), where
    assert m.time_s == 0.0 and len(m.path) == 1  # nothing flown
    m.fly_to((20.0, 20.0, 8.0))  # the envelope's own edges are inside it
    m.fly_to((37.5, 20.0, 14.0))


def test_a_start_outside_the_flight_envelope_is_refused():
    cfg = IPPConfig()
    with pytest.raises(ValueError, match=r"z in \[8, 14\]"):
        Mission(cfg, np.zeros((15, 15)), np.random.default_rng(0), (5.0, 5.0, 30.0))


def test_a_belief_that_is_no_longer_finite_is_an_error_never_a_metric():
    m = make()
    m.belief.mean[:] = 1e300  # as an overflowing prior would leave it: its squared error is inf
    with pytest.raises(FloatingPointError, match="no longer finite at t = .* gp.prior_mean = 0.5"):
        m.fly_to(m.position + [10.0, 0.0, 0.0])


def test_metrics_at_report_times_are_exact():
    # report times split batches, so metrics_at(T) holds exactly the measurements taken up to T
    m = make(budget=200.0, measure_at_start=False, report_times=(50.0, 80.0))
    for delta in ([30.0, 0.0, 0.0], [0.0, 30.0, -6.0], [-30.0, 0.0, 0.0], [0.0, -30.0, 6.0],
                  [25.0, 25.0, 0.0], [-20.0, 0.0, -6.0]):
        m.fly_to(m.position + delta)
    assert m.time_s > 80.0
    for T in (50.0, 80.0):
        expected = sum(m.sensor.observe(p).m for t, *p in m.measurement_log if t <= T)
        assert m.metrics_at(T)["measurements"] == expected
    red = [m.metrics_at(t)["uncertainty_reduction_pct"] for t in (0, 20, 40, 50, 60, m.time_s)]
    assert all(b >= a - 1e-9 for a, b in zip(red, red[1:]))  # uncertainty never grows
    assert m.metrics_at(1e9)["trace_roi"] == m.history[-1].trace_roi


def test_batch_at_report_time_boundary():
    m = make(budget=200.0, measure_at_start=False, report_times=(5.0, 10.0))
    m.fly_to(m.position + [20.0, 0.0, 0.0])  # measurements at 3.75 s, 7.5 s, 10 s
    rec = [round(r.time_s, 6) for r in m.history]
    assert rec == [0.0, 3.75, 10.0]
    assert m.metrics_at(5.0)["measurements"] == m.sensor.observe(m.measurement_log[0][1:]).m


def test_same_seed_same_measurements():
    a, b = make(), make()
    for m in (a, b):
        m.fly_to(m.position + [10.0, 5.0, -6.0])
    np.testing.assert_array_equal(a.belief.mean, b.belief.mean)


# -- the clock: one rule of what a leg costs -----------------------------------------------------
def test_leg_durations_are_length_over_speed():
    m = make(budget=100.0, speed=2.5)
    start = np.array([1.0, 2.0, 8.0])
    ends = np.array([[4.0, 6.0, 8.0], [1.0, 2.0, 14.0], [1.0, 2.0, 8.0]])  # 5 m, 6 m, 0 m
    np.testing.assert_array_equal(m.leg_durations(start, ends), [2.0, 2.4, 0.0])
    assert m.leg_time(m.position + [3.0, 4.0, 0.0]) == 2.0


def test_affordable_is_duration_within_the_remaining_budget():
    m = make(budget=10.0)  # speed 2 m/s: 20 m of flight
    here = m.position
    ends = here + np.array([[20.0, 0.0, 0.0], [20.0 + 1e-9, 0.0, 0.0], [21.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    np.testing.assert_array_equal(m.affordable(ends), [True, True, False, True])
    m.fly_to(here + [10.0, 0.0, 0.0])  # 5 s used
    np.testing.assert_array_equal(m.affordable(m.position + np.array([[10.0, 0, 0], [10.5, 0, 0]])), [True, False])


def test_fly_to_refuses_exactly_what_affordable_refuses():
    m = make(budget=10.0)
    far = m.position + [21.0, 0.0, 0.0]
    assert not m.affordable(far[None])[0]
    with pytest.raises(BudgetExceededError):
        m.fly_to(far)
    near = m.position + [20.0, 0.0, 0.0]
    assert m.affordable(near[None])[0]
    m.fly_to(near)
    assert m.time_s == 10.0 and m.remaining_s == 0.0


def test_one_update_signature_for_both_belief_models_and_hooks_see_every_batch():
    """The mission never asks which belief it has: white noise or the camera-error states, one
    ``update(observations, values)``; the field belief it exposes is updated in place."""
    from ipp_bench.core.belief import GPBelief, PersistentErrorBelief, WhiteNoiseBelief, normalised_innovation
    from ipp_bench.core.sensor import stack

    for states, cls in ((False, WhiteNoiseBelief), (True, PersistentErrorBelief)):
        kw = dict(persistent_var=0.004, persistent_var_binned=0.008, persistent_corr=0.5) if states else {}
        m = make(**kw)
        assert isinstance(m.belief_model, cls) and m.belief_model.field is m.belief
        seen = []
        m.update_hooks.append(lambda obs, zs, t, seen=seen: seen.append((len(obs), t)))
        before = m.belief.copy()
        m.fly_to(cell_to_xyz(m.config, 6, 2, 8.0))
        assert seen and all(n > 0 for n, _ in seen) and seen[-1][1] == pytest.approx(m.time_s)
        assert m.belief.variance.sum() < before.variance.sum()
    # white noise: the update is the GP's own local update on the stacked read-outs (and NIS alike)
    m = make()
    obs = [m.sensor.observe(cell_to_xyz(m.config, 4, 4, 8.0)), m.sensor.observe(cell_to_xyz(m.config, 5, 4, 14.0))]
    zs = [np.full(o.m, 0.3) for o in obs]
    ref = m.belief.copy()
    cells, W, var = stack(obs)
    nis_ref = normalised_innovation(ref, cells, W, np.concatenate(zs), var)
    assert m.belief_model.normalised_innovation(obs, zs) == nis_ref
    ref.update_local(cells, W, np.concatenate(zs), var)
    m.belief_model.update(obs, zs)
    np.testing.assert_array_equal(m.belief.mean, ref.mean)
    np.testing.assert_array_equal(m.belief.cov, ref.cov)
    assert isinstance(ref, GPBelief)


def test_the_graph_platform_is_straight_legs_at_the_mission_speed():
    from ipp_bench.core.mission import StraightLegs

    m = make()
    assert isinstance(m.platform, StraightLegs)
    ends = np.array([cell_to_xyz(m.config, 6, 2, 14.0), cell_to_xyz(m.config, 2, 6, 8.0)])
    d = np.linalg.norm(ends - m.position, axis=1)
    np.testing.assert_allclose(m.leg_durations(m.position, ends), d / m.config.mission.speed, rtol=1e-15)
    leg = m.fly_to(ends[0])
    assert leg.duration_s == pytest.approx(d[0] / m.config.mission.speed) and m.time_s == pytest.approx(leg.duration_s)
