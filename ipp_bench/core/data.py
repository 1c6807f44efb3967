"""Where files are: the data folders (``tasks/``, ``assets/``, ``baselines/``) and output paths.

In a wheel the data folders travel inside the package as ``ipp_bench/_data/<name>``; in a source
checkout or an editable install they are the top-level folders of the repository. Output paths
(``--out``, ``--render``, demo videos) are checked with :func:`check_output_dir` and
:func:`check_output_file` before any episode runs, so a typo never costs a finished run.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parents[1]  # ipp_bench/, above core/


def data_dir(name: str) -> Path:
    """The folder ``name`` (``"tasks"``, ``"assets"``, ``"baselines"``) of the installed suite."""
    for candidate in (_PACKAGE / "_data" / name, _PACKAGE.parent / name):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(
        f"ipp_bench data folder {name!r} not found in {_PACKAGE / '_data'} nor {_PACKAGE.parent}: "
        "reinstall the package (pip install ipp-bench) or run from a full checkout")


def check_output_dir(folder: str | Path, what: str = "--out") -> Path:
    """``folder`` as a Path, if it exists as a writable folder or can be created (nothing is created).

    Raises:
        ValueError: an empty path, a file in the way, or the first existing folder on the way is
            not writable.
    """
    if not str(folder).strip():  # Path("") is the current folder: never what was meant
        raise ValueError(f"{what} {str(folder)!r} is empty: expected a folder path")
    folder = Path(folder)
    existing = next((p for p in (folder, *folder.parents) if p.exists()), None)
    if existing is not None and not existing.is_dir():
        raise ValueError(f"{what} {folder} cannot be written: {existing} is a file, not a folder")
    if existing is not None and not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"{what} {folder} cannot be written: {existing} is not writable")
    return folder


def check_output_file(path: str | Path, what: str, suffix: str | None = None) -> Path:
    """``path`` as a Path, if a file can be written there (suffix checked; nothing is created).

    Raises:
        ValueError: wrong suffix, ``path`` is a folder, or its folder cannot be written.
    """
    if not str(path).strip():
        raise ValueError(f"{what} {str(path)!r} is empty: expected a file path")
    path = Path(path)
    if suffix is not None and path.suffix.lower() != suffix:
        raise ValueError(f"{what} {str(path)!r} is invalid: expected a {suffix} file")
    if path.is_dir():
        raise ValueError(f"{what} {path} is a folder: expected a file path")
    if path.exists() and not os.access(path, os.W_OK):
        raise ValueError(f"{what} {path} cannot be written: the file is read-only")
    check_output_dir(path.parent, what=f"{what} {path}: the folder")
    return path


class OutputWriteError(OSError):
    """A file could not be written (full disk, quota, ...): the message names it and the cause."""


def temporary_sibling(path: str | Path) -> Path:
    """The temporary file an atomic write of ``path`` goes through: hidden, beside it (the same file
    system, so the rename is atomic), with its suffix (writers choose the format by it)."""
    path = Path(path)
    return path.with_name(f".{path.stem}.tmp{os.getpid()}{path.suffix}")


def write_atomically(path: str | Path, write: Callable[[Path], None]) -> Path:
    """Write ``path`` through ``write(tmp)`` into a temporary sibling (same suffix), then rename it
    into place: ``path`` is complete or untouched, never truncated. The file's content is fsync'ed
    before the rename and its folder after it, so the new content survives a power cut once this
    returns. On failure (a full disk, say) the temporary file is removed.

    Raises:
        OutputWriteError: naming ``path`` and the cause.
    """
    path = Path(path)
    tmp = temporary_sibling(path)
    try:
        write(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as err:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise OutputWriteError(f"cannot write {path}: {err.strerror or err}") from None
    _fsync_folder(path.parent)
    return path


def _fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable (fsync of the folder itself); a no-op where the platform or
    the file system refuses it (Windows cannot open a folder; some network file systems)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
