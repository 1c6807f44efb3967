"""The probe planners of ``benchmarks/bench_teachers.py`` (issue 17's G20 wall): each reduces to greedy,
or to the lawnmower, where its definition says it must."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from ipp_bench.envs import make_env
from ipp_bench.eval.runner import run_episode
from ipp_bench.planners import REGISTRY, make_planner, register
from ipp_bench.planners.greedy import leg_batch  # the legs whose gain greedy divides by the flight time

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"
TASK = "ipp_bench/Grid15Train-v1"
SEED = 10_000_003


@pytest.fixture(scope="module")
def bt():
    script = BENCH / "bench_teachers.py"
    if not script.is_file():
        pytest.skip("benchmarks/ is not beside the package (an installed copy, not the repository)")
    spec = importlib.util.spec_from_file_location("bench_teachers", script)
    mod = importlib.util.module_from_spec(spec)
    saved_registry, saved_module = dict(REGISTRY), sys.modules.get("bench_teachers")
    sys.modules["bench_teachers"] = mod
    spec.loader.exec_module(mod)
    mod.register_probes()
    yield mod
    # the probes are not the suite's planners: a later test's default planner list must not hold them
    REGISTRY.clear()
    REGISTRY.update(saved_registry)
    if saved_module is None:
        sys.modules.pop("bench_teachers", None)
    else:
        sys.modules["bench_teachers"] = saved_module


def _fly(spec: str, on_decision=None):
    res = run_episode(TASK, spec, SEED, env=make_env(TASK), on_decision=on_decision)
    return [r["uncertainty_reduction_pct"] for r in res.report], res.decisions


def _check_decisions(bt, base, spec: str, check) -> list[int]:
    """Fly ``spec`` (a name new to the registry, then its options) as ``base`` with ``check(view, node,
    scores, valid)`` run on every decision's scores before it acts (masked neighbours must be -inf);
    the nodes decided at."""
    seen = []

    class Checked(base):
        def act(self, obs):
            node = int(obs["current_node"][0])
            got, ok = self.scores(obs), obs["action_mask"].astype(bool)
            check(self.view, node, got, ok)
            assert np.all(np.isneginf(got[~ok]))
            seen.append(node)
            return super().act(obs)

    name = spec.split(":")[0]
    setattr(bt, f"Checked_{name}", Checked)
    register(name, f"bench_teachers:Checked_{name}")
    _fly(spec)
    return seen


def test_switches_never_reached_are_greedy(bt):
    """A switch later than the budget, power 1 and beta = the task's: the planner is greedy, decision by decision."""
    greedy = _fly("greedy")
    for spec in ("knob", "knob:low_after_s=1000", "roibeta:beta=1", "lateroll:switch_s=1000,top=2",
                 "sweeproi:switch_s=1000", "tieroll:eps=0,horizon_s=20"):
        assert _fly(spec) == greedy, spec
    assert _fly("knob:power=1.2") != greedy  # the knob does move the planner


def test_knob_score_is_gain_over_duration_to_the_power(bt):
    """score = greedy's gain per second x duration ** (1 - power) = gain / duration ** power, on the states
    the planner decides on (masked neighbours -inf)."""
    def check(view, node, got, ok):
        dur = view.neighbour_durations(node, view.position)[ok]
        gain = view.belief.trace_reductions(leg_batch(view, node), view.belief_roi())[ok]
        np.testing.assert_allclose(got[ok], gain / dur ** 0.7, rtol=1e-10)

    seen = _check_decisions(bt, bt.KnobGreedy, "knobcheck:power=0.7", check)
    assert len(seen) >= 10


def test_graphcover_flies_the_lawnmower_lanes_at_the_lowest_level(bt):
    """Its lane ends are the lawnmower's, each within half a cell diagonal of a roadmap node, all at the
    lowest altitude, and it reaches the first one."""
    from ipp_bench.planners import view_for
    from ipp_bench.planners.simple import CoveragePlanner

    env = make_env(TASK)
    env.reset(seed=SEED)
    gc = make_planner("graphcover")
    gc.reset(view_for(gc, env), SEED)
    lawn = CoveragePlanner()
    lawn.reset(view_for(lawn, env), SEED)
    half_diag = env.config.grid.resolution * math.sqrt(2) / 2
    low = env.config.graph.altitudes[0]
    assert np.allclose(gc._pts[:, 2], low)
    lanes = np.unique(gc._pts[:, 1])
    want = np.unique(np.array([lawn._target, *(next(lawn._targets) for _ in range(20))])[:, 1])
    assert lanes.size == want.size
    assert np.all(np.abs(lanes - want) <= half_diag + 1e-9)
    visited = []
    _fly("graphcover", on_decision=lambda d: visited.append(int(d.obs["current_node"][0])))
    positions = gc.view.roadmap.positions
    assert any(np.allclose(positions[n], gc._pts[1]) for n in visited)


@pytest.mark.parametrize("probe, before", [("latesample", "attention"), ("greedysample", "greedy")])
def test_late_sampling_probes_are_their_first_planner_before_the_switch_and_the_sampling_after(bt, probe, before):
    pytest.importorskip("torch")
    assert _fly(f"{probe}:switch_s=1000") == _fly(before)
    from ipp_bench.planners.base import RobotView

    flights = {}
    for spec in (f"{probe}:switch_s=0,samples=3", "attention:samples=3"):
        env = make_env(TASK)
        obs, _ = env.reset(seed=SEED)
        planner = make_planner(spec)
        planner.reset(RobotView(env.unwrapped), SEED)
        flights[spec] = []
        for _ in range(4):
            a = planner.act(obs)
            flights[spec].append((a, planner.plans))
            obs, *_ = env.step(a)
    assert all(len(plans) == 3 for _, plans in flights["attention:samples=3"])  # it imagined, every decision
    assert flights[f"{probe}:switch_s=0,samples=3"] == flights["attention:samples=3"]


def test_tie_rollout_is_the_rollout_among_greedy_near_ties(bt):
    """eps = 0 leaves greedy's choice alone (above); eps = 1 admits every leg, so with the same ``top`` and
    horizon it is the greedy rollout, decision by decision."""
    tie = _fly("tieroll:eps=1,top=2,horizon_s=15")
    assert tie == _fly("rollout:top=2,horizon_s=15")
    assert tie != _fly("greedy")  # the rollout does move it


def test_soft_roi_score_is_the_weighted_kalman_variance_reduction(bt):
    """softroi's score against the Kalman update written out: P+ = P - P H^T (H P H^T + R)^-1 H P per leg,
    score = sum_i Phi((mu_i - mu_th) / sigma_i) (P - P+)_ii / flight time; with 0/1 weights the weighted
    reduction is greedy's trace reduction."""
    from scipy.special import ndtr

    from ipp_bench.planners.base import stacked_leg

    def check(view, node, got, ok):
        P, b = view.belief.cov, view.belief
        w = ndtr((b.mean - view.config.mission.mu_th) / np.sqrt(b.variance))
        dur = view.neighbour_durations(node, view.position)
        for a in np.flatnonzero(ok):
            leg = stacked_leg(view, node, int(a))
            if leg is None:
                assert got[a] == 0.0
                continue
            cells, W, var = leg
            H = np.zeros((W.shape[0], P.shape[0]))
            H[:, cells] = W
            post = P - P @ H.T @ np.linalg.solve(H @ P @ H.T + np.diag(var), H @ P)
            np.testing.assert_allclose(got[a], w @ np.diag(P - post) / dur[a], rtol=1e-8, atol=1e-14)
        roi = view.belief_roi()
        batch = leg_batch(view, node)
        np.testing.assert_allclose(bt.soft_trace_reductions(P, batch, roi.astype(float)),
                                   view.belief.trace_reductions(batch, roi), rtol=1e-9, atol=1e-14)

    seen = _check_decisions(bt, bt.SoftRoiGreedy, "softcheck", check)
    assert len(seen) >= 10
