"""What flying a planner in its own process costs: per-decision wall and CPU time in-process against isolated.

Prints figures, never pass/fail. Run: ``python benchmarks/bench_isolation.py [--task ipp_bench/Hotspots30Eval-v2]
[--planners greedy mcts:simulations=24] [--episodes 3] [--repeat 2]``. Every episode is flown both ways, in-process
then isolated (``fly_episode(..., isolate=True)``, :mod:`ipp_bench.planners.isolation`), alternating, after one
warm-up episode of each (the planner process's start and its imports are paid there, as a leaderboard pays them
once per planner). Per planner it prints:

* the wall time per decision of whole episodes (episode wall time / decisions: the step, the belief update and the
  exchange included) both ways, and the overhead: over all episodes, and the median and range of the overhead of
  each repeat (its ``--episodes`` episodes both ways), the spread that the machine's load puts on the figure;
* the CPU time per decision both ways (isolated: the world's process and the planner's together), which does not
  depend on the machine's load: the isolated side pays a second belief update (the planner's own) and the exchange;
* the mean decision time as the episode loop measures it (isolated: the whole exchange), the planner's own think
  time in its process, and whether both ways gave the same reports.

The load average is printed first and last: where other jobs hold the cores, the planner's process waits for one
and the wall overhead grows towards the CPU overhead and beyond.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from ipp_bench.core._threads import limit_blas_threads
from ipp_bench.envs import make_env
from ipp_bench.planners import isolation
from ipp_bench.planners.episode import fly_episode

_TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")


def cpu_of(pid: int) -> float:
    """CPU time [s] (user + system) of process ``pid`` so far (Linux ``/proc``)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) * _TICK_S


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--task", default="ipp_bench/Hotspots30Eval-v2")
    parser.add_argument("--planners", nargs="+", default=["greedy", "mcts:simulations=24"])
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--repeat", type=int, default=1, help="fly the episodes this many times (both ways)")
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--budget-s", type=float, default=None, help="override the task's budget [s] (smoke runs)")
    args = parser.parse_args()
    limit_blas_threads()
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python {platform.python_version()}, "
          "load {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()))
    env = make_env(args.task, **({} if args.budget_s is None else {"budget_s": args.budget_s}))
    think: list[float] = []
    pids: list[int] = []
    finish = isolation.RemotePlanner.finish

    def keep(self, end_process: bool = False):  # the planner's think times and its process, as it ends an episode
        think.extend(self.think_s)
        pids.append(self.pid)
        finish(self, end_process)

    isolation.RemotePlanner.finish = keep
    print(f"task {args.task}, {args.episodes} episodes x {args.repeat} per planner (seeds {args.seed}..), in-process "
          "then isolated")
    try:
        for spec in args.planners:
            t0 = time.perf_counter()
            fly_episode(env, spec, args.seed - 1, isolate=True)  # warm-up: the process starts, imports, compiles
            start_s = time.perf_counter() - t0
            fly_episode(env, spec, args.seed - 1)
            think.clear()
            inside, apart, same, cpu_in, cpu_iso = [], [], True, 0.0, 0.0
            for i in [i for _ in range(args.repeat) for i in range(args.episodes)]:
                c0 = time.process_time()
                a = fly_episode(env, spec, args.seed + i)
                c1 = time.process_time()
                child0 = cpu_of(pids[-1])
                b = fly_episode(env, spec, args.seed + i, isolate=True)
                cpu_in += c1 - c0
                cpu_iso += time.process_time() - c1 + cpu_of(pids[-1]) - child0
                inside.append(a)
                apart.append(b)
                same = same and a.report == b.report and a.decisions == b.decisions
            n = sum(r.decisions for r in inside)
            wall_in = sum(r.episode_wall_s for r in inside) / n
            wall_iso = sum(r.episode_wall_s for r in apart) / n
            per_repeat = [100 * (sum(r.episode_wall_s for r in apart[j:j + args.episodes])
                                 / sum(r.episode_wall_s for r in inside[j:j + args.episodes]) - 1)
                          for j in range(0, len(inside), args.episodes)]
            dec_in = np.mean(np.concatenate([r.decision_times_s for r in inside]))
            dec_iso = np.mean(np.concatenate([r.decision_times_s for r in apart]))
            print(f"{spec}: {n} decisions; wall per decision in-process {1e3 * wall_in:.3f} ms, isolated "
                  f"{1e3 * wall_iso:.3f} ms, overhead {100 * (wall_iso / wall_in - 1):+.1f} % "
                  f"({1e3 * (wall_iso - wall_in):+.3f} ms); per repeat median {np.median(per_repeat):+.1f} %, "
                  f"{min(per_repeat):+.1f} .. {max(per_repeat):+.1f} %")
            print(f"  {spec}: CPU per decision in-process {1e3 * cpu_in / n:.3f} ms, isolated (both processes) "
                  f"{1e3 * cpu_iso / n:.3f} ms, overhead {100 * (cpu_iso / cpu_in - 1):+.1f} %")
            print(f"  {spec}: decision time in-process {1e3 * dec_in:.3f} ms, isolated exchange {1e3 * dec_iso:.3f} ms "
                  f"(planner's think {1e3 * np.mean(think):.3f} ms); same reports: {same}; first isolated "
                  f"episode (process start) {start_s:.2f} s", flush=True)
    finally:
        isolation.RemotePlanner.finish = finish
        isolation.close_workers()
    print("load after: {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()))


if __name__ == "__main__":
    main()
