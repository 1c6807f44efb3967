import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
import pytest

from ipp_bench.core._threads import limit_blas_threads

limit_blas_threads()


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
