"""numba for the compiled kernels: the decorator every kernel is compiled with, and the check that names the
extra to install where numba is missing."""

from __future__ import annotations

try:
    import numba
except ImportError:  # pragma: no cover (the eval extra installs it)
    numba = None


def require_numba(what: str) -> None:
    """Raise, naming the extra to install, when numba is missing."""
    if numba is None:
        raise ImportError(f'{what} needs numba: pip install "ipp-bench[eval]"')


def kernel(fn):
    """``fn`` compiled (numba, cached on disk beside its module; no fast-math; the function itself without numba)."""
    if numba is None:
        return fn
    try:
        return numba.njit(cache=True, fastmath=False, nogil=True)(fn)
    except RuntimeError:  # no place numba may write its cache (a read-only install and home): compile per process
        return numba.njit(cache=False, fastmath=False, nogil=True)(fn)
