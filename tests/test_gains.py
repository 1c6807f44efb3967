"""ipp_bench.core.gains against the maths it implements: the look-gain feature against the Kalman update where
its assumption holds (white noise and the camera-error states), the batched look gains against the dense
Kalman update, and the far targets against Dijkstra's quickest paths on the mission's leg durations."""

import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

from ipp_bench.core import metrics as M
from ipp_bench.core.belief import GPBelief
from ipp_bench.core.gains import (
    _GRAPHS,
    LookBatch,
    LookGain,
    beats,
    best_far_target,
    duration_graph,
    far_move,
    first_best,
)
from ipp_bench.envs import make_env
from ipp_bench.planners import make_planner, view_for
from ipp_bench.planners.base import RobotView

HOT = "ipp_bench/Hotspots30Eval-v2"


def _stepped(task, seed, steps):
    """An env, its robot view and observation after ``steps`` of greedy (a belief that is not the prior)."""
    env = make_env(task)
    obs, _ = env.reset(seed=seed)
    greedy = make_planner("greedy")
    view = RobotView(env)
    greedy.reset(view, seed)
    for _ in range(steps):
        obs, *_ = env.step(greedy.act(obs))
    return env, view, obs


# -- the look-gain feature --------------------------------------------------------------------------


def test_single_cell_read_outs_of_an_uncorrelated_belief_are_exact():
    env = make_env("ipp_bench/Grid15Eval-v1")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    n = env.config.grid.n_cells
    belief = GPBelief(np.full(n, 0.5), np.diag(rng.uniform(0.01, 0.1, n)))
    roi = rng.random(n) < 0.5
    gain = LookGain.of(env)(belief.variance, roi)
    low = np.flatnonzero(env.roadmap.positions[:, 2] < 10.0)  # 8 m: one read-out per cell
    for i in low[:: max(len(low) // 10, 1)]:
        obs = env.sensor.observe(env.roadmap.positions[i])
        post = RobotView.predict_variance(belief, [obs])
        before = M.trace_roi(belief.variance, roi)
        exact = 10 * (before - M.trace_roi(post, roi)) / before
        assert gain[i] == pytest.approx(exact, rel=1e-4)




def _error_belief(env, neighbour_corr: float = 0.0):
    """A camera-error belief on ``env``'s grid: an uncorrelated field prior, the task's error constants
    (``neighbour_corr`` for the persistent errors' spatial correlation), after a few 8 m looks."""
    import dataclasses

    from ipp_bench.core.belief import PersistentErrorBelief

    rng = np.random.default_rng(4)
    n = env.config.grid.n_cells
    sensor = dataclasses.replace(env.sensor.cfg, persistent_neighbour_corr=neighbour_corr)
    belief = PersistentErrorBelief(GPBelief(rng.uniform(0.2, 0.8, n), np.diag(rng.uniform(0.02, 0.15, n))), sensor)
    low = np.flatnonzero(env.roadmap.positions[:, 2] < 10.0)
    for i in rng.choice(low, 12, replace=False):  # some cells seen, a few of them several times
        obs = env.sensor.observe(env.roadmap.positions[i])
        belief.update([obs], [rng.uniform(0.0, 1.0, obs.m)])
    return belief


def test_camera_error_look_gain_is_the_augmented_kalman_formula_for_single_cell_read_outs():
    """On the deployment's sensor (persistent per-cell error states), with an uncorrelated belief and
    independent cells' errors, an 8 m read-out's rows are single cells: the feature equals the exact
    reduction of the batch formula on the augmented state [x, u_1, u_2] (the white noise at the
    predicted value's scale), and the white-noise formula overstates it where cells were seen before."""
    from ipp_bench.core.belief import value_scale

    env = make_env("ipp_bench/Weed15Twin-v1")
    env.reset(seed=0)
    belief = _error_belief(env)
    n, P = env.config.grid.n_cells, belief.state.cov
    roi = np.random.default_rng(5).random(n) < 0.6
    var = belief.field.variance
    gain = LookGain.of(env)(var, roi, belief)
    white = LookGain.of(env)(var, roi)
    before = var[roi].sum()
    low = np.flatnonzero(env.roadmap.positions[:, 2] < 10.0)
    checked = repeated = 0
    for i in low:
        obs = env.sensor.observe(env.roadmap.positions[i])
        off = belief.offset[obs.factor]
        sd = np.where(belief.seen[obs.cells], belief.sd[obs.factor][obs.cells],
                      np.sqrt(belief.variances[obs.factor] * value_scale(belief.field.mean[obs.cells], belief.floor)))
        H = np.zeros((obs.m, P.shape[0]))
        H[np.arange(obs.m), obs.cells] = 1.0  # W = I at 8 m
        H[np.arange(obs.m), obs.cells + off] = sd
        R = (obs.var - obs.persistent) * value_scale(belief.field.mean[obs.cells], belief.floor)
        S = H @ P @ H.T + np.diag(R)
        K = P[:n] @ H.T
        exact = 10 * np.einsum("ij,jk,ik->i", K, np.linalg.inv(S), K)[roi].sum() / before
        assert gain[i] == pytest.approx(exact, rel=1e-5)
        checked += 1
        if belief.seen[obs.cells].all():
            repeated += 1
            assert white[i] > 2 * gain[i]  # white noise: another look would pin the error again
    assert checked > 20 and repeated > 0




def test_tasks_that_share_a_roadmap_keep_their_own_cameras_feature():
    """Grid15Eval-v1 and the deployment's twin share one roadmap object but not their camera: the
    feature of each is the one built from its own camera, whichever task built its feature first."""
    grid, twin = make_env("ipp_bench/Grid15Eval-v1"), make_env("ipp_bench/Weed15Twin-v1")
    grid.reset(seed=0)
    twin.reset(seed=0)
    assert grid.roadmap is twin.roadmap and grid.sensor.cfg != twin.sensor.cfg
    var, roi = twin.mission.belief.variance, twin.mission.belief_roi()
    LookGain.of(grid)(var, roi)  # built first, from the other camera
    own = LookGain(twin.roadmap.positions, twin.sensor, twin.config.grid.n_cells)
    np.testing.assert_array_equal(LookGain.of(twin)(var, roi), own(var, roi))
    np.testing.assert_array_equal(LookGain.of(twin).noise, own.noise)
    assert not np.array_equal(LookGain.of(grid).noise, own.noise)


# -- exact look gains ---------------------------------------------------------------------------------


def test_a_look_batch_is_the_kalman_trace_reduction_of_each_look_alone():
    """Looks spread over the map, each on its own cells: each one's ROI trace reduction is that of the
    dense Kalman update P+ = P - P H^T S^-1 H P, and the batch agrees with the union-of-cells batch formula."""
    from ipp_bench.core.belief import LegBatch, trace_reductions
    from ipp_bench.core.sensor import stack

    env, _, _ = _stepped(HOT, 3, 5)
    P = env.mission.belief.cov
    roi = env.mission.eval_roi | env.mission.belief_roi()
    nodes = (5, 400, 1000, 1799, 901)
    looks = [env.sensor.observe(env.roadmap.positions[i]) for i in nodes]
    got = LookBatch(looks).trace_reductions(P, roi)
    for g, o in zip(got, looks):
        H = np.zeros((o.weights.shape[0], P.shape[0]))
        H[:, o.cells] = o.weights
        S = H @ P @ H.T + np.diag(o.var)
        post = P - P @ H.T @ np.linalg.solve(S, H @ P)
        np.testing.assert_allclose(g, (np.diag(P) - np.diag(post))[roi].sum(), rtol=1e-9)
    want = trace_reductions(P, LegBatch([stack([o]) for o in looks]), roi)
    np.testing.assert_allclose(got, want, rtol=1e-10)
    assert np.all(want > 0)


# -- far targets ----------------------------------------------------------------------------------------


def test_the_duration_graph_holds_each_legs_flight_time_by_the_mission_clock():
    env, view, _ = _stepped(HOT, 2, 0)
    g = duration_graph(view)
    rm = env.roadmap
    for node in (0, 17, 901, rm.n_nodes - 1):
        np.testing.assert_array_equal(g[node, rm.neighbours[node]].toarray().ravel(), view.neighbour_durations(node))
    assert g.nnz <= rm.n_nodes * rm.k and duration_graph(view) is g  # built once per roadmap and clock


def test_the_best_far_target_is_the_best_rate_over_reachable_targets_reached_by_a_quickest_path():
    """Against a brute force over Dijkstra's distances: the target with the best ``rates`` among those the
    budget reaches, its first leg on a quickest path, and the path's legs summing to its flight time."""
    env, view, obs = _stepped(HOT, 11, 6)
    rm, cur = env.roadmap, int(obs["current_node"][0])
    graph = duration_graph(view)
    t_all = dijkstra(graph, indices=cur)
    rng = np.random.default_rng(0)
    targets = rng.choice(rm.n_nodes, 300, replace=False)
    value = rng.random(targets.size)
    seen = {}

    def rates(t, ok):
        seen["t"], seen["ok"] = t, ok
        return np.where(ok, value / np.where(ok, t, 1.0), -np.inf)

    rate, action, path = best_far_target(view, obs, targets, rates, with_path=True)
    np.testing.assert_array_equal(seen["t"], t_all[targets])
    reach = (t_all[targets] > 0) & np.isfinite(t_all[targets]) & view.fits_budget(t_all[targets], view.remaining_s)
    np.testing.assert_array_equal(seen["ok"], reach)
    brute = np.where(reach, value / np.where(reach, t_all[targets], 1.0), -np.inf)
    j = first_best(brute)
    assert rate == brute[j] and path[-1] == targets[j]
    assert rm.neighbours[cur, action] == path[0]
    legs = [cur, *path]
    flown = sum(graph[a, b] for a, b in zip(legs[:-1], legs[1:]))
    assert flown == pytest.approx(t_all[targets[j]], rel=1e-12)
    assert best_far_target(view, obs, targets, rates) == (rate, action)


def test_no_reachable_far_target_is_minus_infinity_and_rates_are_not_asked():
    env, view, obs = _stepped(HOT, 4, 0)
    cur = int(obs["current_node"][0])

    def never(t, ok):
        raise AssertionError("rates asked with nothing reachable")

    assert best_far_target(view, obs, np.array([cur]), never) == (-np.inf, -1)  # only where it is: t = 0
    assert best_far_target(view, obs, np.array([cur]), never, with_path=True) == (-np.inf, -1, [])


def test_far_move_keeps_the_best_score_unless_a_far_target_beats_it():
    env, view, obs = _stepped(HOT, 5, 3)
    rm, cur = env.roadmap, int(obs["current_node"][0])
    mask = obs["action_mask"].astype(bool)
    scores = np.where(mask, np.linspace(1.0, 2.0, mask.size), -np.inf)
    targets = np.arange(rm.n_nodes)
    t = dijkstra(duration_graph(view), indices=cur)
    assert far_move(view, obs, scores, targets, lambda: np.zeros(targets.size)) == first_best(scores)
    far = int(np.argmax(np.where(np.isfinite(t) & view.fits_budget(t, view.remaining_s), t, 0)))  # farthest reachable
    gains = np.zeros(targets.size)
    gains[far] = 1e6 * t[far]  # a rate of 1e6 per second: beats every neighbour's score
    action = far_move(view, obs, scores, targets, lambda: gains)
    _, first, path = best_far_target(
        view, obs, targets, lambda tt, ok: np.where(ok, gains / np.where(ok, tt, 1), -np.inf), with_path=True)
    assert path[-1] == far and action == first and mask[action] and rm.neighbours[cur, action] == path[0]
    gains[far] = scores.max() * t[far] * (1 + 1e-12)  # a tie by TIE_RTOL: the best score stays
    assert not beats(scores.max() * (1 + 1e-12), scores.max())
    assert far_move(view, obs, scores, targets, lambda: gains) == first_best(scores)


def _built_now(view) -> np.ndarray:
    _GRAPHS.clear()  # the cache kept across decisions and episodes, built afresh here
    return duration_graph(view).toarray()


def test_the_duration_graph_is_the_same_whenever_it_is_built():
    # the twin's clock is exact from the drone's current state (its velocity) and an upper bound from
    # elsewhere: a graph built with the current node's row exact would depend on the decision (and the
    # episode) that built it, and every later episode of the process would plan on it
    env = make_env("ipp_bench/Weed15Twin-v1")
    env.reset(seed=3)
    view = view_for(make_planner("greedy"), env)
    at_start = _built_now(view)
    for _ in range(4):  # legs flown: the drone at another node, moving
        env.step(int(np.flatnonzero(env.action_masks())[-1]))
    assert np.array_equal(_built_now(view), at_start)
    env.reset(seed=7)  # another episode, another start
    assert np.array_equal(_built_now(view), at_start)
