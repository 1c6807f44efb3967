"""Where in the mission does a planner gain, and how does it fly there?

For each planner and task (leaderboard seeds), per window between report times (0-50, 50-100,
... s): the ROI uncertainty reduction gained in the window [points], the legs begun in it, their
mean flight time [s], and the share of the window's flight time spent on legs that end at each
flight altitude; then the budget left unflown at the end [s]. Means over the episodes.

``--then SPEC --switch-s T`` adds, for each planner P, the row "P, then SPEC from T s": P decides
until mission time T, SPEC from there on, on the same episodes. Its last windows against P's own
say whether SPEC does better than P from the states P reached (the late mission's decisions alone).
``--avoid-altitude Z`` keeps SPEC off the neighbours at altitude Z after the hand-over (where any
other neighbour is affordable): with SPEC = P, whether P's own looks from Z are what costs it.

    python benchmarks/bench_mission_phases.py --tasks Hotspots30Eval-v2 --episodes 20 \\
        --env 'altitudes=[8,10,14]' --env k=21 \\
        --planners greedy oracle attention:checkpoint=benchmarks/candidates/attention_l3_ppo2m.pt
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from ipp_bench.envs import make_env, parse_overrides
from ipp_bench.eval.plan import episode_seeds, resolve_task
from ipp_bench.eval.report import bootstrap_ci
from ipp_bench.config import TIME_TOL_S
from ipp_bench.planners import make_planner, view_for
from ipp_bench.planners.base import without_level
from ipp_bench.planners.episode import fly_episode


def check_handover_kind(spec: str, planner) -> None:
    """A hand-over flies roadmap planners only: one line naming the planner otherwise."""
    if planner.kind != "graph":
        raise ValueError(f"--then: {spec!r} is a {planner.kind} planner; a hand-over needs roadmap planners")


class Handover:
    """A roadmap planner that lets ``first`` decide until mission time ``switch_s``, then ``then``."""

    kind = "graph"

    def __init__(self, first: str, then: str, switch_s: float, env, avoid_z: float | None = None) -> None:
        self.first, self.switch_s, self.env, self.avoid_z = make_planner(first), switch_s, env, avoid_z
        self.then = self.first if then == first else make_planner(then)  # the same planner: one instance
        check_handover_kind(first, self.first)
        check_handover_kind(then, self.then)
        self.name = f"{first}, then {then} from {switch_s:g} s"

    def reset(self, view, seed: int) -> None:
        for p in {id(self.first): self.first, id(self.then): self.then}.values():
            p.reset(view_for(p, self.env), seed)

    def act(self, obs):
        late = self.env.mission.time_s >= self.switch_s - TIME_TOL_S
        if not late:
            return self.first.act(obs)
        if self.avoid_z is not None:
            z = self.env.roadmap.positions[np.asarray(obs["neighbours"]), 2]
            mask = without_level(obs["action_mask"], z, self.avoid_z)
            obs = dict(obs) | {"action_mask": mask.astype(np.asarray(obs["action_mask"]).dtype)}
        return self.then.act(obs)


def phases(task: str, spec: str, seeds: list[int], overrides: dict, then: str = "", switch_s: float = 0.0,
           avoid_z: float | None = None) -> dict:
    """Per-window means of one planner on one task (see the module docstring)."""
    env = make_env(task, **overrides)
    times = list(env.unwrapped.config.mission.report_times_in_budget)
    levels = sorted({round(float(z), 3) for z in env.unwrapped.roadmap.positions[:, 2]})
    edges = [0.0, *times]
    w = len(times)
    gain, legs, leg_s = np.zeros(w), np.zeros(w), np.zeros(w)
    at_level = np.zeros((w, len(levels)))
    unflown, per_episode = [], []
    for seed in seeds:
        planner = Handover(spec, then, switch_s, env.unwrapped, avoid_z) if then else spec
        ep = fly_episode(env.unwrapped, planner, seed)
        mission = env.unwrapped.mission
        red = [0.0, *(r["uncertainty_reduction_pct"] for r in ep.report)]
        gain += np.diff(red)
        per_episode.append(red[1:])
        path = np.asarray(mission.path, dtype=float)  # (time, x, y, z) after each leg, the start first
        for (t0, *_), (t1, _, _, z1) in zip(path[:-1], path[1:]):
            i = min(int(np.searchsorted(edges, t0, side="right")) - 1, w - 1)
            legs[i] += 1
            leg_s[i] += t1 - t0
            # the leg's flight time, split over the windows it spans, to the level it ends at
            lvl = int(np.argmin([abs(z1 - z) for z in levels]))
            for j in range(w):
                at_level[j, lvl] += max(0.0, min(t1, edges[j + 1]) - max(t0, edges[j]))
        unflown.append(mission.remaining_s)
    n = len(seeds)
    share = at_level / np.maximum(at_level.sum(axis=1, keepdims=True), 1e-9)
    return {"times": times, "levels": levels, "gain": gain / n, "legs": legs / n,
            "leg_s": leg_s / np.maximum(legs, 1), "share": share, "unflown": float(np.mean(unflown)),
            "reduction": np.asarray(per_episode)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--tasks", nargs="+", default=["Hotspots30Eval-v2"])
    p.add_argument("--planners", nargs="+", default=["greedy"])
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--seed", type=int, default=0, help="the leaderboard's seed (episode seeds from it)")
    p.add_argument("--env", action="append", default=[], metavar="KEY=VALUE", help="environment overrides")
    p.add_argument("--then", action="append", default=[], metavar="SPEC",
                   help="also fly each planner handing over to SPEC at --switch-s (repeatable)")
    p.add_argument("--switch-s", type=float, default=150.0, help="mission time of the hand-over [s] (default 150)")
    p.add_argument("--avoid-altitude", type=float, default=None, metavar="Z",
                   help="after the hand-over, SPEC does not fly to neighbours at altitude Z [m] (if others fit)")
    a = p.parse_args(argv)
    if a.episodes < 1:
        p.error(f"--episodes {a.episodes}: expected at least 1")
    if not a.switch_s > 0:
        p.error(f"--switch-s {a.switch_s}: expected a mission time > 0 s")
    if a.avoid_altitude is not None and not a.then:
        p.error("--avoid-altitude applies to the planner after the hand-over: it needs --then SPEC")
    try:
        overrides = parse_overrides(a.env)
        tasks = [resolve_task(t) for t in a.tasks]
        for spec in [*a.planners, *a.then]:
            planner = make_planner(spec)  # a bad planner spec: one line, before any episode
            if a.then:
                check_handover_kind(spec, planner)
        for t in tasks:
            make_env(t, **overrides)  # a bad task or override: one line, before any episode
    except ValueError as err:
        print(f"bench_mission_phases.py: error: {err}", file=sys.stderr)
        return 2
    seeds = episode_seeds(a.seed, a.episodes)
    for task in tasks:
        print(f"\n### {task}, {a.episodes} episodes" + (f" ({' '.join(a.env)})" if a.env else ""))
        own = {spec: phases(task, spec, seeds, overrides) for spec in a.planners}
        avoid = "" if a.avoid_altitude is None else f", not at {a.avoid_altitude:g} m"
        handovers = [(spec, f"{spec}, then {then} from {a.switch_s:g} s{avoid}",
                      phases(task, spec, seeds, overrides, then, a.switch_s, a.avoid_altitude))
                     for then in a.then for spec in a.planners if spec != then or a.avoid_altitude is not None]
        rows = [*own.items(), *((label, r) for _, label, r in handovers)]
        first = rows[0][1]
        win = [f"{int(t0)}-{int(t1)} s" for t0, t1 in zip([0.0, *first["times"][:-1]], first["times"])]
        lv = " / ".join(f"{z:g}" for z in first["levels"])
        print(f"| planner | window | gained [points] | legs | mean leg [s] | flight time at {lv} m [%] |")
        print("|---|---|---|---|---|---|")
        for spec, r in rows:
            for i, label in enumerate(win):
                share = " / ".join(f"{100 * s:.0f}" for s in r["share"][i])
                print(f"| {spec if i == 0 else ''} | {label} | {r['gain'][i]:.1f} | {r['legs'][i]:.1f} | "
                      f"{r['leg_s'][i]:.2f} | {share} |")
        print("budget left unflown at the end [s]: " + ", ".join(f"{s} {r['unflown']:.2f}" for s, r in rows))
        for spec, label, r in handovers:
            d = r["reduction"] - own[spec]["reduction"]
            cis = [bootstrap_ci(d[:, j]) for j in range(d.shape[1])]  # the leaderboard's paired interval
            print(f"{label} minus its first planner alone, reduction at " + " / ".join(
                f"{t:g}" for t in first["times"]) + " s [95 % paired bootstrap interval]: " + " / ".join(
                f"{m:+.1f}" + (f" [{lo:+.1f}, {hi:+.1f}]" if lo is not None else "") for m, lo, hi in cis))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
