"""A learning method flown over several trained networks: the split, the spec, the two-level bootstrap and a
tiny leaderboard of a two-network method (ipp_bench.eval.methods, ipp_bench.policies.networks)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from lb_helpers import TASKS, results, run_tiny, tiny_plan

from ipp_bench.eval.aggregate import bootstrap_ci, estimate, normalised_board, two_level_indices
from ipp_bench.eval.methods import SPLIT_RULE, network_index, networks_by_seed
from ipp_bench.eval.results import ResultsMismatchError
from ipp_bench.eval.tables import EpisodeTable
from ipp_bench.policies.networks import checkpoint_set


def test_episode_i_is_flown_by_network_i_mod_k():
    assert [network_index(i, 3) for i in range(7)] == [0, 1, 2, 0, 1, 2, 0]
    got = networks_by_seed({"m": {"networks": ["a", "b"], "split": SPLIT_RULE}}, [50, 7, 9, 1])
    assert got == {"m": {50: 0, 7: 1, 9: 0, 1: 1}}  # by place in the seed list, not by seed value


# -- the spec -------------------------------------------------------------------------------------------
def test_a_checkpoint_set_parses_in_order_and_refuses_in_one_line(tmp_path):
    a, b = tmp_path / "a.pt", tmp_path / "b.pt"
    a.write_bytes(b"x")
    b.write_bytes(b"y")
    assert checkpoint_set(f" {b} + {a} ") == (f"{b}+{a}", (str(b), str(a)))
    assert checkpoint_set(str(a)) == (str(a), (str(a),))
    assert checkpoint_set("") == ("", ())
    for value, message in [(f"{a}+{tmp_path / 'gone.pt'}", r"network 2 of 2, \S+gone.pt, cannot be read \(no such "),
                           (f"{a}+{b}+{a}", r"a.pt is listed twice \(networks 1 and 3\)"),
                           (f"{a}+{tmp_path}", r"cannot be read \(not a file\)"),
                           (f"{a}++{b}", "an empty name between")]:
        with pytest.raises(ValueError, match=message) as err:
            checkpoint_set(value)
        assert "\n" not in str(err.value)


def test_a_short_name_is_the_shipped_set_in_seed_order(tmp_path):
    for n in (10, 2, 0):
        (tmp_path / f"net_v7_seed{n}.pt").write_bytes(b"x")
    (tmp_path / "net_v7_seedx.pt").write_bytes(b"x")  # not a seed file
    value, paths = checkpoint_set("net_v7", folder=tmp_path)
    assert value == "net_v7" and [p.rsplit("/", 1)[1] for p in paths] == [
        "net_v7_seed0.pt", "net_v7_seed2.pt", "net_v7_seed10.pt"]
    # no such set: a path, refused when the planner loads it
    assert checkpoint_set("no_such_set", folder=tmp_path) == ("no_such_set", ("no_such_set",))


# -- the two-level bootstrap ----------------------------------------------------------------------------
def test_with_one_network_the_bootstrap_is_todays_exactly():
    x = np.random.default_rng(3).normal(size=17)
    assert bootstrap_ci(x, groups=[0] * 17) == bootstrap_ci(x)
    assert bootstrap_ci(x, groups=None) == bootstrap_ci(x)
    a, b = np.random.default_rng(1), np.random.default_rng(1)
    assert np.array_equal(two_level_indices(a, [4] * 9, 9, 50), b.integers(0, 9, size=(50, 9)))


def test_two_level_indices_draw_networks_then_their_episodes():
    groups = [0, 1, 2, 0, 1, 2, 0]  # the split of 7 episodes among 3 networks
    idx = two_level_indices(np.random.default_rng(0), groups, 7, 400)
    g = np.asarray(groups)
    for row in idx:
        # each network's places (3, 2 and 2 episodes) hold the episodes of one network, drawn anew
        for places in (np.array([0, 3, 6]), np.array([1, 4]), np.array([2, 5])):
            assert len(set(g[row[places]])) == 1
    drawn = g[idx[:, [0, 1, 2]]]
    assert {tuple(r) for r in drawn} > {(0, 1, 2)}  # networks are drawn with replacement: repeats happen
    assert np.mean(drawn[:, 0] == drawn[:, 1]) == pytest.approx(1 / 3, abs=0.08)


def test_constant_networks_give_the_between_network_spread_only():
    values = np.array([10.0, 20.0, 30.0] * 4)  # network n always scores 10 (n + 1)
    groups = [0, 1, 2] * 4
    mean, low, high = bootstrap_ci(values, groups=groups)
    rng = np.random.default_rng(0)
    # the same resamples by hand: a mean of 3 networks drawn with replacement
    means = np.concatenate([values[two_level_indices(rng, groups, 12, 250)].mean(axis=1) for _ in range(8)])
    assert (low, high) == tuple(np.percentile(means, [2.5, 97.5]))
    assert mean == 20 and low < 17 and high > 23
    # every resample is the mean of 3 networks' values drawn with replacement: nothing of the episodes' spread
    assert np.allclose(3 * means / 10, np.round(3 * means / 10)) and set(np.round(3 * means / 10)) == set(range(3, 10))
    _, lo, hi = bootstrap_ci(values)  # the episodes alone: a narrower interval
    assert hi - lo < 0.8 * (high - low)


def test_a_large_between_seed_variance_widens_the_interval():
    rng = np.random.default_rng(5)
    offsets = np.array([-6.0, 0.0, 7.0, 1.0])
    groups = np.arange(40) % 4
    values = offsets[groups] + rng.normal(scale=1.0, size=40)
    _, lo1, hi1 = bootstrap_ci(values)
    _, lo2, hi2 = bootstrap_ci(values, groups=groups)
    assert hi2 - lo2 > 2.5 * (hi1 - lo1)


def _board_rows(n=12, k=3, spread=10.0):
    """Rows of a board with ``random``, ``greedy``, ``oracle`` and a method ``m`` of k networks whose means differ
    by ``spread`` points."""
    rng = np.random.default_rng(0)
    rows = []
    for i, seed in enumerate(range(100, 100 + n)):
        base = rng.normal(50, 5)
        for p, v in (("random", base - 20), ("greedy", base), ("oracle", base + 15),
                     ("m", base + spread * (i % k - 1) + rng.normal())):
            rows.append({"task": "T", "planner": p, "seed": seed, "time_s": 100.0,
                         "uncertainty_reduction_pct": float(v), "rmse_reduction_pct": float(v), "trace_roi": 1.0,
                         "rmse_roi": 1.0, "decisions": 3, "decision_time_mean_s": 0.01, "decision_time_max_s": 0.01,
                         "episode_wall_s": 1.0})
    return rows, list(range(100, 100 + n))


def test_the_aggregate_resamples_a_methods_networks_and_keeps_the_others_intervals():
    rows, seeds = _board_rows()
    networks = {"m": {s: i % 3 for i, s in enumerate(seeds)}}
    board = normalised_board(rows, ["random", "greedy", "m", "oracle"], ["T"])
    plain = estimate(board, n_resamples=400)
    two = estimate(board, n_resamples=400, networks=networks)
    assert two.iqm["greedy"] == plain.iqm["greedy"] and two.poi[("greedy", "random")] == plain.poi[("greedy", "random")]
    assert two.iqm["m"][0] == plain.iqm["m"][0]
    width = [e.iqm["m"][2] - e.iqm["m"][1] for e in (plain, two)]
    assert width[1] > 1.3 * width[0]  # 1.44: the IQM trims part of the between-network spread
    assert two.poi[("m", "greedy")] != plain.poi[("m", "greedy")]
    one = estimate(board, n_resamples=400, networks={"m": {s: 0 for s in seeds}})  # one network: today's
    assert one.iqm == plain.iqm and one.poi == plain.poi


def test_the_tables_pair_a_method_two_level():
    rows, seeds = _board_rows()
    methods = {"m": {"networks": ["a.pt", "b.pt", "c.pt"], "split": SPLIT_RULE}}
    plain, two = EpisodeTable(rows), EpisodeTable(rows, methods=methods, seeds=seeds)
    assert two.stat("T", "greedy", 100.0, "rmse_roi") == plain.stat("T", "greedy", 100.0, "rmse_roi")
    assert two.stat("T", "greedy", 100.0, "uncertainty_reduction_pct") == \
        plain.stat("T", "greedy", 100.0, "uncertainty_reduction_pct")
    s1, s2 = (t.stat("T", "m", 100.0, "uncertainty_reduction_pct") for t in (plain, two))
    assert s1[0] == s2[0] and s2[2] - s2[1] > s1[2] - s1[1]
    from ipp_bench.eval.markdown import paired_table
    from ipp_bench.eval.power import power_rule

    assert paired_table(two, "greedy") != paired_table(plain, "greedy")
    cell = {c.planner: c for c in power_rule(rows, "greedy", networks=two.networks)}
    flat = {c.planner: c for c in power_rule(rows, "greedy")}
    assert cell["m"].half_width > 1.5 * flat["m"].half_width and cell["oracle"] == flat["oracle"]


# -- a tiny leaderboard of a two-network method ---------------------------------------------------------
@pytest.fixture(scope="module")
def two_networks(tmp_path_factory):
    torch = pytest.importorskip("torch")
    from ipp_bench.policies.checkpoint import save_checkpoint
    from ipp_bench.policies.network import AttentionNet, NetConfig

    folder = tmp_path_factory.mktemp("nets")
    paths = []
    for seed in (0, 1, 2):
        torch.manual_seed(seed)
        paths.append(save_checkpoint(AttentionNet(NetConfig(embed_dim=16, n_heads=2, ff_dim=32)),
                                     folder / f"net{seed}.pt"))
    return paths


def test_a_leaderboard_flies_a_method_over_its_networks(two_networks, tmp_path):
    a, b, c = two_networks
    method = f"attention:checkpoint={a}+{b}"
    out = tmp_path / "lb"

    def plan(spec=method, episodes=3):
        return tiny_plan(tasks=TASKS[:1], planners=("random", spec), episodes=episodes)

    p = plan()
    jobs = [j for j in p.jobs() if j.planner == method]
    assert [(j.network, j.flies) for j in jobs] == [(0, f"attention:checkpoint={a}"), (1, f"attention:checkpoint={b}"),
                                                    (0, f"attention:checkpoint={a}")]
    run_tiny(out, p, command="ipp-bench leaderboard (test)")
    meta = json.loads((out / "run.json").read_text())
    assert meta["fingerprint"]["methods"] == {method: {"networks": [str(a), str(b)], "split": SPLIT_RULE}}
    assert len(meta["fingerprint"]["planner_fingerprints"][method]["checkpoint_sha256"].split("+")) == 2
    rows = [r for r in results(out) if r["planner"] == method]
    assert sorted({r["seed"] for r in rows}) == sorted(p.seeds)
    # each row is what its network flies alone
    alone = run_tiny(tmp_path / "alone", tiny_plan(tasks=TASKS[:1], planners=(f"attention:checkpoint={b}",),
                                                   episodes=3))
    assert alone.ran == 3
    theirs = {(r["seed"], r["time_s"]): r["uncertainty_reduction_pct"] for r in results(tmp_path / "alone")}
    mine = {(r["seed"], r["time_s"]): r["uncertainty_reduction_pct"] for r in rows}
    assert all(mine[(p.seeds[1], t)] == theirs[(p.seeds[1], t)] for t in (20.0, 40.0))
    assert any(mine[(p.seeds[0], t)] != theirs[(p.seeds[0], t)] for t in (20.0, 40.0))
    report = (out / "leaderboard.md").read_text()
    assert "## Methods over several trained networks" in report
    assert f"`{method}`: 2 networks, 1 `{a}`, 2 `{b}`." in report
    assert f"| 1 `{a}` | 2 |" in report and f"| 2 `{b}` | 1 |" in report
    before = (out / "results.csv").read_bytes()
    assert run_tiny(out, plan()).ran == 0  # resumes: already complete, byte for byte
    assert (out / "results.csv").read_bytes() == before
    for other in (f"attention:checkpoint={b}+{a}", f"attention:checkpoint={a}+{c}"):
        with pytest.raises(ResultsMismatchError, match="different arguments"):
            run_tiny(out, plan(other))
    copy = tmp_path / "swapped"
    shutil.copytree(out, copy)
    kept = b.read_bytes()
    shutil.copy(c, b)  # another network behind the same name: its hash differs
    try:
        with pytest.raises(ResultsMismatchError, match="planner_fingerprints"):
            run_tiny(copy, plan())
    finally:
        b.write_bytes(kept)


def test_a_method_refuses_to_fly_one_episode_alone(two_networks):
    from ipp_bench.planners import make_planner

    planner = make_planner(f"attention:checkpoint={two_networks[0]}+{two_networks[1]}")
    assert len(planner.networks) == 2
    with pytest.raises(ValueError, match="names 2 networks, a method: the leaderboard flies it"):
        planner.reset(None, 0)
