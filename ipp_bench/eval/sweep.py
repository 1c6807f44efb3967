"""A planner flown over a range of one setting (``ipp-bench leaderboard --sweep``).

``--sweep mcts:simulations=8,24,64`` is three planner specs, ``mcts:simulations=8``, ``mcts:simulations=24`` and
``mcts:simulations=64`` (canonical, :func:`~ipp_bench.eval.plan.canonical_spec`), flown like any other planner of
the run: on the same tasks and episode seeds, in the same resumable folder, recorded in run.json as planners.
Settings that stay fixed follow the values, ``mcts:simulations=8,24,search=reference``: a comma part without
``=`` is one more value of the swept setting, a part with ``=`` a fixed setting. A sweep varies exactly one
setting, a number, over two or more distinct values.

The report finds the sweeps again from the planner specs alone (:func:`ipp_bench.eval.frontier.infer_sweeps`)
and draws quality against decision time (:mod:`ipp_bench.eval.markdown_frontier`).
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

from ..planners.isolation import isolated_by_default
from .plan import canonical_spec, planner_settings

#: the form of a --sweep, as a refusal names it
SWEEP_FORM = "NAME:KEY=V1,V2,... with other settings after the values as KEY=VALUE (e.g. mcts:simulations=8,24,64)"


@dataclass(frozen=True)
class Sweep:
    """One ``--sweep``: planner ``name``'s setting ``key`` at each of ``values`` (as written), with the ``fixed``
    settings; :attr:`specs` are the canonical planner specs, one per value, in the order given."""

    text: str
    name: str
    key: str
    values: tuple[str, ...]
    fixed: tuple[tuple[str, str], ...]
    specs: tuple[str, ...]


def parse_sweep(text: str) -> Sweep:
    """Read one ``--sweep`` (module docstring) and check every point builds as a planner config.

    Raises:
        ValueError: one line naming the sweep, the part or setting at fault and the valid form: no ``NAME:``,
            a value before any ``KEY=``, no setting or two settings with several values, a setting given twice,
            an unknown planner or setting, a value the setting refuses, a setting that is not a number, two
            values that are the same setting.
    """
    where = f"--sweep {text!r}"
    name, colon, rest = str(text).strip().partition(":")
    name = name.strip()
    if not colon or not name or not rest.strip():
        raise ValueError(f"{where}: expected {SWEEP_FORM}")
    lists: dict[str, list[str]] = {}
    last = None
    for part in (p.strip() for p in rest.split(",")):
        if not part:
            raise ValueError(f"{where}: an empty value between commas; expected {SWEEP_FORM}")
        key, eq, value = part.partition("=")
        if not eq:
            if last is None:
                raise ValueError(f"{where}: value {part!r} comes before any KEY=; expected {SWEEP_FORM}")
            lists[last].append(part)
            continue
        key, value = key.strip(), value.strip()
        if not key or not value:
            raise ValueError(f"{where}: {part!r} is not KEY=VALUE; expected {SWEEP_FORM}")
        if key in lists:
            raise ValueError(f"{where}: setting {key!r} is given twice; give it once, its values after it "
                             f"({SWEEP_FORM})")
        lists[key] = [value]
        last = key
    swept = [k for k, v in lists.items() if len(v) > 1]
    if len(swept) != 1:
        what = (f"no setting has more than one value ({', '.join(f'{k}={v[0]}' for k, v in lists.items())})"
                if not swept else f"{' and '.join(swept)} each have several values")
        raise ValueError(f"{where}: {what}; a sweep varies exactly one setting over two or more values: "
                         f"expected {SWEEP_FORM}")
    key = swept[0]
    fixed = tuple((k, v[0]) for k, v in lists.items() if k != key)
    specs, seen = [], {}
    for value in lists[key]:
        spec = f"{name}:" + ",".join(f"{k}={v}" for k, v in ((key, value), *fixed))
        try:
            canon = canonical_spec(spec, isolated=isolated_by_default(spec))  # a plugin's: in its own process
            setting = planner_settings(canon)[key]
        except (ValueError, ImportError, KeyError) as err:
            raise ValueError(f"{where}: {key}={value}: {str(err).splitlines()[0]}") from None
        if isinstance(setting, bool) or not isinstance(setting, numbers.Real):
            raise ValueError(f"{where}: {name}.{key} = {setting!r} is not a number; a sweep varies a numeric "
                             f"setting: expected {SWEEP_FORM}")
        if canon in seen:
            raise ValueError(f"{where}: {key}={seen[canon]} and {key}={value} are the same setting ({canon}); "
                             "give each value once")
        seen[canon] = value
        specs.append(canon)
    return Sweep(str(text), name, key, tuple(lists[key]), fixed, tuple(specs))


def sweep_specs(texts: list[str] | tuple[str, ...]) -> list[str]:
    """The canonical planner specs of every ``--sweep`` in ``texts``, in order, each once.

    Raises:
        ValueError: a sweep :func:`parse_sweep` refuses.
    """
    specs: list[str] = []
    for text in texts:
        specs += [s for s in parse_sweep(text).specs if s not in specs]
    return specs


__all__ = ["SWEEP_FORM", "Sweep", "parse_sweep", "sweep_specs"]
