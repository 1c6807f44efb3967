import os

os.environ.setdefault("MUJOCO_GL", "egl")

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


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
