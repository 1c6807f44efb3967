"""``ipp-bench demo``: fly a planner in the MuJoCo deployment and write an H.264 video.

The orchestration of the demo: which planner flies (:func:`record`, through the one episode loop
:func:`ipp_bench.planners.episode.fly_episode`), ``--compare PLANNER`` on the same seed and the
paper's comparison plot (trace over time, both planners, PNG), and the checks of every argument and
output path before anything flies. The frames themselves are :class:`ipp_bench.sim.video.DemoVideo`.
It lives in ``eval/`` because it drives planners (imports point one way: sim -> planners -> eval).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from pathlib import Path

import numpy as np

from ..core.data import write_atomically
from ..sim.video import DemoVideo, make_sim_env

DEFAULT_TASK = "ipp_bench/MuJoCoWeed15-v1"
CRF_RANGE = (0, 51)  # libx264
FPS_RANGE = (1, 60)  # [frames/s] of the video
SPEEDUP_RANGE = (0.1, 100.0)  # [-] mission seconds per video second
HOLD_RANGE_S = (0.0, 60.0)  # [s] of video holding the final frame
EXIT_FAILED = 1  # the episode or the video failed part-way
EXIT_TERMINATED = 143  # 128 + SIGTERM


def add_demo_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``demo`` options to ``parser`` (a sub-command parser of ``ipp-bench``)."""
    parser.add_argument("--task", default=DEFAULT_TASK, help=f"task id (default {DEFAULT_TASK})")
    parser.add_argument("--planner", default="attention",
                        help="planner spec, any registered planner, e.g. 'greedy' or 'mcts:simulations=50' "
                             "(default: attention)")
    parser.add_argument("--seed", type=int, default=0,
                        help="episode seed: field, texture, start, noise (default: %(default)s)")
    parser.add_argument("--out", default="demo.mp4", help="output video (.mp4, H.264) (default: %(default)s)")
    parser.add_argument("--compare", default=None, metavar="PLANNER",
                        help="also fly this planner on the same seed and plot both traces (PNG)")
    parser.add_argument("--compare-out", default=None, metavar="PNG",
                        help="comparison plot path (default: <out>_compare.png)")
    parser.add_argument("--budget", type=float, default=None, help="override the task's budget [s] (short demos)")
    parser.add_argument("--fps", type=int, default=10,
                        help=f"video frames per second, {FPS_RANGE[0]}-{FPS_RANGE[1]} (default 10)")
    parser.add_argument("--speedup", type=float, default=4.0,
                        help=f"mission seconds per video second, {SPEEDUP_RANGE[0]:g}-{SPEEDUP_RANGE[1]:g} (default 4)")
    parser.add_argument("--size", default="1280x720", help="video WIDTHxHEIGHT, multiples of 16 (default 1280x720)")
    parser.add_argument("--crf", type=int, default=32,
                        help=f"x264 quality in {CRF_RANGE[0]}-{CRF_RANGE[1]}, lower is better/larger (default 32)")
    parser.add_argument("--hold", type=float, default=1.0,
                        help=f"seconds of video holding the final frame, {HOLD_RANGE_S[0]:g}-{HOLD_RANGE_S[1]:g} "
                             "(default 1)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size {text!r} is invalid: expected WIDTHxHEIGHT, e.g. 1280x720") from None
    if w < 320 or h < 180 or w % 16 or h % 16:
        raise ValueError(f"--size {text!r} is invalid: width >= 320, height >= 180, both multiples of 16")
    return w, h


def record(task: str, planner: str, seed: int, out: str, budget: float | None = None, size=(1280, 720),
           fps: int = 10, speedup: float = 4.0, crf: int = 32, hold_s: float = 1.0,
           progress: bool = True):
    """Flies ``planner`` on ``task`` and writes the video; returns the
    :class:`~ipp_bench.planners.episode.EpisodeResult` and the frame count."""
    from ipp_bench.planners.episode import fly_episode, is_team_env

    env = make_sim_env(task, budget)
    video: dict[str, DemoVideo] = {}
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=float(env.config.mission.budget_s), unit="s", desc=f"{planner} seed {seed}",
                   bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s mission [{elapsed}<{remaining}]")

    def on_reset(e) -> None:
        # held before its first frame is sent (ffmpeg opens its temporary file once it has it): a Ctrl-C from
        # here on is cleaned up by the abort below
        video["v"] = v = DemoVideo(e, out, f"{planner} | {task.split('/')[-1]} | seed {seed}", size, fps, speedup,
                                   crf, hold_s, bar)
        team = is_team_env(e)  # a team's drones share one physics: its steps carry the hook
        (e.sim_team if team else e.mission).step_hooks.append(v.hook)
        v.hook(e.mission)  # the frame at t = 0

    try:
        log = fly_episode(env, planner, seed, on_reset=on_reset)
        end = max(m.time_s for m in env.mission.members) if is_team_env(env) else env.mission.time_s
        n = video["v"].close(end)
        if bar is not None:  # the mission is over: 100 %, even when it ended before the last second
            bar.update(max(bar.total - bar.n, 0.0))
    except BaseException:
        if "v" in video:
            video["v"].abort()
        raise
    finally:
        if bar is not None:
            bar.close()
        env.close()
    return log, n


def compare_plot(logs: list, budget: float, report_times, path: str, title: str) -> None:
    """The paper's comparison: trace(P) over the ROI against mission time, one line per planner."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.0, 4.2), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    for log in logs:
        t = np.array([r.time_s for r in log.history] + [log.final["time_s"]])
        tr = np.array([r.trace_roi for r in log.history] + [log.history[-1].trace_roi])
        reds = []
        for rt in report_times:
            if rt <= budget + 1e-9:
                rec = [r for r in log.history if r.time_s <= rt + 1e-9][-1]
                reds.append(f"{rec.uncertainty_reduction_pct:.0f}")
        ax.plot(t, tr, drawstyle="steps-post", lw=2, label=f"{log.planner} (reduction {'/'.join(reds)} %)")
    for rt in report_times:
        if rt <= budget + 1e-9:
            ax.axvline(rt, color="grey", lw=0.8, ls=":")
    ax.set_xlim(0, budget)
    ax.set_ylim(bottom=0)
    ax.set_xlabel("mission time [s]")
    ax.set_ylabel("trace(P) over the ROI")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=9)
    fig.tight_layout()
    write_atomically(path, lambda tmp: fig.savefig(tmp, format="png"))  # complete or absent, never truncated


def _check_writable(path: Path) -> None:
    """Creates ``path``'s folder and checks that a file can be written there (before anything flies)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ValueError(f"output {str(path)!r} is invalid: cannot create its folder ({err})") from None
    if path.is_dir():
        raise ValueError(f"output {str(path)!r} is invalid: it is a folder")
    if not os.access(path.parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise ValueError(f"output {str(path)!r} is invalid: not writable")


def _error(message: str, status: int = 2) -> int:
    print(f"ipp-bench demo: error: {message}", file=sys.stderr)
    return status


class _SigtermAsInterrupt:
    """SIGTERM handler: stop like Ctrl-C (the video in progress is dropped, the old file kept)."""

    received = False

    def __call__(self, signum, frame) -> None:
        self.received = True
        raise KeyboardInterrupt


def _check_video_settings(args: argparse.Namespace) -> tuple[int, int]:
    """The video's (width, height), after every setting that sizes the work is checked (one line each)."""
    from ipp_bench.core.config import check_integer, check_number

    size = _parse_size(args.size)
    check_integer("--fps", args.fps, *FPS_RANGE)
    check_number("--speedup", args.speedup, *SPEEDUP_RANGE)
    check_number("--hold", args.hold, *HOLD_RANGE_S, unit="s")
    if not CRF_RANGE[0] <= args.crf <= CRF_RANGE[1]:
        raise ValueError(f"--crf {args.crf} is invalid: libx264 takes {CRF_RANGE[0]}-{CRF_RANGE[1]}")
    if args.budget is not None:
        check_number("--budget", args.budget, 0.0, low_open=True, unit="s")
    return size


def run_demo(args: argparse.Namespace) -> int:
    """Runs ``ipp-bench demo``; returns the process exit code (2: bad arguments, before anything
    flies; 1: the episode or the video failed part-way; 143: SIGTERM). A video or plot is complete
    or absent: a file that was at the output path is replaced only by a finished one."""
    try:
        size = _check_video_settings(args)
        out = Path(args.out)
        if out.suffix.lower() != ".mp4":
            raise ValueError(f"--out {args.out!r} is invalid: the demo writes an .mp4")
        png = Path(args.compare_out) if args.compare_out else out.with_name(out.stem + "_compare.png")
        if args.compare and png.suffix.lower() != ".png":
            raise ValueError(f"--compare-out {str(png)!r} is invalid: the comparison plot is a .png")
        make_sim_env(args.task, args.budget).close()  # first: without [sim] that is what to install
        from ipp_bench.planners import make_planner

        if args.compare:
            make_planner(args.compare)  # a bad spec fails here, before any mission flies
        make_planner(args.planner)
        for path in [out] + ([png] if args.compare else []):
            _check_writable(path)
    except (ValueError, ImportError, RuntimeError) as err:
        return _error(str(err))
    sigterm = _SigtermAsInterrupt()
    main_thread = threading.current_thread() is threading.main_thread()  # only there can a handler be set
    previous = signal.signal(signal.SIGTERM, sigterm) if main_thread else None
    try:
        return _fly_and_write(args, size, out, png)
    except KeyboardInterrupt:
        if not sigterm.received:
            raise  # Ctrl-C: the command line's one line and exit status 130
        print(f"ipp-bench demo: terminated; {out} left as it was", file=sys.stderr)
        return EXIT_TERMINATED
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, previous)


def _fly_and_write(args: argparse.Namespace, size: tuple[int, int], out: Path, png: Path) -> int:
    from ipp_bench.core.data import OutputWriteError
    from ipp_bench.envs import short_task_id

    from .leaderboard import one_line

    def failed(planner: str, err: Exception, kept: Path) -> int:
        return _error(f"episode {short_task_id(args.task)} {planner} seed {args.seed} failed: {one_line(err)}; "
                      f"{kept} left as it was", EXIT_FAILED)

    try:
        log, frames = record(args.task, args.planner, args.seed, str(out), args.budget, size, args.fps,
                             args.speedup, args.crf, args.hold, progress=not args.no_progress)
    except OutputWriteError as err:
        return _error(str(err), EXIT_FAILED)
    except Exception as err:  # the planner raised part-way: nothing replaced the old video
        return failed(args.planner, err, out)
    m = log.final
    print(f"{out}: {frames} frames, {size[0]}x{size[1]} @ {args.fps} fps; {args.planner} flew "
          f"{m['time_s']:.2f} s ({m['distance_m']:.0f} m, {log.decisions} decisions): uncertainty reduction "
          f"{m['uncertainty_reduction_pct']:.1f} %, RMSE reduction {m['rmse_reduction_pct']:.1f} %")
    if args.compare:
        try:
            env = make_sim_env(args.task, args.budget)
            try:
                from ipp_bench.planners.episode import fly_episode

                other = fly_episode(env, args.compare, args.seed)
            finally:
                env.close()
        except Exception as err:
            return failed(args.compare, err, png)
        cfg = env.config.mission
        try:
            compare_plot([log, other], cfg.budget_s, cfg.report_times, str(png), f"{args.task}, seed {args.seed}")
        except OutputWriteError as err:
            return _error(str(err), EXIT_FAILED)
        o = other.final
        print(f"{png}: {args.compare} flew {o['time_s']:.1f} s: uncertainty reduction "
              f"{o['uncertainty_reduction_pct']:.1f} %, RMSE reduction {o['rmse_reduction_pct']:.1f} %")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m ipp_bench.eval.demo`` (the same as ``ipp-bench demo``)."""
    parser = add_demo_arguments(argparse.ArgumentParser(prog="ipp-bench demo", description=__doc__.splitlines()[0]))
    return run_demo(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
