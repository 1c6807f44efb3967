"""Bad planner settings are refused in one line before any work; what a planner reads of an episode
is its view's public methods, and no attribute path from the view leads to the ground truth."""

from __future__ import annotations

import gc
import inspect
import signal
from contextlib import contextmanager

import numpy as np
import pytest

from ipp_bench.cli import main
from ipp_bench.core._threads import available_cpus
from ipp_bench.envs import make_env
from ipp_bench.planners import RobotView, TruthView, make_planner, parse_spec, split_specs, view_for
from ipp_bench.planners.base import GraphPlanner
from ipp_bench.planners.episode import fly_episode, start_episode

TASK = "ipp_bench/Grid15Eval-v1"


@contextmanager
def deadline(seconds: int):
    """Fail (instead of hanging the suite) when the block runs longer than ``seconds``."""
    def stop(*_):
        raise TimeoutError(f"still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, stop)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def _error_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    return err


# -- coverage: footprint over the whole map, altitudes outside the task's --------------------------------------


def test_coverage_on_a_map_its_footprint_covers_flies_to_the_centre_once_and_ends():
    env = make_env(TASK, rows=3, cols=3, k=4)  # 7.5 m x 7.5 m; the footprint at 8 m is 2 x 8 tan 30 deg = 9.24 m
    width, height = env.config.grid.size_m
    side = env.sensor.footprint_side(8.0)
    assert side == pytest.approx(2 * 8.0 * np.tan(np.radians(30.0))) and side > max(width, height)
    flown = []
    with deadline(30):
        result = fly_episode(env, "coverage", 0, on_decision=lambda d: flown.append(np.asarray(d.action)))
    np.testing.assert_allclose(flown[-1], [width / 2, height / 2, 8.0])
    assert result.decisions == len(flown) == 1  # the one look that sees the whole map, then nothing to cover
    assert env.mission.n_measurements > 0 and result.final["time_s"] < env.config.mission.budget_s


def test_coverage_whose_one_lane_spans_the_map_still_mows_back_and_forth():
    """Footprint wider than the map's height but not its width: one lane, flown both ways until the budget ends."""
    env = make_env(TASK, rows=3, cols=15, k=4)
    flown = []
    with deadline(30):
        fly_episode(env, "coverage", 0, on_decision=lambda d: flown.append(np.asarray(d.action)))
    ys = {round(float(p[1]), 9) for p in flown}
    assert ys == {env.config.grid.size_m[1] / 2} and len(flown) > 3
    assert env.mission.remaining_s < 1.0  # the budget is spent, not abandoned


@pytest.mark.parametrize("altitude", ["60", "100", "0.001", "7.99", "14.01"])
def test_a_coverage_altitude_outside_the_tasks_is_refused_before_the_episode(altitude, capsys):
    assert main(["evaluate", "--task", TASK, "--planner", f"coverage:altitude={altitude}"]) == 2
    err = _error_line(capsys)
    assert err == (f"ipp-bench: error: coverage.altitude = {float(altitude)} is invalid: expected an altitude in "
                   "[8, 14] m (the task's flight envelope, graph.altitudes)"), err


@pytest.mark.parametrize("altitude", [8.0, 11.0, 14.0])
def test_a_coverage_altitude_within_the_tasks_flies_there(altitude):
    env = make_env(TASK, budget_s=30.0, report_times=[30.0])
    flown = []
    fly_episode(env, f"coverage:altitude={altitude}", 0, on_decision=lambda d: flown.append(np.asarray(d.action)))
    assert flown and all(p[2] == pytest.approx(altitude) for p in flown[1:])


# -- specs -----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("spec", ["mcts:simulations=3,simulations=4", "greedy", "mcts:simulations=3, simulations = 3"])
def test_a_setting_given_twice_is_refused(spec, capsys):
    if spec == "greedy":
        assert parse_spec(spec) == ("greedy", {})
        return
    with pytest.raises(ValueError, match=r"setting 'simulations' is given twice .*give each setting once") as err:
        parse_spec(spec)
    assert "\n" not in str(err.value)
    assert main(["evaluate", "--task", TASK, "--planner", spec]) == 2
    assert "given twice" in _error_line(capsys)


def test_a_setting_given_twice_across_command_line_words_is_refused():
    (spec,) = split_specs(["mcts:simulations=3", "simulations=4"])
    with pytest.raises(ValueError, match="given twice"):
        make_planner(spec)


# -- attention's threads -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("threads", ["100000", str(available_cpus() + 1), "-1", "2.5", "many"])
def test_attention_threads_beyond_the_cpus_are_refused_before_torch_sees_them(threads):
    pytest.importorskip("torch")
    with pytest.raises(ValueError) as err:
        make_planner(f"attention:threads={threads}")
    message = str(err.value)
    assert message.startswith("attention.threads = ") and "\n" not in message
    assert message.endswith(f"expected 0 (leave torch's setting alone) or an integer from 1 to {available_cpus()} "
                            "(the CPUs this process may run on)") or "expected an integer" in message


def test_attention_threads_within_the_cpus_are_kept():
    pytest.importorskip("torch")
    from ipp_bench.policies.planner import AttentionConfig

    cpus = available_cpus()
    assert AttentionConfig(threads=0).threads == 0 and AttentionConfig(threads=cpus).threads == cpus


# -- the view: no way to the truth -----------------------------------------------------------------------------


def _episode_view(env):
    env.reset(seed=0)
    return RobotView(env)


def _truth_objects(env):
    m = env.mission
    return {id(env), id(m), id(m.truth), id(m._truth_flat), id(m.eval_roi), id(m.rng)}


def _public_callables(view):
    for name in dir(view):
        if name.startswith("__"):
            continue
        attr = inspect.getattr_static(type(view), name, None)
        value = attr.fget if isinstance(attr, property) else getattr(view, name)
        if callable(value):
            yield name, value


def test_the_view_has_no_env_no_dict_and_its_methods_hold_no_env():
    env = make_env(TASK)
    view = _episode_view(env)
    for path in ("_env", "env", "mission", "_mission", "__dict__"):
        with pytest.raises(AttributeError):
            getattr(view, path)
    with pytest.raises(TypeError):
        vars(view)
    truth = _truth_objects(env)
    assert not any(id(r) in truth for r in gc.get_referents(view))
    for name, fn in _public_callables(view):
        assert getattr(fn, "__self__", view) is view or isinstance(fn, staticmethod), name
        func = getattr(fn, "__func__", fn)
        assert not hasattr(func, "__wrapped__"), name
        cells = getattr(func, "__closure__", None) or ()
        assert not any(id(c.cell_contents) in truth for c in cells), name
        assert not any(isinstance(c.cell_contents, type(env)) for c in cells), name


def test_no_attribute_path_from_the_view_reaches_the_env_or_the_truth():
    """Breadth-first over what attribute access gives (instance state, what the public methods and
    properties return, bound ``__self__``, closures): never the env, its mission, the truth or the noise."""
    env = make_env(TASK)
    view = _episode_view(env)
    truth = _truth_objects(env)
    values = [getattr(view, n) for n in ("config", "roadmap", "sensor", "belief", "position", "current_node",
                                         "time_s", "remaining_s")]
    values += [view.action_mask(), view.belief_roi(), view.node_footprint(), view.static_key(), view.error_states()]
    seen, queue = set(), [view, *values]
    while queue:
        obj = queue.pop()
        if id(obj) in seen or isinstance(obj, (type, type(np), str, bytes, int, float, bool)) or obj is None:
            continue
        seen.add(id(obj))
        assert id(obj) not in truth, f"{type(obj).__name__} reached from the view"
        nxt = []
        if isinstance(obj, dict):
            nxt += [*obj.keys(), *obj.values()]
        elif isinstance(obj, (list, tuple, set, frozenset)):
            nxt += list(obj)
        if hasattr(obj, "__dict__") and not callable(obj):
            nxt += list(vars(obj).values())
        for slot in getattr(type(obj), "__slots__", ()):
            if slot != "__weakref__" and hasattr(obj, slot):
                nxt.append(getattr(obj, slot))
        for attr in ("__self__", "__wrapped__", "base"):  # bound methods, decorators, numpy views
            if attr in dir(obj):
                nxt.append(getattr(obj, attr, None))
        for cell in getattr(obj, "__closure__", None) or ():
            nxt.append(cell.cell_contents)
        queue += nxt
    assert len(seen) > 20  # the walk went somewhere


def test_a_planner_that_digs_for_the_truth_through_its_view_fails_its_first_decision():
    class Digger(GraphPlanner):
        name = "digger"

        def act(self, obs):
            roi = self.view._env.mission.eval_roi  # the path that used to exist
            return int(np.flatnonzero(obs["action_mask"])[0]) + int(roi.any()) * 0

    with pytest.raises(AttributeError, match="_env"):
        fly_episode(make_env(TASK, budget_s=20.0, report_times=[20.0]), Digger(), 0)


def test_only_the_oracle_gets_the_truths_roi_and_a_copy_is_the_same_view():
    import copy
    import pickle

    env = make_env(TASK)
    oracle, _ = start_episode(env, "oracle", 0)
    greedy, _ = start_episode(env, "greedy", 0)
    assert isinstance(oracle.view, TruthView) and type(greedy.view) is RobotView
    np.testing.assert_array_equal(oracle.view.true_roi(), env.mission.eval_roi)
    assert not hasattr(greedy.view, "true_roi")
    assert copy.copy(greedy.view) is greedy.view and copy.deepcopy(greedy.view) is greedy.view
    with pytest.raises(AttributeError):
        oracle.view.__dict__  # noqa: B018
    with pytest.raises(TypeError, match="cannot be pickled"):
        pickle.dumps(greedy.view)
    assert type(view_for(greedy, env)) is RobotView


@pytest.mark.parametrize("horizon", ["1e-300", "1e-9", "0"])
def test_an_mcts_horizon_within_the_clocks_tolerance_is_refused_naming_the_setting(horizon):
    """At or below the clock's tolerance (1e-9 s) the root counts as already at the horizon, no leg is
    scored and the episode would fail with no affordable neighbour: refused when the spec is read."""
    from ipp_bench.planners import make_planner

    with pytest.raises(ValueError, match=r"mcts\.horizon_s = .* is invalid: expected a finite number > 1e-09 \[s\]"):
        make_planner(f"mcts:horizon_s={horizon}")
    make_planner("mcts:horizon_s=2e-9")  # just above it: a search that looks ahead almost nothing, but runs
