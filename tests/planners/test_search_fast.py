"""The look-ahead planners' fast evaluations against their references, on real decision states.

``mcts`` (gains from a low-rank factor of the updates along the tree path) against
``mcts:search=reference`` (a dense covariance copied and downdated per edge), and ``cmaes``'s batched
scoring of a population (from B = P D P) against ``cmaes:evaluation=reference`` (each candidate's
Kalman prediction): the same gains in exact arithmetic, so equal to round-off, and the same moves.
"""

from __future__ import annotations

import numpy as np
import pytest

from ipp_bench.envs import make_env
from ipp_bench.planners import make_planner, view_for

TASKS_15 = ["ipp_bench/Grid15Eval-v1", "ipp_bench/Hotspots15Eval-v2"]
TASKS_30 = ["ipp_bench/Grid30Eval-v1", "ipp_bench/Hotspots30Eval-v2"]
RTOL = 1e-9  # of the largest gain of the state (the bar; round-off is ~1e-14)


def _episode(task: str, seed: int, spec: str = "mcts:simulations=4,search=lowrank", steps: int = 3):
    """An env ``steps`` decisions into episode ``seed`` (flown by ``spec``), and its observation."""
    env = make_env(task)
    obs, _ = env.reset(seed=seed)
    planner = make_planner(spec)
    planner.reset(view_for(planner, env.unwrapped), seed)
    for _ in range(steps):
        obs, *_ = env.step(planner.act(obs))
    return env, obs


def _paths(rng, planner, root, depth: int, count: int):
    """``count`` random action paths of ``depth`` playable moves from ``root`` (by the reference's states)."""
    out = []
    for _ in range(count):
        state, path = root, []
        for _ in range(depth):
            if state.order is None:
                planner._expand_info(state)
            if state.order.size == 0:
                break
            a = int(rng.choice(state.order))
            path.append(a)
            state, _, _ = planner._transition(state, a)
        out.append(path)
    return out


@pytest.mark.parametrize("task", TASKS_15)
def test_lowrank_gains_equal_the_dense_reference_along_tree_paths(task):
    env, obs = _episode(task, seed=7)
    fast = make_planner("mcts:simulations=4,horizon_s=1000,search=lowrank")  # a long horizon: gains at every depth
    ref = make_planner("mcts:simulations=4,horizon_s=1000,search=reference")
    view = view_for(fast, env.unwrapped)
    fast.reset(view, 7)
    ref.reset(view, 7)
    ref_root, fast_root = ref._reference._root(obs), fast._root(obs)
    np.testing.assert_allclose(fast_root.gains, ref_root.gains, rtol=0, atol=RTOL * ref_root.gains.max())
    compared = 0
    for path in _paths(np.random.default_rng(0), ref._reference, ref_root, depth=6, count=4):
        r_state, f_state = ref_root, fast_root
        for a in path:
            r_state, r_rew, r_disc = ref._reference._transition(r_state, a)
            f_state, f_rew, f_disc = fast._transition(f_state, a)
            assert f_disc == r_disc and f_state.node == r_state.node
            np.testing.assert_allclose(f_rew, r_rew, rtol=RTOL)
            ref._reference._expand_info(r_state)
            fast._expand_info(f_state)
            scale = r_state.gains.max()
            assert scale > 0
            np.testing.assert_allclose(f_state.gains, r_state.gains, rtol=0, atol=RTOL * scale)
            assert np.array_equal(f_state.order, r_state.order)
            compared += 1
    assert compared >= 12  # depth 1 to 6 on four paths (fewer where the budget ends)


def test_a_leg_that_sees_nothing_keeps_the_factor():
    """Legs without read-outs (None) give 0 and leave the posterior as it was: the child shares the factor."""
    env, obs = _episode("ipp_bench/Grid15Eval-v1", seed=3, steps=1)
    fast = make_planner("mcts:simulations=2,search=lowrank")
    fast.reset(view_for(fast, env.unwrapped), 3)
    root = fast._root(obs)
    a = int(root.order[0])
    child, _, _ = fast._transition(root, a)
    fast._legs[(child.node, 0)] = None  # pretend the child's first leg sees nothing
    fast._node_legs.pop(child.node, None)
    fast._expand_info(child)
    assert child.gains[0] == 0.0
    grandchild, reward, _ = fast._transition(child, 0)
    assert reward == 0.0
    fast._expand_info(grandchild)
    assert grandchild.fdata is child.fdata and grandchild.r == child.r and grandchild.K is child.K


@pytest.mark.parametrize("task", TASKS_15)
def test_lowrank_search_picks_the_reference_move(task):
    env, obs = _episode(task, seed=11, steps=1)
    fast = make_planner("mcts:simulations=24,search=lowrank")
    ref = make_planner("mcts:simulations=24,search=reference")
    view = view_for(fast, env.unwrapped)
    fast.reset(view, 11)
    ref.reset(view, 11)
    for _ in range(2):
        fast.rng.bit_generator.state = ref.rng.bit_generator.state
        a_ref, a_fast = ref.act(obs), fast.act(obs)
        assert a_fast == a_ref
        assert fast.rng.bit_generator.state == ref.rng.bit_generator.state  # the same draws, as many
        obs, _, term, trunc, _ = env.step(a_ref)
        assert not (term or trunc)


def test_lowrank_search_is_deterministic_per_seed():
    moves = []
    for _ in range(2):
        env = make_env("ipp_bench/Hotspots15Eval-v2")
        obs, _ = env.reset(seed=5)
        planner = make_planner("mcts:simulations=12,search=lowrank")
        planner.reset(view_for(planner, env.unwrapped), 5)
        run = []
        for _ in range(4):
            a = planner.act(obs)
            run.append(a)
            obs, *_ = env.step(a)
        moves.append(run)
    assert moves[0] == moves[1]


@pytest.mark.parametrize("spec, message", [
    ("mcts:search=dense", r"mcts.search = 'dense' is invalid: expected one of \['lowrank', 'reference'\]"),
    ("cmaes:evaluation=fast", r"cmaes.evaluation = 'fast' is invalid: expected one of \['batched', 'reference'\]"),
])
def test_search_setting_is_checked(spec, message):
    with pytest.raises(ValueError, match=message):
        make_planner(spec)


# -- CMA-ES --------------------------------------------------------------------------------------------
def _cmaes_at(task: str, seed: int, decisions: int):
    """(env, batched planner, reference planner) after ``decisions`` waypoints flown by the reference."""
    env = make_env(task)
    env.reset(seed=seed)
    new = make_planner("cmaes:max_evals=24,evaluation=batched")
    ref = make_planner("cmaes:max_evals=24,evaluation=reference")
    view = view_for(new, env.unwrapped)
    new.reset(view, seed)
    ref.reset(view, seed)
    for _ in range(decisions):
        env.unwrapped.mission.fly_to(ref.next_waypoint())
    return env, new, ref


@pytest.mark.parametrize("task", TASKS_15 + TASKS_30[1:])
def test_cmaes_batched_objective_equals_the_reference(task):
    env, new, ref = _cmaes_at(task, seed=4, decisions=2)
    for planner in (new, ref):  # the decision's fixed terms, as next_waypoint sets them
        planner._belief = planner.view.belief
        planner._roi = planner.view.belief_roi()
        planner._before = planner.view.roi_trace(planner._belief.variance, planner._roi)
        planner._lo, planner._hi = planner._search_box()
        planner._begin_batched()
    assert new._PB is not None and ref._PB is None
    cands = np.random.default_rng(1).random((12, 3 * new.settings.n_waypoints))
    f_ref = np.array([ref._objective(c) for c in cands])
    f_new = np.array(new._objectives(list(cands)))
    assert np.all(f_ref < 0)
    np.testing.assert_allclose(f_new, f_ref, rtol=1e-10)


def test_cmaes_batched_flies_the_reference_waypoints():
    env, new, ref = _cmaes_at("ipp_bench/Hotspots15Eval-v2", seed=9, decisions=0)
    for _ in range(3):
        new.rng.bit_generator.state = ref.rng.bit_generator.state
        new._plan = None if ref._plan is None else ref._plan.copy()
        w_ref, w_new = ref.next_waypoint(), new.next_waypoint()
        np.testing.assert_allclose(w_new, w_ref, atol=1e-9)
        env.unwrapped.mission.fly_to(w_ref)


# -- 30 x 30 (slow) --------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("task", TASKS_30)
def test_lowrank_search_on_30x30(task):
    env, obs = _episode(task, seed=2, steps=1)
    fast = make_planner("mcts:simulations=24,search=lowrank")
    ref = make_planner("mcts:simulations=24,search=reference")
    view = view_for(fast, env.unwrapped)
    fast.reset(view, 2)
    ref.reset(view, 2)
    for _ in range(2):
        fast.rng.bit_generator.state = ref.rng.bit_generator.state
        a_ref, a_fast = ref.act(obs), fast.act(obs)
        assert a_fast == a_ref
        obs, *_ = env.step(a_ref)
