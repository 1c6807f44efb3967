"""Choice of MuJoCo's headless OpenGL backend, then the one ``import mujoco`` of the package.

MuJoCo reads ``MUJOCO_GL`` once, when it is first imported, so every module of
``ipp_bench.sim`` takes mujoco from here (``from ipp_bench.sim.gl import mujoco``).
A value the user set is respected. Otherwise the first backend whose
system library loads is chosen: EGL (headless, GPU or Mesa's llvmpipe), then
OSMesa (pure software); if neither is found, rendering is disabled and physics
still works. :func:`require_gl` gives the error, naming the apt package, raised
when a renderer cannot get a context, or at import when the backend the user
chose cannot even be loaded.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import importlib.util
import os
import sys

# backend -> (library name for ctypes.util.find_library, apt packages that provide it)
_BACKENDS: dict[str, tuple[str, str]] = {
    "egl": ("EGL", "libegl1 libgl1-mesa-dri"),
    "osmesa": ("OSMesa", "libosmesa6"),
}

INSTALL_HINT = (
    "MuJoCo needs an OpenGL backend for off-screen rendering. Install one, e.g. "
    "`apt-get install libegl1 libgl1-mesa-dri` (EGL; Mesa's llvmpipe renders without a GPU) "
    "or `apt-get install libosmesa6` (OSMesa) and set MUJOCO_GL=egl or MUJOCO_GL=osmesa "
    "before Python starts. The Python side needs `pip install \"ipp-bench[sim]\"` (mujoco, PyOpenGL)."
)


def _library_loads(name: str) -> bool:
    path = ctypes.util.find_library(name)
    candidates = [path] if path else []
    candidates += [f"lib{name}.so.1", f"lib{name}.so.8", f"lib{name}.so"]
    for candidate in candidates:
        try:
            ctypes.CDLL(candidate)
        except OSError:
            continue
        return True
    return False


def select_backend() -> str | None:
    """Sets ``MUJOCO_GL`` (and ``PYOPENGL_PLATFORM``) if unset and returns the backend.

    Returns:
        The backend name ("egl", "osmesa", or the user's own choice), or None when no backend
        library was found: MuJoCo is then imported with rendering disabled (physics still works,
        renderers raise :func:`require_gl`'s error).
    """
    requested = os.environ.get("MUJOCO_GL", "").strip().lower()
    if requested:
        return requested
    if "mujoco" in sys.modules:
        # Too late to choose: mujoco has already bound its GL context class.
        return None
    for backend, (library, _apt) in _BACKENDS.items():
        if _library_loads(library):
            os.environ["MUJOCO_GL"] = backend
            os.environ.setdefault("PYOPENGL_PLATFORM", backend)
            return backend
    os.environ["MUJOCO_GL"] = "disable"
    return None


def require_gl(error: BaseException | None = None) -> RuntimeError:
    """Returns the error to raise when no off-screen GL context can be made.

    Args:
        error: the underlying failure, if any, whose text is appended.
    """
    backend = os.environ.get("MUJOCO_GL", "") or "<unset>"
    if backend in _BACKENDS:
        library, apt = _BACKENDS[backend]
        what = f"lib{library} is missing or unusable; `apt-get install {apt}` provides it."
    else:
        what = ("no EGL or OSMesa library was found (`apt-get install libegl1 libgl1-mesa-dri` or "
                "`apt-get install libosmesa6`).")
    detail = f" ({type(error).__name__}: {error})" if error is not None else ""
    return RuntimeError(f"Cannot create an off-screen OpenGL context with MUJOCO_GL={backend}: {what}{detail} "
                        + INSTALL_HINT)


BACKEND = select_backend()

try:
    import mujoco  # noqa: E402  (deliberately after the backend choice)
except ImportError as _err:  # pragma: no cover - depends on the installation
    if importlib.util.find_spec("mujoco") is None:
        raise ImportError(f'ipp_bench.sim needs MuJoCo ({_err}): pip install "ipp-bench[sim]"') from _err
    raise require_gl(_err) from _err
except Exception as _err:  # pragma: no cover - e.g. PyOpenGL failing on a missing libOSMesa
    raise require_gl(_err) from _err

__all__ = ["BACKEND", "INSTALL_HINT", "mujoco", "require_gl", "select_backend"]
