"""Where the data folders (``tasks/``, ``assets/``, ``baselines/``) are.

In a wheel they travel inside the package as ``ipp_bench/_data/<name>``; in a source checkout or an
editable install they are the top-level folders of the repository.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent


def data_dir(name: str) -> Path:
    """The folder ``name`` (``"tasks"``, ``"assets"``, ``"baselines"``) of the installed suite."""
    for candidate in (_PACKAGE / "_data" / name, _PACKAGE.parent / name):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(
        f"ipp_bench data folder {name!r} not found in {_PACKAGE / '_data'} nor {_PACKAGE.parent}: "
        "reinstall the package (pip install ipp-bench) or run from a full checkout")
