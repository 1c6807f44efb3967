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
import sys
from pathlib import Path

import numpy as np

from ..data import write_atomically
from ..sim.video import DemoVideo, make_sim_env

DEFAULT_TASK = "ipp_bench/MuJoCoWeed15-v1"
CRF_RANGE = (0, 51)  # libx264


def add_demo_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``demo`` options to ``parser`` (a sub-command parser of ``ipp-bench``)."""
    parser.add_argument("--task", default=DEFAULT_TASK, help=f"task id (default {DEFAULT_TASK})")
    parser.add_argument("--planner", default="attention",
                        help="planner spec, any registered planner, e.g. 'greedy' or 'mcts:simulations=50' "
                             "(default: attention)")
    parser.add_argument("--seed", type=int, default=0, help="episode seed: field, texture, start, noise")
    parser.add_argument("--out", default="demo.mp4", help="output video (.mp4, H.264)")
    parser.add_argument("--compare", default=None, metavar="PLANNER",
                        help="also fly this planner on the same seed and plot both traces (PNG)")
    parser.add_argument("--compare-out", default=None, metavar="PNG",
                        help="comparison plot path (default: <out>_compare.png)")
    parser.add_argument("--budget", type=float, default=None, help="override the task's budget [s] (short demos)")
    parser.add_argument("--fps", type=int, default=10, help="video frames per second (default 10)")
    parser.add_argument("--speedup", type=float, default=4.0,
                        help="mission seconds per video second (default 4)")
    parser.add_argument("--size", default="1280x720", help="video WIDTHxHEIGHT, multiples of 16 (default 1280x720)")
    parser.add_argument("--crf", type=int, default=32,
                        help=f"x264 quality in {CRF_RANGE[0]}-{CRF_RANGE[1]}, lower is better/larger (default 32)")
    parser.add_argument("--hold", type=float, default=1.0, help="seconds of video holding the final frame")
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
    from ipp_bench.planners.episode import fly_episode

    env = make_sim_env(task, budget)
    video: dict[str, DemoVideo] = {}
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=float(env.config.mission.budget_s), unit="s", desc=f"{planner} seed {seed}",
                   bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s mission [{elapsed}<{remaining}]")

    def on_reset(e) -> None:
        v = DemoVideo(e, out, f"{planner} | {task.split('/')[-1]} | seed {seed}", size, fps, speedup, crf, hold_s, bar)
        e.mission.step_hooks.append(v.hook)
        v.hook(e.mission)  # the frame at t = 0
        video["v"] = v

    try:
        log = fly_episode(env, planner, seed, on_reset=on_reset)
        n = video["v"].close(env.mission.time_s)
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


def run_demo(args: argparse.Namespace) -> int:
    """Runs ``ipp-bench demo``; returns the process exit code."""
    try:
        size = _parse_size(args.size)
        if args.fps < 1 or args.speedup <= 0 or args.hold < 0:
            raise ValueError("--fps must be >= 1, --speedup > 0 and --hold >= 0")
        if not CRF_RANGE[0] <= args.crf <= CRF_RANGE[1]:
            raise ValueError(f"--crf {args.crf} is invalid: libx264 takes {CRF_RANGE[0]}-{CRF_RANGE[1]}")
        out = Path(args.out)
        if out.suffix.lower() != ".mp4":
            raise ValueError(f"--out {args.out!r} is invalid: the demo writes an .mp4")
        png = Path(args.compare_out) if args.compare_out else out.with_name(out.stem + "_compare.png")
        if args.compare:
            from ipp_bench.planners import make_planner

            make_planner(args.compare)  # a bad spec fails here, before any mission flies
            if png.suffix.lower() != ".png":
                raise ValueError(f"--compare-out {str(png)!r} is invalid: the comparison plot is a .png")
        from ipp_bench.planners import make_planner

        make_planner(args.planner)
        make_sim_env(args.task, args.budget).close()  # a non-MuJoCo task fails here too
        for path in [out] + ([png] if args.compare else []):
            _check_writable(path)
        log, frames = record(args.task, args.planner, args.seed, str(out), args.budget, size, args.fps,
                             args.speedup, args.crf, args.hold, progress=not args.no_progress)
    except (ValueError, ImportError, RuntimeError) as err:
        print(f"ipp-bench demo: error: {err}", file=sys.stderr)
        return 2
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
            cfg = env.config.mission
            compare_plot([log, other], cfg.budget_s, cfg.report_times, str(png),
                         f"{args.task}, seed {args.seed}")
        except (ValueError, ImportError, RuntimeError) as err:
            print(f"ipp-bench demo: error: {err}", file=sys.stderr)
            return 2
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
