"""The look-ahead planners' fast evaluations against their references, on real decision states.

``mcts:search=lowrank`` (gains from a low-rank factor of the updates along the tree path, compiled) against
``mcts:search=reference`` (a dense covariance copied and downdated per edge), and
``cmaes:evaluation=batched`` (a candidate's read-outs as compiled sparse rows, scored from B = P D P)
against ``cmaes:evaluation=reference`` (each candidate's Kalman prediction): the same gains in exact
arithmetic, so equal to round-off, and the same moves; and the compiled kernels against the camera and
the dense algebra they stand for.
"""

from __future__ import annotations

import numpy as np
import pytest

from ipp_bench.core.sensor import Sensor
from ipp_bench.envs import make_env
from ipp_bench.planners import kernels, make_planner, view_for
from ipp_bench.planners.kernels import jit, lowrank, node_table, readouts

TASKS_15 = ["ipp_bench/Grid15Eval-v1", "ipp_bench/Hotspots15Eval-v2"]
TASKS_30 = ["ipp_bench/Grid30Eval-v1", "ipp_bench/Hotspots30Eval-v2"]
RTOL = 1e-9  # of the largest gain of the state (the bar; round-off is ~1e-14)


def _episode(task: str, seed: int, spec: str = "mcts:simulations=4,search=lowrank", steps: int = 3):
    """An env ``steps`` decisions into episode ``seed`` (flown by ``spec``), and its observation."""
    env = make_env(task)
    obs, _ = env.reset(seed=seed)
    planner = make_planner(spec)
    planner.reset(view_for(planner, env.unwrapped), seed)
    for _ in range(steps):
        obs, *_ = env.step(planner.act(obs))
    return env, obs


def _paths(rng, planner, root, depth: int, count: int):
    """``count`` random action paths of ``depth`` playable moves from ``root`` (by the reference's states)."""
    out = []
    for _ in range(count):
        state, path = root, []
        for _ in range(depth):
            if state.order is None:
                planner._expand_info(state)
            if state.order.size == 0:
                break
            a = int(rng.choice(state.order))
            path.append(a)
            state, _, _ = planner._transition(state, a)
        out.append(path)
    return out


@pytest.mark.parametrize("task", TASKS_15 + TASKS_30[1:])
def test_lowrank_gains_equal_the_dense_reference_along_tree_paths(task):
    env, obs = _episode(task, seed=7)
    fast = make_planner("mcts:simulations=4,horizon_s=1000,search=lowrank")  # a long horizon: gains at every depth
    ref = make_planner("mcts:simulations=4,horizon_s=1000,search=reference")
    view = view_for(fast, env.unwrapped)
    fast.reset(view, 7)
    ref.reset(view, 7)
    ref_root, fast_root = ref._root(obs), fast._root(obs)
    np.testing.assert_allclose(fast_root.gains, ref_root.gains, rtol=0, atol=RTOL * ref_root.gains.max())
    compared = 0
    for path in _paths(np.random.default_rng(0), ref, ref_root, depth=6, count=4):
        r_state, f_state = ref_root, fast_root
        for a in path:
            r_state, r_rew, r_disc = ref._transition(r_state, a)
            f_state, f_rew, f_disc = fast._transition(f_state, a)
            assert f_disc == r_disc and f_state.node == r_state.node
            np.testing.assert_allclose(f_rew, r_rew, rtol=RTOL)
            ref._expand_info(r_state)
            fast._expand_info(f_state)
            scale = r_state.gains.max()
            assert scale > 0
            np.testing.assert_allclose(f_state.gains, r_state.gains, rtol=0, atol=RTOL * scale)
            assert np.array_equal(f_state.order, r_state.order)
            compared += 1
    assert compared >= 12  # depth 1 to 6 on four paths (fewer where the budget ends)


@pytest.mark.parametrize("task", TASKS_15)
def test_terms_from_the_parent_equal_those_from_the_root(task):
    """A state's terms from its parent's (``child_terms``: the shared cells' rows kept, the others rebuilt, the
    edge's rank-m update) are those rebuilt from the root (``state_terms``), to round-off: the gains, each leg's
    L^-1 (L L^T = S) and G, and the rows of U, V, P and P D P on the node's cells."""
    env, obs = _episode(task, seed=5)
    fast = make_planner("mcts:simulations=4,horizon_s=1000,search=lowrank")
    fast.reset(view_for(fast, env.unwrapped), 5)
    root = fast._root(obs)
    compared = 0
    for path in _paths(np.random.default_rng(1), fast, root, depth=5, count=3):
        state = root
        for a in path:
            state, _, _ = fast._transition(state, a)
            fast._expand_info(state)
            legs = fast._model._legs_of(state.node)
            if not legs.index.size:
                continue
            assert state.parent.Pcc is not None  # scored from its parent's terms
            full = lowrank.state_terms(fast._model._P, fast._model._B, state.header, state.idata, state.fdata, state.r,
                                               legs.cells, state.K, legs.m, legs.rptr, legs.nz_cell, legs.nz_w,
                                               legs.var, legs.M)
            mine = (state.gains[legs.index] * fast._unit, state.Li, state.G, state.UV, state.Pcc, state.Bcc)
            for got, want in zip(mine, full):
                assert got.shape == want.shape
                np.testing.assert_allclose(got, want, rtol=0, atol=RTOL * max(np.abs(want).max(initial=0.0), 1e-300))
            compared += 1
    assert compared >= 9


def test_a_leg_that_sees_nothing_keeps_the_factor():
    """Legs without read-outs (None) give 0 and leave the posterior as it was: the child shares the factor."""
    env, obs = _episode("ipp_bench/Grid15Eval-v1", seed=3, steps=1)
    fast = make_planner("mcts:simulations=2,search=lowrank")
    fast.reset(view_for(fast, env.unwrapped), 3)
    model = fast._model
    model._table, model._legs = node_table.NodeTable(*model._table.table.shape[:1], model._table.k), {}  # its own
    root = fast._root(obs)
    a = int(root.order[0])
    child, _, _ = fast._transition(root, a)
    assert not model._table.built(child.node)  # laid out when first scored
    model._legs[(child.node, 0)] = None  # pretend the child's first leg sees nothing
    fast._expand_info(child)
    assert child.gains[0] == 0.0
    grandchild, reward, _ = fast._transition(child, 0)
    assert reward == 0.0
    fast._expand_info(grandchild)
    assert grandchild.fdata is child.fdata and grandchild.r == child.r and grandchild.K is child.K


@pytest.mark.parametrize("task, seed", [(t, 11) for t in TASKS_15]
                         + [pytest.param(t, 2, marks=pytest.mark.slow) for t in TASKS_30])  # 30 x 30: slow
def test_lowrank_search_picks_the_reference_move(task, seed):
    env, obs = _episode(task, seed=seed, steps=1)
    fast = make_planner("mcts:simulations=24,search=lowrank")
    ref = make_planner("mcts:simulations=24,search=reference")
    view = view_for(fast, env.unwrapped)
    fast.reset(view, seed)
    ref.reset(view, seed)
    for _ in range(2):
        fast.rng.bit_generator.state = ref.rng.bit_generator.state
        a_ref, a_fast = ref.act(obs), fast.act(obs)
        assert a_fast == a_ref
        assert fast.rng.bit_generator.state == ref.rng.bit_generator.state  # the same draws, as many
        obs, _, term, trunc, _ = env.step(a_ref)
        assert not (term or trunc)


def test_a_search_laying_out_its_legs_as_it_goes_moves_alike():
    """The compiled rollout stops where a node's legs are not laid out yet, lets Python lay them out, and goes
    on: the same moves and draws as with every node laid out beforehand."""
    env, obs = _episode("ipp_bench/Hotspots15Eval-v2", seed=4, steps=1)
    view = view_for(make_planner("mcts"), env.unwrapped)
    lazy, full = (make_planner("mcts:simulations=24,search=lowrank") for _ in range(2))
    full.reset(view, 4)
    lazy.reset(view, 4)
    model = lazy._model
    model._table, model._legs = node_table.NodeTable(*model._table.table.shape[:1], model._table.k), {}
    for _ in range(2):
        lazy.rng.bit_generator.state = full.rng.bit_generator.state
        a = full.act(obs)
        assert lazy.act(obs) == a
        assert lazy.rng.bit_generator.state == full.rng.bit_generator.state
        obs, *_ = env.step(a)
    built = int(model._table.table[:, lowrank.T_BUILT].sum())
    assert 0 < built < model._table.table.shape[0]  # the nodes the searches reached, no others


def test_the_kernels_compile_where_numba_has_nowhere_to_write_its_cache():
    """A read-only install with a read-only home: numba finds no cache locator and the kernels compile in
    the process instead (no locator is simulated: as root every folder is writable)."""
    import subprocess
    import sys

    code = ("import numba.core.caching as caching\n"
            "caching.CacheImpl._locator_classes = []\n"
            "import numpy as np\n"
            "from ipp_bench.planners.kernels import lowrank as k\n"
            "a = np.random.default_rng(0).random(300)\n"
            "assert k._pairwise_sum(a, 0, a.size) == a.sum()\n"
            "print(type(k._pairwise_sum._cache).__name__)\n")
    env = {k: v for k, v in __import__("os").environ.items() if not k.startswith("NUMBA_CACHE")}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 0 and done.stdout.strip() == "NullCache", done.stderr


def test_the_rollout_draws_as_numpy_does():
    """The compiled rollout's move: one ``rng.random()`` against the cumulative softmax of ``lambda * rate /
    max rate`` (NumPy's pairwise sum, in its order): the move and the draws of ``rng.choice(order, p=...)``."""
    rng = np.random.default_rng(2)
    for n in list(range(1, 40)) + [128, 129, 130, 255, 256, 300, 1000, 4099, 100_003]:
        for a in (rng.random(n), rng.standard_normal(n) * 10.0 ** rng.integers(-8, 9, n)):  # the order shows
            assert lowrank._pairwise_sum(a, 0, n) == a.sum()
    same = 0
    for t in range(400):
        k = int(rng.integers(2, 21))
        gains = rng.random(k) * (rng.random(k) < 0.8)
        costs = rng.uniform(0.5, 3.0, k)
        order = np.flatnonzero(rng.random(k) < 0.9)
        if order.size == 0 or gains[order].max() <= 0:
            continue
        mine, ref = np.random.default_rng(t), np.random.default_rng(t)
        rate = gains[order] / costs[order]
        logits = 8.0 * rate / rate.max()
        p = np.exp(logits - logits.max())
        want = int(ref.choice(order, p=p / p.sum()))
        assert lowrank._draw(mine, gains, costs, order, 8.0) == want
        assert mine.bit_generator.state == ref.bit_generator.state
        same += 1
    assert same > 300


def test_lowrank_search_is_deterministic_per_seed():
    moves = []
    for _ in range(2):
        env = make_env("ipp_bench/Hotspots15Eval-v2")
        obs, _ = env.reset(seed=5)
        planner = make_planner("mcts:simulations=12,search=lowrank")
        planner.reset(view_for(planner, env.unwrapped), 5)
        run = []
        for _ in range(4):
            a = planner.act(obs)
            run.append(a)
            obs, *_ = env.step(a)
        moves.append(run)
    assert moves[0] == moves[1]


def test_fast_searches_without_numba_name_the_extra(monkeypatch):
    monkeypatch.setattr(jit, "numba", None)
    for spec in ("mcts", "cmaes", "mcts:search=lowrank", "cmaes:evaluation=batched"):  # the defaults are the fast forms
        with pytest.raises(ImportError, match=r'needs numba: pip install "ipp-bench\[eval\]"'):
            make_planner(spec)
    make_planner("mcts:search=reference")  # the references need no numba
    make_planner("cmaes:evaluation=reference")


def test_no_kernel_compiles_inside_a_decision():
    """The kernels are compiled when a fast planner is reset, for the argument types the decisions pass
    (read-only camera arrays, int64 indices): a decision never waits for numba."""
    numba = pytest.importorskip("numba")
    kernels.warm_up()
    dispatchers = {f"{m.__name__}.{name}": f for m in kernels.MODULES for name, f in vars(m).items()
                   if isinstance(f, numba.core.registry.CPUDispatcher)}
    compiled = {name: len(f.signatures) for name, f in dispatchers.items()}
    for task in ("ipp_bench/Grid15Eval-v1", "ipp_bench/Hotspots30Eval-v2"):
        _episode(task, seed=3, spec="mcts:simulations=6,search=lowrank", steps=2)  # the MCTS kernels
        env = make_env(task)
        env.reset(seed=3)
        planner = make_planner("cmaes:max_evals=24,evaluation=batched")
        planner.reset(view_for(planner, env.unwrapped), 3)
        for _ in range(2):
            env.unwrapped.mission.fly_to(planner.next_waypoint())
    assert {name: len(f.signatures) for name, f in dispatchers.items()} == compiled


@pytest.mark.slow
def test_no_kernel_compiles_inside_a_decision_in_a_fresh_process():
    """The same, in a process of its own, where no other test compiled anything first: what the planners' resets
    compile (``warm_up``) covers every type their decisions pass."""
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""
        import numba
        from ipp_bench.envs import make_env
        from ipp_bench.planners import kernels, make_planner, view_for
        kernels.warm_up()
        dispatchers = {f"{m.__name__}.{n}": f for m in kernels.MODULES for n, f in vars(m).items()
                       if isinstance(f, numba.core.registry.CPUDispatcher)}
        before = {n: len(f.signatures) for n, f in dispatchers.items()}
        for task in ("ipp_bench/Grid15Eval-v1", "ipp_bench/Hotspots30Eval-v2"):
            for spec in ("mcts:simulations=6,search=lowrank", "cmaes:max_evals=24,evaluation=batched"):
                env = make_env(task)
                obs, _ = env.reset(seed=3)
                planner = make_planner(spec)
                planner.reset(view_for(planner, env.unwrapped), 3)
                for _ in range(2):
                    if spec.startswith("mcts"):
                        obs, *_ = env.step(planner.act(obs))
                    else:
                        env.unwrapped.mission.fly_to(planner.next_waypoint())
        after = {n: len(f.signatures) for n, f in dispatchers.items()}
        print({n: after[n] - before[n] for n in after if after[n] != before[n]})
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().splitlines()[-1] == "{}"


@pytest.mark.parametrize("spec, message", [
    ("mcts:search=dense", r"mcts.search = 'dense' is invalid: expected one of \['lowrank', 'reference'\]"),
    ("cmaes:evaluation=fast", r"cmaes.evaluation = 'fast' is invalid: expected one of \['batched', 'reference'\]"),
])
def test_search_setting_is_checked(spec, message):
    with pytest.raises(ValueError, match=message):
        make_planner(spec)


# -- CMA-ES --------------------------------------------------------------------------------------------
def _rows_of(observations) -> list:
    """Each read-out row of ``observations`` as (map cells, weights) of its nonzero weights, and its variance."""
    out = []
    for o in observations:
        for a in range(o.m):
            nz = o.weights[a] != 0
            out.append((o.cells[nz], o.weights[a][nz], o.var[a]))
    return out


@pytest.mark.parametrize("task", ["ipp_bench/Grid15Eval-v1", "ipp_bench/Hotspots30Eval-v2"])
@pytest.mark.parametrize("persistent", [False, True])
def test_camera_rows_are_the_cameras_read_outs(task, persistent):
    """Compiled read-out rows from many positions (some off the map, below and above the binning altitude)
    against :meth:`Sensor.observe`, row by row: the same cells and weights, the same variance."""
    import dataclasses

    env = make_env(task)
    env.reset(seed=0)
    base = env.unwrapped.mission.sensor
    cfg = base.cfg
    if persistent:  # the camera-error model: a persistent share, correlated over a binned block
        cfg = dataclasses.replace(cfg, persistent_var=0.01, persistent_var_binned=0.02,
                                  persistent_neighbour_corr=0.59)
    sensor = Sensor(base.grid, cfg)
    width, height = env.unwrapped.config.grid.size_m
    alts = env.unwrapped.config.graph.altitudes
    assert alts[0] <= cfg.binning_altitude < alts[-1]  # both kinds of read-out
    rng = np.random.default_rng(1)
    compared = 0
    for _ in range(20):
        pts = np.column_stack([rng.uniform(-8, width + 8, 25), rng.uniform(-8, height + 8, 25),
                               rng.uniform(alts[0], alts[-1], 25)])
        ptr, cells, weights, var = readouts.camera_rows(pts, *readouts.camera_args(sensor))
        expected = _rows_of([o for o in (sensor.observe(p) for p in pts) if o is not None])
        assert len(expected) == var.size == ptr.size - 1
        for a, (c, w, v) in enumerate(expected):
            np.testing.assert_array_equal(cells[ptr[a]:ptr[a + 1]], c)
            np.testing.assert_array_equal(weights[ptr[a]:ptr[a + 1]], w)
            np.testing.assert_allclose(var[a], v, rtol=1e-14)
        compared += len(expected)
    assert compared > 1000


def test_readout_blocks_are_the_dense_products():
    """S = H P H^T + R and G = H B H^T from sparse rows, against dense algebra on a random covariance."""
    rng = np.random.default_rng(3)
    n = 40
    A = rng.standard_normal((n, n))
    P = A @ A.T / n + 0.1 * np.eye(n)
    roi = rng.random(n) < 0.6
    B = P[:, roi] @ P[roi, :]
    ptr = np.array([0, 1, 5, 7, 8], dtype=np.int64)  # a single cell, a 2 x 2 block, a pair, a cell seen again
    cells = np.array([3, 10, 11, 20, 21, 7, 3, 10], dtype=np.int64)
    weights = np.array([1.0, 0.25, 0.25, 0.25, 0.25, 0.5, 0.5, 1.0])
    var = np.array([0.1, 0.2, 0.3, 0.4])
    H = np.zeros((4, n))
    for a in range(4):
        np.add.at(H[a], cells[ptr[a]:ptr[a + 1]], weights[ptr[a]:ptr[a + 1]])
    S, G = readouts.readout_blocks(P, B, ptr, cells, weights, var)
    np.testing.assert_allclose(S, H @ P @ H.T + np.diag(var), rtol=1e-13)
    np.testing.assert_allclose(G, H @ B @ H.T, rtol=1e-13)
    # Tr(S^-1 G) is the reduction of the ROI's trace by the Kalman update
    post = P - P @ H.T @ np.linalg.solve(S, H @ P)
    np.testing.assert_allclose(np.trace(np.linalg.solve(S, G)), np.trace(P[roi][:, roi]) - np.trace(post[roi][:, roi]),
                               rtol=1e-10)


def _cmaes_at(task: str, seed: int, decisions: int):
    """(env, batched planner, reference planner) after ``decisions`` waypoints flown by the reference."""
    env = make_env(task)
    env.reset(seed=seed)
    new = make_planner("cmaes:max_evals=24,evaluation=batched")
    ref = make_planner("cmaes:max_evals=24,evaluation=reference")
    view = view_for(new, env.unwrapped)
    new.reset(view, seed)
    ref.reset(view, seed)
    for _ in range(decisions):
        env.unwrapped.mission.fly_to(ref.next_waypoint())
    return env, new, ref


def test_folding_repeated_rows_keeps_the_posterior():
    """A row seen twice (same cells and weights) becomes one with both looks' precision: the same predicted
    reduction, to round-off; other rows stay as they are, in order."""
    rng = np.random.default_rng(5)
    n = 30
    A = rng.standard_normal((n, n))
    P = A @ A.T / n + 0.1 * np.eye(n)
    roi = rng.random(n) < 0.7
    B = P[:, roi] @ P[roi, :]
    ptr = np.array([0, 4, 5, 9, 10, 11], dtype=np.int64)  # a block, a cell, the block again, another cell, the cell
    cells = np.array([1, 2, 7, 8, 4, 1, 2, 7, 8, 5, 4], dtype=np.int64)
    weights = np.array([0.25] * 4 + [1.0] + [0.25] * 4 + [1.0, 1.0])
    var = np.array([0.3, 0.1, 0.5, 0.2, 0.4])
    f_ptr, f_cells, f_w, f_var = readouts.fold_repeated_rows(ptr, cells, weights, var)
    np.testing.assert_array_equal(f_ptr, [0, 4, 5, 6])
    np.testing.assert_array_equal(f_cells, [1, 2, 7, 8, 4, 5])
    np.testing.assert_allclose(f_var, [1 / (1 / 0.3 + 1 / 0.5), 1 / (1 / 0.1 + 1 / 0.4), 0.2], rtol=1e-15)

    def reduction(*rows):
        S, G = readouts.readout_blocks(P, B, *rows)
        return np.trace(np.linalg.solve(S, G))

    np.testing.assert_allclose(reduction(f_ptr, f_cells, f_w, f_var), reduction(ptr, cells, weights, var), rtol=1e-12)


@pytest.mark.parametrize("task", TASKS_15 + TASKS_30[1:])
def test_cmaes_batched_objective_equals_the_reference(task):
    env, new, ref = _cmaes_at(task, seed=4, decisions=2)
    for planner in (new, ref):  # the decision's fixed terms, as next_waypoint sets them
        planner._belief = planner.view.belief
        planner._roi = planner.view.belief_roi()
        planner._before = planner.view.roi_trace(planner._belief.variance, planner._roi)
        planner._lo, planner._hi = planner._search_box()
        planner._begin_batched()
    assert new._P is not None and ref._P is None
    cands = np.random.default_rng(1).random((12, 3 * new.settings.n_waypoints))
    f_ref = np.array([ref._objective(c) for c in cands])
    f_new = np.array(new._objectives(list(cands)))
    assert np.all(f_ref < 0)
    np.testing.assert_allclose(f_new, f_ref, rtol=1e-10)


def test_cmaes_batched_flies_the_reference_waypoints():
    env, new, ref = _cmaes_at("ipp_bench/Hotspots15Eval-v2", seed=9, decisions=0)
    for _ in range(3):
        new.rng.bit_generator.state = ref.rng.bit_generator.state
        new._plan = None if ref._plan is None else ref._plan.copy()
        w_ref, w_new = ref.next_waypoint(), new.next_waypoint()
        np.testing.assert_allclose(w_new, w_ref, atol=1e-9)
        env.unwrapped.mission.fly_to(w_ref)


def test_the_legs_layout_is_kept_per_roadmap():
    """The laid-out legs are static for a roadmap, camera and spacing: planners on one task share them (across
    episodes), another map has its own."""
    tables = []
    for task in ("ipp_bench/Grid15Eval-v1", "ipp_bench/Grid15Eval-v1", "ipp_bench/Grid30Eval-v1"):
        env = make_env(task)
        env.reset(seed=0)
        planner = make_planner("mcts:search=lowrank")
        planner.reset(view_for(planner, env.unwrapped), 0)
        tables.append(planner._model._table)
    assert tables[0] is tables[1] and tables[2] is not tables[0]
    assert tables[2].table.shape[0] == 4 * tables[0].table.shape[0]  # 30 x 30: four times the nodes
