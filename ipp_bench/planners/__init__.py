"""Planner registry: every planner by name, with a typed config overridable from a spec string.

``make_planner("mcts:simulations=200,exploration=0.5")`` builds the MCTS planner with two fields of
its config replaced. Planner modules are imported lazily, so ``attention`` (torch) costs nothing
until it is asked for.

Planners of other packages join through the ``ipp_bench.planners`` entry-point group (the way
gymnasium and pytest find plugins): a package declaring, in its ``pyproject.toml``,

    [project.entry-points."ipp_bench.planners"]
    theirs = "their_package.module:TheirPlanner"

is found by name (``ipp-bench leaderboard --planners theirs``) once installed. The class follows
:class:`~ipp_bench.planners.base.GraphPlanner` or :class:`~ipp_bench.planners.base.ContinuousPlanner`
and has a ``Config`` dataclass. A built-in name is never replaced by a plugin. A plugin whose import,
``Config`` or constructor raises (or calls ``sys.exit``) is refused in one line naming its entry point,
what it raised and where (:class:`PlannerError`).

The suite's registry is :data:`REGISTRY`, a :class:`PlannerRegistry`. An experiment's probe planners
go into a registry of their own, which the suite's never sees::

    probes = REGISTRY.copy()  # the suite's planners, and room for more
    probes.register("knob", KnobGreedy)  # a class, or "module:Class"
    fly_episode(env, "knob:power=1.2", seed, registry=probes)  # or probes.make_planner("knob:power=1.2")
"""

from __future__ import annotations

import dataclasses
import importlib
import traceback
import typing
from collections.abc import Iterator, Mapping, MutableMapping
from importlib.metadata import entry_points
from types import MappingProxyType
from typing import Any

from .base import ContinuousPlanner, GraphPlanner, Planner, RobotView, TeamRobotView, TeamTruthView, TruthView

#: the planners of this layer: name -> "module:Class"; the class has a ``Config`` dataclass attribute.
#: The suite's planners of the layers above (``attention``, in :mod:`ipp_bench.policies`) join through
#: the entry point a plugin uses, declared in the suite's own ``pyproject.toml``: a plain import here
#: would point upward, and the import-linter contracts would refuse it.
BUILT_IN: Mapping[str, str] = MappingProxyType({
    "random": "ipp_bench.planners.simple:RandomPlanner",
    "coverage": "ipp_bench.planners.simple:CoveragePlanner",
    "greedy": "ipp_bench.planners.greedy:GreedyPlanner",
    "mcts": "ipp_bench.planners.mcts:MCTSPlanner",
    "cmaes": "ipp_bench.planners.cmaes:CMAESPlanner",
    "oracle": "ipp_bench.planners.oracle:OraclePlanner",
    "team-greedy": "ipp_bench.planners.team:TeamGreedyPlanner",
    "team-coverage": "ipp_bench.planners.team:TeamCoveragePlanner",
    "team-oracle": "ipp_bench.planners.team:TeamOraclePlanner",
})
#: reference planners: they read the true ROI (a :class:`~ipp_bench.planners.base.TruthView`) to
#: show the room above the planners that cannot; reports show them apart, never as the best
REFERENCE_PLANNERS: tuple[str, ...] = ("oracle", "team-oracle")
ENTRY_POINT_GROUP = "ipp_bench.planners"
#: the distribution whose entry points are the suite's own planners (not plugins)
SUITE_DISTRIBUTION = "ipp-bench"


def _installed_planners() -> tuple[dict[str, str], dict[str, str]]:
    """The planners installed under :data:`ENTRY_POINT_GROUP`: (the suite's own, the plugins'), each
    name -> ``"module:Class"``."""
    own: dict[str, str] = {}
    plugins: dict[str, str] = {}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        dist = getattr(ep, "dist", None)
        name = (getattr(dist, "name", None) or "").replace("_", "-").lower()
        (own if name == SUITE_DISTRIBUTION else plugins).setdefault(ep.name, ep.value)
    return own, plugins


class PlannerRegistry(MutableMapping):
    """Planner names -> ``"module:Class"`` targets, and the planners built from them.

    A mapping (``registry[name]`` is the target), so ``monkeypatch.setitem`` and ``dict(registry)``
    work on it. :data:`REGISTRY` is the suite's (its built-in planners and the installed plugins);
    ``REGISTRY.copy()`` or ``PlannerRegistry(...)`` make local ones.

    Args:
        targets: name -> ``"module:Class"`` or the class itself.
        plugins: whether the planners installed under :data:`ENTRY_POINT_GROUP` join, on first use
            (never replacing a name already here).
    """

    def __init__(self, targets: Mapping[str, Any] | None = None, *, plugins: bool = False) -> None:
        self._targets: dict[str, str] = {}
        self._classes: dict[str, type] = {}  # names registered with a class, not an importable target
        self._entry_points: set[str] = set()  # names that came from an installed plugin's entry point
        self._suite: set[str] = set()  # names that came from the suite's own entry points (attention)
        self._plugins_pending = False
        for name, target in (targets or {}).items():
            self.register(name, target)
        self._plugins_pending = plugins

    def _loaded(self) -> dict[str, str]:
        """The targets, with the installed plugins added once (if this registry takes them)."""
        if self._plugins_pending:
            self._plugins_pending = False
            own, plugins = _installed_planners()
            own = {n: t for n, t in own.items() if n not in self._targets}
            if own:  # listed among the suite's planners, before its references (the order of the reports)
                names = list(self._targets)
                at = next((i for i, n in enumerate(names) if n in REFERENCE_PLANNERS), len(names))
                self._targets = {**{n: self._targets[n] for n in names[:at]}, **own,
                                 **{n: self._targets[n] for n in names[at:]}}
                self._suite.update(own)
            for name, target in plugins.items():
                if name not in self._targets:
                    self._targets[name] = target
                    self._entry_points.add(name)
        return self._targets

    # -- the mapping ------------------------------------------------------------------------------
    def __getitem__(self, name: str) -> str:
        return self._loaded()[name]

    def __setitem__(self, name: str, target: Any) -> None:
        self.register(name, target)

    def __delitem__(self, name: str) -> None:
        del self._loaded()[name]
        self._classes.pop(name, None)
        self._entry_points.discard(name)
        self._suite.discard(name)

    def __iter__(self) -> Iterator[str]:
        return iter(list(self._loaded()))

    def __len__(self) -> int:
        return len(self._loaded())

    def __repr__(self) -> str:
        return f"PlannerRegistry({self._loaded()!r})"

    # -- registering ------------------------------------------------------------------------------
    def register(self, name: str, target: Any) -> None:
        """Add (or replace) the planner ``name``: ``"module:Class"`` or the class itself."""
        if not isinstance(name, str) or not name or ":" in name or "," in name or name != name.strip():
            raise ValueError(f"planner name {name!r} is invalid: expected a non-empty word without ':' or ','")
        if isinstance(target, type):
            self._classes[name] = target
            target = f"{target.__module__}:{target.__qualname__}"
        elif isinstance(target, str) and target.count(":") == 1 and all(target.partition(":")[::2]):
            self._classes.pop(name, None)
        else:
            raise ValueError(f"planner {name!r}: target {target!r} is invalid: expected 'module:Class' or a class")
        self._loaded()[name] = target
        self._entry_points.discard(name)
        self._suite.discard(name)

    def copy(self) -> PlannerRegistry:
        """A local registry with this one's planners (plugins included): what is registered there stays there."""
        out = PlannerRegistry()
        out._targets = dict(self._loaded())
        out._classes = dict(self._classes)
        out._entry_points = set(self._entry_points)
        out._suite = set(self._suite)
        return out

    # -- building ---------------------------------------------------------------------------------
    def names(self) -> list[str]:
        """Every planner name here."""
        return list(self._loaded())

    def planner_class(self, name: str) -> type:
        """The class of the planner ``name`` (ValueError naming the valid ones if there is none)."""
        try:
            target = self._loaded()[name]
        except KeyError:
            raise ValueError(f"unknown planner {name!r}: valid are {self.names()}") from None
        if name in self._classes:
            return self._classes[name]
        module, _, cls = target.partition(":")
        try:
            loaded = importlib.import_module(module)
        except (Exception, SystemExit) as err:
            if isinstance(err, ImportError) and self._built_in(name):
                raise  # the suite's own: its message names the extra to install
            raise PlannerError(f"{self.describe(name)}: importing {module} raised {what_raised(err)}") from err
        try:
            return getattr(loaded, cls)
        except AttributeError:
            raise ValueError(f"planner {name!r}: {module} has no {cls!r} (registered as {target!r})") from None

    def _built_in(self, name: str) -> bool:
        return name not in self._classes and (name in self._suite or BUILT_IN.get(name) == self._loaded().get(name))

    def describe(self, name: str) -> str:
        """Where a planner came from, for messages: ``planner 'theirs' (entry point 'theirs = module:Class' of
        'ipp_bench.planners')`` for a plugin, else ``planner 'name' (module:Class)``."""
        target = self._loaded().get(name, "?")
        if name in self._entry_points:
            return f"planner {name!r} (entry point '{name} = {target}' of {ENTRY_POINT_GROUP!r})"
        return f"planner {name!r} ({target})"

    def make_config(self, name: str, overrides: dict[str, Any] | None = None) -> Any:
        """The planner's config dataclass with ``overrides`` (strings are converted to the field type)."""
        cls = self.planner_class(name)
        Config = getattr(cls, "Config", None)
        if not (isinstance(Config, type) and dataclasses.is_dataclass(Config)):
            raise ValueError(f"planner {name!r} ({self[name]}) has no Config dataclass: a planner class "
                             "needs one, e.g. 'Config = MyConfig' with @dataclass(frozen=True) class MyConfig "
                             "(empty if it has no settings; see docs/planners.md)")
        overrides = dict(overrides or {})
        hints = typing.get_type_hints(Config)
        fields = {f.name for f in dataclasses.fields(Config)}
        unknown = set(overrides) - fields
        if unknown:
            raise ValueError(f"planner {name!r} has no setting {sorted(unknown)}: valid are {sorted(fields)}")
        values = {k: _coerce(v, hints[k], f"{name}.{k}") for k, v in overrides.items()}
        try:
            return Config(**values)
        except ValueError:
            raise  # a setting refused, in the config's own words
        except (Exception, SystemExit) as err:
            raise PlannerError(f"{self.describe(name)}: its Config raised {what_raised(err)}") from err

    def make_planner(self, spec: str, **overrides: Any) -> Any:
        """A planner from ``"name[:key=value,...]"``; keyword overrides win over the spec's."""
        name, spec_overrides = parse_spec(spec)
        cls = self.planner_class(name)
        config = self.make_config(name, {**spec_overrides, **overrides})
        try:
            return cls(config)
        except ValueError:
            raise  # a setting refused (a checkpoint that does not load, say), in the planner's own words
        except (Exception, SystemExit) as err:
            if isinstance(err, ImportError) and self._built_in(name):
                raise  # the suite's own: its message names the extra to install
            raise PlannerError(f"{self.describe(name)}: building it raised {what_raised(err)}") from err


class PlannerError(ValueError):
    """A planner that cannot be loaded, built or started: its import, constructor or ``reset`` raised
    (or called ``sys.exit``). One line: the planner, where it came from, what it raised and where."""


def what_raised(err: BaseException) -> str:
    """``"RuntimeError: boom (at their_planners/__init__.py:7)"``: an exception in one line, with the
    innermost source line it came from (``sys.exit(3)`` reads ``SystemExit (sys.exit(3))``)."""
    text = " ".join(str(err).split()) or "(no message)"
    if isinstance(err, SystemExit):
        return f"SystemExit (sys.exit({err.code!r})) (at {_where(err)})"
    return f"{type(err).__name__}: {text} (at {_where(err)})"


def _where(err: BaseException) -> str:
    if isinstance(err, SyntaxError) and err.filename:
        return f"{err.filename}:{err.lineno}"
    frames = [f for f in traceback.extract_tb(err.__traceback__) if not f.filename.startswith("<frozen ")]
    return f"{frames[-1].filename}:{frames[-1].lineno}" if frames else "?"


#: the suite's registry: the built-in planners, the suite's own entry points, then the installed plugins
REGISTRY = PlannerRegistry(BUILT_IN, plugins=True)


def _registry(registry: PlannerRegistry | None) -> PlannerRegistry:
    """``registry``, or the suite's: :data:`REGISTRY` as this module holds it now (every default is looked up here,
    so that one registry swapped in is the suite's everywhere)."""
    return REGISTRY if registry is None else registry


def register(name: str, target: Any, registry: PlannerRegistry | None = None) -> None:
    """Add a planner (``"module:Class"`` or the class) under ``name`` to ``registry`` (default: the
    suite's, :data:`REGISTRY`; a probe goes into a registry of its own)."""
    _registry(registry).register(name, target)


def planner_names(registry: PlannerRegistry | None = None) -> list[str]:
    """Every planner name of ``registry`` (default: the suite's: built-in, registered, and from plugins)."""
    return _registry(registry).names()


def planner_class(name: str, registry: PlannerRegistry | None = None) -> type:
    """The class of the planner ``name`` in ``registry`` (default: the suite's)."""
    return _registry(registry).planner_class(name)


def is_team_planner(name: str, registry: PlannerRegistry | None = None) -> bool:
    """Whether planner ``name`` is team-aware (``team-greedy``, ...; on one UAV it flies as its
    single-UAV counterpart)."""
    return bool(getattr(planner_class(name, registry), "team", False))


def split_specs(items: typing.Iterable[str]) -> list[str]:
    """Planner specs from command-line words, where a word may hold several, comma-separated:
    ``["random,coverage", "mcts:simulations=8,exploration=0.5,greedy"]`` ->
    ``["random", "coverage", "mcts:simulations=8,exploration=0.5", "greedy"]``. A comma part with
    ``=`` and no ``:`` is a setting of the spec before it.
    """
    specs: list[str] = []
    for item in items:
        for part in item.split(","):
            part = part.strip()
            if not part:
                continue
            if "=" in part and ":" not in part and specs and ":" in specs[-1]:
                specs[-1] += "," + part
            else:
                specs.append(part)
    return specs


def parse_spec(spec: str) -> tuple[str, dict[str, str]]:
    """``"mcts:simulations=200,exploration=0.5"`` -> ``("mcts", {"simulations": "200", ...})``."""
    name, _, rest = spec.partition(":")
    overrides: dict[str, str] = {}
    for item in filter(None, (p.strip() for p in rest.split(","))):
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise ValueError(f"planner spec {spec!r}: {item!r} is not key=value (e.g. 'mcts:simulations=200')")
        key = key.strip()
        if key in overrides:
            raise ValueError(f"planner spec {spec!r}: setting {key!r} is given twice ({key}={overrides[key]} and "
                             f"{key}={value.strip()}): give each setting once")
        overrides[key] = value.strip()
    return name.strip(), overrides


def _coerce(value: Any, kind: Any, where: str) -> Any:
    if not isinstance(value, str):
        return value
    origin = typing.get_origin(kind)
    args = typing.get_args(kind)
    if origin is typing.Union or (origin is not None and type(None) in args):
        if value.lower() in ("none", "null", ""):
            return None
        kind = next(a for a in args if a is not type(None))
    try:
        if kind is bool:
            if value.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError
            return value.lower() in ("true", "1", "yes")
        if kind in (int, float, str):
            return kind(value)
    except ValueError:
        name = {int: "an integer", float: "a number", str: "a string"}.get(kind, f"a {getattr(kind, '__name__', kind)}")
        raise ValueError(f"{where} = {value!r} is invalid: expected {name}") from None
    return value


def make_config(name: str, overrides: dict[str, Any] | None = None, registry: PlannerRegistry | None = None) -> Any:
    """The planner's config dataclass with ``overrides`` (strings are converted to the field type)."""
    return _registry(registry).make_config(name, overrides)


def is_reference(spec: str) -> bool:
    """Whether the planner of ``spec`` (``"oracle"``, ``"oracle:..."``) is a reference that reads the truth."""
    return parse_spec(spec)[0] in REFERENCE_PLANNERS


def view_for(planner: Any, env: Any) -> RobotView:
    """The view ``planner`` gets of ``env``: a :class:`TruthView` for the suite's reference planners,
    a :class:`RobotView` (no ground truth) for every other; their team forms
    (:class:`TeamRobotView`, :class:`TeamTruthView`) for a UAV of a team and for a team-aware planner.

    Raises:
        ValueError: a planner that asks to read the truth (``reads_truth``) but is not one of
            :data:`REFERENCE_PLANNERS` as :data:`BUILT_IN` names it (neither a plugin nor a planner of a
            local registry can grant itself the truth).
    """
    # a UAV of a team (ipp_bench.envs.team.UAVSeat), or a team-aware planner on one UAV (a team of one)
    team = getattr(env, "team_env", None) is not None or getattr(planner, "team", False)
    if not getattr(planner, "reads_truth", False):
        return TeamRobotView(env) if team else RobotView(env)
    name = getattr(planner, "name", "?")
    target = BUILT_IN.get(name, "")
    module, _, cls = target.partition(":")
    own = (name in REFERENCE_PLANNERS and type(planner).__module__ == module
           and type(planner).__name__ == cls)
    if not own:
        raise ValueError(f"planner {name!r} sets reads_truth, but only the suite's reference planners "
                         f"{list(REFERENCE_PLANNERS)} may read the ground truth")
    return TeamTruthView(env) if team else TruthView(env)


def make_planner(spec: str, *, registry: PlannerRegistry | None = None, **overrides: Any):
    """A planner from ``"name[:key=value,...]"`` of ``registry`` (default: the suite's); keyword overrides
    win over the spec's."""
    return _registry(registry).make_planner(spec, **overrides)


__all__ = ["Planner", "GraphPlanner", "ContinuousPlanner", "RobotView", "TruthView", "BUILT_IN", "REGISTRY",
           "REFERENCE_PLANNERS", "ENTRY_POINT_GROUP", "PlannerRegistry", "PlannerError",
           "what_raised", "register", "is_reference", "is_team_planner", "view_for",
           "planner_names", "planner_class", "split_specs", "parse_spec", "make_config", "make_planner"]
