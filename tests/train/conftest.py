import pytest

pytest.importorskip("torch")
pytest.importorskip("sb3_contrib")

# the training tests share the policy tests' set-up: one torch thread, SB3's logs in pytest's tmp, a
# fixed torch seed per test
from policies.conftest import _sb3_logs_in_tmp, _torch_seed  # noqa: E402, F401
