"""``benchmarks/bench_mission_phases.py``: its per-window figures against the episode loop's own
report, and its hand-over against the planners it hands between."""

from __future__ import annotations

import numpy as np
import pytest
from lb_helpers import benchmark_script

from ipp_bench.envs import make_env
from ipp_bench.eval.plan import episode_seeds
from ipp_bench.planners.episode import fly_episode

TASK = "ipp_bench/Grid15Eval-v1"


@pytest.fixture(scope="module")
def mp():
    return benchmark_script("bench_mission_phases")


def test_window_gains_add_up_to_the_reports(mp):
    seeds = episode_seeds(0, 2)
    r = mp.phases(TASK, "greedy", seeds, {})
    env = make_env(TASK)
    reports = [[x["uncertainty_reduction_pct"] for x in fly_episode(env.unwrapped, "greedy", s).report] for s in seeds]
    np.testing.assert_allclose(np.cumsum(r["gain"]), np.mean(reports, axis=0), atol=1e-9)
    np.testing.assert_allclose(r["reduction"], reports, atol=1e-9)
    np.testing.assert_allclose(r["share"].sum(axis=1), 1.0, atol=1e-9)
    assert r["levels"] == [8.0, 14.0]
    assert 0.0 <= r["unflown"] < 5.0


def test_handover_is_the_first_planner_before_the_switch_and_the_second_after(mp):
    seeds = episode_seeds(0, 2)
    alone = mp.phases(TASK, "random", seeds, {})
    hand = mp.phases(TASK, "random", seeds, {}, "greedy", 100.0)
    greedy = mp.phases(TASK, "greedy", seeds, {})
    np.testing.assert_array_equal(hand["reduction"][:, :2], alone["reduction"][:, :2])  # 50 and 100 s
    assert not np.allclose(hand["reduction"][:, 2:], alone["reduction"][:, 2:])
    env = make_env(TASK)
    h = mp.Handover("random", "greedy", 0.0, env.unwrapped)  # the switch at the start: greedy throughout
    a = fly_episode(env.unwrapped, h, seeds[0]).report
    assert [x["uncertainty_reduction_pct"] for x in a] == greedy["reduction"][0].tolist()


def test_bad_input_is_one_line(mp, capsys):
    assert mp.main(["--tasks", "NoSuchTask-v9", "--episodes", "1"]) == 2
    assert mp.main(["--planners", "nosuchplanner", "--episodes", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("bench_mission_phases.py: error:") for line in err)
    assert mp.main(["--planners", "coverage", "--then", "greedy", "--episodes", "1"]) == 2
    assert "coverage" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        mp.main(["--switch-s", "0"])


def test_avoided_altitude_is_left_after_the_switch_only(mp):
    """Greedy flies the 15 x 15 map at 8 m almost throughout after 100 s; kept off 8 m it flies at 14 m
    there (the leg that crosses 100 s excepted) and the same as before until then."""
    seeds = episode_seeds(0, 2)
    alone = mp.phases(TASK, "greedy", seeds, {})
    kept = mp.phases(TASK, "greedy", seeds, {}, "greedy", 100.0, avoid_z=8.0)
    assert alone["share"][2:, 0].min() > 0.9  # 8 m is greedy's choice there
    np.testing.assert_array_equal(kept["reduction"][:, :2], alone["reduction"][:, :2])
    np.testing.assert_array_equal(kept["share"][:2], alone["share"][:2])
    assert kept["share"][2, 0] < 0.05 and kept["share"][3, 0] == 0.0
    assert (kept["reduction"][:, 3] < alone["reduction"][:, 3]).all()  # and 14 m sees less here
