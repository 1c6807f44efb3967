"""ipp-bench: benchmark suite and toolkit for adaptive 3D informative path planning.

The core (config, belief, sensor, fields, roadmap, metrics, mission) needs only numpy and scipy.
``import ipp_bench`` registers the gymnasium tasks under the ``ipp_bench/`` namespace, as
minigrid and highway-env do (``gym.register_envs(ipp_bench)`` says so to a linter).
"""

__version__ = "0.2.0"

from .envs.registry import register_all as _register_all  # noqa: E402

_register_all()
