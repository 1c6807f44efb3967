"""The dm_env view of the deployment, checked by dm_env's own conformance mixin."""

import numpy as np
import pytest

pytest.importorskip("mujoco")
dm_env = pytest.importorskip("dm_env")

from absl.testing import absltest  # noqa: E402
from dm_env import test_utils  # noqa: E402

from ipp_bench.sim.dmenv import DeploymentEnvironment  # noqa: E402


class DeploymentConformanceTest(test_utils.EnvironmentTestMixin, absltest.TestCase):
    """dm_env's interface contract (FIRST / MID / LAST, specs, step after the end)."""

    def make_object_under_test(self):
        return DeploymentEnvironment(seed=0, budget_s=16.0)

    def make_action_sequence(self):
        # affordable neighbours until the budget runs out, then one more step: the episode ends
        # and dm_env's contract for the step after LAST (a new FIRST) is exercised
        env = self.environment
        for _ in range(14):
            mission = env.gym_env.mission
            if mission is None:
                yield 0
                continue
            mask = env.gym_env.action_masks()
            yield int(np.flatnonzero(mask)[0]) if mask.any() else 0


def test_same_seed_same_episode_and_masked_action_ends_it():
    runs = []
    for _ in range(2):
        env = DeploymentEnvironment(seed=3, budget_s=10.0)
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
