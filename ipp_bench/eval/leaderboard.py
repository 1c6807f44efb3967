"""The leaderboard: every planner on every benchmark task over the same episode seeds.

``run_leaderboard(make_plan(...), out_dir)`` runs the episodes that ``out_dir/results.csv`` does
not hold yet and then writes the report (``leaderboard.md`` and PNG plots, see
:mod:`ipp_bench.eval.report`). Planning the run (arguments, seeds, fingerprint) is
:mod:`ipp_bench.eval.plan`; the results folder (run.json, resumable results.csv, lock) is
:mod:`ipp_bench.eval.results`; where episodes run is :mod:`ipp_bench.eval.executors`. This
module runs them; import the names of the other three from them.

An interrupted run (Ctrl-C, SIGTERM) keeps every finished episode; rerunning the same command
resumes it. Workers of the process pool, and a local Ray the run started, end when the run's
process dies.
"""

from __future__ import annotations

import json
import sys
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..core.data import OutputWriteError
from ..envs import load_task, short_task_id
from .executors import default_backend, make_executor
from .jobs import JobError, JobFailed
from .machine import describe_machine
from .methods import METHODS_KEY
from .plan import EpisodeJob, Plan, report_times
from .power import POWER_HALF_WIDTH
from .results import ResultsStore, copy_published
from .run_json import ISOLATED_KEY, RUN_JSON
from .runner import run_episode


class Interrupted(Exception):
    """The run was interrupted (Ctrl-C or SIGTERM); ``kept`` finished episodes are in ``out_dir``."""

    def __init__(self, kept: int, total: int, out_dir: Path):
        super().__init__(f"interrupted; {kept} of {total} episodes kept in {out_dir}; "
                         "rerun the same command to resume")
        self.kept, self.total, self.out_dir = kept, total, out_dir


class EpisodeFailed(Exception):
    """An episode gave no result (its planner raised, or its worker process died); the run stopped
    and ``kept`` finished episodes are in ``out_dir``."""

    def __init__(self, job: EpisodeJob, reason: str, kept: int, total: int, out_dir: Path, command: str | None):
        resume = f": {command}" if command else ""
        super().__init__(f"episode {short_task_id(job.task)} {job.planner} seed {job.seed} failed: {reason}; "
                         f"stopped, {kept} of {total} episodes kept in {out_dir}; fix the cause and rerun "
                         f"the same command to resume{resume}")
        self.job, self.reason, self.kept, self.total, self.out_dir = job, reason, kept, total, out_dir


def run_job(job: EpisodeJob) -> list[dict[str, Any]]:
    """Fly one episode and return its results.csv rows (one per report time).

    Raises:
        JobError: the episode failed (e.g. a budget too small for any first move, a planner that
            raised): one line, with where the exception was raised.
    """
    try:
        if job.task_file is not None:  # a user's task: registered in this process too
            load_task(job.task_file)
        result = run_episode(job.task, job.flies or job.planner, job.seed, isolate=job.isolate,
                             **dict(job.env_overrides))
    except Exception as err:
        raise JobError(one_line(err)) from None
    expected = report_times(job.task, dict(job.env_overrides))
    got = tuple(r["time_s"] for r in result.report)
    if got != expected:
        raise RuntimeError(f"{job.key}: the runner reported at {got}, expected {expected}")
    common = {
        "decisions": result.decisions,
        "decision_time_mean_s": result.decision_time_mean_s,
        "decision_time_max_s": result.decision_time_max_s,
        "episode_wall_s": result.episode_wall_s,
    }
    return [{"task": job.task, "planner": job.planner, "seed": job.seed, **r, **common} for r in result.report]


def published_meta(plan: Plan) -> dict[str, Any]:
    """The run.json of the published board ``plan`` is paired with ({} without one)."""
    if plan.against is None:
        return {}
    try:
        meta = json.loads((Path(plan.against["folder"]) / RUN_JSON).read_text())
    except (OSError, ValueError):  # read and verified while planning: gone since, the report just cannot say
        return {}
    return meta if isinstance(meta, dict) else {}


def published_isolated(plan: Plan) -> list[str]:
    """The planners whose rows the published board ``plan`` is paired with records as flown isolated."""
    isolated = published_meta(plan).get(ISOLATED_KEY)
    return [str(p) for p in isolated] if isinstance(isolated, list) else []


def board_methods(plan: Plan) -> dict[str, Any]:
    """The methods of the board's report (run.json's record; with ``--against``, the published board's too)."""
    published = (published_meta(plan).get("fingerprint") or {}).get(METHODS_KEY)
    return {**(published if isinstance(published, dict) else {}), **plan.fingerprint().get(METHODS_KEY, {})}


def one_line(err: BaseException) -> str:
    """``Type: first line of the message (at file:line in function)``, the innermost frame."""
    lines = str(err).strip().splitlines()
    text = f"{type(err).__name__}: {lines[0]}" if lines else type(err).__name__
    tb = err.__traceback__
    if tb is None:
        return text
    frame = traceback.extract_tb(tb)[-1]
    return f"{text} (at {Path(frame.filename).name}:{frame.lineno} in {frame.name})"


@dataclass
class Summary:
    out_dir: Path
    total: int
    skipped: int
    ran: int
    wall_s: float
    files: list[Path]


class _Progress:
    """tqdm on a terminal, plain lines otherwise (CI logs)."""

    def __init__(self, total: int, enabled: bool | None, log: Callable[[str], None]):
        self.total = total
        self.count = 0
        self.log = log
        self.bar = None
        if enabled is None:
            enabled = sys.stderr.isatty()
        if enabled and total:
            try:
                from tqdm import tqdm
            except ImportError:  # plain lines are enough
                tqdm = None
            if tqdm is not None:
                self.bar = tqdm(total=total, unit="ep", dynamic_ncols=True, desc="leaderboard")

    def update(self, job: EpisodeJob, rows: list[dict[str, Any]]) -> None:
        self.count += 1
        last = rows[-1]
        task = short_task_id(job.task)
        network = f" network {job.network + 1}" if job.network is not None else ""
        text = (f"{task} {job.planner}{network} seed={job.seed}: "
                f"uncertainty reduction {last['uncertainty_reduction_pct']:.1f}%, "
                f"RMSE reduction {last['rmse_reduction_pct']:.1f}% "
                f"at {last['time_s']:g} s, {last['decisions']} decisions, {last['episode_wall_s']:.1f} s")
        if self.bar is not None:
            self.bar.set_postfix_str(f"{task} {job.planner}", refresh=False)
            self.bar.update(1)
        else:
            self.log(f"[{self.count}/{self.total}] {text}")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def run_leaderboard(plan: Plan, out_dir: str | Path, backend: str | None = None, workers: int | None = None,
                    address: str | None = None, progress: bool | None = None, command: str | None = None,
                    report: bool = True, reference: str | None = "greedy",
                    log: Callable[[str], None] = print, rerun: Sequence[str] = (),
                    power: float | None = POWER_HALF_WIDTH) -> Summary:
    """Run the episodes of ``plan`` that ``out_dir`` lacks, then write the report.

    Args:
        plan: from :func:`make_plan`.
        out_dir: output folder (created).
        backend: ``serial``, ``process`` or ``ray``; default ``process`` when more than one worker,
            else ``serial``.
        workers: processes / local Ray CPUs; default: the CPUs available.
        address: Ray cluster (``ray`` backend).
        progress: tqdm bar (True), plain lines (False), or tqdm only on a terminal (None).
        command: the command line, recorded in run.json and the report.
        report: write leaderboard.md and the plots at the end.
        reference: the planner every other one is compared with, episode by episode, in the report.
        rerun: planners of ``plan`` whose rows in ``out_dir`` are dropped and flown again (a
            retrained checkpoint's, say): the folder then holds what ``command`` gives today, with
            every other row kept.
        power: the half-width target [points] of the report's power rule (None: no power section).

    A plan paired with a published board (:func:`~ipp_bench.eval.plan.against_plan`) flies only its
    own planners; the board's results.csv is copied into ``out_dir`` (never written to) and its rows
    join the report, marked as published.

    Raises:
        ResultsMismatchError: ``out_dir`` holds results of other arguments, is locked or unwritable.
        ExecutorError: the backend cannot start (e.g. no Ray cluster at ``address``); nothing written.
        ImportError: ray backend without Ray.
        Interrupted: Ctrl-C (or SIGTERM turned into KeyboardInterrupt); finished episodes are kept.
        EpisodeFailed: an episode raised or its worker died; the run stopped, finished episodes are kept.
        OutputWriteError: a file could not be written (a full disk), naming it; finished episodes are kept.
    """
    t0 = time.perf_counter()
    if plan.against is not None and Path(out_dir).resolve() == Path(plan.against["folder"]).resolve():
        raise ValueError(f"--out {out_dir} is the published board itself: pairing with it never writes there; "
                         "pass another --out DIR")
    if backend is None:
        backend = default_backend(workers)
    with ResultsStore(out_dir, plan, command, rerun) as store:
        for note in store.notes:
            log(f"note: {note}")
        jobs = plan.jobs()
        todo = [j for j in jobs if j.key not in store.done]
        skipped = len(jobs) - len(todo)
        log(f"leaderboard: {len(plan.tasks)} tasks x {len(plan.planners)} planners x {plan.episodes} episodes "
            f"= {len(jobs)} episodes; {skipped} already in {store.csv_path}, {len(todo)} to run")
        if not todo:
            log(f"all {len(jobs)} episodes are already complete in {store.csv_path}; nothing to run")
        executor = make_executor(backend, workers, address) if todo else None  # before anything is written
        store.begin()
        if executor is not None:
            log(f"running on {executor.describe()}")
            bar = _Progress(len(todo), progress, log)
            aborted = True
            try:
                for job, rows in executor.imap_unordered(run_job, todo):
                    try:
                        store.append(rows)
                    except ValueError as err:  # a value that is not a finite number: never written
                        raise JobFailed(job, str(err)) from None
                    bar.update(job, rows)
                aborted = False
            except KeyboardInterrupt:
                raise Interrupted(len(store.done), len(jobs), Path(out_dir)) from None
            except JobFailed as err:
                raise EpisodeFailed(err.job, err.reason, len(store.done), len(jobs), Path(out_dir), command) from None
            except OutputWriteError as err:  # a full disk: stop, what is on disk stays resumable
                raise OutputWriteError(f"{err}; stopped, {len(store.done)} of {len(jobs)} episodes kept in "
                                       f"{out_dir}; free space and rerun the same command to resume") from None
            finally:
                bar.close()
                executor.close(abort=aborted)
        store.finalize()
        files = [store.csv_path, store.run_json]
        published = None
        if plan.against is not None:
            published = copy_published(plan, out_dir)
            files.append(published)
        if report:
            from .report import write_report

            files += write_report(store.csv_path, out_dir, tasks=plan.tasks, planners=plan.planners,
                                  command=command, quick=store.quick, reference=reference, log=log,
                                  published_csv=published,
                                  published_from=plan.against["folder"] if plan.against else None, power=power,
                                  published_unverified=bool(plan.against and plan.against.get("unverified")),
                                  made_on=[describe_machine(m) for m in store.machines],
                                  isolated=[*store.isolated, *published_isolated(plan)],
                                  methods=board_methods(plan), seeds=plan.seeds)
    wall = time.perf_counter() - t0
    return Summary(Path(out_dir), len(jobs), skipped, len(todo), wall, files)


__all__ = ["EpisodeFailed", "Interrupted", "Summary", "run_job", "run_leaderboard"]
