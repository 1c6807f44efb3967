"""The compiled kernels' cache: a damaged one is removed and compiled again in one line, NUMBA_DISABLE_JIT is said
once, and the leaderboard says when it compiles before it does."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("numba", reason='the fast searches need numba: pip install "ipp-bench[eval]"')

PACKAGE = Path(__file__).resolve().parents[2] / "ipp_bench"
WARM = "from ipp_bench.planners import kernels; kernels.warm_up(); print(kernels.cached())"


def _run(code: str, root: Path, **env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(root), **env})


@pytest.mark.slow
def test_a_cut_short_cache_is_removed_said_in_one_line_and_compiled_again(tmp_path):
    """A copy of the package (its own cache beside its modules): compiled once, every data file cut short, then
    the next process says so in one line, compiles again and the one after loads from the new cache."""
    shutil.copytree(PACKAGE, tmp_path / "ipp_bench", ignore=shutil.ignore_patterns("__pycache__"))
    first = _run(WARM, tmp_path)
    assert first.returncode == 0 and first.stdout.strip() == "True", first.stderr
    data = list((tmp_path / "ipp_bench" / "planners" / "kernels" / "__pycache__").glob("*.nbc"))
    assert data
    for f in data:
        f.write_bytes(f.read_bytes()[:10])
    damaged = _run(WARM, tmp_path)
    assert damaged.returncode == 0 and "Traceback" not in damaged.stderr, damaged.stderr
    lines = [line for line in damaged.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "compiled cache could not be read (UnpicklingError" in lines[0], damaged.stderr
    again = _run(WARM, tmp_path)
    assert again.returncode == 0 and again.stderr.strip() == "" and again.stdout.strip() == "True"


def test_numba_disable_jit_is_said_once():
    code = ("import warnings\nwarnings.simplefilter('always')\nfrom ipp_bench.planners import kernels\n"
            "with warnings.catch_warnings(record=True) as seen:\n"
            "    warnings.simplefilter('always')\n    kernels.warm_up(); kernels.warm_up()\n"
            "print(sum(issubclass(w.category, kernels.KernelsRunInterpretedWarning) for w in seen))")
    out = _run(code, PACKAGE.parent, NUMBA_DISABLE_JIT="1")
    assert out.returncode == 0 and out.stdout.strip() == "1", out.stderr


def test_the_leaderboard_says_it_compiles_before_it_does(monkeypatch, capsys, tmp_path):
    from ipp_bench import cli
    from ipp_bench.planners import kernels

    compiled = []
    monkeypatch.setattr(kernels, "cached", lambda: False)
    monkeypatch.setattr(kernels, "warm_up", lambda: compiled.append(capsys.readouterr().out))
    rc = cli.main(["leaderboard", "--tasks", "Grid15Eval-v1", "--planners", "greedy", "mcts:simulations=2",
                   "--episodes", "1", "--backend", "serial", "--no-progress", "--out", str(tmp_path / "lb"),
                   "--env", "budget_s=20", "--env", "report_times=[20]"])
    out = capsys.readouterr().out
    assert rc == 0 and len(compiled) >= 1
    assert compiled[0].startswith("compiling the search kernels of mcts and cmaes (once: about")
    assert "planning and compiling included" in out
    capsys.readouterr()
    compiled.clear()
    rc = cli.main(["leaderboard", "--tasks", "Grid15Eval-v1", "--planners", "greedy", "--episodes", "1",
                   "--backend", "serial", "--no-progress", "--out", str(tmp_path / "lb2"), "--env", "budget_s=20",
                   "--env", "report_times=[20]"])
    assert rc == 0 and compiled == []  # no search planner: nothing to compile
