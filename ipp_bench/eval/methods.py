"""A learning method flown over several trained networks (training seeds), as rliable and rl-baselines3-zoo
judge a method over independent runs.

A planner whose config names several networks (``attention:checkpoint=a.pt+b.pt+c.pt``; its config's
``members()``) is a *method*: on a board its rows carry the method's spec, and episode i of the board's
seed list is flown by network i mod k, the k networks in the order the spec names them (:data:`SPLIT_RULE`).
The split depends on the seed list alone, so it is the same on every backend and worker count, and a board
extended with more episodes keeps every episode's network (the seeds are prefix-stable).

results.csv is unchanged; run.json records, in its fingerprint, per method its networks in order and the rule
(:func:`methods_record`; the networks' sha256, in order, are the planner's fingerprint), so that each row's
network follows from its seed's place in run.json's ``seeds`` (:func:`networks_by_seed`), and a folder refuses
the same networks in another order or another file behind a name. The report resamples a method's networks as
well as its episodes (:func:`~ipp_bench.eval.aggregate.two_level_indices`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from ..planners import make_config, parse_spec
from ..planners.isolation import isolated_by_default

#: how a method's episodes are split among its networks, as run.json records it
SPLIT_RULE = "episode i of the seeds flies network i mod k"
#: the fingerprint key of the methods (present only on a board that flies one)
METHODS_KEY = "methods"


def planner_members(spec: str) -> tuple[tuple[str, str], ...]:
    """Per network of a method spec, in order, its name and the spec that flies it alone; () for a planner of
    one network (a plugin's planner is never a method: its config is read in its own process only)."""
    if isolated_by_default(spec):
        return ()
    name, overrides = parse_spec(spec)
    members = getattr(make_config(name, overrides), "members", None)
    if not callable(members):
        return ()
    out = []
    for label, settings in members():
        alone = {**overrides, **settings}
        out.append((label, f"{name}:" + ",".join(f"{k}={alone[k]}" for k in sorted(alone))))
    return tuple(out)


def methods_record(members: Mapping[str, Sequence[tuple[str, str]]]) -> dict[str, dict[str, Any]]:
    """What run.json's fingerprint records of each method: its networks' names in order and the rule."""
    return {p: {"networks": [label for label, _ in m], "split": SPLIT_RULE} for p, m in sorted(members.items())}


def network_index(position: int, k: int) -> int:
    """The network (0-based) that flies the episode at ``position`` of the seed list: :data:`SPLIT_RULE`."""
    return position % k


def networks_by_seed(methods: Mapping[str, Mapping[str, Any]] | None,
                     seeds: Sequence[int]) -> dict[str, dict[int, int]]:
    """Per method (run.json's :data:`METHODS_KEY` record), the network (0-based) of each seed of ``seeds``."""
    out = {}
    for planner, record in (methods or {}).items():
        k = len(record["networks"])
        out[planner] = {int(s): network_index(i, k) for i, s in enumerate(seeds)}
    return out


def check_methods_record(record: Any, planners: Sequence[str]) -> str | None:
    """What is wrong with a run.json's :data:`METHODS_KEY` record (None: nothing), for a verifier's message."""
    if not isinstance(record, dict):
        return "is not an object of method specs"
    for planner, entry in record.items():
        if planner not in planners:
            return f"names {planner!r}, not among the planners"
        networks = entry.get("networks") if isinstance(entry, dict) else None
        if not (isinstance(networks, list) and len(networks) >= 2 and all(isinstance(n, str) for n in networks)):
            return f"records no list of two or more networks for {planner!r}"
        if entry.get("split") != SPLIT_RULE:
            return f"records the split {entry.get('split')!r} for {planner!r}; this version flies {SPLIT_RULE!r}"
    return None


__all__ = ["METHODS_KEY", "SPLIT_RULE", "check_methods_record", "methods_record", "network_index",
           "networks_by_seed", "planner_members"]
