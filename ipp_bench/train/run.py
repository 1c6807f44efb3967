"""``ipp-bench train``: the run folder, its state and resume (the command: :mod:`~ipp_bench.train.command`).

One run is a warm start (:mod:`~ipp_bench.train.warmstart`, optional), then PPO
(:mod:`~ipp_bench.train.ppo`, ``--total-steps 0``: none), both resumable, in one run folder
(``--out DIR``, default ``runs/<task>__attention__<seed>__<time>``)::

    config.json      the settings and the exact command
    state.json       what is done (RunState: warm start done, steps trained, best validation)
    train.log        what was printed
    progress.csv     SB3 training log (appended across resumes), validation included
    tb/              TensorBoard logs (if tensorboard is installed)
    warmstart/       bc.pt (warm-start weights), bc_log.csv, progress.json (rounds done)
    checkpoints/     latest.zip (after every PPO update), step_<n>_steps.zip, best.zip (validation)
    export.pt        best validated policy in the shipped checkpoint format (+ export.json)
    last.pt          final policy in the same format

``--resume`` continues a run: the warm start from its last completed round, PPO from
``latest.zip``; the step counter continues from the checkpoint. A recipe
(:mod:`~ipp_bench.train.recipe`) runs each of its stages in such a run folder.
"""

from __future__ import annotations

import math
import shlex
import signal
import sys
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import torch

from ipp_bench.core._threads import keep_freed_memory
from ipp_bench.core.data import OutputWriteError, check_output_dir
from ipp_bench.train.args import (
    RESUMABLE,
    VAL_SEED0,
    TrainArgs,
    check_args,
    command_line,
    evaluation_task_warnings,
    load_init,
)
from ipp_bench.train.files import read_json, write_json_atomic


@dataclass
class RunState:
    """What a run has done (``state.json``), updated as it goes and read back by ``--resume``."""

    bc_done: bool = False  # warmstart/bc.pt is written
    bc_wall_s: float = 0.0  # [s]
    ppo_steps: int = 0  # environment steps of PPO so far
    ppo_wall_s: float = 0.0  # [s] PPO updates and rollouts, validation excluded
    best_score: float = -math.inf  # the best validation score so far (export.pt's)
    best_step: int | None = None  # its PPO step (0: the warm start)
    greedy_val: dict[str, dict[str, float]] | None = field(default=None)  # greedy on the validation episodes
    done: bool = False  # the run finished (its last.pt / export.pt are final)

    @classmethod
    def load(cls, run: Path) -> RunState:
        path = run / "state.json"
        if not path.is_file():
            return cls()
        data = read_json(path, "progress (steps, best validation)")
        known = {f.name for f in fields(cls)}
        state = cls(**{k: v for k, v in data.items() if k in known})
        if state.best_score is None:
            state.best_score = -math.inf
        return state

    def save(self, run: Path) -> None:
        data = asdict(self)
        data["best_score"] = None if self.best_score == -math.inf else self.best_score
        write_json_atomic(run / "state.json", data)


def set_threads(n: int = 0) -> int:
    """Torch intra-op threads: ``n``, or half the CPUs available to this process (at least 1; within
    its cgroup's CPU quota, :func:`~ipp_bench.train.vec.worker_cpus`).

    Measured on a 2-core machine while other jobs ran: PPO made 145 env-steps/s with one torch
    thread and 7 with two, and a 450-node forward pass took 1.5 ms with one thread and 200 ms with
    two (OpenMP threads waiting on each other whenever one is descheduled).
    """
    from ipp_bench.train.vec import worker_cpus

    n = n or max(1, worker_cpus() // 2)
    torch.set_num_threads(n)
    return n


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def resolve_config(given: dict[str, Any], resume: bool) -> tuple[TrainArgs, Path]:
    """The run's settings from the options ``given`` (a new run, or ``resume`` the one in ``--out``),
    checked, and its folder (not yet created). ValueError: one line naming the option or file."""
    if resume:
        if not given.get("out"):
            raise ValueError("--resume needs --out DIR: the run folder to continue")
        run = Path(given["out"])
        cfg_file = run / "config.json"
        if not cfg_file.is_file():
            raise ValueError(f"--resume: {cfg_file} not found; is {run} a run folder of `ipp-bench train`?")
        saved = read_json(cfg_file, "options").get("args")
        known = {f.name for f in fields(TrainArgs)}
        if not isinstance(saved, dict) or set(saved) - known:
            raise ValueError(f"--resume: {cfg_file} was written by another version or is damaged (its 'args' are "
                             "not the options of ipp-bench train"
                             + (f": unknown {sorted(set(saved) - known)}" if isinstance(saved, dict) else "")
                             + "); finish it with that version, or start a new --out")
        changed = {k: v for k, v in given.items() if k not in RESUMABLE and saved.get(k) != v}
        if changed:
            raise ValueError(f"--resume cannot change {sorted(changed)}: the run was started with "
                             + ", ".join(f"{k}={saved.get(k)!r}" for k in sorted(changed)))
        cfg = TrainArgs(**{**saved, **{k: v for k, v in given.items() if k in RESUMABLE}})
        cfg.out = str(run)
        _check_resume_files(run)
    else:
        cfg = TrainArgs(**given)
        if not cfg.out:
            slug = Path(cfg.task).stem if cfg.task.endswith(".toml") else cfg.task.replace("/", "-")
            cfg.out = str(Path("runs") / f"{slug}__attention__{cfg.seed}__{time.strftime('%Y%m%d-%H%M%S')}")
        run = Path(cfg.out)
        check_output_dir(run)  # a file in the way, or not writable: one line, before any work
        if (run / "config.json").is_file():
            raise ValueError(f"{run} already holds a run: pass --resume to continue it, or choose another --out")
    check_args(cfg)
    return cfg, run


def _check_resume_files(run: Path) -> None:
    """The files a resumed run reads, checked before it starts: ``state.json`` and ``latest.zip``."""
    import zipfile

    RunState.load(run)
    latest = run / "checkpoints" / "latest.zip"
    if latest.is_file():
        try:
            with zipfile.ZipFile(latest) as z:
                bad = z.testzip()
                names = set(z.namelist())
        except (OSError, zipfile.BadZipFile) as err:
            bad, names = str(err), set()
        if bad is not None or not {"data", "policy.pth"} <= names:
            numbered = sorted((run / "checkpoints").glob("step_*_steps.zip"))
            hint = (f"replace it with a numbered checkpoint (newest: {numbered[-1].name})" if numbered
                    else "remove it to restart PPO from its start")
            raise ValueError(f"--resume: {latest} is corrupt (not a complete SB3 archive: "
                             f"{bad or 'data or policy.pth missing'}); {hint}")


class RunLog:
    """``say(msg)``: a time-stamped line on the terminal (above any progress bar) and in ``train.log``."""

    def __init__(self, path: Path) -> None:
        self.file = path.open("a")

    def __call__(self, msg: str) -> None:
        from tqdm.auto import tqdm

        line = f"[{time.strftime('%H:%M:%S')}] {msg}"
        tqdm.write(line)
        sys.stdout.flush()
        self.file.write(line + "\n")
        self.file.flush()

    def close(self) -> None:
        self.file.close()


def execute(cfg: TrainArgs, run: Path, again: str = "") -> int:
    """Run (or continue) the checked run ``cfg`` in ``run``; returns the exit code (130: interrupted,
    ``again`` then the command that continues it, by default ``--resume`` of the run folder)."""
    from ipp_bench.policies.checkpoint import save_checkpoint
    from ipp_bench.train.export import run_meta
    from ipp_bench.train.ppo import ResumeError, ppo
    from ipp_bench.train.validation import val_tasks, validation
    from ipp_bench.train.warmstart import warm_start

    run.mkdir(parents=True, exist_ok=True)
    threads = set_threads(cfg.threads)
    kept = keep_freed_memory()  # before the vec env's worker processes fork: they inherit it
    device = resolve_device(cfg.device)
    if not (run / "config.json").is_file():
        write_json_atomic(run / "config.json", {"args": asdict(cfg), "command": command_line(cfg)})
    state = RunState.load(run)
    say = RunLog(run / "train.log")
    say(f"training {', '.join(dict.fromkeys(cfg.tasks))} in {run} on {device} with {threads} torch threads"
        + (f", {cfg.vec_env} vec env" if cfg.total_steps else "")
        + (", freed memory kept for reuse (glibc)" if kept else ""))
    say(f"command: {command_line(cfg)}")
    for line in evaluation_task_warnings(cfg):
        say(line)
    tasks = val_tasks(cfg)
    say(f"validation: {cfg.eval_episodes} argmax episodes on seeds {VAL_SEED0}.. (held out of training) of "
        f"{', '.join(t for t, _ in tasks)}" + (f" every {cfg.eval_every} steps" if cfg.total_steps else "")
        + "; score = the mean ROI uncertainty reduction [%] over the report times"
        + (" and the tasks" if len(tasks) > 1 else "") + "; minus_greedy = score - greedy's on the same episodes")

    def on_term(signum, frame):  # SIGTERM behaves like Ctrl-C: the last checkpoint stays valid
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, on_term)
    try:
        start = Path(cfg.init) if cfg.init else None
        if cfg.warm_start != "none":
            start = run / "warmstart" / "bc.pt"
            if not state.bc_done:
                net, val = warm_start(cfg, run, device, say, validate=lambda n: validation(n, cfg),
                                      init=load_init(cfg, device) if cfg.init else None)
                state.bc_done = True
                state.bc_wall_s = read_json(run / "warmstart" / "progress.json", "warm start")["wall_s"]
                # the warm-start policy is the first candidate for export.pt; PPO must beat it
                state.best_score, state.best_step = val["val/score"], 0
                save_checkpoint(net, run / "export.pt", meta=run_meta(cfg, state, 0, val))
                state.save(run)
        if cfg.total_steps:
            ppo(cfg, run, device, state, start, say)
        state.done = True
    except KeyboardInterrupt:
        say(f"interrupted; continue with: {again or f'ipp-bench train --out {shlex.quote(str(run))} --resume'}")
        return 130
    except ResumeError as err:
        print(f"ipp-bench train: error: {' '.join(str(err).split())}", file=sys.stderr)
        return 2
    except OSError as err:  # a full disk, a quota: every file written so far is whole, the run resumable
        what = str(err) if isinstance(err, OutputWriteError) else f"cannot write in {run}: {err.strerror or err}"
        print(f"ipp-bench train: error: {what}; make room, then continue with: "
              f"{again or f'ipp-bench train --out {shlex.quote(str(run))} --resume'}", file=sys.stderr)
        return 1
    finally:
        signal.signal(signal.SIGTERM, old)
        try:
            state.save(run)
        except OSError:
            pass  # the state.json written last stays: a resume repeats at most the unsaved step
    best = f"{state.best_score:.2f}" if state.best_step is not None else "none"
    say(f"done: {state.ppo_steps} PPO steps, best validation {best} at step {state.best_step}; "
        f"policy in {run / 'export.pt'}")
    say.close()
    return 0
