"""The far teacher of a rate-skip network (``NetConfig.skip_teacher = "far"``): its look gains against
the Kalman update, its scores against greedy's and the roadmap's quickest paths, and the untrained
network that decides as it does."""

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

import ipp_bench.envs  # noqa: F401
from ipp_bench.planners import make_planner
from ipp_bench.planners.base import RobotView
from ipp_bench.planners.far import FarTargets, duration_graph, far_scores
from ipp_bench.policies.features import neighbour_rates

TASK = "ipp_bench/Hotspots30Eval-v2"


def _stepped(task, seed, steps):
    env = gym.make(task).unwrapped
    obs, _ = env.reset(seed=seed)
    greedy = make_planner("greedy")
    view = RobotView(env)
    greedy.reset(view, seed)
    for _ in range(steps):  # a belief that is not the prior
        obs, *_ = env.step(greedy.act(obs))
    return env, view, obs


def test_far_look_gains_are_the_kalman_trace_reduction_of_each_look():
    env, view, _ = _stepped(TASK, 3, 5)
    ft = FarTargets.of(view)
    P = env.mission.belief.cov
    roi = env.mission.belief_roi()
    sel = np.array([0, 17, 600, ft.targets.size - 1])
    got = ft.gains(sel, P, roi)
    for g, j in zip(got, sel):
        o = env.sensor.observe(env.roadmap.positions[ft.targets[j]])
        H = np.zeros((o.weights.shape[0], P.shape[0]))
        H[:, o.cells] = o.weights
        S = H @ P @ H.T + np.diag(o.var)
        post = P - P @ H.T @ np.linalg.solve(S, H @ P)  # the Kalman update, dense
        np.testing.assert_allclose(g, (np.diag(P) - np.diag(post))[roi].sum(), rtol=1e-9)
        assert g > 0


def test_far_scores_are_greedys_unless_a_far_target_wins_then_its_first_leg_on_a_quickest_path():
    from scipy.sparse.csgraph import dijkstra

    from ipp_bench.planners.greedy import greedy_scores

    env = gym.make(TASK).unwrapped
    obs, _ = env.reset(seed=11)
    view = RobotView(env)
    ft = FarTargets.of(view)
    deviated = 0
    for _ in range(25):
        cur = int(obs["current_node"][0])
        mask = obs["action_mask"].astype(bool)
        s = far_scores(view, obs)
        g = np.where(mask, greedy_scores(view, cur), -np.inf)
        assert np.all(s[~mask] == -np.inf)
        differ = np.flatnonzero(s != g)
        assert differ.size <= 1
        if differ.size:
            a = int(differ[0])
            assert s[a] > g.max()  # a far target beats every neighbour's leg
            nb = int(env.roadmap.neighbours[cur, a])
            # the target is where its score comes from: some node j with gain / D[cur, j] == s[a],
            # reached through nb on a quickest path
            D = dijkstra(duration_graph(view), indices=[cur, nb])
            t = D[0, ft.targets]
            through = np.flatnonzero(np.isclose(D[0, nb] + D[1, ft.targets], t) & (t > 0))
            rates = np.concatenate([ft.gains(c, env.mission.belief.cov, env.mission.belief_roi()) / t[c]
                                    for c in np.array_split(through, max(1, through.size // 32))])
            assert np.isclose(rates, s[a], rtol=1e-9).any()
            deviated += 1
        rates = neighbour_rates(view, obs, "far")
        assert rates[mask].max() == pytest.approx(1.0) and np.all(rates[~mask] == 0)
        assert int(np.argmax(rates)) == int(np.argmax(s))
        obs, *_ = env.step(int(np.argmax(s)))
    assert deviated >= 1  # on sparse hotspots the far rule does leave greedy's choice


def test_an_untrained_far_rate_skip_network_decides_as_the_far_rule(tmp_path):
    import torch

    from ipp_bench.policies.checkpoint import load_checkpoint, save_checkpoint
    from ipp_bench.policies.features import RATE_NODE_DIM
    from ipp_bench.policies.network import AttentionNet, NetConfig

    torch.manual_seed(0)
    path = tmp_path / "far.pt"
    save_checkpoint(AttentionNet(NetConfig(node_dim=RATE_NODE_DIM, rate_skip=True, skip_teacher="far",
                                           embed_dim=16, n_heads=2, ff_dim=32)), path)
    assert load_checkpoint(path)[0].cfg.skip_teacher == "far"
    for task in ("ipp_bench/Hotspots15Eval-v2", TASK):
        env = gym.make(task).unwrapped
        obs, _ = env.reset(seed=5)
        view = RobotView(env)
        policy = make_planner(f"attention:checkpoint={path}")
        policy.reset(view, 5)
        for _ in range(12):
            a = int(np.argmax(far_scores(view, obs)))
            assert policy.act(obs) == a
            obs, *_ = env.step(a)


def test_a_bad_skip_teacher_is_refused():
    from ipp_bench.policies.network import NetConfig

    with pytest.raises(ValueError, match="skip_teacher = 'oracle' is invalid: expected one of greedy, far"):
        NetConfig(node_dim=7, rate_skip=True, skip_teacher="oracle")
