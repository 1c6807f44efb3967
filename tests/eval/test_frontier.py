"""Quality against decision time: sweeps found from planner specs, the Pareto front against its definition, and
the paper's questions on synthetic boards whose answers are known by construction."""

from __future__ import annotations

import numpy as np
import pytest

from ipp_bench.core.mission import REPORT_KEYS
from ipp_bench.eval.frontier import headroom, infer_sweeps, match_answers, pareto_front, task_frontier
from ipp_bench.eval.markdown_frontier import frontier_section
from ipp_bench.eval.tables import EpisodeTable

TASK = "ipp_bench/Grid30Eval-v1"
TIMES = (50.0, 100.0, 150.0, 200.0)


def brute_force_front(times, means):
    """A point is dominated when another has a strictly lower time and a mean at least as high."""
    return [not any(j != i and times[j] < times[i] and means[j] >= means[i] for j in range(len(times)))
            for i in range(len(times))]


@pytest.mark.parametrize("seed", range(20))
def test_the_pareto_front_is_its_definition_on_random_points(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 15))
    times = rng.integers(1, 6, n).astype(float)  # small ranges: ties in time and in mean
    means = rng.integers(0, 5, n).astype(float)
    assert pareto_front(times, means) == brute_force_front(list(times), list(means))


def test_the_pareto_front_on_points_whose_front_is_known():
    assert pareto_front([1, 2, 3, 4], [10, 12, 11, 15]) == [True, True, False, True]
    assert pareto_front([1, 1, 2], [5, 6, 6]) == [True, True, False]  # equal time: neither dominates


def test_sweeps_are_found_from_the_specs_defaults_included():
    sweeps = infer_sweeps(["greedy", "mcts:simulations=8", "mcts:simulations=24", "mcts:search=reference,simulations=8",
                           "cmaes", "cmaes:max_evals=36", "oracle", "attention"])
    found = {(s.name, s.key): s.points for s in sweeps}
    assert found == {("mcts", "simulations"): ((8, "mcts:simulations=8"), (24, "mcts:simulations=24")),
                     ("cmaes", "max_evals"): ((36, "cmaes:max_evals=36"), (72, "cmaes"))}  # 72: its default
    assert infer_sweeps(["mcts:simulations=8", "mcts:search=reference,simulations=24", "greedy"]) == []


def rows_of(values, runtimes, times=TIMES):
    """results.csv rows: ``values[planner][time]`` a list over seeds of the uncertainty reduction."""
    rows = []
    for planner, by_time in values.items():
        for t in times:
            for seed, v in enumerate(by_time[t]):
                row = {"task": TASK, "planner": planner, "seed": seed, "time_s": t,
                       "decision_time_mean_s": runtimes[planner], "episode_wall_s": 100 * runtimes[planner] + seed}
                row.update({k: 0.0 for k in REPORT_KEYS})
                row["uncertainty_reduction_pct"] = v
                rows.append(row)
    return rows


def synthetic(n=20, episodes=None):
    """attention scores a per seed; mcts:simulations=8 is 10 points below it everywhere; =64 is 0.5 below on
    average with a spread that puts 0 inside its interval at 100 s, and 5 below (its interval below 0) at 200 s;
    =200 is 2 below at 200 s, also wholly below: at 200 s no setting matches and 200 closes the most."""
    rng = np.random.default_rng(0)
    a = {t: list(50 + 10 * rng.random(n)) for t in TIMES}
    wiggle = np.array([3.0, -4.0] * (n // 2))
    values = {
        "attention": a,
        "greedy": {t: [x - 1 for x in a[t]] for t in TIMES},
        "oracle": {t: [x + 9 for x in a[t]] for t in TIMES},
        "mcts:simulations=8": {t: [x - 10 for x in a[t]] for t in TIMES},
        "mcts:simulations=64": {t: list(np.array(a[t]) + (wiggle if t != 200.0 else -5.0)) for t in TIMES},
        "mcts:simulations=200": {t: [x - 2 - 0.1 * (i % 2) for i, x in enumerate(a[t])] for t in TIMES},
    }
    if episodes is not None:
        values = {p: {t: v[:episodes] for t, v in by.items()} for p, by in values.items()}
    runtimes = {"attention": 1e-4, "greedy": 5e-3, "oracle": 6e-3, "mcts:simulations=8": 0.01,
                "mcts:simulations=64": 0.073, "mcts:simulations=200": 0.25}
    table = EpisodeTable(rows_of(values, runtimes))
    return table, task_frontier(table, TASK, "greedy", infer_sweeps(table.planners))


def test_the_paper_question_on_a_board_whose_answer_is_known():
    table, frontier = synthetic()
    answers = {a.time_s: a for a in match_answers(table, frontier)}
    assert set(answers) == {100.0, 200.0}
    at100, at200 = answers[100.0], answers[200.0]
    assert at100.intervals and at100.first.planner == "mcts:simulations=64"
    lo, hi = at100.first.difference[1:]
    assert lo < 0 <= hi and at100.first.difference[0] == pytest.approx(-0.5)
    assert at200.first is None and at200.closest.planner == "mcts:simulations=200"
    assert at200.closest.difference[0] == pytest.approx(-2.05)
    text = frontier_section(table, [frontier], {TASK: list(answers.values())}, {TASK: headroom(table, frontier)}, {})
    assert "- at 100 s: the smallest setting not below `attention` is `mcts:simulations=64` (simulations=64): " \
           "-0.5 [" in text
    assert "73.0 ms against `attention`'s 0.100 ms, 730x" in text
    assert "- at 200 s: no setting of `mcts:simulations` up to 200 is as good as `attention`" in text
    assert "the largest gap closed is `mcts:simulations=200` (simulations=200): -2." in text
    assert "[-2.1, -2.0] points; its decision time 250 ms against `attention`'s 0.100 ms, 2500x" in text


def test_one_episode_makes_no_claim():
    table, frontier = synthetic(episodes=1)
    answers = match_answers(table, frontier)
    assert answers and all(not a.intervals and a.first is None for a in answers)
    text = frontier_section(table, [frontier], {TASK: answers}, {}, {})
    assert "one episode, no interval, so no setting is said to match" in text and "smallest setting" not in \
        text.split("**Which MCTS", 1)[1].split("\n\n", 1)[1]


def test_the_share_of_the_oracles_headroom_and_the_front_in_the_table():
    table, frontier = synthetic()
    rows = {h.time_s: h for h in headroom(table, frontier)}
    # the best planner that does not read the truth is attention, 1 above greedy; the oracle is 10 above greedy
    assert rows[100.0].best == "attention" and rows[100.0].share == pytest.approx(0.1)
    assert frontier.point("attention").front == frozenset(TIMES)  # fastest and best
    assert frontier.point("mcts:simulations=8").front == frozenset()
    assert frontier.point("oracle").front == frozenset()  # reads the truth: no part of it
    text = frontier_section(table, [frontier], {}, {TASK: list(rows.values())}, {})
    assert "| 100 | `attention` |" in text and "| 10% |" in text
    assert "| `attention` | – | 0.100 |" in text and "◆" in text


def test_the_wall_time_of_each_point_and_of_the_task():
    """A point's episode wall time is the mean over its episodes (one per seed, not per report time); the line
    under the table sums every episode of the task and, apart, the sweeps' points."""
    table, frontier = synthetic(n=4)
    mean_seed = (0 + 1 + 2 + 3) / 4
    assert frontier.point("greedy").episode_wall_s == pytest.approx(100 * 5e-3 + mean_seed)
    assert frontier.point("greedy").wall_s == pytest.approx(4 * (100 * 5e-3 + mean_seed))
    runtimes = {"attention": 1e-4, "greedy": 5e-3, "oracle": 6e-3, "mcts:simulations=8": 0.01,
                "mcts:simulations=64": 0.073, "mcts:simulations=200": 0.25}
    total = sum(4 * (100 * r + mean_seed) for r in runtimes.values())
    sweep = sum(4 * (100 * runtimes[p] + mean_seed) for p in runtimes if p.startswith("mcts"))
    text = frontier_section(table, [frontier], {}, {}, {})
    assert f"took {total / 60:.1f} min of wall time in all" in text
    assert f"{sweep / 60:.1f} min of it the sweeps'" in text
