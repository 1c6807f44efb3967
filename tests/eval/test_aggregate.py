"""The aggregate over tasks (rliable's IQM, probability of improvement, performance profile, the
stratified bootstrap) and the power rule, on exact numbers, against rliable's published definitions
computed here, and against the ``rliable`` package where it is installed."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from ipp_bench.eval import aggregate as A
from ipp_bench.eval import power
from ipp_bench.eval.markdown_stats import aggregate_estimates, aggregate_section, power_section
from ipp_bench.eval.tables import EpisodeTable


def board_of(scores: dict[str, np.ndarray]) -> A.Board:
    """A board from (episodes x tasks) matrices, one report time per task (rliable's layout)."""
    names = list(scores)
    n, m = scores[names[0]].shape
    blocks = [np.stack([scores[p][:, k] for p in names])[:, None, :] for k in range(m)]
    return A.Board(names, [f"task{k}" for k in range(m)], [(100.0,)] * m, [tuple(range(n))] * m, blocks, {},
                   "random", "oracle")


# ------------------------------------------------------------------------------------------------
# point estimates: hand numbers and rliable.metrics
# ------------------------------------------------------------------------------------------------
def test_iqm_is_the_mean_of_the_middle_half_of_every_run_and_task():
    scores = np.arange(1.0, 9.0).reshape(4, 2)  # 1..8: the middle half is 3, 4, 5, 6
    assert A.iqm(scores) == pytest.approx(4.5)
    assert A.iqm(np.array([[0.0], [10.0], [1.0], [2.0]])) == pytest.approx(1.5)  # 0, 1, 2, 10 -> (1 + 2) / 2


def test_probability_of_improvement_counts_ties_a_half_and_averages_over_tasks():
    x = np.array([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    y = np.array([[2.0, 1.0], [2.0, 1.0], [0.0, 1.0]])
    # task 0: x=1 beats y once (0); x=2 ties twice (2 x 0.5) and beats 0; x=3 beats all: (1 + 2 + 3) / 9
    # task 1: x never beats y: 0
    assert A.probability_of_improvement(x, y) == pytest.approx((6 / 9 + 0) / 2)
    assert A.probability_of_improvement(x, x) == pytest.approx(0.5)
    assert A.probability_of_improvement(x, y) + A.probability_of_improvement(y, x) == pytest.approx(1.0)


def test_performance_profile_is_the_fraction_of_runs_above_tau():
    scores = np.array([[0.1, 0.5], [0.9, 1.2]])
    assert A.performance_profile(scores, [0.0, 0.5, 1.0, 2.0]).tolist() == [1.0, 0.5, 0.25, 0.0]


#: why the rliable comparisons skip where it is missing: the dev extra pins a set that imports and runs
NO_RLIABLE = ('rliable is not installed: pip install -e ".[dev]" (it pins rliable 1.2.0 with arch < 8 and pandas < 3, '
              "the releases that import and run together)")


def test_point_estimates_match_rliable_metrics():
    metrics = pytest.importorskip("rliable.metrics", reason=NO_RLIABLE)
    rng = np.random.default_rng(1)
    x, y = rng.normal(0.6, 0.3, (7, 5)), rng.normal(0.5, 0.3, (7, 5))
    y[:, 2] = np.round(y[:, 2], 1)
    x[:, 2] = np.round(x[:, 2], 1)  # ties, which Mann-Whitney counts a half
    assert A.iqm(x) == pytest.approx(metrics.aggregate_iqm(x), abs=1e-12)
    assert A.probability_of_improvement(x, y) == pytest.approx(metrics.probability_of_improvement(x, y), abs=1e-12)
    est = A.estimate(board_of({"x": x, "y": y}), n_resamples=20)
    assert est.iqm["x"][0] == pytest.approx(metrics.aggregate_iqm(x), abs=1e-12)
    assert est.poi[("x", "y")][0] == pytest.approx(metrics.probability_of_improvement(x, y), abs=1e-12)


def test_the_interval_estimates_match_rliables_stratified_bootstrap():
    """rliable's own bootstrap (its ``arch`` dependency must import and run: the dev extra pins releases
    that do, so where rliable is installed a failure here is a failure, not a skip)."""
    pytest.importorskip("rliable", reason=NO_RLIABLE)
    from rliable import library, metrics  # arch 7.2 with pandas 3 raises here: the dev extra pins pandas < 3

    rng = np.random.default_rng(2)
    x = rng.normal(0.6, 0.3, (10, 5))
    np.random.seed(0)
    _, ci = library.get_interval_estimates({"x": x}, lambda s: np.array([metrics.aggregate_iqm(s)]), reps=4000)
    est = A.estimate(board_of({"x": x}), n_resamples=4000)
    assert est.iqm["x"][1] == pytest.approx(ci["x"][0][0], abs=0.02)
    assert est.iqm["x"][2] == pytest.approx(ci["x"][1][0], abs=0.02)


# ------------------------------------------------------------------------------------------------
# the stratified bootstrap, against the definition computed here
# ------------------------------------------------------------------------------------------------
def reference_bootstrap(scores: dict[str, np.ndarray], reps: int, seed: int):
    """The stratified bootstrap from its definition, one resample at a time: per task, draw the
    episode indices with replacement, the same for every planner; IQM over every run and task; P(X > Y)
    per task over every pair of runs, averaged; percentile interval."""
    rng = np.random.default_rng(seed)
    names = list(scores)
    n, m = scores[names[0]].shape
    iqm = {p: [] for p in names}
    poi = []
    for _ in range(reps):
        idx = rng.integers(0, n, size=(m, n))
        res = {p: np.stack([scores[p][idx[k], k] for k in range(m)], axis=1) for p in names}
        for p in names:
            iqm[p].append(stats.trim_mean(res[p], 0.25, axis=None))
        x, y = res[names[0]], res[names[1]]
        poi.append(np.mean([np.mean((x[:, k, None] > y[None, :, k]) + 0.5 * (x[:, k, None] == y[None, :, k]))
                            for k in range(m)]))
    ci = {p: np.percentile(v, [2.5, 97.5]) for p, v in iqm.items()}
    return ci, np.percentile(poi, [2.5, 97.5])


def test_stratified_bootstrap_intervals_match_the_definition():
    rng = np.random.default_rng(3)
    x = rng.normal(0.6, 0.3, (12, 4))
    y = 0.5 * x + rng.normal(0.2, 0.2, (12, 4))  # paired: correlated with x episode by episode
    scores = {"x": x, "y": y}
    est = A.estimate(board_of(scores), n_resamples=2500)
    ci, poi_ci = reference_bootstrap(scores, 2500, seed=11)  # another stream: agreement within Monte Carlo error
    for p in scores:
        assert est.iqm[p][1:] == pytest.approx(tuple(ci[p]), abs=0.015)
    assert est.poi[("x", "y")][1:] == pytest.approx(tuple(poi_ci), abs=0.02)
    assert est.poi[("y", "x")][1:] == pytest.approx((1 - poi_ci[1], 1 - poi_ci[0]), abs=0.02)


def test_episodes_are_resampled_jointly_for_every_planner():
    """A planner that is another plus 0.01 on every episode keeps that lead in every resample: its
    IQM interval is the other's shifted by exactly 0.01 (independent resampling would blur it)."""
    rng = np.random.default_rng(4)
    x = rng.normal(0.5, 0.3, (9, 3))
    est = A.estimate(board_of({"x": x, "x+": x + 0.01}), n_resamples=500)
    assert np.array(est.iqm["x+"]) - np.array(est.iqm["x"]) == pytest.approx([0.01] * 3, abs=1e-12)
    same = A.estimate(board_of({"a": x, "b": x.copy()}), n_resamples=200)
    assert same.poi[("a", "b")] == pytest.approx((0.5, 0.5, 0.5))
    assert same.ranks == {"a": 1, "b": 1}  # tied


def test_report_times_of_one_episode_are_resampled_together():
    """Two report times of the same episodes: the per-time IQMs and the pooled one come from one
    draw of episodes per task, so a planner ahead at every time of every episode is ahead in every
    resample, and the estimates are reproducible."""
    rng = np.random.default_rng(5)
    base = rng.normal(0.5, 0.2, (2, 2, 8))  # (tasks, times, episodes)
    blocks = [np.stack([base[k], base[k] + 0.1]) for k in range(2)]
    board = A.Board(["a", "b"], ["t0", "t1"], [(50.0, 100.0)] * 2, [tuple(range(8))] * 2, blocks, {}, "random",
                    "oracle")
    est = A.estimate(board, n_resamples=300)
    assert est.poi[("b", "a")][0] > 0.5
    for t in (50.0, 100.0):
        assert np.array(est.iqm_by_time[t]["b"]) - np.array(est.iqm_by_time[t]["a"]) == pytest.approx([0.1] * 3)
    again = A.estimate(board, n_resamples=300)
    assert again.iqm == est.iqm and again.poi == est.poi


def test_ranks_tie_the_planners_the_data_cannot_separate():
    rng = np.random.default_rng(6)
    base = rng.normal(0.5, 0.1, (20, 3))
    scores = {"best": base + 1.0, "b": base + rng.normal(0, 0.05, base.shape), "c": base.copy(),
              "oracle": base + 2.0}
    est = A.estimate(board_of(scores), n_resamples=500)
    assert est.ranks == {"best": 1, "b": 2, "c": 2}  # the oracle is never ranked
    section = aggregate_section(EpisodeTable([]), board_of(scores), est)
    rows = [line for line in section.splitlines() if line.startswith("| ") and "`" in line][:4]
    assert rows[0].startswith("| 1 | `best` |") and rows[1].startswith("| 2= |") and rows[2].startswith("| 2= |")
    assert rows[3].startswith("| – | `oracle` (reference) |")


# ------------------------------------------------------------------------------------------------
# normalisation
# ------------------------------------------------------------------------------------------------
def rows_of(values: dict[str, dict[float, list[float]]], task: str = "ipp_bench/Toy-v0") -> list[dict]:
    return [dict(task=task, planner=p, seed=s, time_s=t, uncertainty_reduction_pct=v)
            for p, by_time in values.items() for t, vs in by_time.items() for s, v in enumerate(vs)]


def test_scores_are_the_share_of_the_way_from_random_to_oracle():
    rows = rows_of({"random": {50.0: [10.0, 30.0]}, "greedy": {50.0: [60.0, 40.0]}, "oracle": {50.0: [70.0, 90.0]}})
    board = A.normalised_board(rows)
    assert (board.lower, board.upper) == ("random", "oracle") and board.anchors[("ipp_bench/Toy-v0", 50.0)] == (20, 80)
    # (60 - 20) / 60, (40 - 20) / 60; random averages 0, the oracle 1
    assert board.blocks[0][1, 0].tolist() == pytest.approx([40 / 60, 20 / 60])
    assert board.blocks[0][0, 0].mean() == pytest.approx(0.0) and board.blocks[0][2, 0].mean() == pytest.approx(1.0)


def test_without_the_anchor_planners_the_scale_is_zero_to_a_hundred_percent_and_says_so():
    board = A.normalised_board(rows_of({"greedy": {50.0: [60.0, 40.0]}}))
    assert board.blocks[0][0, 0].tolist() == pytest.approx([0.6, 0.4])
    assert "no `random` rows" in board.lower and "no `oracle` rows" in board.upper


def test_what_cannot_be_aggregated_is_left_out_with_a_note():
    rows = rows_of({"random": {50.0: [10.0, 10.0], 100.0: [10.0, 20.0]}, "oracle": {50.0: [10.5, 10.2],
                                                                                   100.0: [90.0, 80.0]}})
    rows += rows_of({"greedy": {50.0: [30.0, 30.0], 100.0: [50.0, 50.0]}})[:3]  # one episode lacks 100 s
    rows += rows_of({"lonely": {50.0: [1.0]}}, task="ipp_bench/Other-v0")
    board = A.normalised_board(rows)
    assert "lonely" not in board.planners and any("lonely" in n for n in board.notes)
    assert board.tasks == ["ipp_bench/Toy-v0"] and board.times == [(100.0,)]  # 50 s: anchors 0.35 points apart
    assert board.seeds == [(0,)]  # the episode greedy lacks is left out for every planner
    assert any("less than 1 point apart" in n for n in board.notes)


# ------------------------------------------------------------------------------------------------
# the power rule
# ------------------------------------------------------------------------------------------------
def test_episodes_needed_is_the_normal_rule_rounded_up():
    assert power.episodes_needed(10.0, 3.0) == math.ceil((1.96 * 10 / 3) ** 2) == 43
    assert power.episodes_needed(0.0, 3.0) == 2  # an interval needs two episodes
    assert power.episodes_needed(3.0 / 1.96, 1.0) == 9  # exactly 9: no rounding up past it
    with pytest.raises(ValueError, match="half-width"):
        power.episodes_needed(1.0, 0.0)


def test_power_rule_from_the_paired_differences():
    greedy = [50.0, 60.0, 55.0, 70.0, 65.0]
    mine = [52.0, 61.0, 60.0, 69.0, 71.0]
    rows = rows_of({"greedy": {100.0: greedy}, "mine": {100.0: mine}})
    (cell,) = power.power_rule(rows, "greedy", half_width=1.0)
    d = np.subtract(mine, greedy)
    assert cell.sd == pytest.approx(np.std(d, ddof=1)) and cell.episodes == 5
    _, lo, hi = A.bootstrap_ci(d)
    assert cell.half_width == pytest.approx(max(d.mean() - lo, hi - d.mean()))
    assert cell.needed == math.ceil((1.96 * np.std(d, ddof=1) / 1.0) ** 2)
    assert power.needed_per_task([cell]) == {"ipp_bench/Toy-v0": cell}


def test_the_power_section_names_the_rule_and_the_cells():
    rows = rows_of({"greedy": {100.0: [50.0, 60.0, 55.0]}, "mine": {100.0: [52.0, 61.0, 60.0]}})
    rows = [dict(r, trace_roi=1.0, rmse_roi=0.1, rmse_reduction_pct=1.0, decision_time_mean_s=0.01) for r in rows]
    text = power_section(EpisodeTable(rows), "greedy", 3.0)
    assert "n = ceil((1.96 sd / 3)^2)" in text and "| **Toy-v0** | 100 | 3 |" in text
    sd = np.std([2.0, 1.0, 5.0], ddof=1)
    assert f"{sd:.1f} (`mine`)" in text


def test_the_aggregate_of_a_report_has_its_interval_and_profile():
    rows = rows_of({"random": {50.0: [10.0, 30.0, 20.0]}, "greedy": {50.0: [60.0, 40.0, 50.0]},
                    "oracle": {50.0: [70.0, 90.0, 80.0]}})
    rows = [dict(r, trace_roi=1.0, rmse_roi=0.1, rmse_reduction_pct=1.0, decision_time_mean_s=0.01) for r in rows]
    board, est = aggregate_estimates(EpisodeTable(rows))
    assert est is not None and est.iqm["greedy"][0] == pytest.approx(0.5)  # 0.5 +- 1/6: trimmed mean 0.5
    point, low, high = est.profile["greedy"]
    assert np.all(low <= point + 1e-12) and np.all(point <= high + 1e-12)
    assert point[np.searchsorted(est.taus, 0.0)] == 1.0


def test_a_team_board_takes_team_oracle_as_its_upper_anchor():
    from ipp_bench.eval.aggregate import normalised_board

    rows = [{"task": "ipp_bench/Toy-v0", "planner": p, "seed": s, "time_s": 50.0, "uncertainty_reduction_pct": v}
            for s in range(3) for p, v in (("random", 20.0), ("team-oracle", 80.0), ("greedy", 50.0 + s))]
    board = normalised_board(rows)
    assert (board.lower, board.upper) == ("random", "team-oracle")
    assert board.anchors[("ipp_bench/Toy-v0", 50.0)] == (20.0, 80.0)
