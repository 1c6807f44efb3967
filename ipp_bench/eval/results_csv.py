"""The ``results.csv`` of a leaderboard folder: its columns, how rows are written and read, and the
checks every row of a folder to resume must pass.

Long format, one row per (task, planner, seed, report time) with :data:`COLUMNS`. Floats are written
in their shortest round-trip form, so a row reads back bit for bit; a value that is not a finite
number is never written and never read. A torn last line (an append a kill interrupted) is the one
thing a reader drops; any other bad row raises, naming the line.

Each line has a 32-bit digest (:func:`row_digest`) that ``run.json`` records
(:mod:`ipp_bench.eval.results`), so that a number changed by hand, which still parses, is caught.

Before a file is read, :func:`check_results_file` looks at its size and its first line only: a file
bigger than its rows can be, or one that does not start with the header, is refused by name without
being read whole (a 3 GB file that is not CSV is one stat and one short read).
"""

from __future__ import annotations

import csv
import hashlib
import io
import math
from collections.abc import Collection, Iterable, Sequence
from pathlib import Path
from typing import Any

from ..core.mission import REPORT_KEYS

RESULTS_CSV = "results.csv"
KEY_COLUMNS = ("task", "planner", "seed")
TIMING_COLUMNS = ("decision_time_mean_s", "decision_time_max_s", "episode_wall_s")
COLUMNS = (*KEY_COLUMNS, "time_s", *REPORT_KEYS, "decisions", *TIMING_COLUMNS)
_INT_COLUMNS = ("seed", "decisions")
_FLOAT_COLUMNS = tuple(c for c in COLUMNS if c not in KEY_COLUMNS + _INT_COLUMNS or c == "time_s")

#: hex digits of each row's digest in run.json (``rows.digests``): 32 bits, so a row edited by hand
#: passes for another row of a 10 000-row board with a chance of about 2 in a million
ROW_DIGEST_HEX = 8
#: the most characters a number of a row takes (``repr`` of a float: 24 at most; a seed: 10)
_NUMBER_CHARS = 32


def max_results_bytes(rows: int, tasks: Collection[str], planners: Collection[str]) -> int:
    """The most bytes a results.csv of ``rows`` rows of ``tasks`` and ``planners`` can hold: the header,
    every row at its longest (names quoted with every character doubled, every number at
    :data:`_NUMBER_CHARS`), and one more for a torn last line."""
    names = 2 * (max(map(len, tasks), default=0) + max(map(len, planners), default=0)) + 4
    per_row = names + (len(COLUMNS) - 2) * _NUMBER_CHARS + len(COLUMNS)
    return len(format_header()) + (rows + 1) * per_row


def check_results_file(path: str | Path, max_bytes: int | None = None) -> None:
    """Refuse, before reading it, a results.csv that cannot be one: bigger than ``max_bytes``
    (:func:`max_results_bytes` of the rows it should hold), or whose first line is not the header.
    An empty file passes (no rows yet).

    Raises:
        ValueError: ``FILE: N bytes, more than ...`` or ``FILE:1: not a results.csv ...``, one line.
    """
    path = Path(path)
    size = path.stat().st_size
    if size == 0:
        return
    if max_bytes is not None and size > max_bytes:
        raise ValueError(f"{path}: {size} bytes, more than its rows can take ({max_bytes} bytes at most): not "
                         "the results.csv of this board (restore it from the board's source)")
    header = format_header().encode()
    with path.open("rb") as fh:
        head = fh.read(len(header))
    if head != header:
        first = head.split(b"\n", 1)[0][:60].decode("utf-8", "replace")
        raise ValueError(f"{path}:1: not a results.csv of this version: its first line starts {first!r}, "
                         f"expected the header {format_header().strip()!r}")


def row_digest(line: str) -> str:
    """The digest run.json records of one results.csv line (without its newline)."""
    return hashlib.blake2b(line.encode(), digest_size=ROW_DIGEST_HEX // 2).hexdigest()


def finite_problem(row: dict[str, Any]) -> str | None:
    """The first value of a results row that is not a finite number, said as ``column = value ...``."""
    for c in _FLOAT_COLUMNS:
        value = row[c]
        if not (isinstance(value, (int, float)) and math.isfinite(value)):
            return f"{c} = {value!r} is not a finite number"
    return None


def _format_cell(value: Any) -> str:
    if isinstance(value, float):
        return repr(value)  # shortest round-trip form: the same number reads back bit for bit
    return str(value)


def format_header() -> str:
    return ",".join(COLUMNS) + "\n"


def format_rows(rows: Iterable[dict[str, Any]]) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    for row in rows:
        writer.writerow([_format_cell(row[c]) for c in COLUMNS])
    return buf.getvalue()


def parse_row(fields: list[str]) -> dict[str, Any]:
    """One row typed; a ValueError says which field is wrong (``seed = '1.5' is not an integer``)."""
    if len(fields) != len(COLUMNS):
        raise ValueError(f"{len(fields)} fields, expected {len(COLUMNS)} ({','.join(COLUMNS)})")
    row: dict[str, Any] = dict(zip(COLUMNS, fields))
    for c in _INT_COLUMNS:
        try:
            row[c] = int(row[c])
        except ValueError:
            raise ValueError(f"{c} = {row[c]!r} is not an integer") from None
    for c in _FLOAT_COLUMNS:
        try:
            row[c] = float(row[c])
        except ValueError:
            raise ValueError(f"{c} = {row[c]!r} is not a number") from None
    return row


def read_results(path: str | Path) -> list[dict[str, Any]]:
    """The rows of a results.csv (typed); a torn last line (a killed append) is ignored.

    Raises:
        ValueError: ``FILE:LINE: what is wrong`` for the first row that does not parse or holds a
            value that is not a finite number (a bad row is never skipped silently); ``FILE:1: not a
            results.csv ...`` for a file whose first line is not the header (read before the rest).
    """
    path = Path(path)
    check_results_file(path)  # its first line, before the whole file is read
    lines, _ = complete_lines(path.read_text())
    if not lines:
        return []
    header = next(csv.reader([lines[0]]))
    if tuple(header) != COLUMNS:
        raise ValueError(f"{path}:1: the columns are {header}, expected {list(COLUMNS)}")
    rows = []
    for i, fields in enumerate(csv.reader(lines[1:]), start=2):
        try:
            row = parse_row(fields)
        except ValueError as err:
            raise ValueError(f"{path}:{i}: {err}") from None
        problem = finite_problem(row)
        if problem:
            raise ValueError(f"{path}:{i}: {problem}")
        rows.append(row)
    return rows


def complete_lines(text: str) -> tuple[list[str], list[str]]:
    """The lines of a results.csv text without a torn last line (a killed append), and a note if one
    was dropped."""
    if text and not text.endswith("\n"):
        cut = text.rfind("\n") + 1
        return text[:cut].splitlines(), [f"dropped a torn last line ({len(text) - cut} bytes, from an "
                                         "interrupted write)"]
    return text.splitlines(), []


class BadRow(ValueError):
    """A line of results.csv that a run cannot keep: ``line`` (1-based; 1 is the header) and ``what``."""

    def __init__(self, line: int, what: str):
        super().__init__(f"line {line}: {what}")
        self.line, self.what = line, what


def checked_rows(text: str, expected: dict[str, tuple[float, ...]], planners: Sequence[str],
                 seeds: Collection[int], known: Collection[str] | None = None, count: int = 0
                 ) -> tuple[list[dict[str, Any]], list[str], list[str]]:
    """The rows of results.csv ``text``, notes, and the digest of each line. Every row must parse, be
    finite, be an episode and report time of the run (``expected``: task -> report times;
    ``planners``; ``seeds``), appear once, and (where ``known`` digests are given) be a row the run
    wrote: only rows past the first ``count`` (the append a kill cut off from run.json's update, one
    episode at most) may lack one. A torn last line (a killed append) is the one thing dropped.

    Raises:
        BadRow: the first bad line.
    """
    lines, notes = complete_lines(text)
    if not lines:
        return [], notes, []
    header = next(csv.reader([lines[0]]))
    if tuple(header) != COLUMNS:
        raise BadRow(1, f"the columns are {header}, expected {list(COLUMNS)}")
    seeds = set(seeds)
    rows, digests, seen = [], [], {}
    tail_key = None
    for number, (line, fields) in enumerate(zip(lines[1:], csv.reader(lines[1:])), start=2):
        try:
            row = parse_row(fields)
        except ValueError as err:
            raise BadRow(number, str(err)) from None
        problem = finite_problem(row)
        if problem:
            raise BadRow(number, problem)
        if row["task"] not in expected:
            raise BadRow(number, f"task {row['task']!r} is not a task of this run ({', '.join(expected)})")
        if row["planner"] not in planners:
            raise BadRow(number, f"planner {row['planner']!r} is not a planner of this run ({', '.join(planners)})")
        if row["seed"] not in seeds:
            raise BadRow(number, f"seed {row['seed']} is not an episode seed of this run")
        if row["time_s"] not in expected[row["task"]]:
            raise BadRow(number, f"time_s = {row['time_s']!r} is not a report time of {row['task']} "
                                 f"({', '.join(f'{t:g}' for t in expected[row['task']])})")
        key = (row["task"], row["planner"], row["seed"], row["time_s"])
        if key in seen:
            raise BadRow(number, f"repeats line {seen[key]} ({row['task']} {row['planner']} seed {row['seed']} at "
                                 f"{row['time_s']:g} s)")
        seen[key] = number
        digest = row_digest(line)
        if known is not None and digest not in known:
            episode = key[:3]
            if number - 2 < count or (tail_key is not None and tail_key != episode):
                raise BadRow(number, "not a row this run wrote (its digest is not among those run.json records: "
                                     "edited by hand?)")
            tail_key = episode
        rows.append(row)
        digests.append(digest)
    return rows, notes, digests


__all__ = ["COLUMNS", "RESULTS_CSV", "TIMING_COLUMNS", "BadRow", "check_results_file", "checked_rows",
           "finite_problem", "format_header", "format_rows", "max_results_bytes", "parse_row", "read_results",
           "row_digest"]
