"""The roadmap and its Laplacian positional encoding at growing map sizes, dense and sparse.

Prints figures, never pass/fail. Run: ``python benchmarks/bench_roadmap_scale.py [--sizes 15 30 50 128]
[--task ipp_bench/Hotspots30Eval-v2] [--dense-max-nodes 5000]``.

For every size (square maps of that many cells a side, the task's altitudes, k and pe_dim) and each
eigensolver, one fresh child process (so that its peak is its own) builds the roadmap's nodes, the
balanced k-NN edges and their leg costs (``_sample_nodes``, ``_balanced_knn``; one thread), then the
encoding (``laplacian_encoding(..., method)``), and reports each phase's time and the process's peak
resident memory above what it held after the imports, and the whole process's (``resource.ru_maxrss``:
it counts SuperLU's and LAPACK's own allocations, which ``tracemalloc`` does not see). ``auto`` marks the solver the
roadmap itself uses at that size. The dense solver runs up to ``--dense-max-nodes`` nodes; where
both run, the dense child also reports how far the sparse encoding is from the dense one (largest
principal angle between the two 32-dimensional subspaces, largest eigenvalue difference, largest
entry difference). The solver ``auto`` picks also shows ``limits.encoding_bytes``, the estimate
``check_sizes`` refuses maps by.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time

import numpy as np


def child(size: int, method: str, task: str, compare: bool) -> None:
    """Measure one (size, solver) in this process; print one JSON line."""
    from ipp_bench.core._threads import limit_blas_threads
    from ipp_bench.core.limits import encoding_bytes
    from ipp_bench.core.roadmap import DENSE_ENCODING_MAX_NODES, _balanced_knn, _sample_nodes, laplacian_encoding
    from ipp_bench.envs import task_config

    limit_blas_threads()
    config = task_config(task).replace(rows=size, cols=size)
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    positions, levels = _sample_nodes(config.grid, config.graph)
    neighbours, dist = _balanced_knn(positions, levels, config.graph)
    costs = dist / config.mission.speed
    t1 = time.perf_counter()
    knn_peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    pe = laplacian_encoding(neighbours, config.graph.pe_dim, method=method)
    t2 = time.perf_counter()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    n = positions.shape[0]
    out = {"size": size, "method": method, "nodes": n, "knn_s": t1 - t0, "encoding_s": t2 - t1,
           "knn_peak_mb": (knn_peak - base) / 1024, "peak_mb": (peak - base) / 1024, "process_mb": peak / 1024,
           "estimate_mb": encoding_bytes(config) / 2**20,
           "auto": method == ("dense" if n <= DENSE_ENCODING_MAX_NODES else "sparse"),
           "costs_finite": bool(np.isfinite(costs).all())}
    if compare:
        from scipy.linalg import subspace_angles

        from ipp_bench.core.roadmap import sparse_laplacian

        sparse = laplacian_encoding(neighbours, config.graph.pe_dim, method="sparse").astype(np.float64)
        dense = pe.astype(np.float64)
        L = sparse_laplacian(neighbours)
        lam_d = np.einsum("ij,ij->j", dense, L @ dense)
        lam_s = np.einsum("ij,ij->j", sparse, L @ sparse)
        out.update(angle=float(subspace_angles(dense, sparse).max()), eig_diff=float(np.abs(lam_d - lam_s).max()),
                   entry_diff=float(np.abs(dense - sparse).max()), min_gap=float(np.diff(np.sort(lam_d)).min()))
    print(json.dumps(out))


def run_child(size: int, method: str, task: str, compare: bool) -> dict:
    cmd = [sys.executable, __file__, "--child", str(size), method, "--task", task] + (["--compare"] if compare else [])
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[15, 30, 50, 128], help="cells a side")
    parser.add_argument("--task", default="ipp_bench/Hotspots30Eval-v2",
                        help="task whose altitudes, k, pe_dim are used")
    parser.add_argument("--dense-max-nodes", type=int, default=5000, help="largest roadmap the dense solver is run on")
    parser.add_argument("--child", nargs=2, metavar=("SIZE", "METHOD"), help=argparse.SUPPRESS)
    parser.add_argument("--compare", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(int(args.child[0]), args.child[1], args.task, args.compare)
        return
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, numpy {np.__version__}, BLAS threads 1, "
          f"load {os.getloadavg()[0]:.2f}")
    print("| grid | nodes | solver | k-NN + costs [s] | encoding [s] | total [s] | peak [MB] | process peak [MB] | "
          "estimate [MB] | sparse vs dense: angle / eigenvalue / entry |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for size in args.sizes:
        from ipp_bench.core.limits import roadmap_nodes
        from ipp_bench.envs import task_config

        nodes = roadmap_nodes(task_config(args.task).replace(rows=size, cols=size))
        methods = ["dense", "sparse"] if nodes <= args.dense_max_nodes else ["sparse"]
        for method in methods:
            r = run_child(size, method, args.task, compare=method == "dense")
            agree = (f"{r['angle']:.1e} / {r['eig_diff']:.1e} / {r['entry_diff']:.1e} (least gap {r['min_gap']:.1e})"
                     if "angle" in r else "")
            mark = " (auto)" if r["auto"] else ""
            estimate = f"{r['estimate_mb']:.0f}" if r["auto"] else ""  # the estimate is of the solver auto picks
            print(f"| {size} x {size} | {r['nodes']} | {method}{mark} | {r['knn_s']:.3f} | {r['encoding_s']:.3f} | "
                  f"{r['knn_s'] + r['encoding_s']:.2f} | {r['peak_mb']:.0f} | {r['process_mb']:.0f} | {estimate} | "
                  f"{agree} |", flush=True)
        if nodes > args.dense_max_nodes:
            print(f"| {size} x {size} | {nodes} | dense | skipped: a {nodes**2 * 8 / 2**30:.2g} GiB Laplacian "
                  "| | | | | | |")
    print(f"load at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
