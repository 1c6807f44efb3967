"""The `attention` planner: checkpoint loading, masking, errors."""

import numpy as np
import pytest
import torch

gym = pytest.importorskip("gymnasium")

import ipp_bench.envs  # noqa: F401
from ipp_bench.planners import make_planner
from ipp_bench.planners.base import RobotView
from ipp_bench.policies.checkpoint import (
    SHIPPED_CHECKPOINT,
    CheckpointError,
    load_checkpoint,
    save_checkpoint,
)
from ipp_bench.policies.network import AttentionNet, NetConfig


@pytest.fixture(scope="module")
def small_ckpt(tmp_path_factory):
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("ckpt") / "small.pt"
    save_checkpoint(AttentionNet(NetConfig(embed_dim=32, n_heads=2, ff_dim=64)), path, meta={"note": "test"})
    return path


def _fly(planner, task="ipp_bench/Grid15Eval-v1", seed=0, steps=40):
    env = gym.make(task)
    obs, _ = env.reset(seed=seed)
    planner.reset(RobotView(env.unwrapped), seed)
    actions = []
    for _ in range(steps):
        mask = env.unwrapped.action_masks()
        a = planner.act(obs)
        assert mask[a], "the planner chose a masked neighbour"
        actions.append(a)
        obs, _, term, _, _ = env.step(a)
        if term:
            break
    return actions


def test_checkpoint_round_trip(small_ckpt):
    net, meta = load_checkpoint(small_ckpt)
    assert meta == {"note": "test"} and net.cfg.embed_dim == 32
    assert small_ckpt.with_suffix(".json").is_file()


def test_planner_argmax_is_deterministic_and_sampling_is_seeded(small_ckpt):
    det = make_planner(f"attention:checkpoint={small_ckpt}")
    assert _fly(det, seed=1) == _fly(det, seed=1)
    smp = make_planner(f"attention:checkpoint={small_ckpt},sample=true")
    assert smp.settings.sample is True
    a, b = _fly(smp, seed=2), _fly(smp, seed=2)
    assert a == b


def test_planner_single_valid_neighbour(small_ckpt):
    planner = make_planner(f"attention:checkpoint={small_ckpt},sample=true")
    env = gym.make("ipp_bench/Grid15-v0")
    obs, _ = env.reset(seed=0)
    planner.reset(RobotView(env.unwrapped), 0)
    for j in (3, 17):
        only = {**obs, "action_mask": np.eye(20, dtype=np.int8)[j]}
        assert all(planner.act(only) == j for _ in range(30))
        p = planner.probabilities(only)
        assert p[j] == 1.0 and p.sum() == pytest.approx(1.0)


def test_planner_runs_on_the_larger_grid(small_ckpt):
    _fly(make_planner(f"attention:checkpoint={small_ckpt}"), task="ipp_bench/Grid20Eval-v1", steps=10)


def test_missing_checkpoint_says_what_was_expected(tmp_path):
    with pytest.raises(CheckpointError, match="not found: expected an ipp-bench attention checkpoint"):
        make_planner(f"attention:checkpoint={tmp_path / 'nope.pt'}")


def test_incompatible_checkpoints_are_refused(tmp_path, small_ckpt):
    junk = tmp_path / "junk.pt"
    torch.save({"weights": torch.zeros(3)}, junk)
    with pytest.raises(CheckpointError, match="format"):
        load_checkpoint(junk)
    text = tmp_path / "text.pt"
    text.write_text("not a checkpoint")
    with pytest.raises(CheckpointError, match="is not an ipp-bench checkpoint") as err:
        load_checkpoint(text)
    assert "weights_only" not in str(err.value)
    pickled = tmp_path / "pickled.pt"
    torch.save({"format": "ipp_bench.attention/1", "x": tmp_path}, pickled)  # needs weights_only=False
    with pytest.raises(CheckpointError, match="is not an ipp-bench checkpoint") as err:
        load_checkpoint(pickled)
    assert "weights_only" not in str(err.value) and "\n" not in str(err.value)
    payload = torch.load(small_ckpt, weights_only=True)
    payload["net_config"]["embed_dim"] = 64  # weights no longer fit
    bad = tmp_path / "bad.pt"
    torch.save(payload, bad)
    with pytest.raises(CheckpointError, match="does not fit") as err:
        load_checkpoint(bad)
    assert "\n" not in str(err.value)
    with pytest.raises(CheckpointError, match="SB3 model archive"):
        load_checkpoint(tmp_path / "model.zip") if (tmp_path / "model.zip").write_text("x") else None


def test_an_empty_truncated_or_pickled_checkpoint_is_named_as_such_before_torch_reads_it(tmp_path, small_ckpt):
    import pickle
    import warnings

    empty = tmp_path / "empty.pt"
    empty.write_bytes(b"")
    cut = tmp_path / "cut.pt"
    cut.write_bytes(small_ckpt.read_bytes()[:4000])
    pickled = tmp_path / "plain.pt"
    pickled.write_bytes(pickle.dumps({"format": "ipp_bench.attention/1"}, protocol=4))
    for path, why in ((empty, "it is empty \\(0 bytes\\)"), (cut, "it is truncated \\(4000 bytes"),
                      (pickled, "it is a plain pickle, not a torch zip archive")):
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # torch's own notice (e.g. "Detected pickle protocol 4") fails here
            with pytest.raises(CheckpointError, match=f"is not an ipp-bench checkpoint: {why}") as err:
                load_checkpoint(path)
        assert "\n" not in str(err.value)


def test_pe_dim_mismatch_is_refused_at_reset_in_one_line(small_ckpt):
    planner = make_planner(f"attention:checkpoint={small_ckpt}")
    env = gym.make("ipp_bench/Grid15-v0", pe_dim=16)
    env.reset(seed=0)
    with pytest.raises(CheckpointError, match="pe_dim=32 in the checkpoint but pe_dim=16 in the environment") as err:
        planner.reset(RobotView(env.unwrapped), 0)
    assert "\n" not in str(err.value)


def test_same_weights_on_grid15_and_grid30(small_ckpt):
    for task in ("ipp_bench/Grid15Eval-v1", "ipp_bench/Grid30Eval-v1"):
        assert len(_fly(make_planner(f"attention:checkpoint={small_ckpt}"), task=task, steps=5)) == 5


def test_shipped_checkpoint_loads_and_acts():
    assert SHIPPED_CHECKPOINT.is_file(), f"the trained checkpoint must ship at {SHIPPED_CHECKPOINT}"
    assert SHIPPED_CHECKPOINT.stat().st_size < 5 * 2**20
    _, meta = load_checkpoint()
    # the command that made it, and the checkpoint README gives it as written
    assert "command" in meta and meta["command"].startswith(("ipp-bench train", "python benchmarks/"))
    assert all(stage["command"].startswith(("ipp-bench train", "python benchmarks/")) for stage in meta["stages"])
    # the recipe that rebuilds it, all seven stages, is the command its README gives
    assert len(meta["stages"]) == 7
    assert "ipp-bench train --recipe attention_v6" in (SHIPPED_CHECKPOINT.parent / "README.md").read_text()
    from ipp_bench.train.recipe import load_recipe

    assert len(load_recipe("attention_v6").stages) == 7
    _fly(make_planner("attention"), steps=20)


def test_the_context_is_the_nearest_nodes_and_the_network_sees_only_them():
    """``context_nodes``: the network's keys are the nodes nearest the UAV; its logits equal the network
    run on that sub-roadmap built by hand (distances, remapped indices), and a roadmap no larger than the
    context is passed through untouched (full attention, byte for byte)."""
    env = gym.make("ipp_bench/Grid30Eval-v1")  # 1800 nodes
    obs, _ = env.reset(seed=3)
    for a in (0, 5, 11):  # away from the start
        obs, *_ = env.step(int(np.flatnonzero(env.unwrapped.action_masks())[a % 3]))
    full = make_planner("attention")
    full.reset(RobotView(env.unwrapped), 0)
    assert full.settings.context_nodes >= 1800 and full.context(obs) is obs
    planner = make_planner("attention:context_nodes=300")
    view = RobotView(env.unwrapped)
    planner.reset(view, 0)
    from ipp_bench.policies.features import extend_observation

    ext = extend_observation(obs, view, planner.net.cfg.node_dim, invariant=planner.net.cfg.invariant)
    sub = planner.context(ext)
    pos, cur = view.roadmap.positions, int(obs["current_node"][0])
    d = np.hypot(pos[:, 0] - pos[cur, 0], pos[:, 1] - pos[cur, 1])
    chosen = np.zeros(len(pos), bool)
    chosen[np.flatnonzero(np.isin(np.arange(len(pos)), np.unique(np.r_[np.argsort(d, kind="stable")[:300],
                                                                         obs["neighbours"], cur])))] = True
    assert 300 <= sub["node_features"].shape[0] == chosen.sum() < 1800
    assert d[chosen].max() <= d[~chosen].min() + 1e-9  # a disc around the UAV
    nodes = np.flatnonzero(chosen)
    assert nodes[int(sub["current_node"][0])] == cur
    assert np.array_equal(nodes[sub["neighbours"]], obs["neighbours"])
    assert np.array_equal(sub["node_features"], ext["node_features"][nodes])
    assert np.array_equal(sub["pos_encoding"], obs["pos_encoding"][nodes])
    with torch.inference_mode():
        by_hand, _ = planner.net(
            torch.as_tensor(ext["node_features"][nodes]).unsqueeze(0),
            torch.as_tensor(obs["pos_encoding"][nodes], dtype=torch.float32).unsqueeze(0),
            torch.as_tensor([int(np.flatnonzero(nodes == cur)[0])]),
            torch.as_tensor(np.searchsorted(nodes, obs["neighbours"])).unsqueeze(0),
            torch.as_tensor(obs["action_mask"].astype(bool)).unsqueeze(0),
            torch.as_tensor(np.asarray(obs["budget"], dtype=np.float32).reshape(1, 1)))
    got = planner._logits(obs)
    allowed = obs["action_mask"].astype(bool)
    assert np.allclose(got[allowed], by_hand[0].numpy()[allowed], atol=1e-5)
    assert not np.allclose(got[allowed], full._logits(obs)[allowed], atol=1e-5)  # the context matters


@pytest.mark.parametrize("bad", ["-1", "10"])
def test_a_bad_context_size_is_refused_in_one_line(bad):
    with pytest.raises(ValueError, match=r"attention.context_nodes = .* is invalid: expected 0 \(every node\) "
                                         r"or an integer >= 64") as err:
        make_planner(f"attention:context_nodes={bad}")
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("bad", ["1.5", "many"])
def test_a_context_size_that_is_no_integer_is_refused_in_one_line(bad):
    with pytest.raises(ValueError, match=rf"attention.context_nodes = '{bad}' is invalid: expected an integer$"):
        make_planner(f"attention:context_nodes={bad}")


@pytest.mark.parametrize("spec, message", [
    ("stall_legs=-1", r"attention.stall_legs = -1 is invalid: expected 0 \(no stall guard\) or an integer >= 1"),
    ("stall_legs=two", r"attention.stall_legs = 'two' is invalid: expected an integer"),
    ("stall_cells=0", r"attention.stall_cells = 0.0 is invalid: expected a number > 0 \(cells' worth"),
    ("stall_cells=-2", r"attention.stall_cells = -2.0 is invalid: expected a number > 0"),
    ("stall_cells=inf", r"attention.stall_cells = inf is invalid: expected a number > 0"),
    ("stall_cells=nan", r"attention.stall_cells = nan is invalid: expected a number > 0"),
    ("avoid_altitude=-8",
     r"attention.avoid_altitude = -8.0 is invalid: expected 0 \(off\) or a flight level's altitude"),
    ("avoid_altitude=low", r"attention.avoid_altitude = 'low' is invalid: expected a number"),
    ("avoid_altitude=inf", r"attention.avoid_altitude = inf is invalid: expected 0 \(off\)"),
    ("avoid_from_s=-1", r"attention.avoid_from_s = -1.0 is invalid: expected a mission time >= 0 \[s\]"),
    ("avoid_from_s=nan", r"attention.avoid_from_s = nan is invalid: expected a mission time >= 0"),
])
def test_a_bad_stall_guard_or_avoid_setting_is_refused_in_one_line(spec, message):
    with pytest.raises(ValueError, match=message) as err:
        make_planner(f"attention:{spec}")
    assert "\n" not in str(err.value)


class _BackAndForth:
    """Stands in for the network: always the neighbour nearest the node it came from (an oscillation)."""

    def __init__(self, planner):
        self.planner, self.previous = planner, None

    def __call__(self, obs):
        view = self.planner.view
        pos = view.roadmap.positions
        cur = int(obs["current_node"][0])
        back = pos[self.previous if self.previous is not None else cur]
        d = np.linalg.norm(pos[obs["neighbours"]] - back, axis=1)
        logits = np.where(obs["action_mask"].astype(bool), -d, -np.inf)
        self.previous = cur
        return logits


def _fly_twin(spec, seed=608273276):
    from ipp_bench.planners.episode import fly_episode

    env = gym.make("ipp_bench/Weed15Twin-v1").unwrapped
    planner = make_planner(spec)
    totals = []
    original_reset = planner.reset

    def reset(view, s):
        original_reset(view, s)
        planner._logits = _BackAndForth(planner)

    planner.reset = reset
    result = fly_episode(env, planner, seed, on_decision=lambda d: totals.append(env.mission.belief.variance.sum()))
    return planner, result, np.asarray(totals)


def test_the_stall_guard_breaks_an_oscillation_that_the_camera_error_pins():
    """On the deployment's twin a camera looking again at cells it has seen misreads them the same way,
    so a policy flying back and forth between two nodes learns nothing after a few legs (its belief's
    total variance stops falling); the guard sees that and flies to where a look gains most per second,
    so the belief keeps improving and the mission ends far better. Off (``stall_legs=0``), the planner
    is the policy alone."""
    alone, res_alone, tot_alone = _fly_twin("attention:stall_legs=0")
    assert alone.guard_decisions == 0
    assert tot_alone[-1] > (1 - 1e-3) * tot_alone[len(tot_alone) // 4]  # stalled for three quarters of it
    guarded, res_guarded, tot_guarded = _fly_twin("attention")
    assert guarded.guard_decisions > 0
    assert tot_guarded[-1] < 0.8 * tot_alone[-1]
    final = {r["time_s"]: r["uncertainty_reduction_pct"] for r in res_guarded.report}
    before = {r["time_s"]: r["uncertainty_reduction_pct"] for r in res_alone.report}
    assert final[200.0] > before[200.0] + 5
    # deterministic: the same seed flies the same episode
    again, res_again, _ = _fly_twin("attention")
    assert res_again.report == res_guarded.report and again.guard_decisions == guarded.guard_decisions


def _fly_low(spec, task="ipp_bench/Hotspots15Eval-v2", seed=3):
    """An episode of ``spec`` on ``task`` with three flight levels, its network replaced by one that always
    wants the lowest neighbour; -> [(mission time, altitude of the chosen neighbour)] per decision, a decision
    where no neighbour but those at 8 m was affordable left out."""
    from ipp_bench.envs import make_env
    from ipp_bench.planners.episode import fly_episode

    env = make_env(task, altitudes=[8.0, 10.0, 14.0], k=21)
    planner = make_planner(spec)
    original_reset = planner.reset
    chosen = []

    def reset(view, s):
        original_reset(view, s)
        z = view.roadmap.positions[:, 2]
        planner._logits = lambda obs, source=None: np.where(
            obs["action_mask"].astype(bool), -z[np.asarray(obs["neighbours"])], -np.inf)

    def on_decision(d):
        z = env.roadmap.positions[np.asarray(d.obs["neighbours"]), 2]
        if (d.obs["action_mask"].astype(bool) & (z != 8.0)).any():
            chosen.append((time_before[-1], float(env.mission.position[2])))
        time_before.append(env.mission.time_s)

    time_before = [0.0]
    planner.reset = reset
    fly_episode(env, planner, seed, on_decision=on_decision)
    return chosen


def test_avoid_altitude_keeps_the_planner_off_a_flight_level_from_its_time_on():
    """From ``avoid_from_s`` on, no decision lands on the ``avoid_altitude`` level while another neighbour
    is affordable; before it, the decisions are the planner's own (a policy that always wants the lowest
    level flies it all mission long without the rule)."""
    plain = _fly_low("attention:stall_legs=0")
    assert all(z == 8.0 for t, z in plain)
    kept = _fly_low("attention:stall_legs=0,avoid_altitude=8,avoid_from_s=50")
    early = [c for c in kept if c[0] < 50.0]
    assert early == plain[:len(early)] and len(early) >= 3
    late = [z for t, z in kept if t >= 50.0]
    assert late and all(z == 10.0 for z in late)  # the lowest level left
    # from the start, never at 8 m
    assert all(z == 10.0 for t, z in _fly_low("attention:stall_legs=0,avoid_altitude=8")[1:])


def test_avoid_altitude_that_is_no_flight_level_is_refused_at_reset():
    from ipp_bench.envs import make_env

    env = make_env("ipp_bench/Hotspots15Eval-v2", altitudes=[8.0, 10.0, 14.0], k=21)
    env.reset(seed=0)
    planner = make_planner("attention:avoid_altitude=9")
    with pytest.raises(ValueError, match=r"attention.avoid_altitude = 9 is not a flight level of this task: its "
                                         r"roadmap flies at \[8.0, 10.0, 14.0\] m \(or 0: off\)") as err:
        planner.reset(RobotView(env), 0)
    assert "\n" not in str(err.value)
