"""Bad input and faults, tried as a new user would, through the public entry points.

Each case drives ``gym.make`` or the command line's ``main([...])`` and checks that the message
names what was wrong (and, for the command line, that no traceback is printed and nothing is left
half-done). The cases cover every command's user-facing inputs.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import ipp_bench.envs  # registers the tasks
from ipp_bench.cli import main

TASK = "ipp_bench/Grid15Eval-v1"
TINY = ["--env", "budget_s=40", "--env", "report_times=[20,40]"]
REPO = Path(__file__).resolve().parents[1]


def _cli(argv, capsys):
    """(exit status, stdout, stderr) of ``ipp-bench ARGV``."""
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


def _lb(out, *extra):
    return ["leaderboard", "--tasks", "Grid15Eval-v1", "--planners", "random", "--episodes", "1",
            "--backend", "serial", "--no-progress", "--out", str(out), *TINY, *extra]


# -- configuration and environment ------------------------------------------------------------------
def test_numbers_of_any_numeric_type_are_accepted():
    env = gym.make(TASK, rows=np.int64(20), budget_s=np.float32(60.0)).unwrapped
    env.reset(seed=0)
    assert env.config.grid.rows == 20 and type(env.config.grid.rows) is int


@pytest.mark.parametrize("override, field", [
    ({"budget_s": "100"}, "budget_s"), ({"resolution": "2.5"}, "resolution"), ({"rows": "20"}, "rows"),
    ({"budget_s": True}, "budget_s"), ({"mu_th": 0.9}, "mu_th"), ({"mu_th": -1.0}, "mu_th"),
], ids=["budget-string", "resolution-string", "rows-string", "budget-bool", "mu_th-high", "mu_th-negative"])
def test_bad_values_are_refused_at_make_naming_the_field(override, field):
    with pytest.raises(ValueError, match=rf"mission\.{field}|grid\.{field}") as err:
        gym.make(TASK, **override)
    assert "expected" in str(err.value)


def test_a_budget_too_small_for_any_first_move_is_refused_at_reset():
    env = gym.make(TASK, budget_s=1.0, report_times=[1.0])
    with pytest.raises(ValueError, match=r"budget_s = 1.0 is too small.*cheapest takes 1.25 s"):
        env.reset(seed=0)


def test_step_after_the_end_says_call_reset():
    env = gym.make(TASK, budget_s=3.0, report_times=[3.0])
    obs, _ = env.reset(seed=0)
    terminated = False
    while not terminated:
        obs, _, terminated, _, _ = env.step(int(np.flatnonzero(obs["action_mask"])[0]))
    with pytest.raises(RuntimeError, match=r"the episode is over .*call reset\(\)"):
        env.step(0)


def test_human_render_mode_names_the_supported_modes():
    with pytest.raises(ValueError, match=r"render_mode='human' is invalid: valid are \['rgb_array'\]"):
        gym.make(TASK, render_mode="human")


# -- command line -----------------------------------------------------------------------------------
def test_evaluate_with_a_string_override_names_the_field(capsys):
    rc, _, err = _cli(["evaluate", "--task", "Grid15Eval-v1", "--planner", "random", "--env", "budget_s=abc"], capsys)
    assert rc == 2 and "mission.budget_s = 'abc' is invalid" in err and "Traceback" not in err


def test_evaluate_with_a_budget_too_small_is_one_line(capsys):
    rc, _, err = _cli(["evaluate", "--task", "Grid15Eval-v1", "--planner", "random", "--env", "budget_s=1",
                       "--env", "report_times=[1]"], capsys)
    assert rc == 2 and "budget_s = 1 is too small" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("argv, message", [
    (["evaluate", "--task", "Grid15Eval-v1", "--planner", "random", "--seed", "-1"], "--seed -1 is invalid"),
    (["leaderboard", "--planners", "random", "--seed", "-3"], "seed = -3 is invalid"),
], ids=["evaluate", "leaderboard"])
def test_negative_seeds_are_refused(argv, message, capsys, tmp_path):
    rc, _, err = _cli([*argv, *(["--out", str(tmp_path / "o")] if argv[0] == "leaderboard" else [])], capsys)
    assert rc == 2 and message in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_out_under_a_file_is_refused_before_any_episode(capsys, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    rc, out, err = _cli(_lb(blocker / "lb"), capsys)
    assert rc == 2 and f"{blocker} is a file, not a folder" in err and "[1/1]" not in out


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_out_is_refused_before_any_episode(capsys, tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        rc, out, err = _cli(_lb(ro / "lb"), capsys)
    finally:
        ro.chmod(0o700)
    assert rc == 2 and "is not writable" in err and "[1/1]" not in out


@pytest.mark.parametrize("render, message", [("final.gif", "expected a .png file"),
                                             ("file/final.png", "is a file, not a folder"),
                                             ("missing/final.png", "does not exist")],
                         ids=["suffix", "under-file", "missing-folder"])
def test_render_path_is_checked_before_the_episode(render, message, capsys, tmp_path):
    (tmp_path / "file").write_text("x")
    rc, out, err = _cli(["evaluate", "--task", "Grid15Eval-v1", "--planner", "random", "--render",
                         str(tmp_path / render), *TINY], capsys)
    assert rc == 2 and message in err and "decisions" not in out


def test_demo_paths_are_checked_before_the_episode(capsys, tmp_path):
    pytest.importorskip("mujoco")
    (tmp_path / "file").write_text("x")
    for bad in (["--out", str(tmp_path / "file" / "d.mp4")],
                ["--out", str(tmp_path / "d.mp4"), "--compare", "random", "--compare-out",
                 str(tmp_path / "file" / "c.png")]):
        rc, out, err = _cli(["demo", "--planner", "random", "--budget", "4", "--no-progress", *bad], capsys)
        assert rc == 2 and str(tmp_path / "file") in err and "Traceback" not in err and "frames" not in out
        assert not (tmp_path / "d.mp4").exists()


def test_ctrl_c_prints_one_line_keeps_the_episodes_and_exits_130(capsys, tmp_path, monkeypatch):
    import ipp_bench.eval.leaderboard as lb

    real, calls = lb.run_job, []

    def interrupted_after_two(job):
        if len(calls) == 2:
            raise KeyboardInterrupt
        calls.append(job)
        return real(job)

    monkeypatch.setattr(lb, "run_job", interrupted_after_two)
    out = tmp_path / "lb"
    rc, _, err = _cli(_lb(out, "--episodes", "4"), capsys)
    assert rc == 130
    assert err.strip() == f"ipp-bench: interrupted; 2 of 4 episodes kept in {out}; rerun the same command to resume"
    monkeypatch.setattr(lb, "run_job", real)
    rc, stdout, _ = _cli(_lb(out, "--episodes", "4"), capsys)
    assert rc == 0 and "2 already in" in stdout


def _descendants_alive(pgid: int) -> list[int]:
    """Pids of live (not zombie) processes in process group ``pgid``."""
    alive = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        if fields[0] != "Z" and int(fields[2]) == pgid:
            alive.append(int(entry.name))
    return alive


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc (Linux)")
@pytest.mark.timeout(240)
@pytest.mark.parametrize("sig", [signal.SIGTERM, pytest.param(signal.SIGKILL, marks=pytest.mark.slow)],
                         ids=["SIGTERM", "SIGKILL"])
def test_sigterm_leaves_no_child_behind_and_a_rerun_completes(tmp_path, sig):
    """SIGTERM stops the run like Ctrl-C; after SIGKILL (no cleanup at all) the workers notice
    that the run is gone and exit by themselves."""
    out = tmp_path / "lb"
    argv = [sys.executable, "-m", "ipp_bench.cli", "leaderboard", "--tasks", "Grid15Eval-v1", "--planners", "random",
            "greedy", "--episodes", "6", "--backend", "process", "--workers", "2", "--no-progress", "--out", str(out),
            "--env", "budget_s=60", "--env", "report_times=[30,60]"]
    proc = subprocess.Popen(argv, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        csv_path = out / "results.csv"
        while time.monotonic() < deadline:  # wait for the pool to run (one episode written)
            if csv_path.exists() and len(csv_path.read_text().splitlines()) > 1:
                break
            assert proc.poll() is None, proc.stdout.read()
            time.sleep(0.2)
        assert len(_descendants_alive(proc.pid)) >= 3  # the run, its workers (and their forkserver)
        os.kill(proc.pid, sig)
        proc.wait(timeout=60)
        _none_left(proc, "a worker")
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    output = proc.stdout.read()
    assert "Traceback" not in output
    if sig == signal.SIGTERM:
        assert "episodes kept in" in output and proc.returncode == 143
    rerun = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=180)
    assert rerun.returncode == 0, rerun.stderr[-2000:]
    assert "already in" in rerun.stdout and len((out / "results.csv").read_text().splitlines()) == 1 + 2 * 6 * 2


def test_ray_address_without_a_cluster_is_one_line_and_leaves_no_run_json(capsys, tmp_path, monkeypatch):
    pytest.importorskip("ray")
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    out = tmp_path / "lb"
    rc, _, err = _cli(["leaderboard", "--tasks", "Grid15Eval-v1", "--planners", "random", "--episodes", "1",
                       "--backend", "ray", "--address", "auto", "--no-progress", "--out", str(out), *TINY], capsys)
    assert rc == 2 and "no Ray cluster found at 'auto'" in err and "ray start --head" in err
    assert len(err.strip().splitlines()) == 1 and not (out / "run.json").exists()


@pytest.mark.timeout(120)
def test_a_ray_address_that_answers_nothing_is_one_line_within_seconds(capsys, tmp_path, monkeypatch):
    """A listener that accepts and never speaks (ray.init alone waits there for more than 9 minutes)."""
    pytest.importorskip("ray")
    import socket
    import threading

    from ipp_bench.eval.ray_executor import RAY_CONNECT_TIMEOUT_S

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(16)
    held = []
    threading.Thread(target=lambda: [held.append(silent.accept()) for _ in range(64)], daemon=True).start()
    address = f"127.0.0.1:{silent.getsockname()[1]}"
    out = tmp_path / "lb"
    t0 = time.monotonic()
    try:
        rc, _, err = _cli(["leaderboard", "--tasks", "Grid15Eval-v1", "--planners", "random", "--episodes", "1",
                           "--backend", "ray", "--address", address, "--no-progress", "--out", str(out), *TINY], capsys)
    finally:
        silent.close()
    assert time.monotonic() - t0 < RAY_CONNECT_TIMEOUT_S + 30
    assert rc == 2 and f"no Ray cluster answers at '{address}' (no connection within" in err, err
    assert len(err.strip().splitlines()) == 1 and not (out / "run.json").exists()


def test_a_replaced_checkpoint_is_refused_like_any_other_change(capsys, tmp_path):
    pytest.importorskip("torch")
    from ipp_bench.policies.checkpoint import SHIPPED_CHECKPOINT, load_checkpoint, save_checkpoint

    ckpt = tmp_path / "net.pt"
    net, meta = load_checkpoint(SHIPPED_CHECKPOINT)
    save_checkpoint(net, ckpt, meta)
    argv = ["leaderboard", "--tasks", "Grid15Eval-v1", "--planners", f"attention:checkpoint={ckpt}", "--episodes",
            "1", "--backend", "serial", "--no-progress", "--out", str(tmp_path / "lb"), *TINY]
    assert _cli(argv, capsys)[0] == 0
    import torch

    with torch.no_grad():
        next(net.parameters()).add_(0.01)  # another network under the same file name
    save_checkpoint(net, ckpt, meta)
    rc, _, err = _cli(argv, capsys)
    assert rc == 2 and "planner_fingerprints" in err and "checkpoint_sha256" in err


def test_a_folder_from_before_checkpoint_hashes_does_not_adopt_todays_checkpoint(capsys, tmp_path):
    """Rows of a checkpoint planner in a folder whose run.json has no planner fingerprints were made by
    an unknown network: the rerun refuses them instead of labelling them with the current hash."""
    pytest.importorskip("torch")
    out = tmp_path / "lb"
    argv = ["leaderboard", "--tasks", "Grid15Eval-v1", "--planners", "random", "attention", "--episodes", "1",
            "--backend", "serial", "--no-progress", "--out", str(out), *TINY]
    assert _cli(argv, capsys)[0] == 0
    meta = json.loads((out / "run.json").read_text())
    del meta["fingerprint"]["planner_fingerprints"]  # as written before fingerprints existed
    (out / "run.json").write_text(json.dumps(meta))
    rc, _, err = _cli(argv, capsys)
    assert rc == 2 and "predates planner fingerprints" in err and "attention" in err
    lines = (out / "results.csv").read_text().splitlines()
    (out / "results.csv").write_text("\n".join(ln for ln in lines if ",attention," not in ln) + "\n")
    assert _cli(argv, capsys)[0] == 0  # without those rows it upgrades and reruns them
    assert "checkpoint_sha256" in (out / "run.json").read_text()


def test_a_no_op_quick_does_not_relabel_the_report(capsys, tmp_path):
    out = tmp_path / "lb"
    assert _cli(_lb(out), capsys)[0] == 0
    assert _cli(_lb(out, "--quick"), capsys)[0] == 0  # random has no quick settings, episodes are explicit
    assert "quick mode" not in (out / "leaderboard.md").read_text()
    assert json.loads((out / "run.json").read_text())["quick"] is False


def test_core_only_install_runs_the_default_leaderboard_and_names_the_extras(capsys, tmp_path, monkeypatch):
    # scipy (a core dependency) asks sys.modules whether torch is loaded, and a None entry reads as loaded
    # when scipy.stats is first imported: import it first, as it would be without torch installed at all
    import scipy.stats  # noqa: F401

    for module in ("matplotlib", "cma", "torch", "tqdm"):  # as after pip install ipp-bench (no extras)
        monkeypatch.setitem(sys.modules, module, None)
    out = tmp_path / "lb"
    rc, stdout, err = _cli(["leaderboard", "--tasks", "Grid15Eval-v1", "--episodes", "1", "--backend", "serial",
                            "--out", str(out), *TINY], capsys)
    assert rc == 0, err
    assert "leaving planner 'cmaes' out" in stdout and "ipp-bench[eval]" in stdout
    assert "leaving planner 'attention' out" in stdout and "ipp-bench[train]" in stdout
    assert (out / "leaderboard.md").exists() and not list(out.glob("*.png"))
    assert "the plots need matplotlib" in (out / "leaderboard.md").read_text()


def test_planners_in_comma_form_work(capsys, tmp_path):
    rc, stdout, _ = _cli(["leaderboard", "--tasks", "Grid15Eval-v1", "--planners", "random,coverage",
                          "mcts:simulations=2,exploration=0.5,greedy", "--episodes", "1", "--backend", "serial",
                          "--no-progress", "--out", str(tmp_path / "lb"), *TINY], capsys)
    assert rc == 0
    assert "planners: random, coverage, mcts:exploration=0.5,simulations=2, greedy" in stdout


def test_ctrl_c_during_evaluate_is_one_line_and_exit_130(capsys, monkeypatch):
    import ipp_bench.eval.runner as runner

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "run_episode", interrupted)
    rc, _, err = _cli(["evaluate", "--task", "Grid15Eval-v1", "--planner", "random", *TINY], capsys)
    assert rc == 130 and err.strip() == "ipp-bench: interrupted"


def _none_left(proc, what):
    """Wait up to 30 s for every descendant of ``proc`` to end; fail naming ``what`` if one is left."""
    deadline = time.monotonic() + 30
    while _descendants_alive(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert _descendants_alive(proc.pid) == [], f"{what} outlived the leaderboard"


def _greedy_leaderboard(out, backend, episodes):
    """(argv, process) of a greedy leaderboard on 60 s missions, 2 workers, in its own session."""
    argv = [sys.executable, "-m", "ipp_bench.cli", "leaderboard", "--tasks", "Grid15Eval-v1", "--planners", "greedy",
            "--episodes", str(episodes), "--backend", backend, "--workers", "2", "--no-progress", "--out", str(out),
            "--env", "budget_s=60", "--env", "report_times=[30,60]"]
    return argv, subprocess.Popen(argv, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                  start_new_session=True)


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc (Linux)")
@pytest.mark.timeout(240)
def test_a_worker_killed_by_the_os_stops_the_run_with_one_line_and_the_resume_command(tmp_path):
    """SIGKILL on one pool worker (as the OOM killer does): one line naming an episode, exit 1,
    the resume command, no process left; the rerun completes."""
    out = tmp_path / "lb"
    argv, proc = _greedy_leaderboard(out, "process", 8)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:  # the workers: children of the forkserver, grandchildren of the run
            workers = [p for p in _descendants_alive(proc.pid) if p != proc.pid and _ppid(p) != proc.pid]
            if len(workers) >= 2 and (out / "run.json").exists():
                break
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.2)
        os.kill(workers[0], signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=90)
        _none_left(proc, "a worker")
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 1, (stdout, stderr)
    assert "Traceback" not in stderr and len(stderr.strip().splitlines()) == 1, stderr
    assert "episode Grid15Eval-v1 greedy seed" in stderr and "worker process died" in stderr
    assert "rerun the same command to resume: ipp-bench leaderboard --tasks Grid15Eval-v1" in stderr
    rerun = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=180)
    assert rerun.returncode == 0, rerun.stderr[-2000:]
    assert len((out / "results.csv").read_text().splitlines()) == 1 + 8 * 2


def _ppid(pid: int) -> int:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return -1
    return int(stat[stat.rindex(")") + 2:].split()[1])


# -- errors before work ------------------------------------------------------------------------
def _run_cli(argv, block=(), timeout=120):
    """``ipp-bench ARGV`` in a subprocess, with the modules ``block`` made unimportable (as on an
    install without their extra); (exit status, stdout, stderr)."""
    code = ("import sys\n" + "".join(f"sys.modules[{m!r}] = None\n" for m in block)
            + "from ipp_bench.cli import main\nsys.exit(main(sys.argv[1:]))\n")
    proc = subprocess.run([sys.executable, "-c", code, *argv], cwd=REPO, capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, "MUJOCO_GL": "egl"})
    return proc.returncode, proc.stdout, proc.stderr


def test_render_without_matplotlib_is_refused_before_the_episode(tmp_path):
    png = tmp_path / "x.png"
    rc, out, err = _run_cli(["evaluate", "--task", "Grid15Eval-v1", "--planner", "greedy", "--render", str(png)],
                            block=("matplotlib",))
    expected = 'ipp-bench: error: the --render figure needs matplotlib: pip install "ipp-bench[eval]"'
    assert rc == 2 and err.strip() == expected
    assert "decisions" not in out and not png.exists()


def test_a_deployment_task_without_the_sim_extra_names_the_extra(tmp_path):
    for argv in (["evaluate", "--task", "MuJoCoWeed15-v1", "--planner", "random"],
                 ["leaderboard", "--tasks", "MuJoCoWeed15-v1", "--planners", "random", "--episodes", "1",
                  "--out", str(tmp_path / "lb")]):
        rc, _, err = _run_cli(argv, block=("mujoco", "cv2"))
        assert rc == 2 and 'pip install "ipp-bench[sim]"' in err and "Traceback" not in err, err
        assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "lb").exists()


@pytest.mark.parametrize("extra, message", [
    (["--planners", "greedy", "--env", "budget_s=1", "--env", "report_times=[1]"], "budget_s = 1 is too small"),
    (["--planners", "attention", "--env", "pe_dim=8"], "pe_dim=32 in the checkpoint but pe_dim=8"),
], ids=["budget-too-small", "checkpoint-pe_dim"])
def test_what_an_episode_start_refuses_is_refused_before_run_json(extra, message, tmp_path):
    """Refused before the folder is written, so the corrected rerun is not refused as 'other arguments'."""
    if "attention" in extra:
        pytest.importorskip("torch")
    out = tmp_path / "lb"
    rc, _, err = _run_cli(["leaderboard", "--tasks", "Grid15Eval-v1", "--episodes", "1", "--no-progress",
                           "--out", str(out), *extra])
    assert rc == 2 and message in err and "task ipp_bench/Grid15Eval-v1" in err and "Traceback" not in err, err
    assert not out.exists()


# -- bounds on every size-like input -----------------------------------------------------------
@pytest.mark.parametrize("extra, message", [
    (["--episodes", "100000000000"], "episodes = 100000000000 is invalid: expected an integer in [1, 10000]"),
    (["--workers", "100000"], "workers = 100000 is invalid: expected an integer in [1, 256]"),
    (["--env", "measurement_spacing=1e-4"], "mission.measurement_spacing = 0.0001 m"),
    (["--env", "altitudes=[8,10000]"], "graph.altitudes = [8.0, 10000.0] is too fine"),
    (["--env", "rows=100", "--env", "cols=100"], "100 x 100 cells is too large for the dense belief"),
    (["--env", "rows=400", "--env", "cols=400"], "= 320000 roadmap nodes is too large"),
    (["--env", "speed=1e6"], "mission.budget_s x mission.speed = 200 s x 1e+06 m/s"),
], ids=["episodes", "workers", "measurement_spacing", "altitudes", "rows-cols", "rows-cols-encoding", "speed"])
def test_a_size_beyond_its_bound_is_one_line_before_any_work(extra, message, capsys, tmp_path):
    out = tmp_path / "lb"
    t0 = time.perf_counter()
    rc, stdout, err = _cli(["leaderboard", "--tasks", "Grid15Eval-v1", "--planners", "random", "--no-progress",
                            "--out", str(out), *extra], capsys)
    assert rc == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert any(w in err for w in ("limit", "expected", "valid:"))  # the valid range or the memory needed
    assert time.perf_counter() - t0 < 30 and not out.exists()


def test_the_size_limits_hold_every_task_of_the_suite():
    from ipp_bench.core.limits import check_sizes
    from ipp_bench.envs import TASKS

    for spec in TASKS.values():
        check_sizes(spec.config)


def test_gym_make_refuses_a_map_too_large_for_memory():
    with pytest.raises(ValueError, match="too large for the dense belief.*GiB.*WindowBelief"):
        gym.make(TASK, rows=100, cols=100)


def test_a_dense_belief_too_large_is_one_line_before_any_allocation():
    """128 x 128: the roadmap and encoding fit, the dense belief does not; said before allocating."""
    import tracemalloc

    from ipp_bench.core.limits import ARRAY_LIMIT_BYTES, check_sizes, dense_belief_bytes, encoding_bytes

    config = ipp_bench.envs.task_config(TASK)
    big = config.replace(rows=128, cols=128)
    assert encoding_bytes(big) < 2**30 <= ARRAY_LIMIT_BYTES < dense_belief_bytes(big)  # the sparse encoding: < 1 GiB
    tracemalloc.start()
    with pytest.raises(ValueError) as err:
        gym.make(TASK, rows=128, cols=128)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 50 * 2**20  # nothing of the map's size was allocated
    assert str(err.value) == (
        "grid.rows x grid.cols = 128 x 128 cells is too large for the dense belief: its covariance of 16384 states "
        "needs 2 GiB, 10 GiB while its prior is built (limit 2 GiB, at most 7327 states); a map this large needs "
        "the scalable belief ipp_bench.core.belief_window.WindowBelief: set gp.belief = 'window' (--env belief=window)")
    check_sizes(config.replace(rows=85, cols=85))
    check_sizes(big.replace(belief="window"))  # the window belief's estimate instead: ~0.1 GiB


def test_an_encoding_too_large_is_one_line_naming_its_memory_and_limit():
    from ipp_bench.core.limits import check_sizes

    config = ipp_bench.envs.task_config(TASK)
    with pytest.raises(ValueError) as err:
        check_sizes(config.replace(rows=1000, cols=1000))
    assert str(err.value) == (
        "grid.rows x grid.cols x len(graph.altitudes) = 1000 x 1000 x 2 = 2000000 roadmap nodes is too large: the "
        "positional encoding's sparse eigensolver (k = 20) needs about 26.6 GiB (limit 2 GiB, at most 241284 nodes)")
    with pytest.raises(ValueError, match=r"graph.n_samples = 400000 = 400000 roadmap nodes is too large: .* GiB "
                                         r"\(limit"):
        check_sizes(config.replace(sampling="uniform", n_samples=400_000))


# -- no silent wrong results -------------------------------------------------------------------
@pytest.mark.parametrize("extra, message", [
    (["--planners", ","], "--planners ',' names no planner"),
    (["--planners", ""], "names no planner"),
    (["--planners", "random", "--reference", "mcts"], "--reference 'mcts' names no planner of this run"),
    (["--planners", "random", "--env", "episode_seeds=[0,2]", "--episodes", "6"],
     "play 2 distinct episodes of the 6 asked for"),
    (["--planners", "random", "--out", ""], "--out '' is empty"),
], ids=["comma-only-planners", "empty-planners", "reference-not-run", "repeating-seeds", "empty-out"])
def test_arguments_that_would_give_a_silently_wrong_run_are_refused(extra, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = ["leaderboard", "--tasks", "Grid15Eval-v1", "--episodes", "1", "--no-progress", "--out", "lb", *TINY]
    argv = argv[:argv.index("--out")] + extra + argv[argv.index("--out"):] if "--out" not in extra else \
        ["leaderboard", "--tasks", "Grid15Eval-v1", "--episodes", "1", "--no-progress", *TINY, *extra]
    rc, stdout, err = _cli(argv, capsys)
    assert rc == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == [] and "leaderboard:" not in stdout


def test_the_default_reference_absent_from_the_run_is_no_error(capsys, tmp_path):
    rc, _, err = _cli(_lb(tmp_path / "lb"), capsys)  # random only: no greedy to compare with
    assert rc == 0, err
    assert "No paired comparison" in (tmp_path / "lb" / "leaderboard.md").read_text()


def test_evaluate_json_is_strict_json_without_nan(capsys, monkeypatch):
    import ipp_bench.eval.runner as runner

    real = runner.run_episode

    def with_nan(*args, **kwargs):  # a metric that is not a number (e.g. an empty ROI)
        result = real(*args, **kwargs)
        result.final["rmse_roi"] = float("nan")
        result.report[0]["rmse_reduction_pct"] = float("inf")
        return result

    monkeypatch.setattr(runner, "run_episode", with_nan)
    rc, out, _ = _cli(["evaluate", "--task", "Grid15Eval-v1", "--planner", "random", "--json", *TINY], capsys)
    assert rc == 0 and "NaN" not in out and "Infinity" not in out
    data = json.loads(out, parse_constant=lambda c: pytest.fail(f"bare {c} in --json"))
    assert data["final"]["rmse_roi"] is None and data["report"][0]["rmse_reduction_pct"] is None


def test_progress_lines_print_reductions_as_the_report_does(capsys, tmp_path):
    """A negative reduction (the RMSE grew) prints as -5.4%, never as '--5.4%'."""
    rc, out, _ = _cli(_lb(tmp_path / "lb", "--episodes", "2"), capsys)
    lines = [ln for ln in out.splitlines() if ln.startswith("[")]
    assert rc == 0 and lines and all("uncertainty reduction " in ln and "RMSE reduction " in ln for ln in lines)
    assert "--" not in "".join(ln.split(":", 1)[1] for ln in lines)


# -- a full disk ---------------------------------------------------------------------------------
def test_a_file_written_atomically_is_complete_or_untouched(tmp_path):
    import errno

    from ipp_bench.core.data import OutputWriteError, write_atomically

    path = tmp_path / "plot.png"
    path.write_bytes(b"old")

    def half_then_full(tmp):
        tmp.write_bytes(b"\x89PNG half")
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(OutputWriteError, match=f"cannot write {path}: No space left on device"):
        write_atomically(path, half_then_full)
    assert path.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["plot.png"]


def test_a_full_disk_during_a_leaderboard_is_one_line_and_the_rerun_completes(capsys, tmp_path, monkeypatch):
    import errno
    import types

    import ipp_bench.eval.results as results_module

    real_os, writes = results_module.os, []

    def write(fd, data):
        writes.append(len(data))
        if len(writes) > 2:  # the third episode's rows meet a full disk
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_os.write(fd, data)

    monkeypatch.setattr(results_module, "os", types.SimpleNamespace(**{**vars(real_os), "write": write}))
    out = tmp_path / "lb"
    rc, _, err = _cli(_lb(out, "--episodes", "4"), capsys)
    assert rc == 1 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert f"cannot write {out / 'results.csv'}: No space left on device" in err
    assert "2 of 4 episodes kept" in err and "rerun the same command to resume" in err
    monkeypatch.setattr(results_module, "os", real_os)
    rc, stdout, _ = _cli(_lb(out, "--episodes", "4"), capsys)
    assert rc == 0 and "2 already in" in stdout
    assert not [p for p in out.iterdir() if ".tmp" in p.name]


@pytest.mark.slow
@pytest.mark.ray
@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc (Linux)")
@pytest.mark.timeout(240)
def test_sigterm_on_the_ray_backend_is_the_same_one_line_and_exit_143(tmp_path):
    """Ray's own SIGTERM handler (a C++ stack dump, then death) does not replace the leaderboard's."""
    pytest.importorskip("ray")
    out = tmp_path / "lb"
    argv, proc = _greedy_leaderboard(out, "ray", 6)
    try:
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline:
            if (out / "results.csv").exists() and len((out / "results.csv").read_text().splitlines()) > 1:
                break
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.2)
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=120)
        _none_left(proc, "a Ray process")
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 143, stderr
    assert "SIGTERM received" not in stderr and "episodes kept in" in stderr


def test_fit_prior_maps_beyond_its_bound_is_one_line(capsys):
    rc, out, err = _cli(["fit-prior", "--task", "Grid15Eval-v1", "--maps", "100000000"], capsys)
    assert rc == 2 and "--maps = 100000000 is invalid: expected an integer in [2, 10000]" in err
    assert "fitting" not in out


# -- nothing silently wrong, one line naming the field -------------------------------------------
@pytest.mark.parametrize("env, message", [
    (["--env", "prior_mean=1e300"], "gp.prior_mean = 1e+300 is invalid: expected a finite number in [-1000, 1000]"),
    (["--env", "noise_a=1e-300"], "sensor.noise_a = 1e-300 is invalid: expected a finite number in [1e-06, 1000]"),
    (["--env", "signal_variance=1e300"], "gp.signal_variance = 1e+300 is invalid"),
    (["--env", "nugget=1e300"], "gp.nugget = 1e+300 is invalid"),
    (["--env", "start=[10,10,1e9]"], "altitude in [8, 14] m, the range of graph.altitudes"),
    (["--env", "budget_s=20", "--env", "budget_s=30"], "--env budget_s is given twice (budget_s=20 and budget_s=30)"),
    (["--env", 'grid={"nosuch":5}'], "unknown fields ['nosuch'] in section 'grid': valid are"),
    (["--env", 'mission={"foo":1}'], "unknown fields ['foo'] in section 'mission': valid are"),
    (["--seed", "2147483648"], "--seed 2147483648 is invalid: expected an integer in [0, 2147483647]"),
], ids=["prior_mean", "noise_a", "signal_variance", "nugget", "start", "twice", "grid-section", "mission-section",
        "seed-beyond-the-task"])
def test_evaluate_refuses_before_the_episode_in_one_line(env, message, capsys):
    """Unchecked, each would play: inf RMSE and nan %, a 'Singular matrix' naming nothing, a start at
    14 m for 1e9, the second budget, a TypeError traceback, seed 0 reported as 2147483648."""
    rc, out, err = _cli(["evaluate", "--task", "Grid15Eval-v1", "--planner", "random", *env], capsys)
    assert rc == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert "decisions" not in out


@pytest.mark.parametrize("planner", ["coverage:altitude=60", "coverage:altitude=0.001"])
def test_a_planner_that_flies_outside_the_tasks_altitudes_is_stopped(planner, capsys):
    """Unchecked, coverage:altitude=60 scores 88 % against greedy's 79 % from above the task's altitudes."""
    rc, out, err = _cli(["evaluate", "--task", "Grid15Eval-v1", "--planner", planner, *TINY], capsys)
    # refused by the planner at the episode's start (exit 2), or else by the mission at its first leg (exit 1):
    # the mission refuses whatever planner asks (tests/test_mission.py)
    assert rc in (1, 2) and "[8, 14]" in err, err
    assert len(err.strip().splitlines()) == 1 and "decisions" not in out


def test_a_planner_that_raises_in_evaluate_is_the_leaderboards_line_exit_1(capsys, monkeypatch):
    from ipp_bench.planners.simple import RandomPlanner

    def broken(self, obs):
        raise KeyError("no such node")

    monkeypatch.setattr(RandomPlanner, "act", broken)
    rc, out, err = _cli(["evaluate", "--task", "Grid15Eval-v1", "--planner", "random", "--seed", "3", *TINY], capsys)
    assert rc == 1 and len(err.strip().splitlines()) == 1, err
    assert err.startswith("ipp-bench: error: episode Grid15Eval-v1 random seed 3 failed: KeyError: 'no such node' "
                          "(at test_bad_input.py:") and err.strip().endswith("in broken)")


@pytest.mark.timeout(120)
def test_evaluate_render_on_a_full_disk_is_exit_1_and_keeps_the_old_file(tmp_path):
    """Files past 64 KiB cannot be written (RLIMIT_FSIZE, SIGXFSZ ignored: EFBIG, as on a full disk)."""
    import resource

    png = tmp_path / "final.png"
    png.write_bytes(b"an older figure")

    def small_disk():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (64 * 1024, 64 * 1024))

    code = "import sys\nfrom ipp_bench.cli import main\nsys.exit(main(sys.argv[1:]))\n"
    proc = subprocess.run([sys.executable, "-c", code, "evaluate", "--task", "Grid15Eval-v1", "--planner", "random",
                           "--render", str(png), *TINY], cwd=REPO, capture_output=True, text=True, timeout=100,
                          preexec_fn=small_disk)
    assert proc.returncode == 1 and f"cannot write {png}: File too large" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert png.read_bytes() == b"an older figure" and sorted(p.name for p in tmp_path.iterdir()) == ["final.png"]


def test_fit_prior_on_a_map_too_large_is_one_line_before_any_map(capsys):
    """128 x 128 cells: the fit's n x n arrays (10 GiB) would end in SIGSEGV."""
    t0 = time.perf_counter()
    rc, out, err = _cli(["fit-prior", "--task", "Hotspots128Eval-v2"], capsys)
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "fitting" not in out, err
    assert ("grid.rows x grid.cols = 128 x 128 cells is too large to fit a prior on: the log marginal likelihood of "
            "40 maps holds 5 covariances of 16384 x 16384 cells, 10 GiB (limit 2 GiB") in err
    assert time.perf_counter() - t0 < 10


def test_a_missing_extra_is_named_once(tmp_path):
    rc, _, err = _run_cli(["evaluate", "--task", "MuJoCoWeed15-v1", "--planner", "random"], block=("mujoco", "cv2"))
    assert rc == 2 and err.count('pip install "ipp-bench[sim]"') == 1, err
    rc, _, err = _run_cli(["train", "--help"], block=("torch",))
    assert rc == 2 and err.count('pip install "ipp-bench[train]"') == 1, err


def test_demo_without_the_sim_extra_names_it_not_torch(tmp_path):
    """The default planner (attention) needs torch too: the simulation is what the demo needs first."""
    code = ("import sys\nimport scipy.stats\n"
            + "".join(f"sys.modules[{m!r}] = None\n" for m in ("mujoco", "cv2", "torch"))
            + "from ipp_bench.cli import main\nsys.exit(main(sys.argv[1:]))\n")
    proc = subprocess.run([sys.executable, "-c", code, "demo", "--budget", "4", "--out", str(tmp_path / "d.mp4")],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stderr.count('pip install "ipp-bench[sim]"') == 1, proc.stderr
    assert "torch" not in proc.stderr and "[train]" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
