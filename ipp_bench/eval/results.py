"""The results folder of a leaderboard run: its lock, its run.json and a resumable results.csv.

The folder holds:

``run.json``
    the fingerprint of the arguments that decide the numbers and what is recorded beside it
    (:mod:`ipp_bench.eval.run_json`: a rerun with other arguments is refused, naming what differs;
    one with more episodes extends the folder). The executor (backend, workers) is not part of it:
    results do not depend on it. Also ``machine`` (:func:`~ipp_bench.eval.machine.machine_info`;
    rows appended elsewhere add ``other_machines``), and ``rows``: a 32-bit digest of every
    results.csv row (:func:`~ipp_bench.eval.results_csv.row_digest`), rewritten after each
    episode's append and, once the folder is complete, in file order: what a published board is
    verified against (:mod:`ipp_bench.eval.verify`). ``rows.added`` marks digests added after the
    rows were made.
``results.csv``
    :mod:`ipp_bench.eval.results_csv`. Its size and first line are checked before it is read (a
    file bigger than the run's rows can be, or not starting with the header, is refused by name).
    An episode's rows are appended in one write, flushed and fsync'ed as soon as it finishes, so a
    killed run loses no finished episode. On resume a torn last line (the write a kill interrupted)
    and episodes with missing rows (a row deleted by hand) are dropped and run again. Any other bad
    row refuses the resume in one line naming the file, the line and what is wrong, and nothing is
    written (:func:`~ipp_bench.eval.results_csv.checked_rows`): a row that does not parse, a value that is
    not a finite number, a task, planner, seed or report time that is not this run's, a repeated
    row, or a row whose digest run.json does not record (edited by hand; only the rows of the one
    append a kill cut off from run.json's update may lack one). A run.json without ``rows`` gets
    the other checks alone. ``isolated_planners``: the planners of which at least one episode here
    flew in a process of its own (:data:`~ipp_bench.eval.run_json.ISOLATED_KEY`). When every episode
    is in, the file is rewritten sorted (task, planner, seed, time), so its content does not depend
    on the order in which workers finished.
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
import json
import os
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..core.data import OutputWriteError, check_output_dir, write_atomically
from .machine import machine_info, same_machine
from .plan import Plan, report_times
from .results_csv import (
    KEY_COLUMNS,
    RESULTS_CSV,
    ROW_DIGEST_HEX,
    BadRow,
    check_results_file,
    checked_rows,
    finite_problem,
    format_header,
    format_rows,
    max_results_bytes,
    row_digest,
)
from .run_json import ISOLATED_KEY, ROWS_ADDED_KEY, RUN_JSON, ResultsMismatchError, new_meta, resumed_meta

#: the copy of a published board's results.csv in a folder paired with it (``--against``)
PUBLISHED_CSV = "published_results.csv"


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
        return new_meta(self.plan, self.command, created)

    def _check_fingerprint(self) -> None:
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
        self._meta, notes = resumed_meta(stored_meta, stored, self.plan, self.command, self.rerun, self.csv_path)
        self.notes += notes

    def _load(self) -> None:
        """Read finished episodes; note torn lines and incomplete episodes (dropped at begin())."""
        if not self.csv_path.exists() or self.csv_path.stat().st_size == 0:
            self._rewrite_rows = []
            return
        expected = {t: report_times(t, self.plan.env_overrides) for t in self.plan.tasks}
        rows_at_most = sum(len(ts) for ts in expected.values()) * len(self.plan.planners) * len(self.plan.seeds)
        try:  # its size and first line before reading it: a huge file that is not CSV is never read whole
            check_results_file(self.csv_path, max_results_bytes(rows_at_most, self.plan.tasks, self.plan.planners))
            text = self.csv_path.read_text()
        except (OSError, UnicodeDecodeError) as err:
            raise ResultsMismatchError(f"{self.csv_path} cannot be read ({getattr(err, 'strerror', None) or err}); "
                                       f"pass a new --out DIR (or delete {self.dir})") from None
        except ValueError as err:
            raise ResultsMismatchError(f"{err}; pass a new --out DIR (or delete {self.dir})") from None
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
        """:func:`~ipp_bench.eval.results_csv.checked_rows` of ``text`` against this run and the
        digests run.json records (where it records them).

        Raises:
            ResultsMismatchError: ``FILE:LINE: what is wrong``, the first bad row; nothing is changed.
        """
        recorded = (self._stored_meta or {}).get("rows")
        known, count = None, 0
        if isinstance(recorded, dict) and isinstance(recorded.get("digests"), str):
            d = recorded["digests"]
            known = {d[i:i + ROW_DIGEST_HEX] for i in range(0, len(d), ROW_DIGEST_HEX)}
            count = int(recorded.get("count", len(d) // ROW_DIGEST_HEX))
        try:
            return checked_rows(text, expected, self.plan.planners, self.plan.seeds, known, count)
        except BadRow as err:
            if err.line == 1:
                raise ResultsMismatchError(f"{self.csv_path}:1: {err.what}; not a results file of this version: "
                                           "pass a new --out DIR") from None
            raise ResultsMismatchError(
                f"{self.csv_path}:{err.line}: {err.what}; restore the line, or delete it to fly its episode again "
                "(the other rows are kept), or pass a new --out DIR") from None

    def _write_meta(self, meta: dict[str, Any]) -> None:
        rows = {"count": len(self._digests), "digests": "".join(self._digests)}
        recorded = (self._stored_meta or {}).get("rows")
        if isinstance(recorded, dict) and ROWS_ADDED_KEY in recorded:  # older rows' digests added after the fact
            rows[ROWS_ADDED_KEY] = recorded[ROWS_ADDED_KEY]
        meta["rows"] = rows
        write_atomically(self.run_json, lambda tmp: tmp.write_text(json.dumps(meta, indent=2) + "\n"))
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
            write_atomically(self.csv_path, lambda tmp: tmp.write_text(format_header() + body))
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
            problem = finite_problem(row)
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
        recorded = [m for m in [meta.get("machine"), *meta.get("other_machines", [])] if isinstance(m, dict)]
        if not any(same_machine(m, here) for m in recorded):
            meta["other_machines"] = [*meta.get("other_machines", []), here]
        isolated = set(meta.get(ISOLATED_KEY) or [])
        if key[1] in self.plan.isolated and key[1] not in isolated:  # the planner flew isolated in this folder
            meta[ISOLATED_KEY] = sorted(isolated | {key[1]})
        self._write_meta(meta)

    def finalize(self) -> None:
        """Rewrite results.csv sorted by (task, planner, seed, time): independent of finishing order."""
        rows = sorted((r for v in self.done.values() for r in v), key=_sort_key(self.plan))
        body = format_rows(rows)
        digests = [row_digest(line) for line in body.splitlines()]
        # the same rows: the digests run.json records still hold while it is rewritten
        write_atomically(self.csv_path, lambda tmp: tmp.write_text(format_header() + body))
        recorded = (self._stored_meta or {}).get("rows")
        # run.json records every row's digest in file order: what a published board is verified against
        # (a kill between an episode's append and run.json's update leaves that episode unrecorded until now)
        stale = isinstance(recorded, dict) and recorded.get("digests") != "".join(digests)
        if digests != self._digests or stale:
            self._digests = digests
            self._write_meta(dict(self._stored_meta or self._new_meta()))

    @property
    def machines(self) -> list[dict[str, Any]]:
        """Where the rows were made (run.json's ``machine`` and ``other_machines``): [] when not recorded."""
        meta = self._stored_meta or {}
        return [m for m in [meta.get("machine"), *meta.get("other_machines", [])] if isinstance(m, dict)]

    @property
    def isolated(self) -> list[str]:
        """The planners of which at least one episode here flew isolated (run.json's ``isolated_planners``)."""
        return list((self._stored_meta or {}).get(ISOLATED_KEY) or [])

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
    into ``out_dir`` as :data:`PUBLISHED_CSV`, checking that it is the file the plan read; only the rows of the
    plan's tasks and seeds (some of the board's tasks, its first seeds), each line as it is (its digest holds).

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
    write_atomically(target, lambda tmp: tmp.write_bytes(_rows_of(data, set(plan.tasks), set(plan.seeds))))
    return target


def _rows_of(data: bytes, tasks: set[str], seeds: set[int]) -> bytes:
    """The header and the lines of ``data`` (a results.csv) of a task in ``tasks`` and a seed in ``seeds``."""
    lines = data.decode().splitlines(keepends=True)
    t, s = KEY_COLUMNS.index("task"), KEY_COLUMNS.index("seed")
    kept = [ln for ln in lines[1:] if (f := next(csv.reader([ln])))[t] in tasks and int(f[s]) in seeds]
    return "".join(lines[:1] + kept).encode()


__all__ = ["PUBLISHED_CSV", "ResultsStore", "copy_published"]
