"""Pairing new planners with a published leaderboard folder (``ipp-bench leaderboard --against FOLDER``).

:func:`read_published` reads a finished folder and verifies it (:mod:`ipp_bench.eval.verify`);
:func:`against_plan` plans new planners on its tasks, task configurations, environment overrides and
episode seeds, refusing any difference by name.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..envs.registry import resolve_task
from .fingerprint import config_differences, normalised_overrides, short_json, task_config_record
from .plan import SEED_SCHEME, Plan, episode_seeds, make_plan
from .run_json import RUN_JSON
from .verify import TRUST_FLAG, BoardRefused, read_board


@dataclass(frozen=True)
class PublishedBoard:
    """A finished leaderboard folder, read from its ``run.json`` and ``results.csv`` and verified
    (:func:`~ipp_bench.eval.verify.read_board`)."""

    folder: str
    tasks: tuple[str, ...]
    planners: tuple[str, ...]
    episodes: int
    seed: int
    seeds: tuple[int, ...]
    env_overrides: dict[str, Any]
    task_configs: dict[str, Any]
    seed_scheme: str | None
    quick: bool
    results_sha256: str
    verified: bool = True  # False: its run.json records no row digests, used with --trust-unverified

    def identity(self) -> dict[str, Any]:
        """What a board paired with it records (:attr:`Plan.against`); ``unverified`` only where it is."""
        out = {"folder": self.folder, "planners": sorted(self.planners), "episodes": self.episodes,
               "results_sha256": self.results_sha256}
        if not self.verified:
            out["unverified"] = True
        return out


def read_published(folder: str | Path, trust_unverified: bool = False) -> PublishedBoard:
    """The published board in ``folder``, verified: its ``run.json`` and every row of its complete
    ``results.csv`` (:func:`~ipp_bench.eval.verify.read_board`).

    Args:
        trust_unverified: use a board whose run.json records no row digests (``--trust-unverified``).

    Raises:
        ValueError: ``--against FOLDER: ...`` and one line naming the row or the run.json field that
            fails verification (an edited, foreign, repeated or missing row; another format; no digests
            without ``trust_unverified``), or no such folder.
    """
    try:
        board = read_board(folder, trust_unverified)
    except BoardRefused as err:
        raise ValueError(f"--against {folder}: {err}") from None
    meta, fp = board.meta, board.meta["fingerprint"]
    try:
        return PublishedBoard(str(folder), tuple(meta["tasks"]), tuple(meta["planners"]), len(meta["seeds"]),
                              int(fp["seed"]), tuple(meta["seeds"]), dict(fp.get("env_overrides") or {}),
                              dict(fp["task_configs"]), fp.get("seed_scheme"), bool(meta.get("quick", False)),
                              board.results_sha256, board.verified)
    except (ValueError, KeyError, TypeError) as err:
        raise ValueError(f"--against {folder}: {RUN_JSON} is unreadable ({type(err).__name__}: {err})") from None


def against_plan(folder: str | Path, planners: Sequence[str], tasks: Sequence[str] | None = None,
                 episodes: int | None = None, seed: int | None = None, quick: bool = False,
                 env_overrides: dict[str, Any] | None = None, log: Callable[[str], None] = print,
                 check_start: bool = True, trust_unverified: bool = False, sweeps: Sequence[str] = ()) -> Plan:
    """The plan that flies ``planners`` on the published board in ``folder``: its tasks, task
    configurations, environment overrides and episode seeds, so every new row pairs with every
    published one.

    ``tasks`` may name some of the board's tasks and ``episodes`` its first ``episodes`` seeds (the seeds are
    prefix-stable, :func:`~ipp_bench.eval.plan.episode_seeds`): the plan flies those, and only the published rows
    of those tasks and seeds join its report (:func:`~ipp_bench.eval.results.copy_published`), so a board can be
    paired with in chunks. ``seed`` and ``env_overrides`` may be given only as the board has them;
    ``trust_unverified`` uses a board whose run.json records no row digests (the report says so).
    ``sweeps``: planner specs of ``--sweep`` points (:func:`~ipp_bench.eval.sweep.sweep_specs`); a point that is on
    the board already is not flown (its published rows join the sweep), with a note.
    Every planner flies isolated, in a process of its own (a submission never runs beside the truth).

    Raises:
        ValueError: naming what differs: an argument given otherwise than the board has it (a task not on the
            board, more episodes than it has), a task configuration that today's suite gives otherwise (field
            by field), seeds that today's seed scheme derives otherwise, a planner that is on the board already;
            or the board's own problems (:func:`read_published`).
    """
    board = read_published(folder, trust_unverified)
    name = f"--against {folder}"
    if not board.verified:
        log(f"note: {name}: its {RUN_JSON} records no row digests; its rows are used unverified ({TRUST_FLAG})")
    given = []
    mine = list(board.tasks)
    if tasks is not None:
        mine = [resolve_task(t) for t in tasks]
        if set(mine) - set(board.tasks):
            given.append(f"--tasks {' '.join(t for t in mine if t not in board.tasks)}: not on the board, which has "
                         f"{' '.join(board.tasks)} (name some of these)")
    if episodes is not None and not 1 <= episodes <= board.episodes:
        given.append(f"--episodes {episodes}: the board has {board.episodes} per task and planner (give at most "
                     f"{board.episodes}: the first N of its seeds fly)")
    if seed is not None and seed != board.seed:
        given.append(f"--seed {seed}: the board's episode seeds derive from seed {board.seed}")
    if quick:
        given.append("--quick: the board decides episodes; name cheaper planner settings in --planners instead")
    if env_overrides and normalised_overrides(board.tasks, env_overrides) != board.env_overrides:
        given.append(f"--env {short_json(env_overrides)}: the board has {short_json(board.env_overrides)}")
    if given:
        raise ValueError(f"{name}: " + "; ".join(given) + " (leave these out: the published board decides them)")
    differences = []
    if board.seed_scheme not in (None, SEED_SCHEME):
        differences.append(f"seed scheme: there {board.seed_scheme!r}, now {SEED_SCHEME!r}")
    for t in board.tasks:
        if t not in board.task_configs:
            differences.append(f"{t}: the board recorded no configuration")
            continue
        differences += [f"{t} {line}" for line in
                        config_differences(board.task_configs[t], task_config_record(t, board.env_overrides))]
    if episode_seeds(board.seed, board.episodes) != list(board.seeds):
        differences.append(f"episode seeds: there {short_json(list(board.seeds))}, today's scheme gives "
                           f"{short_json(episode_seeds(board.seed, board.episodes))}")
    if differences:
        raise ValueError(f"{name}: the published board was flown on other tasks or episodes than today's suite "
                         "gives, so new rows would not pair with it:\n" + "\n".join(f"  {d}" for d in differences))
    swept = [s for s in sweeps if s not in board.planners]
    for spec in (s for s in sweeps if s in board.planners):
        log(f"note: {name}: {spec} is on the board already: its published rows join the sweep, it is not flown again")
    if not planners and not swept:
        raise ValueError(f"{name}: nothing to fly: every --sweep point is on the board already; name other values "
                         "or --planners")
    plan = make_plan([t for t in board.tasks if t in mine], planners, episodes or board.episodes, board.seed, False,
                     board.env_overrides, log=log, check_start=check_start, isolate=True,
                     isolate_why="every planner of an --against submission is isolated by default", sweeps=swept)
    clash = [p for p in plan.planners if p in board.planners]
    if clash:
        raise ValueError(f"{name}: {', '.join(clash)} is on the board already (its published rows join the report "
                         "as they are); name planners that are not on it")
    return dataclasses.replace(plan, quick=board.quick, against=board.identity())


__all__ = ["PublishedBoard", "against_plan", "read_published"]
