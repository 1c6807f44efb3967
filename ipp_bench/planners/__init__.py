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
and has a ``Config`` dataclass. A built-in name is never replaced by a plugin.
"""

from __future__ import annotations

import dataclasses
import importlib
import typing
from importlib.metadata import entry_points
from typing import Any

from .base import ContinuousPlanner, GraphPlanner, Planner, RobotView, TruthView

# name -> "module:Class"; the class has a ``Config`` dataclass attribute.
REGISTRY: dict[str, str] = {
    "random": "ipp_bench.planners.simple:RandomPlanner",
    "coverage": "ipp_bench.planners.simple:CoveragePlanner",
    "greedy": "ipp_bench.planners.greedy:GreedyPlanner",
    "mcts": "ipp_bench.planners.mcts:MCTSPlanner",
    "cmaes": "ipp_bench.planners.cmaes:CMAESPlanner",
    "attention": "ipp_bench.policies.planner:AttentionPlanner",
    "oracle": "ipp_bench.planners.oracle:OraclePlanner",
}
#: reference planners: they read the true ROI (a :class:`~ipp_bench.planners.base.TruthView`) to
#: show the room above the planners that cannot; reports show them apart, never as the best
REFERENCE_PLANNERS: tuple[str, ...] = ("oracle",)
ENTRY_POINT_GROUP = "ipp_bench.planners"
_plugins_loaded = False


def _load_plugins() -> None:
    """Add the planners other packages declare under :data:`ENTRY_POINT_GROUP` (once)."""
    global _plugins_loaded
    if _plugins_loaded:
        return
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        REGISTRY.setdefault(ep.name, ep.value)
    _plugins_loaded = True


def register(name: str, target: str) -> None:
    """Add a planner ``"module:Class"`` under ``name`` (e.g. from a plugin)."""
    REGISTRY[name] = target


def planner_names() -> list[str]:
    """Every planner name: built-in, registered, and from installed plugins."""
    _load_plugins()
    return list(REGISTRY)


def planner_class(name: str) -> type:
    _load_plugins()
    try:
        target = REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown planner {name!r}: valid are {planner_names()}") from None
    module, _, cls = target.partition(":")
    try:
        return getattr(importlib.import_module(module), cls)
    except AttributeError:
        raise ValueError(f"planner {name!r}: {module} has no {cls!r} (registered as {target!r})") from None


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
        if not eq or not key:
            raise ValueError(f"planner spec {spec!r}: {item!r} is not key=value (e.g. 'mcts:simulations=200')")
        overrides[key.strip()] = value.strip()
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


def make_config(name: str, overrides: dict[str, Any] | None = None) -> Any:
    """The planner's config dataclass with ``overrides`` (strings are converted to the field type)."""
    cls = planner_class(name)
    Config = getattr(cls, "Config", None)
    if not (isinstance(Config, type) and dataclasses.is_dataclass(Config)):
        raise ValueError(f"planner {name!r} ({REGISTRY[name]}) has no Config dataclass: a planner class "
                         "needs one, e.g. 'Config = MyConfig' with @dataclass(frozen=True) class MyConfig "
                         "(empty if it has no settings; see docs/planners.md)")
    overrides = dict(overrides or {})
    hints = typing.get_type_hints(Config)
    fields = {f.name for f in dataclasses.fields(Config)}
    unknown = set(overrides) - fields
    if unknown:
        raise ValueError(f"planner {name!r} has no setting {sorted(unknown)}: valid are {sorted(fields)}")
    values = {k: _coerce(v, hints[k], f"{name}.{k}") for k, v in overrides.items()}
    return Config(**values)


def is_reference(spec: str) -> bool:
    """Whether the planner of ``spec`` (``"oracle"``, ``"oracle:..."``) is a reference that reads the truth."""
    return parse_spec(spec)[0] in REFERENCE_PLANNERS


def view_for(planner: Any, env: Any) -> RobotView:
    """The view ``planner`` gets of ``env``: a :class:`TruthView` for the suite's reference planners,
    a :class:`RobotView` (no ground truth) for every other.

    Raises:
        ValueError: a planner that asks to read the truth (``reads_truth``) but is not one of
            :data:`REFERENCE_PLANNERS` registered here (a plugin cannot grant itself the truth).
    """
    if not getattr(planner, "reads_truth", False):
        return RobotView(env)
    name = getattr(planner, "name", "?")
    target = REGISTRY.get(name, "")
    module, _, cls = target.partition(":")
    own = (name in REFERENCE_PLANNERS and type(planner).__module__ == module
           and type(planner).__name__ == cls)
    if not own:
        raise ValueError(f"planner {name!r} sets reads_truth, but only the suite's reference planners "
                         f"{list(REFERENCE_PLANNERS)} may read the ground truth")
    return TruthView(env)


def make_planner(spec: str, **overrides: Any):
    """A planner from ``"name[:key=value,...]"``; keyword overrides win over the spec's."""
    name, spec_overrides = parse_spec(spec)
    cls = planner_class(name)
    return cls(make_config(name, {**spec_overrides, **overrides}))


__all__ = ["Planner", "GraphPlanner", "ContinuousPlanner", "RobotView", "TruthView", "REGISTRY", "REFERENCE_PLANNERS",
           "ENTRY_POINT_GROUP", "register", "is_reference", "view_for", "planner_names", "planner_class",
           "split_specs", "parse_spec", "make_config", "make_planner"]
