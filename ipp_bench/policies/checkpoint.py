"""Saving and loading the attention network as a small, self-describing torch file.

A checkpoint is a ``torch.save`` of a plain dict (loadable with ``weights_only=True``)::

    {"format": "ipp_bench.attention/1", "net_config": {...NetConfig...},
     "state_dict": {...AttentionNet...}, "meta": {...training config, command, task...}}

A JSON file with the same stem beside it repeats ``net_config`` and ``meta`` for people. The
suite ships one trained checkpoint, :data:`SHIPPED_CHECKPOINT`; training writes SB3 ``.zip`` files
during a run and exports this format at the end (``export.pt`` in the run folder).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch

from ipp_bench.policies.network import AttentionNet, NetConfig

FORMAT = "ipp_bench.attention/1"
CHECKPOINT_DIR = Path(__file__).resolve().parent / "checkpoints"
SHIPPED_CHECKPOINT = CHECKPOINT_DIR / "attention_v1.pt"  # v0: attention_grid15.pt (still shipped)


class CheckpointError(ValueError):
    """A checkpoint that is missing, unreadable or does not fit the network."""


def save_checkpoint(net: AttentionNet, path: str | Path, meta: dict[str, Any] | None = None) -> Path:
    """Write ``net`` (float32, CPU) to ``path`` and its description to ``path.with_suffix('.json')``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().to("cpu", torch.float32).clone() for k, v in net.state_dict().items()}
    payload = {"format": FORMAT, "net_config": net.cfg.to_dict(), "state_dict": state, "meta": dict(meta or {})}
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)
    info = {"format": FORMAT, "net_config": payload["net_config"], "meta": payload["meta"],
            "parameters": int(sum(v.numel() for v in state.values()))}
    path.with_suffix(".json").write_text(json.dumps(info, indent=2, sort_keys=True) + "\n")
    return path


def load_checkpoint(path: str | Path | None = None, device: str | torch.device = "cpu") -> tuple[AttentionNet, dict]:
    """Load an AttentionNet (eval mode) and its meta from ``path`` (default: the shipped one).

    Raises:
        CheckpointError: the file is missing, is not an ipp-bench attention checkpoint, or its
            weights do not fit the network it describes.
    """
    path = Path(path) if path is not None else SHIPPED_CHECKPOINT
    expected = (f"an ipp-bench attention checkpoint (torch file with format {FORMAT!r}, written by "
                f"ipp_bench.policies.checkpoint.save_checkpoint or `ipp-bench train`, file export.pt)")
    if not path.is_file():
        hint = ""
        if path == SHIPPED_CHECKPOINT:
            hint = " The shipped checkpoint is part of the package; reinstall ipp-bench or pass checkpoint=PATH."
        raise CheckpointError(f"checkpoint {path} not found: expected {expected}.{hint}")
    if path.suffix == ".zip":
        raise CheckpointError(
            f"checkpoint {path} is an SB3 model archive; expected {expected}. Export one with "
            f"`python -m ipp_bench.policies.train --export {path}` (writes {path.with_suffix('.pt')})")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # noqa: BLE001 - any unreadable file gets the same message
        # Never torch's advice to retry with weights_only=False: a file that needs it is not ours.
        raise CheckpointError(f"checkpoint {path} is not an ipp-bench checkpoint (torch cannot read it as "
                              f"plain tensors and dicts); expected {expected}") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        found = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
        raise CheckpointError(f"checkpoint {path} has format {found!r}; expected {expected}")
    try:
        cfg = NetConfig.from_dict(payload["net_config"])
    except (KeyError, TypeError, ValueError) as err:
        raise CheckpointError(f"checkpoint {path} has an invalid net_config ({err})") from None
    net = AttentionNet(cfg)
    try:
        net.load_state_dict(payload["state_dict"], strict=True)
    except (KeyError, RuntimeError) as err:
        first = str(err).strip().splitlines()
        why = " ".join(line.strip() for line in first[1:3]) if len(first) > 1 else (first[0] if first else "")
        raise CheckpointError(f"checkpoint {path} does not fit AttentionNet({cfg}): {why}") from None
    net.to(device).eval()
    return net, dict(payload.get("meta") or {})


def check_feature_dims(cfg: NetConfig, node_dim: int, pe_dim: int, source: str = "checkpoint") -> None:
    """Raise CheckpointError (a ValueError; one line naming both values) if a network of ``cfg``
    cannot read observations with ``node_dim`` node features and ``pe_dim`` encoding columns."""
    if (node_dim, pe_dim) != (cfg.node_dim, cfg.pe_dim):
        what = [f"{name}={mine} in the checkpoint but {name}={theirs} in the environment"
                for name, mine, theirs in (("node_dim", cfg.node_dim, node_dim), ("pe_dim", cfg.pe_dim, pe_dim))
                if mine != theirs]
        hint = f" (set GraphConfig.pe_dim={cfg.pe_dim}, e.g. gym.make(task, pe_dim={cfg.pe_dim}))" \
            if cfg.pe_dim != pe_dim else ""
        raise CheckpointError(f"{source} does not fit this task: " + "; ".join(what) + hint)
