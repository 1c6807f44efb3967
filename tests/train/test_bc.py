"""Behaviour cloning: the soft targets, the dataset of several map sizes, its round files."""

from ipp_bench.train.bc import soft_target


def test_soft_targets():
    import numpy as np

    s = np.array([1.0, 0.95, 0.5, -np.inf])
    t = soft_target(0, s, 4, 0.1)
    assert t[3] == 0 and t.argmax() == 0 and t[1] > t[2] > 0 and abs(t.sum() - 1) < 1e-6
    assert soft_target(2, None, 4, 0.1).tolist() == [0, 0, 1, 0]
    assert soft_target(1, s, 4, 0.0).tolist() == [0, 1, 0, 0]


def _fake_obs(n_nodes: int, k: int, value: float) -> dict:
    import numpy as np

    return {"node_features": np.full((n_nodes, 6), value, np.float32), "current_node": np.array([0]),
            "neighbours": np.arange(k), "action_mask": np.ones(k, bool), "budget": np.array([0.5], np.float32),
            "pos_encoding": np.full((n_nodes, 4), float(n_nodes), np.float32)}


def test_warm_start_batches_hold_one_map_size_each_and_every_sample_once(tmp_path):
    """States of two roadmaps in one DAgger dataset: each minibatch stacks one roadmap's states, every
    sample comes exactly once per epoch; with one roadmap the batches are the plain shuffle's."""
    import numpy as np
    import torch

    from ipp_bench.train.bc import BCDataset, load_chunk, save_chunk

    data = BCDataset()
    k = 3
    for e, n in enumerate([10, 25, 10, 25, 25]):
        obs = [_fake_obs(n, k, 100 * e + j) for j in range(7)]
        data.add_episode(obs, [0] * 7, [np.eye(k, dtype=np.float32)[0]] * 7, [1.0] * 7, 0.9)
    seen = []
    for obs, _, _ in data.batches(4, np.random.default_rng(0), torch.device("cpu")):
        nf = obs["node_features"]
        assert nf.shape[1] in (10, 25) and obs["pos_encoding"].shape[1] == nf.shape[1]
        assert torch.all(obs["pos_encoding"] == nf.shape[1])  # each state's own roadmap's encoding
        seen += nf[:, 0, 0].tolist()
    assert sorted(seen) == sorted(100 * e + j for e in range(5) for j in range(7))

    # a round's samples to disk and back (the resumable warm start), sizes kept
    save_chunk(data, 7, tmp_path / "data_0.npz")
    back = BCDataset()
    load_chunk(back, tmp_path / "data_0.npz")
    assert len(back) == len(data) - 7
    assert all(np.array_equal(a, b) for a, b in zip(back.nf, data.nf[7:]))
    assert [back.pes[i].shape[0] for i in back.pe_id] == [a.shape[0] for a in data.nf[7:]]

    one = BCDataset()
    one.add_episode([_fake_obs(10, k, j) for j in range(9)], [0] * 9, [np.eye(k, dtype=np.float32)[0]] * 9,
                    [1.0] * 9, 0.9)
    got = [b[0]["node_features"][:, 0, 0].tolist() for b in one.batches(4, np.random.default_rng(1), "cpu")]
    order = np.random.default_rng(1).permutation(9)
    assert got == [order[s:s + 4].astype(float).tolist() for s in range(0, 9, 4)]
