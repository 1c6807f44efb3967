"""Saving and loading the attention network as a small, self-describing torch file.

A checkpoint is a ``torch.save`` of a plain dict (loadable with ``weights_only=True``)::

    {"format": "ipp_bench.attention/1", "net_config": {...NetConfig...},
     "state_dict": {...AttentionNet...}, "meta": {...training config, command, task...}}

An ensemble (:class:`~ipp_bench.policies.network.AttentionEnsemble`, written by
``save_checkpoint(AttentionEnsemble([net_a, net_b, ...]), path)``) holds
``"members": [{...AttentionNet...}, ...]`` instead of
``"state_dict"``, every member of the one ``net_config``; loading it gives the ensemble.

A JSON file with the same stem beside it repeats ``net_config`` and ``meta`` for people. The
suite ships one trained checkpoint, :data:`SHIPPED_CHECKPOINT`; training writes SB3 ``.zip`` files
during a run and exports this format at the end (``export.pt`` in the run folder).
"""

from __future__ import annotations

import json
import math
import zipfile
from pathlib import Path
from typing import Any

import torch

from ipp_bench.core.data import write_atomically
from ipp_bench.policies.network import MAX_MEMBERS, AttentionEnsemble, AttentionNet, NetConfig

FORMAT = "ipp_bench.attention/1"
CHECKPOINT_DIR = Path(__file__).resolve().parent / "checkpoints"
SHIPPED_CHECKPOINT = CHECKPOINT_DIR / "attention_v6.pt"  # rebuilt by `ipp-bench train --recipe attention_v6`


class CheckpointError(ValueError):
    """A checkpoint that is missing, unreadable or does not fit the network."""


def _cpu_state(net: AttentionNet) -> dict[str, torch.Tensor]:
    return {k: v.detach().to("cpu", torch.float32).clone() for k, v in net.state_dict().items()}


def save_checkpoint(net: AttentionNet | AttentionEnsemble, path: str | Path,
                    meta: dict[str, Any] | None = None) -> Path:
    """Write ``net`` (float32, CPU; an ensemble as its members) to ``path`` and its description to
    ``path.with_suffix('.json')``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload: dict[str, Any] = {"format": FORMAT, "net_config": net.cfg.to_dict()}
    if isinstance(net, AttentionEnsemble):
        payload["members"] = [_cpu_state(m) for m in net.members]
        states = payload["members"]
    else:
        payload["state_dict"] = _cpu_state(net)
        states = [payload["state_dict"]]
    payload["meta"] = dict(meta or {})
    write_atomically(path, lambda tmp: torch.save(payload, tmp))
    info = {"format": FORMAT, "net_config": payload["net_config"], "meta": payload["meta"],
            "parameters": int(sum(v.numel() for state in states for v in state.values()))}
    if isinstance(net, AttentionEnsemble):
        info["members"] = len(states)
    text = json.dumps(info, indent=2, sort_keys=True) + "\n"
    write_atomically(path.with_suffix(".json"), lambda tmp: tmp.write_text(text))
    return path


def load_checkpoint(path: str | Path | None = None,
                    device: str | torch.device = "cpu") -> tuple[AttentionNet | AttentionEnsemble, dict]:
    """Load an AttentionNet, or the AttentionEnsemble of an ensemble checkpoint (eval mode), and its
    meta from ``path`` (default: the shipped one).

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
            f"`ipp-bench train --export {path}` (writes {path.with_suffix('.pt')})")
    _check_container(path, expected)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # noqa: BLE001 - any unreadable file gets the same message
        # Never torch's advice to retry with weights_only=False: a file that needs it is not ours.
        raise CheckpointError(f"checkpoint {path} is not an ipp-bench checkpoint (torch cannot read it as "
                              f"plain tensors and dicts); expected {expected}") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        found = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
        raise CheckpointError(f"checkpoint {path} has format {found!r}; expected {expected}")
    net_config, meta = payload.get("net_config"), payload.get("meta", {})
    if not isinstance(net_config, dict):
        raise CheckpointError(f"checkpoint {path}: net_config is {type(net_config).__name__}, expected a dict "
                              "of NetConfig fields")
    try:
        cfg = NetConfig.from_dict(net_config)
    except (KeyError, TypeError, ValueError) as err:
        raise CheckpointError(f"checkpoint {path} has an invalid net_config ({err})") from None
    if meta is None:
        meta = {}
    if not isinstance(meta, dict):
        raise CheckpointError(f"checkpoint {path}: meta is {type(meta).__name__}, expected a dict")
    if "members" in payload:
        members = payload["members"]
        if not isinstance(members, list) or not 2 <= len(members) <= MAX_MEMBERS:
            what = f"a list of {len(members)}" if isinstance(members, list) else type(members).__name__
            raise CheckpointError(f"checkpoint {path}: members is {what}, expected a list of 2 to {MAX_MEMBERS} "
                                  "state dicts (an ensemble)")
        nets = [_net_from_state(path, cfg, state, f" (member {i})") for i, state in enumerate(members)]
        net: AttentionNet | AttentionEnsemble = AttentionEnsemble(nets)
    else:
        net = _net_from_state(path, cfg, payload.get("state_dict"), "")
    net.to(device).eval()
    return net, dict(meta)


def _check_container(path: Path, expected: str) -> None:
    """Refuse, in words, a file that cannot be a torch checkpoint before torch reads it: an empty file, a
    cut-short one (a torch file is a zip archive whose directory is written last) and a plain pickle
    (whose reading torch would announce with a warning of its own before refusing it)."""
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            head = fh.read(4)
    except OSError as err:
        raise CheckpointError(f"checkpoint {path} cannot be read ({err.strerror or err})") from None
    if size == 0:
        why = "it is empty (0 bytes)"
    elif head[:1] == b"\x80":
        why = "it is a plain pickle, not a torch zip archive (a pickle can run code: it is never read)"
    elif not head.startswith(b"PK"):
        why = "it is not a torch file (a torch file is a zip archive)"
    elif not zipfile.is_zipfile(path):
        why = f"it is truncated ({size} bytes, its zip directory missing: the write was cut short)"
    else:
        return
    raise CheckpointError(f"checkpoint {path} is not an ipp-bench checkpoint: {why}; expected {expected}")


def _net_from_state(path: Path, cfg: NetConfig, state: Any, which: str) -> AttentionNet:
    """The AttentionNet of ``cfg`` with ``state`` (CheckpointError if it does not fit)."""
    if not isinstance(state, dict) or not all(isinstance(k, str) and isinstance(v, torch.Tensor)
                                              for k, v in state.items()):
        raise CheckpointError(f"checkpoint {path}{which}: state_dict is {type(state).__name__}, expected a dict "
                              "of named tensors")
    _check_shapes(path, cfg, state, which)
    bad = [k for k, v in state.items() if v.is_floating_point() and not bool(torch.isfinite(v).all())]
    if bad:
        raise CheckpointError(f"checkpoint {path}{which} has non-finite weights (NaN or inf) in {', '.join(bad[:3])}"
                              + (f" and {len(bad) - 3} more tensors" if len(bad) > 3 else "")
                              + ": a diverged training run; export an earlier one")
    net = AttentionNet(cfg)
    try:
        net.load_state_dict(state, strict=True)
    except (KeyError, RuntimeError, TypeError, ValueError) as err:
        first = str(err).strip().splitlines()
        why = " ".join(line.strip() for line in first[1:3]) if len(first) > 1 else (first[0] if first else "")
        raise CheckpointError(f"checkpoint {path}{which} does not fit AttentionNet({cfg}): {why}") from None
    return net


#: the most parameters a checkpoint's network may have (the shipped one has ~0.6 M)
MAX_PARAMETERS = 200_000_000


def _check_shapes(path: Path, cfg: NetConfig, state: dict[str, torch.Tensor], which: str = "") -> None:
    """Compare ``state`` with the network ``cfg`` describes, built on torch's ``meta`` device (no
    memory), so that a net_config of absurd sizes is refused before anything is allocated."""
    try:
        with torch.device("meta"):
            shapes = {k: tuple(v.shape) for k, v in AttentionNet(cfg).state_dict().items()}
    except (RuntimeError, ValueError, TypeError) as err:
        raise CheckpointError(f"checkpoint {path}: its net_config {cfg} cannot be built ({err})") from None
    n = sum(math.prod(s) for s in shapes.values())
    if n > MAX_PARAMETERS:
        raise CheckpointError(f"checkpoint {path}: its net_config describes {n:.3g} parameters, more than the "
                              f"{MAX_PARAMETERS:.3g} an attention checkpoint may have")
    missing = sorted(set(shapes) - set(state))
    unexpected = sorted(set(state) - set(shapes))
    wrong = [k for k in shapes if k in state and tuple(state[k].shape) != shapes[k]]
    if missing or unexpected or wrong:
        what = [f"missing {missing[:3]}"] if missing else []
        what += [f"unexpected {unexpected[:3]}"] if unexpected else []
        what += [f"{k} is {tuple(state[k].shape)}, expected {shapes[k]}" for k in wrong[:2]]
        raise CheckpointError(f"checkpoint {path}{which} does not fit AttentionNet({cfg}): {'; '.join(what)}")


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
