"""The deployment as a dm_control environment, checked by dm_env's own conformance mixin."""

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("dm_control")

from absl.testing import absltest  # noqa: E402
from dm_control import mujoco as dm_mujoco  # noqa: E402
from dm_control.rl import control  # noqa: E402
from dm_env import test_utils  # noqa: E402

import ipp_bench.sim  # noqa: E402


class DeploymentConformanceTest(test_utils.EnvironmentTestMixin, absltest.TestCase):
    """dm_env's interface contract (FIRST / MID / LAST, specs, step after the end), on ``ipp_bench.sim.load``."""

    def make_object_under_test(self):
        return ipp_bench.sim.load(seed=0, budget_s=16.0)

    def make_action_sequence(self):
        # affordable neighbours until the budget runs out, then one more step: the episode ends
        # and dm_env's contract for the step after LAST (a new FIRST) is exercised
        env = self.environment
        for _ in range(14):
            task = env.task
            if task.mission is None:
                yield 0
                continue
            mask = task.env.action_masks()
            yield int(np.flatnonzero(mask)[0]) if mask.any() else 0


def test_load_is_a_dm_control_environment_over_one_core():
    env = ipp_bench.sim.load("MuJoCoWeed15-v1", seed=1, budget_s=12.0)
    assert isinstance(env, control.Environment)
    assert isinstance(env.physics, dm_mujoco.Physics)
    assert isinstance(env.task, control.Task)
    ts = env.reset()
    task = env.task
    # the task is the gymnasium environment itself: one mission, stepped by the dm_control face
    assert task.world.scene.physics is env.physics and task.mission is not None
    start = env.physics.named.data.qpos[task.world.scene.joint_name][:3].copy()
    np.testing.assert_allclose(start, task.mission.position, atol=1e-9)
    t0 = env.physics.data.time
    ts = env.step(int(np.flatnonzero(ts.observation["action_mask"])[0]))
    # one time step is one leg: the physics flew it (thousands of steps), the mission clock agrees
    assert env.physics.data.time - t0 > 1.0
    assert task.mission.time_s == pytest.approx(task.world.flight.ref_time)
    assert ts.reward == pytest.approx(task._dm_last[1]) and ts.reward >= 0.0
    # named reads of the physics see the flown drone
    flown = env.physics.named.data.qpos[task.world.scene.joint_name][:3]
    assert np.linalg.norm(flown - start) > 1.0
    frame = env.physics.render(48, 48, camera_id="quad/down")
    assert frame.shape == (48, 48, 3) and frame.std() > 0
    env.close()


def test_the_task_holds_the_gymnasium_env_and_the_env_is_no_task():
    """dm_control's suite shape: a control.Task that holds the episode's env and delegates to it; the
    gymnasium env is one (a gymnasium.Env only)."""
    import gymnasium as gym

    from ipp_bench.sim.dmenv import DeploymentTask
    from ipp_bench.sim.env import MuJoCoIPPEnv

    env = ipp_bench.sim.load(seed=2, budget_s=12.0)
    task = env.task
    assert type(task) is DeploymentTask and not isinstance(task, gym.Env)
    assert isinstance(task.env, MuJoCoIPPEnv) and not isinstance(task.env, control.Task)
    ts = env.reset()
    assert task.mission is task.env.mission and task.world is task.env.world
    for key, value in task.env.observer.observe(task.mission, task.env.current_node,
                                                task.env.action_masks()).items():
        np.testing.assert_array_equal(ts.observation[key], value)
    env.close()


def test_bad_action_is_one_line_and_other_tasks_are_refused():
    env = ipp_bench.sim.load(seed=0, budget_s=12.0)
    env.reset()
    with pytest.raises(ValueError, match=r"neighbour index in \[0, 20\)"):
        env.step(99)
    with pytest.raises(ValueError, match="not a MuJoCo deployment"):
        ipp_bench.sim.load("Grid15Eval-v1")
    env.close()


def test_same_seed_same_episode_and_masked_action_ends_it():
    runs = []
    for _ in range(2):
        env = ipp_bench.sim.load(seed=3, budget_s=10.0)
        ts = env.reset()
        assert set(ts.observation) >= {"node_features", "action_mask", "estimated_position"}
        rewards = []
        while not ts.last():
            ts = env.step(int(np.flatnonzero(ts.observation["action_mask"])[0]))
            rewards.append(ts.reward)
        runs.append((rewards, ts.observation["estimated_position"]))
        # a masked action ends the episode instead of raising
        ts = env.reset()
        masked = np.flatnonzero(ts.observation["action_mask"] == 0)
        if masked.size:
            end = env.step(int(masked[0]))
            assert end.last() and end.reward == 0.0 and end.discount == 0.0
        env.close()
    assert runs[0][0] == runs[1][0]
    np.testing.assert_array_equal(runs[0][1], runs[1][1])


def test_viewer_loader_and_runtime_without_a_display():
    """What ``dm_control.viewer.launch`` does with the loader, minus the window: its Runtime
    builds the environment and steps it with the planner policy."""
    from dm_control.viewer import runtime

    from ipp_bench.sim.viewer import PlannerPolicy, environment_loader

    loader = environment_loader("ipp_bench/MuJoCoWeed15-v1", seed=0, budget_s=12.0)
    env = loader()
    rt = runtime.Runtime(env, policy=PlannerPolicy(env, "greedy"))
    rt.tick(0.0, paused=False)  # starts the episode
    assert env.task.mission is not None
    t0 = env.physics.data.time
    rt.tick(1.0, paused=False)  # one simulated second of viewer time: one leg of greedy
    assert env.physics.data.time > t0 and len(env.task.mission.path) >= 2
    with pytest.raises(ValueError, match="continuous planner"):
        PlannerPolicy(env, "cmaes")
    env.close()


def test_the_viewer_without_a_display_is_one_line(capsys, monkeypatch):
    from ipp_bench.sim.viewer import main

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["--task", "ipp_bench/MuJoCoWeed15-v1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("python -m ipp_bench.sim.viewer: error: the viewer opens a window and no display was found")
    assert len(err.strip().splitlines()) == 1 and "ipp-bench demo" in err
    assert main(["--task", "ipp_bench/Grid15Eval-v1"]) == 2  # checked before any window, display or not
    assert "is not a single-drone MuJoCo deployment" in capsys.readouterr().err
    assert main(["--task", "ipp_bench/MuJoCoWeed15Team2-v1"]) == 2  # a team: the viewer flies one drone
    err = capsys.readouterr().err
    assert "is not a single-drone MuJoCo deployment" in err and "MuJoCoWeed15Team2" not in err.split("valid are")[1]


@pytest.mark.timeout(120)
def test_the_viewer_on_a_display_that_does_not_answer_is_one_line():
    """GLFW cannot open the window (dm_control raises RuntimeError 'Failed to create window')."""
    import os
    import subprocess
    import sys

    def viewer(backend):
        env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
        env.update({"DISPLAY": ":97"} if backend is None else {"DISPLAY": ":97", "MUJOCO_GL": backend})
        proc = subprocess.run([sys.executable, "-m", "ipp_bench.sim.viewer"], capture_output=True, text=True,
                              timeout=100, env=env)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        return proc.stderr.strip().splitlines()

    for backend in (None, "glfw"):
        assert viewer(backend) == [
            "python -m ipp_bench.sim.viewer: error: cannot open the viewer's window (GLFW: Failed to create window); "
            "run it on a desktop or over 'ssh -X'; without a display, 'ipp-bench demo' renders an episode to a video"]
    assert viewer("egl") == ["python -m ipp_bench.sim.viewer: error: the viewer draws into a window: run it with "
                             "MUJOCO_GL=glfw (or unset; MUJOCO_GL='egl' renders off-screen only)"]


@pytest.mark.parametrize("seed", [-1, "x", 2.5])
def test_load_names_a_bad_seed(seed):
    from ipp_bench.sim import load

    with pytest.raises(ValueError, match=r"load\(seed\) = .* is invalid: expected an integer >= 0"):
        load(seed=seed)
