"""Where a board's rows were made, as run.json records it: the CPU, every library whose version can
move a row, and the BLAS kernel in use (the MCTS rows depend on it)."""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import pytest
from lb_helpers import run_tiny

from ipp_bench.eval.machine import describe_machine, machine_info, same_machine
from ipp_bench.eval.results_csv import RESULTS_CSV
from ipp_bench.eval.run_json import RUN_JSON

REPO = Path(__file__).resolve().parents[2]
#: distribution -> the name run.json records it under
LIBRARIES = {"numpy": "numpy", "scipy": "scipy", "torch": "torch", "numba": "numba", "cma": "cma",
             "gymnasium": "gymnasium", "pettingzoo": "pettingzoo", "stable-baselines3": "stable-baselines3",
             "sb3-contrib": "sb3-contrib", "opencv-python-headless": "opencv", "opencv-python": "opencv"}


def _installed(dist: str) -> str | None:
    try:
        return version(dist)
    except PackageNotFoundError:
        return None


def test_machine_info_records_every_library_that_moves_a_row_and_the_blas_kernel():
    info = machine_info()
    for dist, name in LIBRARIES.items():
        if _installed(dist) is not None:
            assert name in info["packages"], (dist, info["packages"])
    import numpy  # noqa: F401  (its OpenBLAS is loaded, so threadpoolctl sees it)
    from threadpoolctl import threadpool_info

    kernels = {i.get("architecture") for i in threadpool_info() if i.get("user_api") == "blas"}
    assert info["blas"] and {b.get("architecture") for b in info["blas"]} >= kernels - {None}, info["blas"]
    assert all({"api", "version", "of"} <= set(b) for b in info["blas"])
    line = describe_machine(info)
    assert any(b["architecture"] in line for b in info["blas"] if b.get("architecture"))


def test_the_readme_one_liner_shows_the_blas_kernels():
    """baselines/README.md's command to show the kernels prints them (numpy imported first), not []."""
    text = (REPO / "baselines" / "README.md").read_text()
    (command,) = re.findall(r"`(python -c \"[^`]*threadpoolctl[^`]*\")`", text)
    proc = subprocess.run([sys.executable, *shlex.split(command)[1:]], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() != "[]" and "architecture" in proc.stdout, proc.stdout


def test_a_machine_recorded_with_fewer_keys_is_the_same_machine(reference_copy):
    """A folder recorded before the BLAS kernel and the other libraries were: resumed here, its rows
    are not said to come from another machine."""
    meta = json.loads((reference_copy / RUN_JSON).read_text())
    older = dict(meta["machine"])
    older.pop("blas", None)
    older["packages"] = {k: v for k, v in older["packages"].items() if k in ("numpy", "scipy", "torch")}
    assert same_machine(older, machine_info())
    assert not same_machine(dict(older, cores=older["cores"] + 1), machine_info())
    assert not same_machine(dict(older, packages={**older["packages"], "numpy": "0.0"}), machine_info())
    meta["machine"] = older
    (reference_copy / RUN_JSON).write_text(json.dumps(meta, indent=2) + "\n")
    lines = (reference_copy / RESULTS_CSV).read_text().splitlines()
    (reference_copy / RESULTS_CSV).write_text("\n".join(lines[:-2]) + "\n")  # one episode flies again
    assert run_tiny(reference_copy).ran == 1
    after = json.loads((reference_copy / RUN_JSON).read_text())
    assert after["machine"] == older and "other_machines" not in after


@pytest.mark.parametrize("folder", ["quick", "v2"])
def test_a_committed_folders_machine_is_not_part_of_its_fingerprint(folder):
    meta = json.loads((REPO / "baselines" / folder / RUN_JSON).read_text())
    assert "machine" not in json.dumps(meta["fingerprint"]) and "blas" not in json.dumps(meta["fingerprint"])
