"""ipp-bench: benchmark suite and toolkit for adaptive 3D informative path planning.

The core (config, belief, sensor, fields, roadmap, metrics, mission) needs only numpy and scipy.
``import ipp_bench.envs`` registers the gymnasium tasks under the ``ipp_bench/`` namespace.
"""

__version__ = "0.1.0"
