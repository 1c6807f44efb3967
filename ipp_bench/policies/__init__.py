"""The attention policy of the paper: network, features, SB3 policy, checkpoints, planner.

- :mod:`~ipp_bench.policies.network`: the encoder / pointer-decoder network (torch only);
- :mod:`~ipp_bench.policies.features`: the look-gain node feature the network reads;
- :mod:`~ipp_bench.policies.checkpoint`: the small checkpoint format and the shipped checkpoint;
- :mod:`~ipp_bench.policies.sb3`: ``AttentionPolicy`` for ``sb3_contrib.MaskablePPO``;
- :mod:`~ipp_bench.policies.planner`: the ``attention`` planner.

Training (``ipp-bench train``) lives in :mod:`ipp_bench.train`, above this package: nothing here
imports it. Importing this package needs torch only; the SB3 policy needs the ``[train]`` extra
(stable-baselines3, sb3-contrib).
"""

try:
    import torch  # noqa: F401
except ImportError as err:  # pragma: no cover - depends on the installation
    raise ImportError(
        'ipp_bench.policies needs torch: install the training extra with pip install "ipp-bench[train]"'
    ) from err

from ipp_bench.policies.checkpoint import (
    SHIPPED_CHECKPOINT,
    CheckpointError,
    load_checkpoint,
    save_checkpoint,
)
from ipp_bench.policies.network import AttentionNet, NetConfig

_LAZY = {  # name -> (module, what it needs): imported on first use, so that torch alone suffices here
    "AttentionPolicy": ("ipp_bench.policies.sb3", "stable-baselines3 and sb3-contrib"),
    "AttentionPlanner": ("ipp_bench.policies.planner", "torch"),
}


def __getattr__(name: str):
    """``from ipp_bench.policies import AttentionPolicy`` (the SB3 policy; needs the ``[train]`` extra)."""
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    module, needs = _LAZY[name]
    import importlib

    try:
        return getattr(importlib.import_module(module), name)
    except ImportError as err:
        raise ImportError(f"ipp_bench.policies.{name} needs {needs} ({err}): "
                          'pip install "ipp-bench[train]"') from None


__all__ = ["SHIPPED_CHECKPOINT", "AttentionNet", "AttentionPlanner", "AttentionPolicy", "CheckpointError", "NetConfig",
           "load_checkpoint", "save_checkpoint"]
