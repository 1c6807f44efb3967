"""Where a leaderboard's rows are made: the machine ``run.json`` records beside its fingerprint.

Not part of the fingerprint (the same arguments give the same numbers on any machine, up to the last
bits of the BLAS kernels and the libraries' versions), but said in the report, so that a reader
knows where a board's rows come from. A folder recorded before a key was added (the BLAS kernels,
more libraries) is still the same machine where what it records agrees (:func:`same_machine`).
"""

from __future__ import annotations

import os
import platform
from typing import Any

#: the CPU flags that change floating-point results (which BLAS kernels run, fused multiply-adds)
FLOAT_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f")
#: the packages whose versions can move a row, recorded where installed: name recorded -> its distributions
#: (numba: the fast MCTS and CMA-ES searches; cma: CMA-ES; gymnasium, PettingZoo: the environments; SB3,
#: sb3-contrib: the attention policy; OpenCV: the MuJoCo camera's blur, under whichever wheel is installed)
RECORDED_PACKAGES: dict[str, tuple[str, ...]] = {
    "numpy": ("numpy",), "scipy": ("scipy",), "torch": ("torch",), "mujoco": ("mujoco",),
    "dm-control": ("dm-control",), "numba": ("numba",), "cma": ("cma",), "gymnasium": ("gymnasium",),
    "pettingzoo": ("pettingzoo",), "stable-baselines3": ("stable-baselines3",), "sb3-contrib": ("sb3-contrib",),
    "opencv": ("opencv-python-headless", "opencv-python", "opencv-contrib-python-headless",
               "opencv-contrib-python"),
}


def blas_info() -> list[dict[str, str]]:
    """The BLAS libraries numpy and scipy load and the kernels they picked for this CPU (threadpoolctl,
    after importing both: before, it finds none): per library its ``api`` (openblas, mkl, ...),
    ``version``, ``architecture`` (OpenBLAS's kernel set, e.g. SkylakeX or Haswell) and the package it
    ships with (``of``)."""
    import numpy  # noqa: F401  (loads its BLAS)
    import scipy.linalg  # noqa: F401  (loads scipy's, where it has its own)
    from threadpoolctl import threadpool_info

    out = []
    for lib in threadpool_info():
        if lib.get("user_api") != "blas":
            continue
        folder = os.path.basename(os.path.dirname(lib.get("filepath") or ""))
        entry = {"api": str(lib.get("internal_api")), "version": str(lib.get("version")),
                 "of": folder.removesuffix(".libs") or os.path.basename(lib.get("filepath") or "?")}
        if lib.get("architecture"):
            entry["architecture"] = str(lib["architecture"])
        if entry not in out:
            out.append(entry)
    return out


def machine_info() -> dict[str, Any]:
    """Where rows are made: CPU model, the flags of :data:`FLOAT_FLAGS` it has, cores, OS, Python,
    the versions of :data:`RECORDED_PACKAGES` that are installed (read from their metadata, not
    imported) and the BLAS kernels numpy and scipy use (:func:`blas_info`)."""
    from importlib.metadata import PackageNotFoundError, version

    cpu, flags = platform.processor() or platform.machine(), set()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                if key.strip() == "model name" and cpu in ("", platform.processor() or platform.machine()):
                    cpu = value.strip()
                elif key.strip() in ("flags", "Features") and not flags:
                    flags = set(value.split())
    except OSError:  # no /proc (not Linux): the model from platform, no flags
        pass
    packages = {}
    for name, dists in RECORDED_PACKAGES.items():
        for dist in dists:
            try:
                packages[name] = version(dist)
                break
            except PackageNotFoundError:
                continue
    return {"cpu": cpu, "cpu_flags": [f for f in FLOAT_FLAGS if f in flags], "cores": os.cpu_count(),
            "os": f"{platform.system()} {platform.machine()}", "python": platform.python_version(),
            "packages": packages, "blas": blas_info()}


def same_machine(recorded: dict[str, Any], here: dict[str, Any]) -> bool:
    """Whether rows made ``here`` come from the machine ``recorded`` (a run.json's ``machine``): the same
    in everything it records. What it does not record (a library or the BLAS kernels, recorded since)
    does not make another machine of it."""
    for key, value in recorded.items():
        if key == "packages" and isinstance(value, dict):
            if any(here.get("packages", {}).get(k) != v for k, v in value.items()):
                return False
        elif here.get(key) != value:
            return False
    return True


def describe_machine(info: dict[str, Any]) -> str:
    """One line of :func:`machine_info`: ``CPU (N cores; avx2, fma), OS; Python X, numpy Y, ...``."""
    flags = ", ".join(info.get("cpu_flags") or []) or "no vector flags known"
    packages = ", ".join(f"{k} {v}" for k, v in (info.get("packages") or {}).items())
    blas = "; ".join(f"{b.get('of', '?')}'s {b.get('api', '?')} {b.get('version', '?')}"
                     + (f" ({b['architecture']} kernels)" if b.get("architecture") else "")
                     for b in info.get("blas") or [])
    return (f"{info.get('cpu', '?')} ({info.get('cores', '?')} cores; {flags}), {info.get('os', '?')}; "
            f"Python {info.get('python', '?')}" + (f", {packages}" if packages else "") + (f"; {blas}" if blas else ""))


__all__ = ["FLOAT_FLAGS", "RECORDED_PACKAGES", "blas_info", "describe_machine", "machine_info", "same_machine"]
