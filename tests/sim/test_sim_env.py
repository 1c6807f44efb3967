"""The MuJoCo deployment task: registration, spaces, determinism, clock, budget, planners."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

pytest.importorskip("mujoco")

import ipp_bench.envs as envs  # noqa: E402
from ipp_bench.core.mission import BudgetExceededError  # noqa: E402
from ipp_bench.planners.episode import fly_episode  # noqa: E402
from ipp_bench.sim.env import MuJoCoIPPEnv  # noqa: E402
from ipp_bench.sim.mission import MuJoCoMission  # noqa: E402

TASK = "ipp_bench/MuJoCoWeed15-v0"


@pytest.fixture(scope="module")
def env():
    e = gym.make(TASK, budget_s=30.0).unwrapped
    yield e
    e.close()


def test_task_is_registered_with_the_papers_deployment_settings():
    assert TASK in envs.tagged("deployment")
    cfg = envs.task_spec(TASK).config
    assert (cfg.grid.rows, cfg.grid.cols, cfg.grid.resolution) == (15, 15, 2.5)
    assert cfg.mission.mu_th == 0.05 and cfg.mission.budget_s == 200.0 and cfg.mission.speed == 2.0
    assert cfg.mission.start == (2.0, 2.0, 14.0) and cfg.mission.field == "weed_patches"


def test_same_spaces_as_the_graph_tasks(env):
    graph = gym.make("ipp_bench/Grid15Eval-v0").unwrapped
    assert env.observation_space == graph.observation_space
    assert env.action_space == graph.action_space
    assert isinstance(env, MuJoCoIPPEnv)


@pytest.mark.filterwarnings("ignore:.*Box observation space m")
def test_check_env():
    e = gym.make(TASK, budget_s=12.0).unwrapped
    check_env(e, skip_render_check=True)
    e.close()


def _rollout(env, seed, steps=4):
    obs, _ = env.reset(seed=seed)
    assert isinstance(env.mission, MuJoCoMission)
    rng = np.random.default_rng(seed)
    feats, rewards = [obs["node_features"].copy()], []
    for _ in range(steps):
        obs, r, term, _, info = env.step(int(rng.choice(np.flatnonzero(obs["action_mask"]))))
        feats.append(obs["node_features"].copy())
        rewards.append(r)
        if term:
            break
    return np.stack(feats), np.array(rewards), env.world.scene.data.qpos.copy(), info


def test_same_seed_same_episode(env):
    a = _rollout(env, 5)
    b = _rollout(env, 5)
    for x, y in zip(a[:3], b[:3]):
        np.testing.assert_array_equal(x, y)
    assert a[3] == b[3]
    c = _rollout(env, 6)
    assert not np.array_equal(a[0], c[0])


def test_mission_time_is_simulated_time(env):
    obs, _ = env.reset(seed=0)
    mission = env.mission
    assert mission.n_measurements > 0  # the start read-out came from the camera
    nbrs = obs["neighbours"][obs["action_mask"].astype(bool)]
    target = env.roadmap.positions[nbrs[0]]
    length = np.linalg.norm(target - mission.position)
    obs, *_ = env.step(int(np.flatnonzero(obs["action_mask"])[0]))
    assert mission.time_s == pytest.approx(env.world.flight.time_s)
    assert mission.time_s >= length / 2.0  # a real flight is never faster than length / speed
    reference = length / 2.0 + env.world.flight.ramp_s  # cruise at 2 m/s plus the velocity ramps (legs >= 2 m)
    assert mission.time_s == pytest.approx(reference, abs=0.3)
    assert np.linalg.norm(mission.position - target) < 0.3
    assert mission.path[-1][0] == mission.time_s
    assert obs["budget"][0] == pytest.approx(mission.remaining_s / mission.budget_s)


def test_budget_rules(env):
    env.reset(seed=1)
    mission = env.mission
    with pytest.raises(ValueError, match="outside the map"):
        mission.fly_to([-5.0, 3.0, 8.0])
    # masks follow the reference flight time: length / 2 m/s + the 1 s of ramps (every roadmap
    # leg is longer than 2 m), worked out here from the maths, not from the mission's code
    nbrs = env.roadmap.neighbours[env.current_node]
    length = np.linalg.norm(env.roadmap.positions[nbrs] - mission.position, axis=1)
    assert length.min() > 2.0
    np.testing.assert_allclose(mission.leg_durations(mission.position, env.roadmap.positions[nbrs]),
                               length / 2.0 + 1.0, rtol=1e-12)
    mission.time_s = mission.budget_s - 3.0  # 3 s left: legs up to 4 m fit (4 / 2 + 1 = 3 s)
    np.testing.assert_array_equal(env.action_masks(), length <= 4.0 + 1e-9)
    mission.time_s = 0.0
    # flying until the end: the clock never passes the budget and the episode terminates
    obs, terminated = env._observation(), False
    while not terminated:
        obs, _, terminated, _, _ = env.step(int(np.flatnonzero(obs["action_mask"])[-1]))
    assert mission.time_s <= mission.budget_s
    assert not env.action_masks().any()
    far = [37.0, 37.0, 8.0] if mission.position[0] < 18 else [0.5, 0.5, 8.0]
    with pytest.raises(BudgetExceededError):  # the reference time over the remaining budget
        mission.fly_to(far)


@pytest.mark.parametrize("planner", ["random", "coverage"])
def test_graph_and_continuous_planners_run_unchanged(env, planner):
    log = fly_episode(env, planner, seed=2)
    assert log.decisions > 0
    assert 0.0 < log.final["uncertainty_reduction_pct"] <= 100.0
    assert env.mission.time_s <= env.mission.budget_s + 1e-9


def test_render_rgb_array():
    e = gym.make(TASK, budget_s=10.0, render_mode="rgb_array", image_size=64).unwrapped
    e.reset(seed=0)
    img = e.render()
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3 and img.shape[0] > 300
    assert e.world.cfg.image_size == 64
    e.close()


@pytest.mark.slow
def test_full_200s_mission():
    e = gym.make(TASK).unwrapped
    log = fly_episode(e, "random", seed=0)
    m = e.mission
    assert 195.0 <= m.time_s <= 200.0
    for t in (50.0, 100.0, 150.0, 200.0):
        assert np.isfinite(m.metrics_at(t)["trace_roi"])
    assert log.final["uncertainty_reduction_pct"] > 0
    assert m.n_measurements > 100
    e.close()


def test_an_env_dropped_without_close_exits_without_an_egl_traceback():
    """A MuJoCo env a script forgets to close is freed before EGL's display is terminated at exit."""
    import os
    import subprocess
    import sys

    code = ("from ipp_bench.envs import make_env\n"
            "from ipp_bench.planners.episode import fly_episode\n"
            "e = make_env('MuJoCoWeed15-v1', budget_s=10.0); fly_episode(e, 'random', 0)\n"
            "e = make_env('Weed15Twin-v1', budget_s=10.0); fly_episode(e, 'random', 0)\n"
            "print('done')\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")})
    assert proc.returncode == 0 and proc.stdout.strip() == "done", proc.stderr
    assert "Traceback" not in proc.stderr and "EGLError" not in proc.stderr, proc.stderr

