"""``ipp-bench``: the command line of the suite.

Subcommands::

    ipp-bench tasks                                     registered tasks and their tags
    ipp-bench fit-prior --task T [--write]              fit the task's GP prior to its field family
    ipp-bench evaluate --task T --planner P --seed S    one episode, its metrics (--render out.png)
    ipp-bench leaderboard [--quick] [--out DIR] ...     every planner on every benchmark task
    ipp-bench leaderboard --planners P --against DIR    a new planner paired with a published board
    ipp-bench leaderboard --sweep mcts:simulations=8,64 one setting's range: quality against decision time
    ipp-bench power DIR [--half-width 3]                episodes each task needs for a paired interval
    ipp-bench train ... | --recipe NAME --out DIR       train the attention policy   (extra [train])
    ipp-bench demo ...                                  MuJoCo deployment demo       (extra [sim])

A subcommand's module is imported only when that subcommand runs, so ``ipp-bench leaderboard``
never imports torch or mujoco for itself (a planner that needs torch imports it when it is built).
Bad arguments (unknown task or planner, a bad planner setting, results of other arguments in
``--out``, an unwritable path, no Ray cluster) end with the library's message and exit status 2,
without a traceback, before any episode runs. Ctrl-C ends with one line and exit status 130 (SIGTERM
during a leaderboard: 143); a leaderboard keeps its finished episodes and resumes on a rerun. An
episode that fails part-way (its planner raised, its worker died, a full disk) ends the leaderboard
with one line naming it and exit status 1; the finished episodes are kept.

Over 400 lines because it holds every subcommand's arguments and their checks; the work itself is
done by the modules each subcommand calls.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import os
import shlex
import signal
import sys
import time
from collections.abc import Sequence

from . import __version__

EXIT_USAGE = 2
MAX_FIT_MAPS = 10_000  # fit-prior --maps: the fit's cost grows linearly, 40 is the default
EXIT_FAILED = 1  # an episode failed part-way (finished ones are kept)
EXIT_INTERRUPTED = 130  # 128 + SIGINT, what a shell reports for Ctrl-C
EXIT_TERMINATED = 143  # 128 + SIGTERM

# subcommand -> (module, add_arguments, run, extra)
_DELEGATED = {
    "train": ("ipp_bench.train.command", "add_train_arguments", "run_train", "train",
              "train the attention policy (DAgger warm start + MaskablePPO), or rebuild a shipped one "
              "(--recipe attention_v6)"),
    "demo": ("ipp_bench.eval.demo", "add_demo_arguments", "run_demo", "sim",
             "fly a planner in the MuJoCo deployment and render it"),
}


def _error(message: str) -> int:
    print(f"ipp-bench: error: {message}", file=sys.stderr)
    return EXIT_USAGE


# --------------------------------------------------------------------------------------------------
# parser
# --------------------------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ipp-bench", description="Benchmark suite for adaptive 3D informative path planning with UAVs.")
    parser.add_argument("--version", action="version", version=f"ipp-bench {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    sub.add_parser("tasks", help="list the registered tasks and their tags",
                   description="List the registered tasks with their tags.")

    fp = sub.add_parser("fit-prior", help="fit a task's GP prior to its field family (log marginal likelihood)",
                        description="Fit the Matern 3/2 prior (length scale, signal variance, nugget; the mean "
                                    "fixed at the task's, or fitted with --fit-mean) to independent maps of the "
                                    "task's field family by maximising the log marginal likelihood, as the paper "
                                    "did (Section V-A).")
    fp.add_argument("--task", required=True, help="task id, e.g. ipp_bench/Grid15Eval-v1 (prefix optional)")
    fp.add_argument("--maps", type=int, default=None, help="independent maps to fit on (default 40)")
    fp.add_argument("--seed", type=int, default=None, help="seed of the fitting maps (default: the fixed fit seed)")
    fp.add_argument("--fit-mean", action="store_true",
                    help="fit the prior mean too (generalised least squares; sparse fields such as weed patches "
                         "average far below the paper's 0.5)")
    fp.add_argument("--write", action="store_true",
                    help="write the fitted values into the task's TOML file, with this command as a comment")

    ev = sub.add_parser("evaluate", help="run one episode and print its metrics",
                        description="Run one episode of one planner on one task and print its metrics.")
    ev.add_argument("--task", required=True,
                    help="task id, e.g. ipp_bench/Grid15Eval-v1 (prefix optional), or a task file path/to/mine.toml")
    ev.add_argument("--planner", required=True, help="planner spec, e.g. greedy or mcts:simulations=50")
    ev.add_argument("--seed", type=int, default=0, help="episode seed (field, start, sensor noise); default 0")
    ev.add_argument("--render", metavar="PNG", help="save the final render of the episode to this PNG")
    ev.add_argument("--env", metavar="KEY=VALUE", action="append", default=[],
                    help="override a task config field, e.g. --env budget_s=100 (repeatable)")
    ev.add_argument("--json", action="store_true", help="print the metrics as JSON")

    lb = sub.add_parser("leaderboard", help="every planner on every benchmark task, with report",
                        description="Run the leaderboard: every planner on every task over the same episode "
                                    "seeds; writes results.csv, leaderboard.md, plots and run.json to --out. "
                                    "Resumable: rerun the same command to complete an interrupted run.")
    lb.add_argument("--tasks", nargs="+", metavar="TASK",
                    help="task ids or task files path/to/mine.toml (default: all tagged 'benchmark')")
    lb.add_argument("--planners", nargs="+", metavar="SPEC",
                    help="planner specs such as greedy or mcts:simulations=50, separated by spaces or commas "
                         "(default: every registered planner that can be built here; the others are named)")
    lb.add_argument("--sweep", metavar="SPEC", action="append", default=[],
                    help="fly a planner over a range of one numeric setting, one planner spec per value, beside the "
                         "other planners: NAME:KEY=V1,V2,... with fixed settings after the values as KEY=VALUE, e.g. "
                         "mcts:simulations=8,24,64 (repeatable); the report draws quality against decision time")
    lb.add_argument("--episodes", type=int, help="episodes per task and planner (default 20; --quick: 3)")
    lb.add_argument("--seed", type=int, default=None, help="base seed the episode seeds derive from (default 0)")
    lb.add_argument("--workers", type=int, help="parallel workers (default: the CPUs available)")
    lb.add_argument("--backend", choices=("serial", "process", "ray"),
                    help="where episodes run (default: process with more than one worker, else serial)")
    lb.add_argument("--address", help="Ray cluster address for --backend ray (default: RAY_ADDRESS, else local)")
    lb.add_argument("--out", default="leaderboard", metavar="DIR", help="output folder (default ./leaderboard)")
    lb.add_argument("--quick", action="store_true",
                    help="few episodes and cheaper look-ahead settings: minutes on 2 cores")
    lb.add_argument("--env", metavar="KEY=VALUE", action="append", default=[],
                    help="override a config field of every task, e.g. --env budget_s=100 (repeatable)")
    lb.add_argument("--rerun", metavar="SPEC", action="append", default=[],
                    help="drop this planner's rows in --out and fly them again, keeping every other row (e.g. "
                         "after retraining a checkpoint, whose rows the folder then refuses); repeatable; the "
                         "folder records the command without it")
    lb.add_argument("--reference", default=None, metavar="SPEC",
                    help="planner the report compares every other one with, episode by episode (default greedy, "
                         "when it runs); it must be one of the run's planners")
    lb.add_argument("--isolate", action="store_true",
                    help="fly every planner in a process of its own, which receives only what the robot measures and "
                         "never the ground truth (the same numbers); on by default for planners of installed plugins "
                         "and for every --against planner; refused for team and MuJoCo tasks")
    lb.add_argument("--against", metavar="FOLDER",
                    help="pair the --planners and --sweep with a published board (e.g. baselines/v2): fly them on its "
                         "tasks, task configurations and episode seeds (--tasks: some of its tasks; --episodes N: its "
                         "first N seeds), and write to --out a report with its rows of those copied in (marked "
                         "published); FOLDER is only read. A task configuration or seed set that differs is refused, "
                         "naming what differs")
    lb.add_argument("--trust-unverified", action="store_true",
                    help="with --against: use a published board whose run.json records no row digests (made before "
                         "they were recorded); its rows are still checked otherwise, and the report says they are "
                         "unverified")
    lb.add_argument("--power", type=float, default=None, metavar="POINTS",
                    help="half-width target of the report's power rule: the episodes each task needs for a paired "
                         "95%% interval of every planner minus the reference within +-POINTS (default 3)")
    progress = lb.add_mutually_exclusive_group()
    progress.add_argument("--progress", dest="progress", action="store_true", default=None,
                          help="always show a progress bar")
    progress.add_argument("--no-progress", dest="progress", action="store_false",
                          help="plain lines instead of a progress bar (the default off a terminal)")

    pw = sub.add_parser("power", help="episodes each task of a leaderboard folder needs for a given paired interval",
                        description="The power rule on a finished leaderboard folder: per task and report time, the "
                                    "sd of every planner's paired difference with the reference, the episodes, the "
                                    "half-width reached, and the episodes needed for a paired 95 % interval of "
                                    "half-width at most --half-width points: n = ceil((1.96 sd / h)^2). Reads only; "
                                    "the folder is verified first (every row against its run.json, as --against "
                                    "does).")
    pw.add_argument("folder", metavar="DIR", help="a finished leaderboard folder (its run.json and results.csv)")
    pw.add_argument("--half-width", type=float, default=None, metavar="POINTS",
                    help="the target half-width in points (default 3)")
    pw.add_argument("--reference", default=None, metavar="SPEC",
                    help="the planner every other one is paired with (default greedy)")
    pw.add_argument("--trust-unverified", action="store_true",
                    help="use a folder whose run.json records no row digests (made before they were recorded); "
                         "its rows are still checked otherwise")

    for name, (_, _, _, extra, text) in _DELEGATED.items():
        sub.add_parser(name, help=f"{text} (needs ipp-bench[{extra}]; see 'ipp-bench {name} --help')",
                       add_help=False)
    return parser


# --------------------------------------------------------------------------------------------------
# subcommands
# --------------------------------------------------------------------------------------------------
def cmd_tasks(args: argparse.Namespace) -> int:
    from .envs import TASK_FILE_ERRORS, TASKS

    for error in TASK_FILE_ERRORS:
        print(f"skipped task file {error}", file=sys.stderr)

    width = max(len(t) for t in TASKS) if TASKS else 0
    tag_width = max((len(", ".join(s.tags)) for s in TASKS.values()), default=1)
    for task_id, spec in TASKS.items():
        mission, grid = spec.config.mission, spec.config.grid
        print(f"{task_id:<{width}}  tags: {', '.join(spec.tags) or '-':<{tag_width}}  "
              f"{grid.rows}x{grid.cols} cells, {mission.field} fields, budget {mission.budget_s:g} s")
    return 0


def _rough_seconds(seconds: float) -> str:
    """A duration for a progress line: "10 s", "2 min"."""
    if seconds < 90:
        return f"{max(1, round(seconds, -1 if seconds >= 20 else 0)):.0f} s"
    return f"{round(seconds / 60):.0f} min"


def cmd_fit_prior(args: argparse.Namespace) -> int:
    from .core import gp_fit
    from .envs import task_spec

    maps = gp_fit.DEFAULT_MAPS if args.maps is None else args.maps
    seed = gp_fit.FIT_SEED if args.seed is None else args.seed
    try:
        spec = task_spec(args.task)
        if not 2 <= maps <= MAX_FIT_MAPS:
            raise ValueError(f"--maps = {maps} is invalid: expected an integer in [2, {MAX_FIT_MAPS}]")
        if seed < 0:
            raise ValueError(f"--seed = {seed} is invalid: expected an integer >= 0")
        if args.write and not os.access(spec.source, os.W_OK):
            raise ValueError(f"--write: the task file {spec.source} is not writable")
        from .core.limits import check_fit_size

        check_fit_size(spec.config, maps)  # before any map is drawn (128 x 128: 10 GiB)
    except ValueError as err:
        return _error(str(err))
    from .core._threads import limit_blas_threads

    limit_blas_threads()  # two BLAS threads on a busy 2-core machine made the fit 10-20 times slower
    cfg = spec.config
    mean_text = "prior mean fitted" if args.fit_mean else f"prior mean {cfg.gp.prior_mean:g} fixed"
    eta = gp_fit.estimate_seconds(cfg, maps, seed)
    print(f"{spec.id}: fitting a Matern 3/2 prior to {maps} {cfg.mission.field} maps of "
          f"{cfg.grid.rows} x {cfg.grid.cols} cells (seed {seed}, {mean_text}) by maximising the log marginal "
          f"likelihood from 2 starts, then scoring it on 20 held-out maps; roughly {_rough_seconds(eta)}", flush=True)
    started = time.perf_counter()

    def progress(line: str) -> None:
        print(f"  [{time.perf_counter() - started:5.1f} s] {line}", flush=True)

    fit = gp_fit.fit_prior(cfg, maps, seed, fit_mean=args.fit_mean, progress=progress)
    held = gp_fit.held_out_lml(cfg, fit.length_scale, fit.signal_variance, fit.nugget, prior_mean=fit.prior_mean)
    task_gp = cfg.gp
    held_task = gp_fit.held_out_lml(cfg, task_gp.length_scale, task_gp.signal_variance, max(task_gp.nugget, 1e-9))
    mean_line = f"  prior_mean      {fit.prior_mean:.4g} (fitted)\n" if args.fit_mean else ""
    print(f"  length_scale    {fit.length_scale:.4g} m\n  signal_variance {fit.signal_variance:.4g}\n"
          f"  nugget          {fit.nugget:.4g}\n{mean_line}  log marginal likelihood per map: "
          f"{fit.lml_per_map:.2f} (fit maps), "
          f"{held:.2f} (held-out maps; the task file's current prior: {held_task:.2f})")
    if fit.length_scale > 100.0 and fit.nugget > fit.signal_variance:
        print("  note: the maps have no spatial structure at this scale (the nugget holds the variance)")
    if args.write:
        command = f"ipp-bench fit-prior --task {spec.id}" + ("" if args.maps is None else f" --maps {maps}") \
            + ("" if args.seed is None else f" --seed {seed}") + (" --fit-mean" if args.fit_mean else "") + " --write"
        gp_fit.write_gp_section(spec.source, fit, command)
        print(f"wrote [config.gp] of {spec.source}")
    return 0


def _finite_or_none(value):
    """``value`` with every non-finite float replaced by None (JSON has no NaN or Infinity)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(v) for v in value]
    return value


#: [s] wall time between two progress lines of a long ``evaluate`` episode (on stderr)
EVALUATE_PROGRESS_EVERY_S = 10.0


class _EpisodeProgress:
    """``on_decision`` hook: a line on stderr every :data:`EVALUATE_PROGRESS_EVERY_S` of wall time
    (mission time, decisions), so a long episode (MCTS on 30 x 30: minutes) is not silent."""

    def __init__(self, env):
        import time

        self._env, self._clock = env, time.perf_counter
        self._start = self._last = self._clock()

    def __call__(self, decision) -> None:
        now = self._clock()
        if now - self._last < EVALUATE_PROGRESS_EVERY_S:
            return
        self._last = now
        mission = self._env.mission
        print(f"  ... mission time {mission.time_s:.0f} of {mission.budget_s:g} s, {decision.index + 1} decisions, "
              f"{now - self._start:.0f} s so far", file=sys.stderr, flush=True)


def cmd_evaluate(args: argparse.Namespace) -> int:
    from .core.data import OutputWriteError, check_output_file
    from .envs import parse_overrides, resolve_task, task_config, task_spec
    from .eval.plan import canonical_spec
    from .planners import make_planner

    try:
        task = resolve_task(args.task)
        task_spec(task)  # names the valid tasks
        env = parse_overrides(args.env)
        lo, hi = task_config(task, env).mission.episode_seeds  # validates the overrides
        if not 0 <= args.seed < hi - lo:  # reset(seed=s) plays lo + s mod (hi - lo): a larger one repeats
            raise ValueError(f"--seed {args.seed} is invalid: expected an integer in [0, {hi - lo - 1}] "
                             f"(the task's {hi - lo} episode seeds, mission.episode_seeds = [{lo}, {hi}))")
        if args.render:
            from .eval.figure import require_figure

            render = check_output_file(args.render, "--render", suffix=".png")
            if not render.parent.is_dir():  # the figure is written into an existing folder, never makes one
                raise ValueError(f"--render {args.render}: the folder {render.parent} does not exist "
                                 "(create it, or pass a path in an existing folder)")
            require_figure()  # before the episode, not after it
        spec = canonical_spec(args.planner)
        planner = make_planner(spec)  # a planner that cannot be built here fails now, with its message
        from .envs import make_env
        from .eval.runner import run_episode
        from .planners.episode import start_episode

        task_env = make_env(task, **env)
        start_episode(task_env, planner, args.seed)  # what the episode's start refuses, refused now
    except (ValueError, ImportError) as err:
        return _error(str(err))

    try:
        result = run_episode(task, spec, args.seed, env=task_env, render_path=args.render,
                             on_decision=_EpisodeProgress(task_env))
    except OutputWriteError as err:  # --render: a full disk, say (the old file is left as it was)
        print(f"ipp-bench: error: {err}", file=sys.stderr)
        return EXIT_FAILED
    except Exception as err:  # the planner (or the episode) raised part-way: as the leaderboard says it
        from .envs import short_task_id
        from .eval.leaderboard import one_line

        print(f"ipp-bench: error: episode {short_task_id(task)} {spec} seed {args.seed} failed: {one_line(err)}",
              file=sys.stderr)
        return EXIT_FAILED
    if args.json:  # strict JSON: a metric that is not a number (no ROI, say) is null, never NaN
        print(json.dumps(_finite_or_none(result.to_dict()), indent=2, allow_nan=False))
        return 0
    print(f"{task}  planner {spec}  seed {args.seed}")
    print(f"{'time [s]':>9} {'ROI trace':>11} {'ROI RMSE':>9} {'uncertainty red.':>17} {'RMSE red.':>10}")
    rows = result.report or [result.final]  # no report time within the budget: the end of the mission
    for r in rows:
        print(f"{r['time_s']:>9g} {r['trace_roi']:>11.4g} {r['rmse_roi']:>9.4f} "
              f"{r['uncertainty_reduction_pct']:>16.1f}% {r['rmse_reduction_pct']:>9.1f}%")
    if not result.report:
        print("(no report time lies within the budget: the row is the end of the mission)")
    print(f"decisions {result.decisions}, decision time mean {result.decision_time_mean_s:.4g} s, "
          f"max {result.decision_time_max_s:.4g} s, episode wall time {result.episode_wall_s:.2f} s")
    if args.render:
        print(f"render saved to {args.render}")
    return 0


def _reference(reference: str | None, planners: Sequence[str]) -> str | None:
    """The report's reference planner: ``--reference`` must name one of the run's planners; without
    it, greedy where it runs (else the report says there is no paired comparison)."""
    from .eval.tables import DEFAULT_REFERENCE

    if reference is None:
        return DEFAULT_REFERENCE
    _one_of(reference, planners, "--reference")
    return reference.strip()


def _one_of(spec: str, planners: Sequence[str], flag: str) -> str:
    """The run's planner that ``spec`` names (its canonical spec, or its bare name when only one
    spec of the run has that name)."""
    from .eval.tables import resolve_reference

    found = resolve_reference(spec.strip(), planners) if spec.strip() else None
    if found is None:
        raise ValueError(f"{flag} {spec!r} names no planner of this run: valid are {list(planners)}")
    return found


def _without_option(argv: Sequence[str], flag: str) -> list[str]:
    """``argv`` without ``flag VALUE`` and ``flag=VALUE``."""
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a == flag:
            skip = True
        elif not a.startswith(flag + "="):
            out.append(a)
    return out


class _SigtermAsInterrupt:
    """SIGTERM handler: stop like Ctrl-C (KeyboardInterrupt), remembering that it was SIGTERM."""

    received = False

    def __call__(self, signum, frame) -> None:
        self.received = True
        raise KeyboardInterrupt


def _half_width(value: float | None, flag: str) -> float:
    """The power rule's target: a finite number of points > 0 (default 3)."""
    from .eval.power import POWER_HALF_WIDTH

    if value is None:
        return POWER_HALF_WIDTH
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{flag} {value:g} is invalid: expected a number of points > 0 (e.g. 3)")
    return float(value)


def cmd_power(args: argparse.Namespace) -> int:
    from .envs import short_task_id
    from .eval.power import needed_per_task, power_rule
    from .eval.tables import DEFAULT_REFERENCE, resolve_reference
    from .eval.verify import read_board

    try:
        h = _half_width(args.half_width, "--half-width")
        board = read_board(args.folder, args.trust_unverified)  # every row checked before a figure is computed
        rows = board.rows
        planners = board.planners
        reference = resolve_reference((args.reference or DEFAULT_REFERENCE).strip(), planners)
        if reference is None:
            raise ValueError(f"--reference {args.reference or DEFAULT_REFERENCE!r} names no planner of {args.folder}: "
                             f"valid are {planners}")
    except ValueError as err:
        return _error(str(err))
    cells = power_rule(rows, reference, h, networks=board.networks)
    if not cells:
        return _error(f"{args.folder}: no planner shares an episode with {reference}")
    print(board.describe())
    print(f"{args.folder}: every planner minus {reference}, paired 95% interval of half-width <= {h:g} points; "
          f"n = ceil((1.96 sd / {h:g})^2), sd of the paired difference over the folder's episodes")
    print(f"{'task':<20} {'time [s]':>8} {'episodes':>8} {'largest sd':>10} {'half-width':>10} {'needed':>7}  set by")
    for task in dict.fromkeys(c.task for c in cells):
        for t in sorted({c.time_s for c in cells if c.task == task}):
            cs = [c for c in cells if c.task == task and c.time_s == t]
            top = max(cs, key=lambda c: (c.needed, c.sd))
            widths = [c.half_width for c in cs if c.half_width is not None]
            print(f"{short_task_id(task):<20} {t:>8g} {max(c.episodes for c in cs):>8} {top.sd:>10.2f} "
                  f"{(f'{max(widths):.2f}' if widths else '-'):>10} {top.needed:>7}  {top.planner}")
    print("episodes each task needs (the most over planners and report times):")
    for task, c in needed_per_task(cells).items():
        flown = max(x.episodes for x in cells if x.task == task)
        print(f"  {task}: {c.needed} (flown {flown}; set by {c.planner} at {c.time_s:g} s)")
    print("caveat: sd is estimated from these episodes (roughly, from few): apply the rule again once the folder is "
          "extended; the percentile bootstrap interval is about sqrt((n-1)/n) times the normal one")
    return 0


def cmd_leaderboard(args: argparse.Namespace, argv: Sequence[str]) -> int:
    from .core.data import OutputWriteError, check_output_dir
    from .envs import parse_overrides
    from .eval.against import against_plan
    from .eval.executors import check_executor_args, default_backend
    from .eval.jobs import ExecutorError
    from .eval.leaderboard import EpisodeFailed, Interrupted, run_leaderboard
    from .eval.plan import describe_quick, make_plan
    from .eval.run_json import ResultsMismatchError
    from .eval.sweep import sweep_specs
    from .planners import split_specs

    started = time.perf_counter()
    if args.quick:
        print(describe_quick(), flush=True)
    try:
        check_output_dir(args.out)
        specs = split_specs(args.planners) if args.planners is not None else None
        if specs is not None and not specs:
            raise ValueError(f"--planners {' '.join(args.planners)!r} names no planner: pass planner specs "
                             "(e.g. --planners random greedy), or leave --planners out for every planner")
        power = _half_width(args.power, "--power")
        swept = sweep_specs(args.sweep)  # a bad --sweep is refused here, before any work
        _compile_search_kernels([*(specs if specs is not None else [] if args.against else ["mcts"]), *swept])
        if args.against is not None:
            if specs is None and not swept:
                raise ValueError("--against needs --planners or --sweep: the planners to pair with the published board")
            plan = against_plan(args.against, specs or [], args.tasks, args.episodes, args.seed, args.quick,
                                parse_overrides(args.env), log=lambda m: print(m, flush=True),
                                trust_unverified=args.trust_unverified, sweeps=swept)
            if os.path.realpath(args.out) == os.path.realpath(args.against):
                raise ValueError(f"--out {args.out} is the published board itself: --against never writes there; "
                                 "pass another --out DIR")
            reported = [*plan.against["planners"], *plan.planners]
        else:
            if args.trust_unverified:
                raise ValueError("--trust-unverified goes with --against FOLDER (a published board without row "
                                 "digests); a folder of one's own is checked against its run.json as it resumes")
            plan = make_plan(args.tasks, specs, args.episodes, 0 if args.seed is None else args.seed, args.quick,
                             parse_overrides(args.env), log=lambda m: print(m, flush=True), isolate=args.isolate,
                             sweeps=swept)
            reported = list(plan.planners)
        reference = _reference(args.reference, reported)
        rerun = [_one_of(spec, plan.planners, "--rerun") for spec in args.rerun]
        backend = args.backend or ("ray" if args.address else default_backend(args.workers))
        check_executor_args(backend, args.workers, args.address)  # e.g. the ray extra, before anything runs
    except (ValueError, ImportError) as err:
        return _error(str(err))
    print(f"tasks: {', '.join(plan.tasks)}\nplanners: {', '.join(plan.planners)}\n"
          f"episodes: {plan.episodes} per task and planner, seed {plan.seed}"
          + (f", env overrides {plan.env_overrides}" if plan.env_overrides else "")
          + (f"\nisolated (each in a process of its own): {', '.join(plan.isolated)}" if plan.isolated else ""),
          flush=True)
    command = "ipp-bench " + " ".join(shlex.quote(a) for a in _without_option(argv, "--rerun"))
    sigterm = _SigtermAsInterrupt()
    previous = signal.signal(signal.SIGTERM, sigterm)  # SIGTERM stops like Ctrl-C
    try:
        summary = run_leaderboard(plan, args.out, backend=backend, workers=args.workers, address=args.address,
                                  progress=args.progress, command=command, reference=reference,
                                  log=lambda m: print(m, flush=True), rerun=rerun, power=power)
    except Interrupted as err:
        print(f"ipp-bench: {err}", file=sys.stderr)
        return EXIT_TERMINATED if sigterm.received else EXIT_INTERRUPTED
    except (EpisodeFailed, OutputWriteError) as err:
        print(f"ipp-bench: error: {err}", file=sys.stderr)
        return EXIT_FAILED
    except (ResultsMismatchError, ExecutorError, ImportError, ValueError) as err:
        return _error(str(err))
    finally:
        signal.signal(signal.SIGTERM, previous)
    print(f"done in {time.perf_counter() - started:.1f} s ({summary.ran} episodes run, {summary.skipped} resumed; "
          "planning and compiling included); wrote:")
    for path in summary.files:
        print(f"  {path}")
    return 0


def _compile_search_kernels(planners: Sequence[str]) -> None:
    """Compile the fast searches' kernels here, once, saying so, when a planner of the run uses them and numba's
    cache lacks them (planning starts every planner once, and the workers then load the kernels from the cache
    in about a second)."""
    from .planners import parse_spec

    if not any(parse_spec(p)[0] in ("mcts", "cmaes") for p in planners):
        return
    from .planners import kernels

    if kernels.jit.numba is None:  # the planner says what to install when it is built
        return
    if not kernels.cached():
        print(f"compiling the search kernels of mcts and cmaes (once: about {kernels.COMPILE_S} s on 2 cores; "
              "numba caches them for later runs)", flush=True)
    kernels.warm_up()


def _run_delegated(name: str, argv: Sequence[str]) -> int:
    module_name, add_name, run_name, extra, text = _DELEGATED[name]
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        if "pip install" in str(err):  # the module's own message already names what to install
            return _error(f"'ipp-bench {name}' is unavailable: {err}")
        return _error(f"'ipp-bench {name}' is unavailable ({err}); it needs the {extra} extra: "
                      f'pip install "ipp-bench[{extra}]"')
    parser = argparse.ArgumentParser(prog=f"ipp-bench {name}", description=text)
    getattr(module, add_name)(parser)
    args = parser.parse_args(list(argv))
    return int(getattr(module, run_name)(args) or 0)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``ipp-bench`` console script; returns the exit status (130 after Ctrl-C)."""
    try:
        return _main(argv)
    except KeyboardInterrupt:
        print("ipp-bench: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # the reader of the output left (``ipp-bench power DIR | head``): nothing to say
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # Python's flush at exit would raise again
        return 0


def _main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in _DELEGATED:  # their parsers live in their (heavy) modules
        return _run_delegated(argv[0], argv[1:])
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command == "tasks":
        return cmd_tasks(args)
    if args.command == "fit-prior":
        return cmd_fit_prior(args)
    if args.command == "evaluate":
        return cmd_evaluate(args)
    if args.command == "leaderboard":
        return cmd_leaderboard(args, argv)
    if args.command == "power":
        return cmd_power(args)
    parser.error(f"unknown command {args.command!r}")  # unreachable: argparse checks the choices
    return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
