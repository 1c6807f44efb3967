import os
import sys

os.environ.setdefault("MUJOCO_GL", "egl")
# pytest-xdist's workers share the CPUs (2 on the reference machine): torch's OpenMP pool and Mesa's llvmpipe
# rasteriser would start a thread per CPU in every process, and the surplus threads' hand-over makes the default
# run 15 % slower (benchmarks/RESULTS.md). One thread each, here and in the commands the tests start; a test or
# a planner that sets its own count (torch.set_num_threads) still does.
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("LP_NUM_THREADS", "1")

import numpy as np
import pytest

from ipp_bench.core._threads import limit_blas_threads

limit_blas_threads()


#: [s] the time limit of a test marked slow (the default tests': ``timeout`` in pyproject.toml)
SLOW_TEST_TIMEOUT_S = 1500


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.get_closest_marker("slow") is not None and item.get_closest_marker("timeout") is None:
            item.add_marker(pytest.mark.timeout(SLOW_TEST_TIMEOUT_S))


#: a plugin's module: a planner ``first`` that takes the first affordable neighbour (or the ``index``-th)
FIRST_PLANNER = """
from dataclasses import dataclass

import numpy as np

from ipp_bench.planners.base import GraphPlanner


@dataclass(frozen=True)
class FirstConfig:
    \"\"\"index: which affordable neighbour (0: the first; past the last: the last).\"\"\"

    index: int = 0


class FirstPlanner(GraphPlanner):
    name = "first"
    Config = FirstConfig

    def act(self, obs):
        affordable = np.flatnonzero(obs["action_mask"])
        return int(affordable[min(self.settings.index, len(affordable) - 1)])
"""


@pytest.fixture
def plugin_site(tmp_path, monkeypatch):
    """``install(package)``: "installs" :data:`FIRST_PLANNER` as ``package`` the way pip leaves a plugin on disk
    (the module and a ``.dist-info`` whose entry point names it ``theirs``) in a folder put on sys.path;
    returns that ``.dist-info`` folder. The module is forgotten again after the test."""
    site = tmp_path / "site"
    installed = []

    def install(package: str):
        (site / package).mkdir(parents=True)
        (site / package / "__init__.py").write_text(FIRST_PLANNER)
        info = site / f"{package}-0.1.dist-info"
        info.mkdir()
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {package.replace('_', '-')}\nVersion: 0.1\n")
        (info / "entry_points.txt").write_text(f"[ipp_bench.planners]\ntheirs = {package}:FirstPlanner\n")
        monkeypatch.syspath_prepend(str(site))
        installed.append(package)
        return info

    yield install
    for package in installed:
        monkeypatch.delitem(sys.modules, package, raising=False)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
