"""The ``run.json`` of a leaderboard folder: what it records, and how a stored one meets a run's arguments.

It records the fingerprint of the arguments that decide the numbers (:meth:`Plan.fingerprint
<ipp_bench.eval.plan.Plan.fingerprint>`: tasks and their configs, planner specs and what their
decisions depend on, the seed, environment overrides), and beside it, not part of it, the episodes,
their seeds, the command, the version and where the rows were made (:func:`new_meta`).
:func:`resumed_meta` compares a stored run.json with a run's plan: other arguments are refused,
naming what differs; more episodes extend the folder (seeds are prefix-stable); the same arguments
recorded another way (a field added since at its default, ``30`` for ``30.0``) are rewritten as the
plan records them. The results folder (:mod:`ipp_bench.eval.results`) reads and writes the file.
"""

from __future__ import annotations

import csv
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .. import __version__
from .fingerprint import fingerprint_differences
from .machine import machine_info
from .plan import Plan

RUN_JSON = "run.json"
FORMAT_VERSION = 1
#: ``rows`` key of a folder whose digests were added after its rows were made, saying when and from what
#: (kept when the folder is extended: the older rows' digests vouch for them from then on only)
ROWS_ADDED_KEY = "added"
#: fingerprint keys that a folder may lack: filled in (with a note) instead of refusing the folder
ADDED_FINGERPRINT_KEYS = ("planner_fingerprints",)
#: the planners of which at least one episode in the folder flew isolated, in a process of their own
#: (``--isolate``, a plugin, an ``--against`` submission); beside the fingerprint, not in it: isolation changes no
#: number, so a folder flown without it resumes with it and vice versa (the list then names a planner whose
#: episodes flew isolated only in part)
ISOLATED_KEY = "isolated_planners"


class ResultsMismatchError(ValueError):
    """``out_dir`` holds results made with other arguments, or cannot be used."""


def new_meta(plan: Plan, command: str | None, created: str | None = None) -> dict[str, Any]:
    """The run.json of ``plan``, made by ``command`` (``created``: when the folder was, default now;
    the machine: this one)."""
    meta = {
        "format": FORMAT_VERSION,
        "fingerprint": plan.fingerprint(),
        "quick": plan.quick,
        "tasks": list(plan.tasks),
        "planners": list(plan.planners),
        "episodes": plan.episodes,
        "seeds": list(plan.seeds),
        "ipp_bench_version": __version__,
        "command": command,
        "created": created or time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "machine": machine_info(),
    }
    if plan.against is not None:
        meta["against"] = dict(plan.against)
    return meta


def resumed_meta(stored_meta: dict[str, Any], stored: dict[str, Any], plan: Plan, command: str | None,
                 rerun: Sequence[str], csv_path: Path) -> tuple[dict[str, Any] | None, list[str]]:
    """What a run of ``plan`` does with the folder whose run.json is ``stored_meta`` (its fingerprint
    ``stored``): the run.json to write (None: keep it as it is) and notes for the log.

    Args:
        rerun: planners whose rows are dropped and flown again: what they were made with no longer matters.
        csv_path: the folder's results.csv (read only when the folder lacks planner fingerprints).

    Raises:
        ResultsMismatchError: other arguments (naming each difference), fewer episodes than the folder
            holds, or rows of a planner whose fingerprint the folder does not record.
    """
    folder = csv_path.parent
    fingerprint = plan.fingerprint()
    stored = dict(stored)
    stored_episodes = stored_meta.get("episodes") or len(stored_meta.get("seeds", []))
    notes = []
    added = [k for k in ADDED_FINGERPRINT_KEYS if k not in stored]
    if "planner_fingerprints" in added:
        _refuse_unfingerprinted_rows(csv_path, fingerprint.get("planner_fingerprints") or {})
    for k in added:
        stored[k] = fingerprint[k]
    if rerun:
        pf = dict(stored.get("planner_fingerprints") or {})
        now = fingerprint.get("planner_fingerprints") or {}
        for p in rerun:
            pf.pop(p, None)
            if p in now:
                pf[p] = now[p]
        stored["planner_fingerprints"] = pf
    differences = fingerprint_differences(stored, fingerprint)
    if differences:
        lines = [f"  {k}: {line}" for k, ls in differences.items() for line in ls]
        raise ResultsMismatchError(
            f"{folder} holds results made with different arguments ({', '.join(differences)}):\n"
            + "\n".join(lines)
            + f"\nTo resume that run, repeat its arguments ({RUN_JSON} has them); for these arguments "
            f"pass a new --out DIR (or delete {folder}). Results of different arguments are never mixed.")
    if stored_episodes and plan.episodes < int(stored_episodes):
        raise ResultsMismatchError(
            f"{folder} holds {stored_episodes} episodes per task and planner; --episodes {plan.episodes} "
            f"would drop some: pass --episodes {stored_episodes} or more (more episodes extend the folder)")
    if added:
        notes.append(f"{RUN_JSON} predates {', '.join(added)}; recorded them now")
    # the same arguments, recorded another way (fields added since at their defaults, 30 for 30.0):
    # record them as the plan does
    rerecord = stored != fingerprint
    if rerecord and not added:
        notes.append(f"{RUN_JSON} records the same arguments in an older form; rewrote it in today's")
    if not (added or rerecord or rerun or plan.episodes != stored_episodes):
        return None, notes
    if plan.episodes != stored_episodes:
        notes.append(f"extending {folder} from {stored_episodes} to {plan.episodes} episodes "
                     "per task and planner (the first seeds are the same)")
    meta = new_meta(plan, command or stored_meta.get("command"), stored_meta.get("created"))
    meta["machine"] = stored_meta.get("machine")  # where the kept rows were made (None: not recorded)
    if "other_machines" in stored_meta:
        meta["other_machines"] = stored_meta["other_machines"]
    meta["quick"] = bool(stored_meta.get("quick", plan.quick))  # the label stays the folder's
    isolated = [p for p in stored_meta.get(ISOLATED_KEY) or [] if p not in rerun]  # --rerun drops their rows
    if isolated:
        meta[ISOLATED_KEY] = isolated
    return meta, notes


def _refuse_unfingerprinted_rows(csv_path: Path, fingerprints: dict[str, dict[str, str]]) -> None:
    """A folder without planner fingerprints may hold rows of a planner whose decisions depend on
    more than its spec (the attention planner's checkpoint, the MCTS search, the CMA-ES evaluation):
    what made them is unknown, so they cannot be kept under the plan's."""
    if not fingerprints or not csv_path.exists():
        return
    with csv_path.open(newline="") as fh:
        held = sorted({row.get("planner") for row in csv.DictReader(fh)} & set(fingerprints))
    if held:
        raise ResultsMismatchError(
            f"{csv_path.parent} predates planner fingerprints and holds rows of {', '.join(held)}, whose decisions "
            f"depend on what it does not record (a checkpoint, a search form): delete those rows from "
            f"{csv_path.name} to fly them again with today's, or pass a new --out DIR")


__all__ = ["FORMAT_VERSION", "ISOLATED_KEY", "ROWS_ADDED_KEY", "RUN_JSON", "ResultsMismatchError", "new_meta",
           "resumed_meta"]
