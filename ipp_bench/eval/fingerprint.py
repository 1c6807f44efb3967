"""What decides a leaderboard's numbers, as run.json records it, and how a stored record is compared.

A run's fingerprint (:meth:`Plan.fingerprint <ipp_bench.eval.plan.Plan.fingerprint>`) holds every
task's configuration field by field (:func:`task_config_record`), the environment overrides as the
config normalises them (:func:`normalised_overrides`) and what each planner's decisions depend on
beyond its spec (:func:`planner_fingerprint`). Values are JSON values, so that a record read back
from run.json compares equal to the one made now.

:func:`fingerprint_differences` names what differs between a stored fingerprint and today's, field
by field for the task configurations (:func:`config_differences`); the results folder refuses a run
whose arguments differ, and ``--against`` a published board whose tasks today's suite gives otherwise.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

from ..core.config import IPPConfig, field_owners
from ..envs import task_config


def _json(value: Any) -> Any:
    """``value`` as JSON reads it back (tuples become lists), so that a stored one compares equal."""
    return json.loads(json.dumps(value, default=str))


def task_config_record(task: str, env_overrides: dict[str, Any] | None = None) -> dict[str, dict[str, Any]]:
    """The configuration of ``task`` (with ``env_overrides``) as run.json records it: every field,
    by section, as the config normalises it (JSON values)."""
    return _json(task_config(task, env_overrides).to_dict())


def _flat(record: dict[str, Any]) -> dict[str, Any]:
    return {f"{section}.{name}": value for section, fields in record.items() if isinstance(fields, dict)
            for name, value in fields.items()}


def config_differences(stored: Any, current: dict[str, Any]) -> list[str]:
    """What differs between a stored task config record and today's, one ``field: there X, now Y``
    each; empty when they are the same arguments.

    Values compare as numbers (``30`` and ``30.0`` are the same budget); a field the stored record
    lacks is the same when today's value is its default (a field added since, at the value that
    keeps the behaviour the record was made with).
    """
    if not isinstance(stored, dict):
        return [f"a config record that is not field by field ({short_json(stored)}): nothing to compare"]
    there, now = _flat(stored), _flat(current)
    defaults = _flat(_json(IPPConfig().to_dict()))
    out = []
    for key in sorted(set(there) | set(now)):
        if key not in there:
            if key in defaults and now[key] == defaults[key]:
                continue  # added since, at its default
            out.append(f"{key}: not recorded there (the default {defaults.get(key)!r} then), now {now[key]!r}")
        elif key not in now:
            out.append(f"{key}: there {there[key]!r}, a field today's config no longer has")
        elif there[key] != now[key]:
            out.append(f"{key}: there {there[key]!r}, now {now[key]!r}")
    return out


def fingerprint_differences(stored: dict[str, Any], current: dict[str, Any]) -> dict[str, list[str]]:
    """Per differing fingerprint key, lines saying how (empty dict: the same arguments).

    ``task_configs`` compare field by field (:func:`config_differences`); every other key by
    value, numbers as numbers.
    """
    out: dict[str, list[str]] = {}
    for key in sorted(set(stored) | set(current)):
        there, now = stored.get(key), current.get(key)
        if key == "task_configs" and isinstance(there, dict) and isinstance(now, dict):
            lines = []
            for task in sorted(set(there) | set(now)):
                if task not in there or task not in now:
                    lines.append(f"{task}: {'not there' if task not in there else 'not now'}")
                    continue
                lines += [f"{task} {line}" for line in config_differences(there[task], now[task])]
            if lines:
                out[key] = lines
        elif there != now:
            out[key] = [f"there {short_json(there)}, now {short_json(now)}"]
    return out


def short_json(value: Any, limit: int = 200) -> str:
    """``value`` as sorted JSON, cut to ``limit`` characters (for a message)."""
    text = json.dumps(value, sort_keys=True, default=str)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def normalised_overrides(tasks: Sequence[str], env_overrides: dict[str, Any]) -> dict[str, Any]:
    """``env_overrides`` as the config holds them (``budget_s=30`` and ``30.0`` alike), JSON values."""
    if not env_overrides or not tasks:
        return _json(dict(sorted(env_overrides.items())))
    config = task_config(tasks[0], env_overrides)
    owners = field_owners()
    out = {}
    for k in sorted(env_overrides):
        if k in owners:
            out[k] = getattr(getattr(config, owners[k]), k)
        else:  # a whole section given as a dict
            out[k] = env_overrides[k]
    return _json(out)


def planner_fingerprint(planner: Any) -> dict[str, str]:
    """What a built planner's decisions depend on beyond its spec (the attention planner: its
    checkpoint's content hash), from its optional ``fingerprint()`` method."""
    fn = getattr(planner, "fingerprint", None)
    return dict(fn()) if callable(fn) else {}


__all__ = ["config_differences", "fingerprint_differences", "normalised_overrides", "planner_fingerprint",
           "short_json", "task_config_record"]
