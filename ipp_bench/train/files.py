"""Files of a run folder written whole or not at all (temporary file, then rename), and read back
with one line naming the file when damaged."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ipp_bench.core.data import write_atomically


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file beside it: an interrupt or a full disk
    leaves the old file and no temporary one (:func:`ipp_bench.core.data.write_atomically`)."""
    write_atomically(path, lambda tmp: tmp.write_text(text))


def write_json_atomic(path: Path, data: Any) -> None:
    write_text_atomic(path, json.dumps(data, indent=2, sort_keys=True) + "\n")


def read_json(path: Path, what: str) -> dict:
    """``path``'s JSON object, or ValueError (one line naming the file and what it holds)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"{path} is damaged ({' '.join(str(err).split())}); it holds the run's {what}: "
                         "restore it, or start a new --out") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path} is damaged (a JSON {type(data).__name__}, expected an object); it holds the "
                         f"run's {what}: restore it, or start a new --out")
    return data
