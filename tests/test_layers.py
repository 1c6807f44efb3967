"""The import layers hold: the contracts of pyproject.toml ``[tool.importlinter]`` (run through
``lint-imports``), the core importing neither torch, MuJoCo nor gymnasium when it is loaded, and no
import circle between the package's modules."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import ipp_bench

PACKAGE = Path(ipp_bench.__file__).resolve().parent
ROOT = PACKAGE.parent
PYPROJECT = ROOT / "pyproject.toml"
HEAVY = ("torch", "stable_baselines3", "sb3_contrib", "mujoco", "dm_control", "gymnasium")
CORE_CONTRACT = "The core needs numpy and scipy only: no torch, MuJoCo or gymnasium"


def _contracts() -> list[dict]:
    if not PYPROJECT.is_file():
        pytest.skip("pyproject.toml is not beside the package (an installed copy, not the repository)")
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    return tomllib.loads(PYPROJECT.read_text())["tool"]["importlinter"]["contracts"]


def _core() -> list[str]:
    return next(c for c in _contracts() if c["name"] == CORE_CONTRACT)["source_modules"]


def _fresh(code: str) -> list[str]:
    """What ``code`` prints as JSON, run in a fresh interpreter from the repository root."""
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_import_contracts_hold():
    _contracts()
    pytest.importorskip("importlinter", reason='lint-imports comes with the dev extra: pip install -e ".[dev]"')
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent)) or shutil.which("lint-imports")
    if exe is None:
        pytest.skip("the lint-imports command is not on the PATH")
    out = subprocess.run([exe, "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    assert f"{len(_contracts())} kept, 0 broken" in out.stdout


def test_every_top_level_module_is_core_or_named_apart():
    """A module added at the package's top level joins the core contract (or is the CLI): what the core
    may import is then checked for it too."""
    modules = {f"ipp_bench.{p.stem}" for p in PACKAGE.glob("*.py")} - {"ipp_bench.__init__", "ipp_bench.cli"}
    assert modules == set(_core())


def test_the_core_loads_without_torch_mujoco_or_gymnasium():
    """Each core module loaded alone (the package's ``__init__``, which registers the gymnasium tasks, left
    out) in a fresh interpreter brings none of the heavy packages along."""
    code = f"""
import importlib, json, sys, types
pkg = types.ModuleType("ipp_bench")
pkg.__path__ = [{str(PACKAGE)!r}]
sys.modules["ipp_bench"] = pkg
loaded = {{}}
for name in {_core()!r}:
    importlib.import_module(name)
    loaded[name] = [m for m in {HEAVY!r} if m in sys.modules]
print(json.dumps(loaded))
"""
    loaded = _fresh(code)
    assert set(loaded) == set(_core())
    assert all(heavy == [] for heavy in loaded.values()), loaded


def test_the_environments_and_planners_load_without_torch_or_mujoco():
    code = f"""
import json, sys
import ipp_bench.envs, ipp_bench.gains
import ipp_bench.planners.greedy, ipp_bench.planners.oracle, ipp_bench.planners.simple, ipp_bench.planners.episode
import ipp_bench.planners.mcts, ipp_bench.planners.cmaes
from ipp_bench.planners import planner_names
planner_names()
print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))
"""
    assert _fresh(code) == ["gymnasium"]


def test_no_import_circle_between_the_packages_modules():
    """Every import of the package that runs, function-level ones included, read from the source (grimp,
    which import-linter builds on; ``if TYPE_CHECKING:`` imports left out): no module reaches itself again."""
    grimp = pytest.importorskip("grimp", reason='grimp comes with import-linter: pip install -e ".[dev]"')
    graph = grimp.build_graph("ipp_bench", exclude_type_checking_imports=True, cache_dir=None)
    edges = {m: set(graph.find_modules_directly_imported_by(m)) for m in graph.modules}
    circles = _strongly_connected(edges)
    assert not circles, "import circles: " + "; ".join(" <-> ".join(c) for c in circles)


def _strongly_connected(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    for start in sorted(edges):
        if start in index:
            continue
        work = [(start, iter(sorted(edges[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(edges.get(w, ())))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def test_the_circle_finder_finds_circles():
    assert _strongly_connected({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _strongly_connected({"a": {"b"}, "b": set(), "c": {"c"}}) == []
