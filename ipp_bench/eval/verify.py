"""A published board verified before it is used: ``--against FOLDER`` and ``ipp-bench power DIR``.

:func:`read_board` reads a finished leaderboard folder and refuses it, in one line naming the row
(file, line, task, planner, seed, report time) or the ``run.json`` field, unless

- ``run.json`` is JSON of this version's format (``"format"``: :data:`~ipp_bench.eval.run_json.FORMAT_VERSION`)
  with the fields a board needs (its tasks, planners, seeds and the task configurations it records);
- ``results.csv`` is no bigger than its rows can be and starts with the header (both looked at
  before the file is read: :func:`~ipp_bench.eval.results_csv.check_results_file`);
- every row parses, holds finite numbers, is an episode and report time ``run.json`` names (its
  tasks, planners and seeds; the report times of the task configuration it records) and appears once;
- every (task, planner, seed, report time) ``run.json`` names has its row: no episode is incomplete;
- every row's digest is among those ``run.json`` records (``rows.digests``), one per row.

**What the digests guarantee.** Each is an unkeyed 32-bit BLAKE2b digest of one line
(:func:`~ipp_bench.eval.results_csv.row_digest`), written by the run that made the row. Together with
the checks above they catch a row changed, added, repeated or deleted by hand or by a tool that does
not rewrite ``run.json``, a ``results.csv`` and a ``run.json`` of different boards, and a file cut or
mangled in transit; an edited row passes for another row of a 10 000-row board with a chance of about
2 in a million. They do not authenticate: the code that computes them is public, so whoever edits a
row on purpose can record its new digest too, and the board passes. A keyed digest (HMAC) would not
change that: to let anyone verify a board the key would ship with the suite, and then anyone could
sign one. That a board is the one its authors published is for where it is published to say (its git
commit, a signed release); a folder paired with a board records the sha256 of the ``results.csv`` it
paired with.

A board without digests (made before they were recorded) is refused unless the user passes
``--trust-unverified``: every other check still applies, the digests are skipped, and the report of
a folder paired with it says so. The committed boards made before digests (``baselines/v0``,
``baselines/v0/quick``, ``baselines/large``) have them now, added after the fact from their committed,
unchanged rows; their ``rows.added`` says so.
"""

from __future__ import annotations

import csv
import hashlib
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..core.config import TIME_TOL_S
from .methods import METHODS_KEY, check_methods_record, networks_by_seed
from .results_csv import (
    RESULTS_CSV,
    ROW_DIGEST_HEX,
    check_results_file,
    complete_lines,
    finite_problem,
    max_results_bytes,
    parse_row,
    row_digest,
)
from .run_json import FORMAT_VERSION, ROWS_ADDED_KEY, RUN_JSON

#: the option that lets a board without row digests be used
TRUST_FLAG = "--trust-unverified"
_HEX = re.compile(r"[0-9a-f]*")


class BoardRefused(ValueError):
    """A published board that cannot be used as it is: one line naming the row or the field."""


@dataclass(frozen=True)
class Board:
    """A finished leaderboard folder that passed :func:`read_board`.

    Attributes:
        meta: its run.json.
        rows: its results.csv rows (typed), in file order.
        verified: every row's digest was checked; False: the board records none (``--trust-unverified``).
        digests_added: what ``rows.added`` says (digests added after the rows were made), else None.
        results_sha256: of the results.csv bytes the rows were read from.
    """

    folder: Path
    meta: dict[str, Any]
    rows: list[dict[str, Any]]
    verified: bool
    digests_added: str | None
    results_sha256: str

    @property
    def planners(self) -> list[str]:
        return list(self.meta["planners"])

    @property
    def networks(self) -> dict[str, dict[int, int]]:
        """Per method (a planner flown over several networks), each seed's network (0-based)."""
        return networks_by_seed(self.meta["fingerprint"].get(METHODS_KEY), self.meta["seeds"])

    def describe(self) -> str:
        """One line for a log: what was checked."""
        if not self.verified:
            return (f"{self.folder}: {len(self.rows)} rows checked, their digests NOT verified ({RUN_JSON} records "
                    f"none; used as {TRUST_FLAG} asks)")
        added = f"; its digests were {self.digests_added}" if self.digests_added else ""
        return f"{self.folder}: {len(self.rows)} rows verified against the digests {RUN_JSON} records{added}"


def _field(run_json: Path, name: str, problem: str) -> BoardRefused:
    return BoardRefused(f'{run_json}: "{name}" {problem}')


def _report_times(run_json: Path, meta: dict[str, Any], task: str) -> tuple[float, ...]:
    """The report times within the budget of ``task``'s configuration as run.json records it."""
    name = f"fingerprint.task_configs.{task}.mission"
    try:
        mission = meta["fingerprint"]["task_configs"][task]["mission"]
        budget = float(mission["budget_s"])
        times = tuple(float(t) for t in mission["report_times"] if float(t) <= budget + TIME_TOL_S)
    except (KeyError, TypeError, ValueError):
        raise _field(run_json, name, "does not record the task's budget_s and report_times") from None
    if not times:
        raise _field(run_json, name, "records no report time within the budget")
    return times


def _read_meta(run_json: Path) -> dict[str, Any]:
    try:
        meta = json.loads(run_json.read_text())
    except OSError as err:
        raise BoardRefused(f"{run_json} cannot be read ({err.strerror or err})") from None
    except ValueError as err:  # not JSON, or not UTF-8
        raise BoardRefused(f"{run_json} is not JSON ({err})") from None
    if not isinstance(meta, dict):
        raise BoardRefused(f"{run_json} is not a run.json (a JSON {type(meta).__name__}, not an object)")
    if meta.get("format") != FORMAT_VERSION:
        shown = json.dumps(meta["format"]) if "format" in meta else "(missing)"
        raise BoardRefused(f'{run_json}: "format": {shown} is not a format this version reads ({FORMAT_VERSION}): '
                           "a board of another ipp-bench version; read it with that version")
    if not isinstance(meta.get("fingerprint"), dict) or not isinstance(meta["fingerprint"].get("task_configs"), dict):
        raise _field(run_json, "fingerprint", "is missing or records no task_configs")
    for name in ("tasks", "planners"):
        value = meta.get(name)
        if not (isinstance(value, list) and value and all(isinstance(v, str) and v for v in value)
                and len(set(value)) == len(value)):
            raise _field(run_json, name, f"is {json.dumps(value)[:80]}: expected a list of distinct names")
    seeds = meta.get("seeds")
    if not (isinstance(seeds, list) and seeds and all(isinstance(s, int) and not isinstance(s, bool) for s in seeds)
            and len(set(seeds)) == len(seeds)):
        raise _field(run_json, "seeds", f"is {json.dumps(seeds)[:80]}: expected a list of distinct integers")
    if "episodes" in meta and meta["episodes"] != len(seeds):
        raise _field(run_json, "episodes", f"is {json.dumps(meta['episodes'])}, but it records {len(seeds)} seeds")
    if METHODS_KEY in meta["fingerprint"]:
        problem = check_methods_record(meta["fingerprint"][METHODS_KEY], meta["planners"])
        if problem:
            raise _field(run_json, f"fingerprint.{METHODS_KEY}", problem)
    return meta


def _recorded_digests(run_json: Path, meta: dict[str, Any]) -> set[str] | None:
    """The digests run.json records (None: it records none), checked for form."""
    if "rows" not in meta:
        return None
    recorded = meta["rows"]
    if not isinstance(recorded, dict):
        raise _field(run_json, "rows", "is not an object with count and digests")
    digests = recorded.get("digests")
    if not (isinstance(digests, str) and len(digests) % ROW_DIGEST_HEX == 0 and _HEX.fullmatch(digests)):
        raise _field(run_json, "rows.digests", f"is not a string of {ROW_DIGEST_HEX}-digit hex digests")
    count = recorded.get("count")
    if count != len(digests) // ROW_DIGEST_HEX:
        raise _field(run_json, "rows.count", f"is {json.dumps(count)}, but rows.digests holds "
                                             f"{len(digests) // ROW_DIGEST_HEX} digests")
    return {digests[i:i + ROW_DIGEST_HEX] for i in range(0, len(digests), ROW_DIGEST_HEX)}


def read_board(folder: str | Path, trust_unverified: bool = False) -> Board:
    """The finished leaderboard board in ``folder``, verified (module docstring).

    Args:
        trust_unverified: use a board whose run.json records no row digests (every other check applies).

    Raises:
        BoardRefused: one line naming the folder's file and the row (line, task, planner, seed, report
            time) or the run.json field that fails; nothing is written.
    """
    root = Path(folder)
    run_json, csv_path = root / RUN_JSON, root / RESULTS_CSV
    if not run_json.is_file() or not csv_path.is_file():
        raise BoardRefused(f"{folder}: not a leaderboard folder (it needs {RUN_JSON} and {RESULTS_CSV})")
    meta = _read_meta(run_json)
    known = _recorded_digests(run_json, meta)
    if known is None and not trust_unverified:
        raise BoardRefused(f'{run_json} records no row digests ("rows"): its rows cannot be verified; pass '
                           f"{TRUST_FLAG} to use them as they are (the report says so)")
    tasks, planners, seeds = meta["tasks"], meta["planners"], set(meta["seeds"])
    times = {t: _report_times(run_json, meta, t) for t in tasks}
    expected = sum(len(ts) for ts in times.values()) * len(planners) * len(seeds)
    try:
        check_results_file(csv_path, max_results_bytes(expected, tasks, planners))
        data = csv_path.read_bytes()
        text = data.decode()
    except OSError as err:
        raise BoardRefused(f"{csv_path} cannot be read ({err.strerror or err})") from None
    except UnicodeDecodeError as err:
        raise BoardRefused(f"{csv_path} is not UTF-8 text ({err.reason} at byte {err.start})") from None
    except ValueError as err:
        raise BoardRefused(str(err)) from None
    lines, torn = complete_lines(text)
    if torn:
        raise BoardRefused(f"{csv_path}:{len(lines) + 1}: the last line is cut short (no newline): a board "
                           "still being written, or a damaged copy")
    rows, seen = [], {}
    for number, (line, fields) in enumerate(zip(lines[1:], csv.reader(lines[1:])), start=2):
        where = f"{csv_path}:{number}"
        try:
            row = parse_row(fields)
        except ValueError as err:
            raise BoardRefused(f"{where}: {err}") from None
        name = f"{row['task']} {row['planner']} seed {row['seed']} at {row['time_s']:g} s"
        problem = finite_problem(row)
        if problem is None and row["task"] not in times:
            problem = f"task {row['task']!r} is not among the tasks {RUN_JSON} records"
        if problem is None and row["planner"] not in planners:
            problem = f"planner {row['planner']!r} is not among the planners {RUN_JSON} records"
        if problem is None and row["seed"] not in seeds:
            problem = (f"seed {row['seed']} is not among the {len(seeds)} episode seeds {RUN_JSON} records "
                       f"(a row of another board, or a {RUN_JSON} of another board)")
        if problem is None and row["time_s"] not in times[row["task"]]:
            problem = (f"{row['time_s']:g} s is not a report time of the task configuration {RUN_JSON} records "
                       f"({', '.join(f'{t:g}' for t in times[row['task']])})")
        key = (row["task"], row["planner"], row["seed"], row["time_s"])
        if problem is None and key in seen:
            problem = f"repeats line {seen[key]}"
        if problem is None and known is not None and row_digest(line) not in known:
            problem = (f"not a row the board's run wrote (its digest is not among those {RUN_JSON} records): "
                       "changed since it was published")
        if problem is not None:
            raise BoardRefused(f"{where}: {name}: {problem}")
        seen[key] = number
        rows.append(row)
    missing = [(t, p, s, ts) for t in tasks for p in planners for s in meta["seeds"] for ts in times[t]
               if (t, p, s, ts) not in seen]
    if missing:
        t, p, s, ts = missing[0]
        raise BoardRefused(f"{csv_path}: no row of {t} {p} seed {s} at {ts:g} s (missing: {len(missing)} of the "
                           f"{expected} rows {RUN_JSON} names): an incomplete board; complete it first (rerun its "
                           "command)")
    if known is not None and meta["rows"]["count"] != len(rows):
        raise _field(run_json, "rows.count", f"is {meta['rows']['count']}, but {RESULTS_CSV} holds {len(rows)} rows")
    added = meta["rows"].get(ROWS_ADDED_KEY) if known is not None else None
    return Board(root, meta, rows, known is not None, added, hashlib.sha256(data).hexdigest())


__all__ = ["TRUST_FLAG", "Board", "BoardRefused", "read_board"]
