"""The oracle as a warm start's teacher (``--warm-start oracle``, ``--warm-start-for
TASK=oracle``): a privileged teacher at training time, the student on the robot's view only."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

import ipp_bench.envs  # noqa: F401
from ipp_bench.planners.episode import fly_episode
from ipp_bench.policies.features import gain_feature_wrapper
from ipp_bench.policies.network import NetConfig
from ipp_bench.train.warmstart import BCDataset, collect_episodes, make_expert

TASK = "ipp_bench/Hotspots15Eval-v2"


class _Recording:
    """The expert, noting per decision whether its move is other than its scores' argmax (a far move)."""

    def __init__(self, expert):
        self.expert, self.planner, self.far = expert, expert.planner, []

    def __call__(self, obs):
        action, scores = self.expert(obs)
        self.far.append(action != int(np.argmax(self.planner.scores(obs))))
        return action, scores


def test_the_oracle_labels_dagger_states_with_the_moves_it_flies_alone_far_moves_one_hot():
    """With beta 1 the labels are the oracle's own moves on the same seed (it reads the true ROI
    through its own view; the student's states are the robot's). Where it flies towards a far target
    rather than its scores' argmax, the label is one-hot on that move; elsewhere soft over its scores."""
    seed = 4
    alone = []
    fly_episode(gym.make(TASK).unwrapped, "oracle", seed, on_decision=lambda d: alone.append(int(d.action)))
    data, expert = BCDataset(), _Recording(make_expert("oracle"))
    env = gain_feature_wrapper(gym.make(TASK), invariant=True)
    collect_episodes(env, expert, None, 1, 1.0, data, 0.99, np.random.default_rng(0), seed,
                     torch.device("cpu"), temperature=0.05, net_config=NetConfig(node_dim=6, invariant=True))
    assert len(alone) > 5 and len(data) == len(alone)
    assert [int(np.argmax(t)) for t in data.target] == data.action == alone
    assert any(expert.far) and not all(expert.far)  # both kinds of label were made
    assert all(np.count_nonzero(t) == 1 for t, f in zip(data.target, expert.far) if f)
    soft = [t for t in data.target if np.count_nonzero(t) > 1]
    assert soft, "no label was soft over the oracle's scores"
    assert all(abs(float(t.sum()) - 1.0) < 1e-5 for t in data.target)
