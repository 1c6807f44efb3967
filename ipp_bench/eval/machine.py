"""Where a leaderboard's rows are made: the machine ``run.json`` records beside its fingerprint.

Not part of the fingerprint (the same arguments give the same numbers on any machine, up to the last
bits of the BLAS kernels and the libraries' versions), but said in the report, so that a reader
knows where a board's rows come from.
"""

from __future__ import annotations

import os
import platform
from typing import Any

#: the CPU flags that change floating-point results (which BLAS kernels run, fused multiply-adds)
FLOAT_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f")
#: the packages whose versions decide the numbers, recorded where installed
RECORDED_PACKAGES = ("numpy", "scipy", "torch", "mujoco", "dm-control")


def machine_info() -> dict[str, Any]:
    """Where rows are made: CPU model, the flags of :data:`FLOAT_FLAGS` it has, cores, OS, Python
    and the versions of :data:`RECORDED_PACKAGES` that are installed (none is imported)."""
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
    for name in RECORDED_PACKAGES:
        try:
            packages[name] = version(name)
        except PackageNotFoundError:
            continue
    return {"cpu": cpu, "cpu_flags": [f for f in FLOAT_FLAGS if f in flags], "cores": os.cpu_count(),
            "os": f"{platform.system()} {platform.machine()}", "python": platform.python_version(),
            "packages": packages}


def describe_machine(info: dict[str, Any]) -> str:
    """One line of :func:`machine_info`: ``CPU (N cores; avx2, fma), OS; Python X, numpy Y, ...``."""
    flags = ", ".join(info.get("cpu_flags") or []) or "no vector flags known"
    packages = ", ".join(f"{k} {v}" for k, v in (info.get("packages") or {}).items())
    return (f"{info.get('cpu', '?')} ({info.get('cores', '?')} cores; {flags}), {info.get('os', '?')}; "
            f"Python {info.get('python', '?')}" + (f", {packages}" if packages else ""))


__all__ = ["describe_machine", "machine_info"]
