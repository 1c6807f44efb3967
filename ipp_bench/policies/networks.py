"""The networks an ``attention`` spec names: one checkpoint, or a method flown over several.

``checkpoint=PATH`` names one trained network. ``checkpoint=A.pt+B.pt+C.pt`` names a *method*: the
networks of several training runs (seeds) of one recipe, in this order; the leaderboard flies
episode i of its seed list with network i mod k (:mod:`ipp_bench.eval.methods`) and its report
resamples the networks as well as the episodes. ``checkpoint=NAME`` (no folder, no suffix) names the
shipped set ``NAME_seed*.pt`` in :data:`CHECKPOINT_DIR`, in the order of the seed numbers.

Torch-free: the planner's config parses and checks the names (:func:`checkpoint_set`) wherever a spec
is read; the networks are loaded by the planner.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

#: the shipped checkpoints (the same folder :mod:`ipp_bench.policies.checkpoint` reads)
CHECKPOINT_DIR = Path(__file__).resolve().parent / "checkpoints"
#: between the checkpoints of a method (a spec separates settings with commas)
SEPARATOR = "+"
#: the most networks one method may name
MAX_NETWORKS = 64
_SEED_FILE = re.compile(r"_seed(\d+)\.pt$")


def shipped_set(name: str, folder: Path | None = None) -> list[Path]:
    """The shipped checkpoints ``NAME_seed<N>.pt`` of ``folder`` (default :data:`CHECKPOINT_DIR`), by N."""
    folder = CHECKPOINT_DIR if folder is None else folder
    found = [(int(m.group(1)), p) for p in folder.glob(f"{name}_seed*.pt")
             if (m := _SEED_FILE.search(p.name)) and p.name == f"{name}_seed{m.group(1)}.pt"]
    return [p for _, p in sorted(found)]


def checkpoint_set(value: str, folder: Path | None = None) -> tuple[str, tuple[str, ...]]:
    """The networks ``checkpoint=value`` names: (the value as a spec keeps it, the path of each network).

    ``""`` is the shipped default (no path: the planner loads it); ``A.pt+B.pt`` a method of those files,
    in that order; a bare name whose shipped set ``NAME_seed*.pt`` exists, that set; anything else one path.

    Raises:
        ValueError: one line: an empty part, more than :data:`MAX_NETWORKS` networks, a file of a method
            that is missing or unreadable, or one listed twice.
    """
    value = value.strip()
    if not value:
        return "", ()
    if SEPARATOR not in value:
        if os.sep not in value and "." not in value and not Path(value).exists():
            paths = shipped_set(value, folder)
            if paths:
                return value, tuple(str(p) for p in paths)
        return value, (value,)
    parts = [p.strip() for p in value.split(SEPARATOR)]
    if not all(parts):
        raise ValueError(f"attention.checkpoint = {value!r} is invalid: an empty name between '{SEPARATOR}'s; "
                         f"expected checkpoint files joined by '{SEPARATOR}' (A.pt{SEPARATOR}B.pt)")
    if len(parts) > MAX_NETWORKS:
        raise ValueError(f"attention.checkpoint names {len(parts)} networks: at most {MAX_NETWORKS}")
    seen: dict[str, int] = {}
    for i, part in enumerate(parts):
        path = Path(part)
        if not path.is_file() or not os.access(path, os.R_OK):
            why = "no such file" if not path.exists() else ("not a file" if not path.is_file() else "unreadable")
            raise ValueError(f"attention.checkpoint: network {i + 1} of {len(parts)}, {part}, cannot be read "
                             f"({why}); name existing checkpoint files joined by '{SEPARATOR}'")
        real = os.path.realpath(path)
        if real in seen:
            raise ValueError(f"attention.checkpoint: {part} is listed twice (networks {seen[real] + 1} and {i + 1}): "
                             "a method's networks are distinct training runs; name each once")
        seen[real] = i
    return SEPARATOR.join(parts), tuple(parts)


__all__ = ["CHECKPOINT_DIR", "MAX_NETWORKS", "SEPARATOR", "checkpoint_set", "shipped_set"]
