"""The results folder of a leaderboard run: its fingerprint, its lock and a resumable results.csv.

The folder holds:

``run.json``
    the fingerprint of the arguments that decide the numbers (tasks and their configs, planner
    specs and what their decisions depend on, e.g. the attention checkpoint's content hash, the
    seed, environment overrides; :meth:`Plan.fingerprint`). A rerun with other arguments is
    refused, naming what differs; a rerun with more episodes extends the folder (seeds are
    prefix-stable). The executor (backend, workers) is not part of it: results do not depend on it.
    Beside it, not part of it: ``machine`` (:func:`machine_info`: CPU model and the flags that change
    floating-point results, cores, Python, numpy, scipy, torch, mujoco, dm-control; rows appended
    elsewhere add ``other_machines``), and ``rows``: a 32-bit digest of every results.csv row
    (:func:`row_digest`), rewritten after each episode's append.
``results.csv``
    long format, one row per (task, planner, seed, report time) with :data:`COLUMNS`. An episode's
    rows are appended in one write, flushed and fsync'ed as soon as it finishes, so a killed run
    loses no finished episode. On resume a torn last line (the write a kill interrupted) and
    episodes with missing rows (a row deleted by hand) are dropped and run again. Any other bad
    row refuses the resume in one line naming the file, the line and what is wrong, and nothing is
    written: a row that does not parse, a value that is not a finite number, a task, planner, seed
    or report time that is not this run's, a repeated row, or a row whose digest run.json does not
    record (edited by hand; only the rows of the one append a kill cut off from run.json's update
    may lack one). The checks are what a reader can verify of every row; the digests catch what
    still parses (a number changed by hand), and a folder from before the digests gets the checks
    alone. Non-finite values are never written. When every episode is in, the file is
    rewritten sorted (task, planner, seed, time), so its content does not depend on the order in
    which workers finished.
``published_results.csv``
    only in a folder paired with a published board (``--against``): a copy of that board's
    results.csv (whose sha256 run.json records), so the report is made from this folder alone.

Opening the store (a context manager) only reads and locks; nothing is written until
:meth:`ResultsStore.begin`, so a run that fails before its first episode (no Ray cluster, say)
leaves no ``run.json`` behind.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import os
import platform
import shutil
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from .. import __version__
from ..core.data import OutputWriteError, check_output_dir, write_atomically
from ..core.mission import REPORT_KEYS
from .plan import Plan, fingerprint_differences, report_times

RESULTS_CSV = "results.csv"
RUN_JSON = "run.json"
#: the copy of a published board's results.csv in a folder paired with it (``--against``)
PUBLISHED_CSV = "published_results.csv"
FORMAT_VERSION = 1
#: fingerprint keys that older folders lack: filled in (with a note) instead of refusing the folder
ADDED_FINGERPRINT_KEYS = ("planner_fingerprints",)

KEY_COLUMNS = ("task", "planner", "seed")
TIMING_COLUMNS = ("decision_time_mean_s", "decision_time_max_s", "episode_wall_s")
COLUMNS = (*KEY_COLUMNS, "time_s", *REPORT_KEYS, "decisions", *TIMING_COLUMNS)
_INT_COLUMNS = ("seed", "decisions")
_FLOAT_COLUMNS = tuple(c for c in COLUMNS if c not in KEY_COLUMNS + _INT_COLUMNS or c == "time_s")


class ResultsMismatchError(ValueError):
    """``out_dir`` holds results made with other arguments, or cannot be used."""


#: hex digits of each row's digest in run.json (``rows.digests``): 32 bits, so a row edited by hand
#: passes for another row of a 10 000-row board with a chance of about 2 in a million
ROW_DIGEST_HEX = 8


def row_digest(line: str) -> str:
    """The digest run.json records of one results.csv line (without its newline)."""
    return hashlib.blake2b(line.encode(), digest_size=ROW_DIGEST_HEX // 2).hexdigest()


#: the CPU flags that change floating-point results (which BLAS kernels run, fused multiply-adds)
FLOAT_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f")
#: the packages whose versions decide the numbers, recorded where installed
RECORDED_PACKAGES = ("numpy", "scipy", "torch", "mujoco", "dm-control")


def machine_info() -> dict[str, Any]:
    """Where rows are made: CPU model, the flags of :data:`FLOAT_FLAGS` it has, cores, OS, Python
    and the versions of :data:`RECORDED_PACKAGES` that are installed (none is imported)."""
    from importlib.metadata import PackageNotFoundError, version

    cpu, flags = platform.processor() or platform.machine(), set()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                if key.strip() == "model name" and cpu in ("", platform.processor() or platform.machine()):
                    cpu = value.strip()
                elif key.strip() in ("flags", "Features") and not flags:
                    flags = set(value.split())
    except OSError:  # no /proc (not Linux): the model from platform, no flags
        pass
    packages = {}
    for name in RECORDED_PACKAGES:
        try:
            packages[name] = version(name)
        except PackageNotFoundError:
            continue
    return {"cpu": cpu, "cpu_flags": [f for f in FLOAT_FLAGS if f in flags], "cores": os.cpu_count(),
            "os": f"{platform.system()} {platform.machine()}", "python": platform.python_version(),
            "packages": packages}


def describe_machine(info: dict[str, Any]) -> str:
    """One line of :func:`machine_info`: ``CPU (N cores; avx2, fma), OS; Python X, numpy Y, ...``."""
    flags = ", ".join(info.get("cpu_flags") or []) or "no vector flags known"
    packages = ", ".join(f"{k} {v}" for k, v in (info.get("packages") or {}).items())
    return (f"{info.get('cpu', '?')} ({info.get('cores', '?')} cores; {flags}), {info.get('os', '?')}; "
            f"Python {info.get('python', '?')}" + (f", {packages}" if packages else ""))


def _finite_problem(row: dict[str, Any]) -> str | None:
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


def _parse_row(fields: list[str]) -> dict[str, Any]:
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
            value that is not a finite number (a bad row is never skipped silently).
    """
    return _parse_text(Path(path).read_text(), Path(path))[0]


def _complete_lines(text: str) -> tuple[list[str], list[str]]:
    """The lines of a results.csv text without a torn last line (a killed append), and a note if one
    was dropped."""
    if text and not text.endswith("\n"):
        cut = text.rfind("\n") + 1
        return text[:cut].splitlines(), [f"dropped a torn last line ({len(text) - cut} bytes, from an "
                                         "interrupted write)"]
    return text.splitlines(), []


def _parse_text(text: str, path: Path | str = RESULTS_CSV) -> tuple[list[dict[str, Any]], list[str]]:
    """Rows of a results.csv text, and notes on what was dropped (a torn last line).

    Raises:
        ValueError: another header, or ``FILE:LINE: what`` for a row that does not parse or is not finite.
    """
    lines, notes = _complete_lines(text)
    if not lines:
        return [], notes
    header = next(csv.reader([lines[0]]))
    if tuple(header) != COLUMNS:
        raise ValueError(f"{path}:1: the columns are {header}, expected {list(COLUMNS)}")
    rows = []
    for i, fields in enumerate(csv.reader(lines[1:]), start=2):
        try:
            row = _parse_row(fields)
        except ValueError as err:
            raise ValueError(f"{path}:{i}: {err}") from None
        problem = _finite_problem(row)
        if problem:
            raise ValueError(f"{path}:{i}: {problem}")
        rows.append(row)
    return rows, notes


def _sort_key(plan: Plan):
    t_index = {t: i for i, t in enumerate(plan.tasks)}
    p_index = {p: i for i, p in enumerate(plan.planners)}
    s_index = {s: i for i, s in enumerate(plan.seeds)}
    return lambda r: (t_index.get(r["task"], 1 << 30), p_index.get(r["planner"], 1 << 30),
                      s_index.get(r["seed"], 1 << 30), r["time_s"])


class ResultsStore:
    """``out_dir`` of a leaderboard run: fingerprint check, lock, resumable results.csv.

    Use as a context manager; entering locks the folder against a second concurrent run and
    reads it; :meth:`begin` writes run.json and the cleaned results.csv.
    """

    def __init__(self, out_dir: str | Path, plan: Plan, command: str | None = None, rerun: Sequence[str] = ()):
        self.dir = Path(out_dir)
        self.plan = plan
        self.command = command
        unknown = [p for p in rerun if p not in plan.planners]
        if unknown:
            raise ValueError(f"--rerun {', '.join(unknown)}: not a planner of this run ({', '.join(plan.planners)})")
        #: planners whose rows are dropped and flown again (e.g. a retrained checkpoint's)
        self.rerun = tuple(rerun)
        self.csv_path = self.dir / RESULTS_CSV
        self.run_json = self.dir / RUN_JSON
        self._lock_fd: int | None = None
        self._created = False
        self._meta: dict[str, Any] | None = None  # run.json to write at begin(), None: keep
        self._rewrite_rows: list[dict[str, Any]] | None = None  # results.csv to write at begin()
        self.notes: list[str] = []
        self.done: dict[tuple[str, str, int], list[dict[str, Any]]] = {}
        self._stored_meta: dict[str, Any] | None = None  # run.json as read
        self._digests: list[str] = []  # row_digest of every data line of results.csv, in file order

    # -- setup ----------------------------------------------------------------------------------------
    def __enter__(self) -> ResultsStore:
        try:
            check_output_dir(self.dir)
        except ValueError as err:
            raise ResultsMismatchError(str(err)) from None
        if self.dir.is_symlink() and not self.dir.exists():
            raise ResultsMismatchError(
                f"--out {self.dir} is a symbolic link to {os.readlink(self.dir)}, which does not exist: create "
                "that folder, remove the link, or pass another --out DIR")
        try:  # atomic: of two runs starting at once on a new folder, exactly one created it
            self.dir.mkdir(parents=True)
            self._created = True
        except FileExistsError:
            self._created = False
        try:
            self._lock()
            self._check_files()
            self._check_fingerprint()
            self._load()
        except BaseException:
            self._close(failed=True)
            raise
        return self

    def __exit__(self, exc_type, *exc) -> None:
        self._close(failed=exc_type is not None)

    def _close(self, failed: bool) -> None:
        """Unlock; a run that failed before writing anything removes the folder it created, but
        only while it holds the lock: a run that lost the lock touches nothing (the folder is the
        winner's now, even if this run made it)."""
        if self._lock_fd is None:
            return
        if failed and self._created and not self.run_json.exists():  # leave nothing behind
            shutil.rmtree(self.dir, ignore_errors=True)
        os.close(self._lock_fd)  # releases the flock
        self._lock_fd = None

    def _lock(self) -> None:
        """Lock the folder itself (flock on its descriptor): no lock file is created or left."""
        try:
            import fcntl
        except ImportError:  # pragma: no cover (Windows): no lock
            return
        try:
            fd = os.open(self.dir, os.O_RDONLY)
        except FileNotFoundError:  # a run that made it a moment ago failed and removed it
            raise ResultsMismatchError(
                f"{self.dir} was removed by another leaderboard run that started at the same moment and "
                "failed; run the command again") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise ResultsMismatchError(
                f"{self.dir} is in use by another leaderboard run (locked); wait for it or pass another --out"
            ) from None
        self._lock_fd = fd

    def _check_files(self) -> None:
        """Refuse a folder (or anything but a regular file) where the folder's files belong."""
        for path in (self.run_json, self.csv_path, self.dir / PUBLISHED_CSV):
            if path.exists() and not path.is_file():
                kind = "a folder" if path.is_dir() else "not a regular file"
                raise ResultsMismatchError(f"{path} is {kind}, not a file: move it away, or pass a new --out DIR")

    def _new_meta(self, created: str | None = None) -> dict[str, Any]:
        meta = {
            "format": FORMAT_VERSION,
            "fingerprint": self.plan.fingerprint(),
            "quick": self.plan.quick,
            "tasks": list(self.plan.tasks),
            "planners": list(self.plan.planners),
            "episodes": self.plan.episodes,
            "seeds": list(self.plan.seeds),
            "ipp_bench_version": __version__,
            "command": self.command,
            "created": created or time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "machine": machine_info(),
        }
        if self.plan.against is not None:
            meta["against"] = dict(self.plan.against)
        return meta

    def _check_fingerprint(self) -> None:
        fingerprint = self.plan.fingerprint()
        if not self.run_json.exists():
            if self.csv_path.exists() and self.csv_path.stat().st_size > 0:
                raise ResultsMismatchError(
                    f"{self.csv_path} exists without {RUN_JSON}: its arguments are unknown, so it cannot be "
                    f"resumed; pass a new --out DIR (or delete {self.dir})")
            self._meta = self._new_meta()
            return
        try:
            stored_meta = json.loads(self.run_json.read_text())
            stored = dict(stored_meta["fingerprint"])
        except OSError as err:
            raise ResultsMismatchError(f"{self.run_json} cannot be read ({err.strerror or err}); pass a new --out "
                                       f"DIR (or delete {self.dir})") from None
        except (ValueError, KeyError, TypeError) as err:
            raise ResultsMismatchError(
                f"{self.run_json} is unreadable ({err}); pass a new --out DIR (or delete {self.dir})") from None
        self._stored_meta = stored_meta
        stored_episodes = (stored.pop("episodes", None) or stored_meta.get("episodes")
                           or len(stored_meta.get("seeds", [])))
        added = [k for k in ADDED_FINGERPRINT_KEYS if k not in stored]
        if "planner_fingerprints" in added:
            self._refuse_unfingerprinted_rows(fingerprint.get("planner_fingerprints") or {})
        for k in added:
            stored[k] = fingerprint[k]
        if self.rerun:  # their rows go (see _load): what they were made with no longer matters
            pf = dict(stored.get("planner_fingerprints") or {})
            now = fingerprint.get("planner_fingerprints") or {}
            for p in self.rerun:
                pf.pop(p, None)
                if p in now:
                    pf[p] = now[p]
            stored["planner_fingerprints"] = pf
        differences = fingerprint_differences(stored, fingerprint)
        if differences:
            lines = [f"  {k}: {line}" for k, ls in differences.items() for line in ls]
            raise ResultsMismatchError(
                f"{self.dir} holds results made with different arguments ({', '.join(differences)}):\n"
                + "\n".join(lines)
                + f"\nTo resume that run, repeat its arguments ({RUN_JSON} has them); for these arguments "
                f"pass a new --out DIR (or delete {self.dir}). Results of different arguments are never mixed.")
        if stored_episodes and self.plan.episodes < int(stored_episodes):
            raise ResultsMismatchError(
                f"{self.dir} holds {stored_episodes} episodes per task and planner; --episodes {self.plan.episodes} "
                f"would drop some: pass --episodes {stored_episodes} or more (more episodes extend the folder)")
        if added:
            self.notes.append(f"{RUN_JSON} predates {', '.join(added)}; recorded them now")
        # the same arguments, recorded another way (digests of the task configs, fields added since
        # at their defaults, 30 for 30.0): record them as today's code does
        rerecord = stored != fingerprint
        if rerecord and not added:
            self.notes.append(f"{RUN_JSON} records the same arguments in an older form; rewrote it in today's")
        if (added or rerecord or self.rerun or self.plan.episodes != stored_episodes
                or "episodes" in stored_meta.get("fingerprint", {})):
            if self.plan.episodes != stored_episodes:
                self.notes.append(f"extending {self.dir} from {stored_episodes} to {self.plan.episodes} episodes "
                                  "per task and planner (the first seeds are the same)")
            meta = self._new_meta(stored_meta.get("created"))
            meta["machine"] = stored_meta.get("machine")  # where the kept rows were made (None: not recorded)
            if "other_machines" in stored_meta:
                meta["other_machines"] = stored_meta["other_machines"]
            meta["quick"] = bool(stored_meta.get("quick", self.plan.quick))  # the label stays the folder's
            meta["command"] = self.command or stored_meta.get("command")
            self._meta = meta

    def _refuse_unfingerprinted_rows(self, fingerprints: dict[str, dict[str, str]]) -> None:
        """A folder from before planner fingerprints were recorded may hold rows of a planner whose
        decisions depend on more than its spec (the attention planner's checkpoint, the MCTS search,
        the CMA-ES evaluation): what made them is unknown, so they cannot be kept under today's."""
        if not fingerprints or not self.csv_path.exists():
            return
        with self.csv_path.open(newline="") as fh:
            held = sorted({row.get("planner") for row in csv.DictReader(fh)} & set(fingerprints))
        if held:
            raise ResultsMismatchError(
                f"{self.dir} predates planner fingerprints and holds rows of {', '.join(held)}, whose decisions "
                f"depend on what it does not record (a checkpoint, a search form): delete those rows from "
                f"{self.csv_path.name} to fly them again with today's, or pass a new --out DIR")

    def _load(self) -> None:
        """Read finished episodes; note torn lines and incomplete episodes (dropped at begin())."""
        if not self.csv_path.exists() or self.csv_path.stat().st_size == 0:
            self._rewrite_rows = []
            return
        try:
            text = self.csv_path.read_text()
        except (OSError, UnicodeDecodeError) as err:
            raise ResultsMismatchError(f"{self.csv_path} cannot be read ({getattr(err, 'strerror', None) or err}); "
                                       f"pass a new --out DIR (or delete {self.dir})") from None
        expected = {t: report_times(t, self.plan.env_overrides) for t in self.plan.tasks}
        rows, notes, self._digests = self._checked_rows(text, expected)
        wanted = {job.key for job in self.plan.jobs()}
        groups: dict[tuple[str, str, int], dict[float, dict[str, Any]]] = {}
        for row in rows:
            key = (row["task"], row["planner"], row["seed"])
            groups.setdefault(key, {})[row["time_s"]] = row
        done = {}
        dropped: dict[str, int] = {}
        for key, by_time in groups.items():
            if key[1] in self.rerun:
                dropped[key[1]] = dropped.get(key[1], 0) + 1
                continue
            if key not in wanted:
                notes.append(f"dropped rows of {key}: not an episode of these arguments")
                continue
            if tuple(sorted(by_time)) != expected[key[0]]:
                notes.append(f"dropped the incomplete episode {key} ({len(by_time)} of {len(expected[key[0]])} rows); "
                             "it runs again")
                continue
            done[key] = [by_time[t] for t in expected[key[0]]]
        notes += [f"dropped {n} episodes of {p} (--rerun): they run again" for p, n in dropped.items()]
        kept = sum(len(v) for v in done.values())
        if kept != len(rows) or not text.endswith("\n") or notes:
            self._rewrite_rows = [r for v in done.values() for r in v]
        self.notes.extend(notes)
        self.done = done

    def _checked_rows(self, text: str, expected: dict[str, tuple[float, ...]]
                      ) -> tuple[list[dict[str, Any]], list[str], list[str]]:
        """The rows of results.csv ``text``, notes, and the digest of each line; every row must parse,
        be finite, be an episode and report time of this run, appear once, and (where run.json records
        digests) be a row this run wrote. A torn last line (a killed append) is the one thing dropped.

        Raises:
            ResultsMismatchError: ``FILE:LINE: what is wrong``, the first bad row; nothing is changed.
        """
        lines, notes = _complete_lines(text)
        if not lines:
            return [], notes, []
        header = next(csv.reader([lines[0]]))
        if tuple(header) != COLUMNS:
            raise ResultsMismatchError(f"{self.csv_path}:1: the columns are {header}, expected {list(COLUMNS)}; "
                                       f"not a results file of this version: pass a new --out DIR")
        recorded = (self._stored_meta or {}).get("rows")
        known, count = None, 0
        if isinstance(recorded, dict) and isinstance(recorded.get("digests"), str):
            d = recorded["digests"]
            known = {d[i:i + ROW_DIGEST_HEX] for i in range(0, len(d), ROW_DIGEST_HEX)}
            count = int(recorded.get("count", len(d) // ROW_DIGEST_HEX))
        seeds, planners = set(self.plan.seeds), set(self.plan.planners)
        rows, digests, seen = [], [], {}
        tail_key = None
        for number, (line, fields) in enumerate(zip(lines[1:], csv.reader(lines[1:])), start=2):
            def bad(what: str, number: int = number) -> ResultsMismatchError:
                return ResultsMismatchError(
                    f"{self.csv_path}:{number}: {what}; restore the line, or delete it to fly its episode again "
                    "(the other rows are kept), or pass a new --out DIR")

            try:
                row = _parse_row(fields)
            except ValueError as err:
                raise bad(str(err)) from None
            problem = _finite_problem(row)
            if problem:
                raise bad(problem)
            if row["task"] not in expected:
                raise bad(f"task {row['task']!r} is not a task of this run ({', '.join(expected)})")
            if row["planner"] not in planners:
                raise bad(f"planner {row['planner']!r} is not a planner of this run ({', '.join(self.plan.planners)})")
            if row["seed"] not in seeds:
                raise bad(f"seed {row['seed']} is not an episode seed of this run")
            if row["time_s"] not in expected[row["task"]]:
                raise bad(f"time_s = {row['time_s']!r} is not a report time of {row['task']} "
                          f"({', '.join(f'{t:g}' for t in expected[row['task']])})")
            key = (row["task"], row["planner"], row["seed"], row["time_s"])
            if key in seen:
                raise bad(f"repeats line {seen[key]} ({row['task']} {row['planner']} seed {row['seed']} at "
                          f"{row['time_s']:g} s)")
            seen[key] = number
            digest = row_digest(line)
            if known is not None and digest not in known:
                # rows past the recorded count are those of the append a kill cut off from run.json's
                # update: one episode at most
                episode = key[:3]
                if number - 2 < count or (tail_key is not None and tail_key != episode):
                    raise bad(f"not a row this run wrote (its digest is not among those {RUN_JSON} records: "
                              "edited by hand?)")
                tail_key = episode
            rows.append(row)
            digests.append(digest)
        return rows, notes, digests

    def _write_meta(self, meta: dict[str, Any]) -> None:
        meta["rows"] = {"count": len(self._digests), "digests": "".join(self._digests)}
        _atomic_write(self.run_json, json.dumps(meta, indent=2) + "\n")
        self._stored_meta = meta

    # -- writing --------------------------------------------------------------------------------------
    def begin(self) -> None:
        """Write what opening decided: run.json (new, extended or upgraded) and a clean results.csv."""
        # A new folder's run.json comes first (results.csv without it is refused); an existing folder's
        # results.csv first: digests run.json still records of rows since dropped are harmless, rows
        # it does not record are not.
        meta, rewrite = self._meta, self._rewrite_rows
        self._meta = self._rewrite_rows = None
        if rewrite is not None:
            body = format_rows(rewrite)
            self._digests = [row_digest(line) for line in body.splitlines()]
        if meta is not None and self._stored_meta is None:
            self._write_meta(meta)
            meta = None
        if rewrite is not None:
            _atomic_write(self.csv_path, format_header() + body)
        if meta is not None or (rewrite is not None and self._stored_meta is not None and
                                self._stored_meta.get("rows", {}).get("digests") != "".join(self._digests)):
            self._write_meta(meta if meta is not None else dict(self._stored_meta))

    def append(self, rows: list[dict[str, Any]]) -> None:
        """Append one episode's rows: one write of whole lines, flushed and fsync'ed; then run.json
        records their digests.

        Raises:
            ValueError: a row with a value that is not a finite number (nothing is written).
            OutputWriteError: the file could not be written.
        """
        for row in rows:
            problem = _finite_problem(row)
            if problem:
                raise ValueError(f"{row['task']} {row['planner']} seed {row['seed']} at {row['time_s']} s: "
                                 f"{problem}; the episode's rows are not written")
        text = format_rows(rows)
        data = text.encode()
        try:
            fd = os.open(self.csv_path, os.O_WRONLY | os.O_APPEND)
            try:
                view = memoryview(data)
                while view:
                    n = os.write(fd, view)
                    view = view[n:]
                os.fsync(fd)
            finally:
                os.close(fd)
        except OSError as err:  # a torn line at most: the resume drops it
            raise OutputWriteError(f"cannot write {self.csv_path}: {err.strerror or err}") from None
        key = (rows[0]["task"], rows[0]["planner"], rows[0]["seed"])
        self.done[key] = rows
        self._digests += [row_digest(line) for line in text.splitlines()]
        meta = dict(self._stored_meta or self._new_meta())
        here = machine_info()
        if meta.get("machine") != here and here not in meta.get("other_machines", []):
            meta["other_machines"] = [*meta.get("other_machines", []), here]
        self._write_meta(meta)

    def finalize(self) -> None:
        """Rewrite results.csv sorted by (task, planner, seed, time): independent of finishing order."""
        rows = sorted((r for v in self.done.values() for r in v), key=_sort_key(self.plan))
        body = format_rows(rows)
        digests = [row_digest(line) for line in body.splitlines()]
        _atomic_write(self.csv_path, format_header() + body)  # the same rows: run.json's digests still hold
        if digests != self._digests:
            self._digests = digests
            self._write_meta(dict(self._stored_meta or self._new_meta()))

    @property
    def machines(self) -> list[dict[str, Any]]:
        """Where the rows were made (run.json's ``machine`` and ``other_machines``): [] when not recorded."""
        meta = self._stored_meta or {}
        return [m for m in [meta.get("machine"), *meta.get("other_machines", [])] if isinstance(m, dict)]

    @property
    def quick(self) -> bool:
        """Whether the report is a quick run's: the stored label, and this run's."""
        if self.run_json.exists():
            try:
                return bool(json.loads(self.run_json.read_text()).get("quick", False))
            except ValueError:
                pass
        return self.plan.quick


def copy_published(plan: Plan, out_dir: str | Path) -> Path:
    """Copy the results.csv of the published board ``plan`` is paired with (:attr:`Plan.against`)
    into ``out_dir`` as :data:`PUBLISHED_CSV`, checking that it is the file the plan read.

    Raises:
        ResultsMismatchError: the published results.csv changed since (or is gone).
    """
    against = plan.against or {}
    source = Path(against["folder"]) / RESULTS_CSV
    try:
        data = source.read_bytes()
    except OSError as err:
        raise ResultsMismatchError(f"cannot read the published {source}: {err.strerror or err}") from None
    if hashlib.sha256(data).hexdigest() != against["results_sha256"]:
        raise ResultsMismatchError(f"the published {source} is not the one this folder was paired with (its content "
                                   "changed): pass a new --out DIR to pair with it as it is now")
    target = Path(out_dir) / PUBLISHED_CSV
    write_atomically(target, lambda tmp: tmp.write_bytes(data))
    return target


def _atomic_write(path: Path, text: str) -> None:
    write_atomically(path, lambda tmp: tmp.write_text(text))
    try:  # make the rename itself durable
        dfd = os.open(path.parent, os.O_RDONLY)
    except OSError:  # pragma: no cover
        return
    try:
        os.fsync(dfd)
    except OSError:  # pragma: no cover (file systems that refuse fsync on a folder)
        pass
    finally:
        os.close(dfd)


__all__ = ["COLUMNS", "PUBLISHED_CSV", "RESULTS_CSV", "RUN_JSON", "TIMING_COLUMNS", "ResultsMismatchError",
           "describe_machine", "machine_info", "row_digest",
           "ResultsStore", "copy_published", "format_header", "format_rows", "read_results"]
