"""The look-ahead planners' search against their reference implementations (printed, never pass/fail).

Usage::

    python benchmarks/bench_search.py                          # per-decision times, reference vs fast, in one run
    python benchmarks/bench_search.py --agreement 240          # same move on 240 real decision states?
    python benchmarks/bench_search.py --paired 100 --out runs/search_paired.jsonl   # metrics over episodes

Figures:

- timing (default): on every task of ``--tasks`` (15 x 15 and 30 x 30, v1 and v2), ``--decisions``
  decisions of a real episode, each planned by both searches from the same state with the same random
  state (the order of the two alternates): the median time per decision of ``mcts:search=lowrank``
  (low-rank gains, compiled) and of ``mcts:search=reference`` (a dense covariance per tree edge), their
  ratio, and the same for ``cmaes:evaluation=batched`` against ``cmaes:evaluation=reference``; with the
  machine's load average (``os.getloadavg``) before and after each task, since both are timed on a shared
  machine. The fast planners' numba kernels are compiled (or loaded from numba's cache on disk) when such
  a planner is first reset (never inside a decision); the first line says how long that took.
  ``mcts:search=lowrank`` lays out every roadmap node's legs when it is first reset on a roadmap (kept for
  the process): the longest reset of the fast MCTS is printed with its times;
- ``--agreement N``: N decision states of real episodes (the reference flying, fixed seeds, split
  over the v1 and v2 tasks of ``--agreement-tasks``), both searches from each with the same random
  state: the share of identical moves, and for each other one why the two trees parted (the first
  edge where they differ, and how far apart the gains there were);
- ``--paired N``: N episodes per task of ``--paired-tasks`` with the leaderboard's seeds, flown by each
  search (``--paired-planner cmaes``: by each of CMA-ES's evaluations): per report time, the mean
  paired difference (new - reference) of the ROI uncertainty and RMSE reductions [points] and its
  95 % t-interval. Episodes are appended to ``--out`` as they end (JSON lines), and a rerun with the
  same ``--out`` skips the episodes it already holds.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import numpy as np

TIMING_TASKS = ("ipp_bench/Grid15Eval-v1", "ipp_bench/Hotspots15Eval-v2", "ipp_bench/Grid30Eval-v1",
                "ipp_bench/Hotspots30Eval-v2")
AGREEMENT_TASKS = ("ipp_bench/Grid15Eval-v1", "ipp_bench/Hotspots15Eval-v2", "ipp_bench/Grid30Eval-v1",
                   "ipp_bench/Hotspots30Eval-v2")
PAIRED_TASKS = ("ipp_bench/Grid15Eval-v1", "ipp_bench/Hotspots15Eval-v2")
MCTS = "mcts:simulations=24,search=lowrank"
CMAES = "cmaes:evaluation=batched"


def _compile_kernels() -> str:
    """Compile the fast searches' kernels now, and say how long it took."""
    t0 = time.perf_counter()
    from ipp_bench.planners import kernels

    kernels.warm_up()
    return (f"numba kernels ready in {time.perf_counter() - t0:.1f} s (compiled, or loaded from numba's cache, when "
            "a fast planner is first reset; in no decision's time)")


def _load() -> str:
    return "load {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


def _with_setting(spec: str, setting: str) -> str:
    """``spec`` with ``setting`` (``key=value``) in place of any value it gives that key."""
    key = setting.split("=")[0]
    name, _, settings = spec.partition(":")
    kept = [s for s in settings.split(",") if s and s.split("=")[0] != key]
    return f"{name}:" + ",".join(kept + [setting])


def _pair(spec: str, reference_setting: str):
    """(new, reference) planners of ``spec``."""
    from ipp_bench.planners import make_planner

    return make_planner(spec), make_planner(_with_setting(spec, reference_setting))


def _sync(src, dst) -> None:
    """Give ``dst`` the random state of ``src`` (both searches draw the same numbers)."""
    dst.rng.bit_generator.state = src.rng.bit_generator.state


def time_mcts(task: str, decisions: int, seed: int, spec: str = MCTS) -> dict:
    """Both searches at each of ``decisions`` states of real episodes (the reference flies), each in its
    own copy of the env (stepped alike), so that neither warms the other's caches."""
    from ipp_bench.envs import make_env
    from ipp_bench.planners import view_for

    envs = {"new": make_env(task), "ref": make_env(task)}
    planners = dict(zip(("new", "ref"), _pair(spec, "search=reference")))
    times: dict[str, list] = {"new": [], "ref": []}
    same = ep = 0
    resets = []  # [s] of the fast planner's resets (its first on a roadmap lays out every node's legs)
    while len(times["new"]) < decisions:
        obs = {}
        for k in envs:
            obs[k], _ = envs[k].reset(seed=seed + ep)
            t0 = time.perf_counter()
            planners[k].reset(view_for(planners[k], envs[k].unwrapped), seed + ep)
            if k == "new":
                resets.append(time.perf_counter() - t0)
        done = False
        while not done and len(times["new"]) < decisions:
            _sync(planners["ref"], planners["new"])
            moves = {}
            for k in (("new", "ref") if len(times["new"]) % 2 else ("ref", "new")):  # alternate who goes first
                t0 = time.perf_counter()
                moves[k] = planners[k].act(obs[k])
                times[k].append(time.perf_counter() - t0)
            same += moves["new"] == moves["ref"]
            for k in envs:
                obs[k], _, term, trunc, _ = envs[k].step(moves["ref"])
            done = term or trunc
        ep += 1
    return {"new": np.asarray(times["new"]), "ref": np.asarray(times["ref"]), "same": same, "resets": resets}


def time_cmaes(task: str, decisions: int, seed: int, spec: str = CMAES) -> dict:
    """Both evaluations of CMA-ES at each of ``decisions`` states of real episodes (the reference flies),
    each in its own copy of the env."""
    from ipp_bench.envs import make_env
    from ipp_bench.planners import view_for

    envs = {"new": make_env(task), "ref": make_env(task)}
    planners = dict(zip(("new", "ref"), _pair(spec, "evaluation=reference")))
    times: dict[str, list] = {"new": [], "ref": []}
    dist = []
    ep = 0
    while len(times["new"]) < decisions:
        for k in envs:
            envs[k].reset(seed=seed + ep)
            planners[k].reset(view_for(planners[k], envs[k].unwrapped), seed + ep)
        while len(times["new"]) < decisions:
            new, ref = planners["new"], planners["ref"]
            _sync(ref, new)
            new._plan = None if ref._plan is None else ref._plan.copy()  # the same warm start
            points = {}
            for k in (("new", "ref") if len(times["new"]) % 2 else ("ref", "new")):
                t0 = time.perf_counter()
                points[k] = planners[k].next_waypoint()
                times[k].append(time.perf_counter() - t0)
            if points["ref"] is None:
                break
            dist.append(np.inf if points["new"] is None else float(np.linalg.norm(points["new"] - points["ref"])))
            for k in envs:
                envs[k].unwrapped.mission.fly_to(points["ref"])
        ep += 1
    return {"new": np.asarray(times["new"]), "ref": np.asarray(times["ref"]), "dist": np.asarray(dist)}


def bench_timing(args) -> None:
    print(f"{'task':<28} {'planner':<20} {'n':>3} {'reference ms':>13} {'new ms':>9} {'ratio':>7}  load before / after")
    for task in args.tasks:
        for name, fn in (("mcts", time_mcts), ("cmaes", time_cmaes)):
            if name not in args.planners:
                continue
            before = _load()
            r = fn(task, args.decisions, args.seed)
            ref, new = np.median(r["ref"]) * 1e3, np.median(r["new"]) * 1e3
            extra = (f"same move {r['same']}/{r['new'].size}; new planner's resets {max(r['resets']):.2f} s at most "
                     f"({len(r['resets'])})" if name == "mcts"
                     else f"waypoints within 1 mm: {int(np.sum(r['dist'] < 1e-3))}/{r['dist'].size}")
            print(f"{task:<28} {name:<20} {r['new'].size:>3} {ref:>13.1f} {new:>9.1f} {ref / new:>6.1f}x  "
                  f"{before} / {_load()}; totals {r['ref'].sum():.1f} s / {r['new'].sum():.1f} s; {extra}",
                  flush=True)


# -- agreement ----------------------------------------------------------------------------------------
def _traced(planner) -> list:
    """Record every tree edge the search of ``planner`` (reset) adds: (node, elapsed, action, gains, order, rates)
    (the rollouts' moves are left out: the fast search draws them in compiled code)."""
    model = planner._model
    log: list = []
    original, original_rollout = planner._transition, model.rollout
    rolling = [False]

    def transition(state, action):
        if not rolling[0]:
            log.append((state.node, round(state.elapsed, 9), int(action), state.gains.copy(), state.order.copy(),
                        state.gains / state.costs))
        return original(state, action)

    def rollout(tree, state):
        rolling[0] = True
        try:
            return original_rollout(tree, state)
        finally:
            rolling[0] = False

    planner._transition = transition
    model.rollout = rollout
    return log


def _why(log_new: list, log_ref: list) -> str:
    """Why two searches from one state chose differently: where their edge logs part, and the gains there."""
    for i, (a, b) in enumerate(zip(log_new, log_ref)):
        if a[:3] != b[:3]:
            g_new, g_ref = a[3], b[3]
            scale = max(np.abs(g_ref).max(), 1e-300)
            gap = float(np.abs(g_new - g_ref).max() / scale)
            if a[:2] != b[:2]:
                return (f"tree edge {i}: different states ({a[:2]} / {b[:2]}): the rollouts before it returned "
                        f"differently (a draw, or rounding in a UCT tie); gains there differ by {gap:.1e} of the best")
            if not np.array_equal(a[4], b[4]):
                k = int(np.flatnonzero(a[4] != b[4])[0])
                x, y = int(a[4][k]), int(b[4][k])
                rate = b[5]
                tie = abs(rate[x] - rate[y]) / max(np.abs(rate).max(), 1e-300)
                return (f"tree edge {i}: expansion order differs at legs {x}/{y}, whose gains per second differ by "
                        f"{tie:.1e} of the best (a tie); the gains there differ by {gap:.1e} of the best")
            return (f"tree edge {i}: move {a[2]} / {b[2]} from the same state (a UCT pick); "
                    f"gains there differ by {gap:.1e} of the best")
    if len(log_new) != len(log_ref):
        return f"tree edge logs of different lengths ({len(log_new)} / {len(log_ref)}) with a common prefix"
    return ("the same tree edges: the rollouts' returns differ (a draw, or rounding) or the final pick's (visits, "
            "value) tie is broken by rounding")


def bench_agreement(args) -> None:
    from ipp_bench.envs import make_env
    from ipp_bench.planners import view_for

    per_task = -(-args.agreement // len(args.agreement_tasks))
    total = same = 0
    reasons: list[str] = []
    for task in args.agreement_tasks:
        env = make_env(task)
        new, ref = _pair(args.spec, "search=reference")
        n = ep = 0
        t0 = time.perf_counter()
        while n < per_task:
            seed = args.seed + ep
            obs, _ = env.reset(seed=seed)
            new.reset(view_for(new, env.unwrapped), seed)
            ref.reset(view_for(ref, env.unwrapped), seed)
            done = False
            while not done and n < per_task:
                _sync(ref, new)
                log_new, log_ref = _traced(new), _traced(ref)
                a_new, a_ref = new.act(obs), ref.act(obs)
                n += 1
                if a_new == a_ref:
                    same += 1
                else:
                    why = _why(log_new, log_ref)
                    reasons.append(f"{task} seed {seed} decision {env.unwrapped.mission.time_s:.1f} s: "
                                   f"{a_new} / {a_ref}: {why}")
                obs, _, term, trunc, _ = env.step(a_ref)
                done = term or trunc
            ep += 1
        total += n
        print(f"{task}: {n} states from {ep} episode(s), {time.perf_counter() - t0:.0f} s; {_load()}", flush=True)
    print(f"same move in {same}/{total} decision states ({100.0 * same / total:.1f} %)")
    for r in reasons:
        print("  differs:", r)


# -- paired episodes -------------------------------------------------------------------------------------
def _t95(n: int) -> float:
    from scipy import stats

    return float(stats.t.ppf(0.975, n - 1)) if n > 1 else float("nan")


def bench_paired(args) -> None:
    from ipp_bench.eval.plan import episode_seeds
    from ipp_bench.eval.runner import run_episode

    spec = args.spec if args.paired_planner == "mcts" else CMAES
    setting = "search=reference" if args.paired_planner == "mcts" else "evaluation=reference"
    specs = {"new": spec, "reference": _with_setting(spec, setting)}
    done: dict[tuple, dict] = {}
    if args.out and os.path.exists(args.out):
        with open(args.out) as fh:
            for line in fh:
                row = json.loads(line)
                done[(row["task"], row["search"], row["seed"])] = row
    for seed in ([] if args.summary_only else episode_seeds(args.seed, args.paired)):  # seeds outermost: an
        for task in args.paired_tasks:  # interrupted run has every task
            for search, spec in specs.items():
                if (task, search, seed) in done:
                    continue
                res = run_episode(task, spec, seed)
                row = {"task": task, "search": search, "seed": seed, "report": res.report,
                       "decision_time_mean_s": res.decision_time_mean_s}
                done[(task, search, seed)] = row
                if args.out:
                    with open(args.out, "a") as fh:  # one line per episode, so an interrupted run keeps its episodes
                        fh.write(json.dumps(row) + "\n")
    for task in args.paired_tasks:
        seeds = [s for s in episode_seeds(args.seed, args.paired)
                 if (task, "new", s) in done and (task, "reference", s) in done]
        print(f"{task}: {len(seeds)} paired episodes; {_load()}")
        if not seeds:
            continue
        times = [r["time_s"] for r in done[(task, "new", seeds[0])]["report"]]
        for i, t in enumerate(times):
            for key in ("uncertainty_reduction_pct", "rmse_reduction_pct"):
                d = np.array([done[(task, "new", s)]["report"][i][key] - done[(task, "reference", s)]["report"][i][key]
                              for s in seeds])
                half = _t95(d.size) * d.std(ddof=1) / np.sqrt(d.size) if d.size > 1 else float("nan")
                print(f"  {t:5.0f} s {key:<26} new - reference: mean {d.mean():+.3f}, 95 % interval "
                      f"[{d.mean() - half:+.3f}, {d.mean() + half:+.3f}], identical in {int(np.sum(d == 0))}/{d.size}")
        dt = {s: np.mean([done[(task, s, x)]["decision_time_mean_s"] for x in seeds]) for s in specs}
        print(f"  mean decision time: new {dt['new'] * 1e3:.1f} ms, reference {dt['reference'] * 1e3:.1f} ms")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--tasks", nargs="+", default=list(TIMING_TASKS), help="tasks timed")
    p.add_argument("--planners", nargs="+", default=["mcts", "cmaes"], choices=["mcts", "cmaes"], help="planners timed")
    p.add_argument("--decisions", type=int, default=8, help="decisions timed per task and planner")
    p.add_argument("--seed", type=int, default=0, help="first episode seed")
    p.add_argument("--spec", default=MCTS, help="MCTS spec of --agreement and --paired (default: the leaderboard's)")
    p.add_argument("--agreement", type=int, default=0, metavar="N", help="decision states compared (0: skip)")
    p.add_argument("--agreement-tasks", nargs="+", default=list(AGREEMENT_TASKS))
    p.add_argument("--paired", type=int, default=0, metavar="N", help="paired episodes per task (0: skip)")
    p.add_argument("--paired-tasks", nargs="+", default=list(PAIRED_TASKS))
    p.add_argument("--paired-planner", choices=["mcts", "cmaes"], default="mcts",
                   help="--paired: MCTS (--spec against its search=reference) or CMA-ES (against evaluation=reference)")
    p.add_argument("--out", help="--paired: episodes appended here (JSON lines); a rerun skips those it holds")
    p.add_argument("--summary-only", action="store_true", help="--paired: summarise the episodes --out holds, fly none")
    p.add_argument("--skip-timing", action="store_true")
    args = p.parse_args()
    for name in ("decisions", "agreement", "paired"):
        if getattr(args, name) < 0 or (name == "decisions" and args.decisions < 1):
            low = 1 if name == "decisions" else 0
            p.error(f"--{name} = {getattr(args, name)} is invalid: expected an integer >= {low}")
    from ipp_bench.core._threads import limit_blas_threads

    limit_blas_threads()
    print(f"python {platform.python_version()}, numpy {np.__version__}, {platform.processor() or platform.machine()}, "
          f"{len(os.sched_getaffinity(0))} CPUs available; {_load()}", flush=True)
    print(_compile_kernels(), flush=True)
    if not args.skip_timing:
        bench_timing(args)
    if args.agreement:
        bench_agreement(args)
    if args.paired:
        bench_paired(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
