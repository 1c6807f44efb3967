"""Trajectory sampling of the `attention` planner (``attention:samples=K,plan_s=T``, CAtNIPP's test-time
sampling): the imagined flights against the real episode's Kalman updates, the choice rule, bad input."""

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("torch")

import ipp_bench.envs  # noqa: F401
from ipp_bench.planners import make_planner
from ipp_bench.planners.base import RobotView
from ipp_bench.policies.features import extend_observation

TASK = "ipp_bench/Grid15Eval-v1"


def _start(task=TASK, seed=5, **env_kwargs):
    env = gym.make(task, **env_kwargs)
    obs, _ = env.reset(seed=seed)
    return env, obs


def _planner(spec, env, seed=5):
    planner = make_planner(spec)
    planner.reset(RobotView(env.unwrapped), seed)
    return planner


def test_imagined_flights_predict_the_real_episodes_roi_trace_and_inputs():
    """The variance of a Kalman update does not depend on the values measured, so each imagined flight's
    ROI trace reduction (ROI of the decision fixed, the leg crossing plan_s pro rata) is what the real
    episode's belief gives when the same legs are flown; and the imagined network inputs after a leg are
    the real ones with the belief mean held at the decision's."""
    env, obs = _start()
    planner = _planner("attention:samples=4,plan_s=25", env)
    for _ in range(3):  # a few decisions in, where the belief is no longer the prior
        obs, *_ = env.step(planner.act(obs))
    view = RobotView(env.unwrapped)
    roi, node0, remaining0 = view.belief_roi(), env.unwrapped.current_node, view.remaining_s
    trace0 = view.roi_trace(view.belief.variance, roi)
    planner.act(obs)
    assert len(planner.plans) == 4 and len({tuple(p) for p, _ in planner.plans}) > 1
    for path, predicted in planner.plans:
        real, real_obs = _start()
        replay = _planner("attention", real)
        for _ in range(3):
            real_obs, *_ = real.step(replay.act(real_obs))
        rview = RobotView(real.unwrapped)
        assert real.unwrapped.current_node == node0
        elapsed, reduction, before = 0.0, 0.0, trace0
        for i, a in enumerate(path):
            t0 = rview.time_s
            real_obs, *_ = real.step(a)
            cost = rview.time_s - t0
            after = rview.roi_trace(rview.belief.variance, roi)
            reduction += min(1.0, (25.0 - elapsed) / cost) * (before - after)
            elapsed, before = elapsed + cost, after
            if i == 0:  # the state after the first leg, imagined and real
                imagined, source = planner.imagined_state(obs, real.unwrapped.current_node,
                                                          rview.belief.variance.copy(), remaining0 - cost, roi)
                held = dict(real_obs)
                held["node_features"] = real_obs["node_features"].copy()
                held["node_features"][:, 3] = obs["node_features"][:, 3]  # the mean the imagination holds
                a_in = extend_observation(imagined, source, 6, invariant=True)
                b_in = extend_observation(held, _HeldRoi(rview, roi), 6, invariant=True)
                np.testing.assert_allclose(a_in["node_features"], b_in["node_features"], rtol=1e-5, atol=1e-6)
                for key in ("current_node", "neighbours", "action_mask", "budget"):
                    np.testing.assert_allclose(a_in[key], real_obs[key], rtol=1e-6)
        assert elapsed >= 25.0 - 1e-9 or not real.unwrapped.action_masks().any()
        assert predicted == pytest.approx(reduction, rel=1e-6)


class _HeldRoi:
    """A real view whose ROI is the decision's (the imagination holds it fixed)."""

    def __init__(self, view, roi):
        self._view, self._roi = view, roi

    def __getattr__(self, name):
        return getattr(self._view, name)

    def belief_roi(self):
        return self._roi


def test_the_flown_leg_is_the_best_trajectorys_first_and_the_first_trajectory_is_the_argmax():
    env, obs = _start(seed=2)
    planner = _planner("attention:samples=6,plan_s=40", env, seed=2)
    argmax = _planner("attention", env, seed=2)
    for _ in range(6):
        a = planner.act(obs)
        best = max(range(len(planner.plans)), key=lambda j: (planner.plans[j][1], -j))
        assert a == planner.plans[best][0][0]
        assert planner.plans[0][0][0] == argmax.act(obs)
        assert all(p[1] <= planner.plans[best][1] for p in planner.plans)
        obs, *_ = env.step(a)


def test_trajectory_sampling_is_seeded_per_episode():
    def fly(seed):
        env, obs = _start(seed=seed, budget_s=40.0, report_times=(40.0,))
        planner = _planner("attention:samples=3,plan_s=20", env, seed=seed)
        actions = []
        while env.unwrapped.action_masks().any():
            actions.append(planner.act(obs))
            obs, *_ = env.step(actions[-1])
        return actions

    assert fly(4) == fly(4)


@pytest.mark.parametrize("spec, message", [
    ("attention:samples=1",
     "attention.samples = 1 is invalid: expected 0 (no trajectory sampling) or an integer from 2 to 256"),
    ("attention:samples=-3", "attention.samples = -3 is invalid"),
    ("attention:samples=300", "attention.samples = 300 is invalid"),
    ("attention:samples=many", "attention.samples = 'many' is invalid: expected an integer"),
    ("attention:samples=4,plan_s=0", "attention.plan_s = 0.0 is invalid: expected a number > 0 [s]"),
    ("attention:samples=4,plan_s=inf", "attention.plan_s = inf is invalid: expected a number > 0 [s]"),
    ("attention:samples=4,sample=true", "attention.sample = true and attention.samples = 4 exclude each other"),
])
def test_bad_sampling_settings_are_one_line(spec, message):
    with pytest.raises(ValueError) as err:
        make_planner(spec)
    assert message in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("task, kwargs, message", [
    ("ipp_bench/Hotspots30Eval-v2", {"belief": "window", "budget_s": 40.0, "report_times": (40.0,)},
     "cannot run on ipp_bench/Hotspots30Eval-v2 (gp.belief = 'window')"),
    ("ipp_bench/Weed15Twin-v1", {}, "attention.samples cannot run on a task whose camera repeats its error"),
])
def test_tasks_it_cannot_imagine_are_refused_at_reset_in_one_line(task, kwargs, message):
    env, _ = _start(task, seed=0, **kwargs)
    planner = make_planner("attention:samples=4")
    with pytest.raises(ValueError) as err:
        planner.reset(RobotView(env.unwrapped), 0)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_a_network_on_the_five_env_features_imagines_too(tmp_path):
    """Sampling needs node inputs read from the belief alone: the env's five (here an untrained network's)
    as well as the look-gain ones."""
    import torch

    from ipp_bench.policies.checkpoint import save_checkpoint
    from ipp_bench.policies.network import AttentionNet, NetConfig

    torch.manual_seed(0)
    path = tmp_path / "five.pt"
    save_checkpoint(AttentionNet(NetConfig(embed_dim=32, n_heads=2, ff_dim=64)), path, meta={})
    env, obs = _start()
    planner = _planner(f"attention:checkpoint={path},samples=3,plan_s=20", env)
    for _ in range(3):
        a = planner.act(obs)
        assert len(planner.plans) == 3 and a == max(planner.plans, key=lambda p: p[1])[0][0]
        obs, *_ = env.step(a)


def test_a_sampling_teacher_labels_dagger_states_with_the_actions_it_flies_alone():
    """As a warm start's teacher (``ipp-bench train --warm-start-for TASK=SPEC``), the sampling planner
    sees the environment's own observation, as in a leaderboard episode: with beta 1 (round 0) the
    labels are the actions it flies alone on the same seed, and the student's states carry its own
    six features."""
    import torch

    from ipp_bench.planners.episode import fly_episode
    from ipp_bench.policies.features import gain_feature_wrapper
    from ipp_bench.policies.network import NetConfig
    from ipp_bench.train.warmstart import BCDataset, collect_episodes, make_expert

    spec, seed, short = "attention:samples=2,plan_s=15", 3, {"budget_s": 60.0, "report_times": (60.0,)}
    alone = []
    fly_episode(gym.make(TASK, **short).unwrapped, spec, seed, on_decision=lambda d: alone.append(int(d.action)))
    data = BCDataset()
    cfg = NetConfig(node_dim=6, invariant=True)
    student_env = gain_feature_wrapper(gym.make(TASK, **short), invariant=True)  # the training env's six features
    collect_episodes(student_env, make_expert(spec), None, 1, 1.0, data, 0.99, np.random.default_rng(0), seed,
                     torch.device("cpu"), net_config=cfg)
    assert len(alone) > 5 and len(data) == len(alone)
    assert [int(np.argmax(t)) for t in data.target] == data.action == alone
    assert {a.shape[-1] for a in data.nf} == {6}
