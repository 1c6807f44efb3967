"""Compiled kernels of the look-ahead planners' fast searches (numba, cached on disk as Python caches bytecode).

- :mod:`.readouts`: the camera's read-outs along a path as sparse rows (both planners), and the S and G of a
  batch of them against the belief (CMA-ES, ``evaluation = "batched"``);
- :mod:`.node_table`: every roadmap node's legs laid out once per roadmap (MCTS, ``search = "lowrank"``);
- :mod:`.lowrank`: the MCTS's gains from a low-rank factor of the tree's updates, and its rollout;
- :mod:`.jit`: the decorator they are compiled with.

They compute the references' quantities in exact arithmetic (the Kalman update's ``Tr(S^-1 G)``
regrouped; floating point reordered, nothing approximated) and are deterministic: no fast-math, a fixed
loop order, one thread, BLAS only through ``np.dot`` (on one thread, ``ipp_bench.core._threads``).

They are compiled once, when a planner that uses them is first reset (:func:`warm_up`, outside any
decision), and numba caches the machine code: in ``__pycache__`` beside each module where it may write
there, else in its user-wide cache (``NUMBA_CACHE_DIR``, by default under ``~/.cache``), so a later process
loads it instead of compiling (``benchmarks/RESULTS.md`` has the times). A kernel's cache is keyed on its
module's file (it is compiled again after any change to it) and on the CPU's name and features (another CPU
compiles its own). It also holds the kernels that kernel calls, and numba does not see a change to another
file, so a kernel calls only kernels of its own module. Where neither place can be written, every process
compiles them again and nothing is cached.
"""

from __future__ import annotations

import sys
import traceback
import warnings
from pathlib import Path

import numpy as np

from . import lowrank, node_table, readouts
from .jit import numba, require_numba

#: every module of kernels (:func:`warm_up` compiles all of theirs)
MODULES = (readouts, node_table, lowrank)
#: [s] about how long compiling every kernel takes on one core of a 2-core machine (said before it starts)
COMPILE_S = 40
_READY = False


class KernelsRunInterpretedWarning(RuntimeWarning):
    """``NUMBA_DISABLE_JIT`` is set: the fast searches run as plain Python, many times slower."""


def _dispatchers() -> list:
    return [v for m in MODULES for v in vars(m).values() if hasattr(v, "_cache") and hasattr(v, "py_func")]


def _index_files() -> list[Path]:
    """The cache index file of every kernel (none where numba may write no cache)."""
    paths = [getattr(getattr(d._cache, "_cache_file", None), "_index_path", None) for d in _dispatchers()]
    return [Path(p) for p in paths if p is not None]


def cached() -> bool:
    """Whether every kernel's machine code is in numba's cache (a process then loads it in about a second)."""
    if numba is None or numba.config.DISABLE_JIT:
        return True  # nothing to compile
    files = _index_files()
    return bool(files) and len(files) == len(_dispatchers()) and all(f.is_file() for f in files)


def _clear_cache() -> int:
    """Remove this package's cache files (index and data); returns how many."""
    removed = 0
    for d in _dispatchers():
        index = getattr(getattr(d._cache, "_cache_file", None), "_index_path", None)
        if index is None:
            continue
        stem = Path(index).name.rsplit(".nbi", 1)[0]
        for f in Path(index).parent.glob(f"{stem}*"):
            if f.suffix in (".nbi", ".nbc"):
                f.unlink(missing_ok=True)
                removed += 1
    return removed


def _from_the_cache(err: BaseException) -> bool:
    return any("numba" in f.filename and "caching" in f.filename for f in traceback.extract_tb(err.__traceback__))


def warm_up() -> None:
    """Compile every kernel now (once per process; nothing after it compiles), not in a decision.

    A cache file that cannot be read (cut short, say) is removed, said in one line, and the kernels are
    compiled again. With ``NUMBA_DISABLE_JIT`` set they run as plain Python: a warning says so, once.
    """
    global _READY
    require_numba("the fast searches")
    if _READY:
        return
    if numba.config.DISABLE_JIT:
        warnings.warn("NUMBA_DISABLE_JIT is set: the fast searches of mcts and cmaes run as plain Python, many "
                      "times slower (unset it to compile them)", KernelsRunInterpretedWarning, stacklevel=2)
    try:
        _compile_all()
    except Exception as err:  # noqa: BLE001 - only a failure inside numba's cache loading is handled
        if not _from_the_cache(err):
            raise
        removed = _clear_cache()
        print(f"ipp-bench: the search kernels' compiled cache could not be read ({type(err).__name__}: "
              f"{' '.join(str(err).split())}); removed its {removed} files, compiling again (about {COMPILE_S} s, "
              "once)", file=sys.stderr, flush=True)
        _compile_all()
    _READY = True


def _compile_all() -> None:
    P = np.ones((2, 2)) + np.eye(2)
    readouts.readout_blocks(P, P, np.array([0, 1, 2], dtype=np.int64), np.array([0, 1], dtype=np.int64), np.ones(2),
                            np.ones(2))
    readouts.fold_repeated_rows(np.array([0, 1, 2], dtype=np.int64), np.array([0, 0], dtype=np.int64), np.ones(2),
                                np.ones(2))
    readouts.camera_rows(np.array([[1.0, 1.0, 2.0], [1.0, 1.0, 9.0]]), 0.05, 0.2, 8.0, 0.5, 1.0, 4, 4, 5.0, 2, 0.1,
                         0.1, 0.5)
    # the MCTS search: a two-node roadmap, each node's one leg seeing two cells (state_terms as the root's, step_terms
    # and rollout as the search's)
    P = np.ones((4, 4)) + np.eye(4)
    table = node_table.NodeTable(2, 1)
    leg = (np.array([0, 1, 2], dtype=np.int64), np.array([0, 1], dtype=np.int64), np.ones(2), np.ones(2))
    for node in (0, 1):
        table.add(node, [leg])
    neighbours = np.array([[1], [0]], dtype=np.int64)
    costs = np.ones((2, 1))
    known = np.ones(2, dtype=np.bool_)
    b, M, _, _, cells, m, rptr, var, _, _, nz_cell, _, nz_w = lowrank.node_view(table.ipool, table.fpool, table.table,
                                                                                0, 1)
    header, idata = np.zeros((0, 5), dtype=np.int64), np.zeros(0, dtype=np.int64)
    fdata, K = np.zeros(0), np.zeros((0, 0))
    g, Li, G, UV, Pcc, Bcc = lowrank.state_terms(P, P, header, idata, fdata, 0, cells, K, m, rptr, nz_cell, nz_w, var,
                                                 M)
    terms = (header, idata, fdata, 0, K, UV, Pcc, Bcc, Li, G)
    lowrank.step_terms(P, P, table.ipool, table.fpool, table.table, 1, 0, 0, 1, *terms)
    rng = np.random.default_rng(0)
    for mode in (0, 1):
        lowrank.rollout(P, P, table.ipool, table.fpool, table.table, neighbours, costs, known, rng, 3.5, 1e-9, 0.9,
                        1.0, 8.0, 1.0, mode, 0, 10.0, 1.0, g, 0, 0.0, 1.0, *terms)


__all__ = ["COMPILE_S", "MODULES", "KernelsRunInterpretedWarning", "cached", "require_numba", "warm_up"]
