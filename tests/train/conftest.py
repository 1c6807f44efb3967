import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("sb3_contrib")

# One intra-op thread: these tests run tiny batches, and two OpenMP threads on a shared 2-core
# machine were measured 100x slower than one (see ipp_bench.train.run.set_threads).
torch.set_num_threads(1)


@pytest.fixture(autouse=True, scope="session")
def _sb3_logs_in_tmp(tmp_path_factory):
    """SB3 writes a logger folder under $TMPDIR/SB3-<date> for every ``learn``; keep it in pytest's tmp."""
    mp = pytest.MonkeyPatch()
    mp.setenv("SB3_LOGDIR", str(tmp_path_factory.mktemp("sb3_logs")))
    yield
    mp.undo()


@pytest.fixture(autouse=True)
def _torch_seed():
    torch.manual_seed(0)
