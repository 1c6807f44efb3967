"""Reading a run's SB3 archives (``checkpoints/*.zip``) without unpickling anything.

An SB3 archive stores its settings as JSON in the member ``data``; the entries JSON cannot hold
(the policy class, the spaces, the schedules, ``policy_kwargs`` with the positional encoding) are
cloudpickle payloads under a ``":serialized:"`` key, which SB3 would unpickle on load, running
whatever code the payload carries. The weights (``*.pth``) SB3 already reads as plain tensors.

So nothing here unpickles. :func:`read_archive` returns the JSON and the policy's weights;
:func:`load_objects` gives, for every pickled entry of an archive, the object this package would
have written there (taken from the run's own settings), and refuses an archive with a pickled entry
it does not know. ``MaskablePPO.load(..., custom_objects=load_objects(...))`` then never reaches
cloudpickle: SB3 uses a custom object in place of the entry, whatever the entry holds.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path
from typing import Any

from ipp_bench.policies.checkpoint import CheckpointError

EXPECTED = "an SB3 archive (.zip) of a MaskablePPO AttentionPolicy written by `ipp-bench train`"
# Where the policy's modules sit in an AttentionPolicy's state dict, and where in an AttentionNet's.
_PREFIXES = {"features_extractor.encoder.": "encoder.", "mlp_extractor.decoder.": "decoder.",
             "action_net.pointer.": "pointer.", "value_net.": "value_head."}
_ALIASES = ("pi_features_extractor.", "vf_features_extractor.")  # the shared encoder, named again


def pickled_entries(data: dict[str, Any]) -> list[str]:
    """The entries of an archive's ``data`` that SB3 would unpickle."""
    return [key for key, value in data.items() if isinstance(value, dict) and ":serialized:" in value]


def read_archive(path: str | Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """The archive's settings (its ``data`` JSON, pickled entries left as JSON) and the policy's
    weights (``policy.pth``, read as plain tensors).

    Raises:
        CheckpointError: missing, not a zip, or without a readable ``data`` and ``policy.pth``.
    """
    import torch

    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such file; expected {EXPECTED}")
    if not zipfile.is_zipfile(path):
        raise CheckpointError(f"{path}: not a zip archive; expected {EXPECTED}")
    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data"))
            weights = torch.load(io.BytesIO(archive.read("policy.pth")), map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - any unreadable archive gets the same message
        raise CheckpointError(f"{path}: could not be read as an SB3 archive ({type(err).__name__}); "
                              f"expected {EXPECTED}") from None
    if not isinstance(data, dict) or not isinstance(weights, dict):
        raise CheckpointError(f"{path}: its data or policy.pth is not a mapping; expected {EXPECTED}")
    return data, weights


def check_attention_policy(path: Path, data: dict[str, Any]) -> None:
    """Refuse an archive whose policy class is not this package's ``AttentionPolicy``, judged by the
    class's module and methods as the JSON describes them (the class itself is never unpickled)."""
    entry = data.get("policy_class")
    if not (isinstance(entry, dict) and entry.get("__module__") == "ipp_bench.policies.sb3"
            and "attention_net" in entry):
        module = entry.get("__module__") if isinstance(entry, dict) else entry
        raise CheckpointError(f"{path}: its policy class is not ipp_bench's AttentionPolicy (module {module!r}); "
                              f"expected {EXPECTED}")


def load_objects(path: str | Path, known: dict[str, Any]) -> dict[str, Any]:
    """``custom_objects`` for ``MaskablePPO.load``: ``known[key]`` for every pickled entry of the
    archive at ``path``, so that SB3 unpickles none of them.

    Raises:
        CheckpointError: the archive is unreadable, is not of an AttentionPolicy, or holds a pickled
            entry not in ``known`` (this package never writes one there; it is refused unread).
    """
    path = Path(path)
    data, _ = read_archive(path)
    check_attention_policy(path, data)
    unknown = [key for key in pickled_entries(data) if key not in known]
    if unknown:
        raise CheckpointError(f"{path}: holds pickled entries this package never writes ({', '.join(unknown)}); "
                              "refused without reading them (unpickling can run code)")
    return {key: known[key] for key in known if key in data}


def attention_state_dict(path: Path, weights: dict[str, Any]) -> dict[str, Any]:
    """The AttentionNet state dict inside an AttentionPolicy's (``policy.pth``)."""
    out = {}
    for key, value in weights.items():
        if key.startswith(_ALIASES):
            continue
        prefix = next((p for p in _PREFIXES if key.startswith(p)), None)
        if prefix is None:
            raise CheckpointError(f"{path}: policy.pth has the tensor {key!r}, which an AttentionPolicy "
                                  f"does not; expected {EXPECTED}")
        out[_PREFIXES[prefix] + key[len(prefix):]] = value
    return out
