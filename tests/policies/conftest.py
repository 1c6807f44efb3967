import numpy as np
import pytest

torch = pytest.importorskip("torch")


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


def fake_obs(n_nodes: int = 60, k: int = 20, pe_dim: int = 32, batch: int = 4, seed: int = 0) -> dict:
    """A batch of random observations with the shapes of GraphIPPEnv's."""
    g = torch.Generator().manual_seed(seed)
    cur = torch.randint(0, n_nodes, (batch, 1), generator=g)
    mask = torch.rand(batch, k, generator=g) > 0.3
    mask[:, 0] = True
    return {
        "node_features": torch.rand(batch, n_nodes, 5, generator=g),
        "pos_encoding": torch.randn(batch, n_nodes, pe_dim, generator=g) * 0.1,
        "current_node": cur,
        "neighbours": torch.randint(0, n_nodes, (batch, k), generator=g),
        "action_mask": mask.to(torch.int8),
        "budget": torch.rand(batch, 1, generator=g),
    }


def to_batch(obs: dict) -> dict:
    """One env observation (numpy) -> a batch of one (torch)."""
    return {key: torch.as_tensor(np.asarray(v)).unsqueeze(0) for key, v in obs.items()}
