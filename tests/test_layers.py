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
    """Every module of the core package, from its folder."""
    return sorted(f"ipp_bench.core.{p.stem}" for p in (PACKAGE / "core").glob("*.py") if p.stem != "__init__")


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


def test_the_top_level_holds_the_package_and_the_cli_only():
    """A module added at the package's top level would sit outside every layer of the contracts: it
    belongs in the core (``ipp_bench/core/``, checked by the core's contracts) or in a layer's package."""
    assert {p.stem for p in PACKAGE.glob("*.py")} == {"__init__", "cli"}
    contract = next(c for c in _contracts() if c["name"] == CORE_CONTRACT)
    assert contract["source_modules"] == ["ipp_bench.core"]


def test_the_core_loads_without_torch_mujoco_or_gymnasium():
    """Each core module imported through the real package in a fresh interpreter brings none of the heavy
    packages along; and with gymnasium not installed (blocked), every core module still imports."""
    code = f"""
import importlib, json, sys
loaded = {{}}
for name in {_core()!r}:
    importlib.import_module(name)
    loaded[name] = [m for m in {HEAVY!r} if m in sys.modules]
print(json.dumps(loaded))
"""
    loaded = _fresh(code)
    assert set(loaded) == set(_core()) and len(loaded) >= 16
    assert all(heavy == [] for heavy in loaded.values()), loaded
    blocked = _fresh(f"""
import importlib, json, sys
sys.modules["gymnasium"] = None  # as if it were not installed
print(json.dumps([importlib.import_module(name).__name__ for name in {_core()!r}]))
""")
    assert blocked == _core()


def test_the_tasks_register_whichever_of_gymnasium_and_ipp_bench_is_imported_first():
    """``import ipp_bench`` registers the tasks when gymnasium is loaded, at once or later; once."""
    for code in ("import gymnasium as gym, ipp_bench", "import ipp_bench, gymnasium as gym",
                 "import ipp_bench.core.belief, ipp_bench; import gymnasium as gym"):
        ids = _fresh(code + "; import json; print(json.dumps(sorted(k for k in gym.registry "
                            "if k.startswith('ipp_bench/'))))")
        assert "ipp_bench/Grid15Eval-v1" in ids and "ipp_bench/Hotspots30Eval-v2" in ids, code
    from ipp_bench.envs import TASKS

    assert set(ids) == set(TASKS)


def test_the_environments_and_planners_load_without_torch_or_mujoco():
    code = f"""
import json, sys
import ipp_bench.envs, ipp_bench.core.gains
import ipp_bench.planners.greedy, ipp_bench.planners.oracle, ipp_bench.planners.simple, ipp_bench.planners.episode
import ipp_bench.planners.mcts, ipp_bench.planners.cmaes
from ipp_bench.planners import planner_names
planner_names()
print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))
"""
    assert _fresh(code) == ["gymnasium"]


def test_no_import_circle_between_the_packages_modules():
    """Every import of the package, function-level and ``if TYPE_CHECKING:`` ones included, read from the
    source (grimp, which import-linter builds on): no module reaches itself again."""
    grimp = pytest.importorskip("grimp", reason='grimp comes with import-linter: pip install -e ".[dev]"')
    graph = grimp.build_graph("ipp_bench", exclude_type_checking_imports=False, cache_dir=None)
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


def test_no_module_above_600_lines_and_above_400_only_with_a_reason():
    """A module of one idea stays short: none above 600 lines, and one above 400 says in its docstring why
    it is one module ("... over 400 lines ...")."""
    import ast

    too_long, unexplained = [], []
    for path in sorted(PACKAGE.rglob("*.py")):
        text = path.read_text()
        lines = text.count("\n")
        name = str(path.relative_to(ROOT))
        if lines > 600:
            too_long.append(f"{name} ({lines})")
        elif lines > 400 and "400 lines" not in (ast.get_docstring(ast.parse(text)) or ""):
            unexplained.append(f"{name} ({lines})")
    assert not too_long, f"modules above 600 lines: {too_long}"
    assert not unexplained, f"modules above 400 lines without a reason in their docstring: {unexplained}"
