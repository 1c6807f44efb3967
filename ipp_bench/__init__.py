"""ipp-bench: benchmark suite and toolkit for adaptive 3D informative path planning.

``import ipp_bench`` makes the gymnasium tasks of the ``ipp_bench/`` namespace available to
``gym.make``, as minigrid and highway-env do (``gym.register_envs(ipp_bench)`` says so to a linter).
:mod:`ipp_bench.envs` registers them, once: at once if gymnasium is loaded already, else as soon as
it is (Gymnasium 1.x reads no plugin entry points, so the package's import is the hook). Until then
nothing of gymnasium is loaded: the core, :mod:`ipp_bench.core`, needs numpy and scipy only.
"""

import importlib.abc
import importlib.util
import sys

__version__ = "0.2.0"


def _register_tasks() -> None:
    from . import envs  # noqa: F401  (registers the tasks with gymnasium)


class _RegisterAfterGymnasium(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds ``gymnasium`` with the other finders, lets it load, then registers the tasks."""

    def find_spec(self, name, path=None, target=None):
        if name != "gymnasium" or self not in sys.meta_path:
            return None
        sys.meta_path.remove(self)  # once; the lookup below goes to the other finders
        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None:
            return spec
        self._loader = spec.loader
        spec.loader = self
        return spec

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module):
        self._loader.exec_module(module)
        _register_tasks()


if sys.modules.get("gymnasium") is not None:
    _register_tasks()
elif not any(isinstance(f, _RegisterAfterGymnasium) for f in sys.meta_path):
    sys.meta_path.insert(0, _RegisterAfterGymnasium())
