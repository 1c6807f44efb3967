"""Bad input and faults around the leaderboard's results folder, its executors and its report.

Each case is something a hostile user (or a crash) does to a run: a hand-edited or torn
``results.csv``, a folder where a file belongs, a dangling ``--out`` link, a signal at the worst
moment, a killed run whose helpers could outlive it. The run must say what is wrong in one line,
name the file and line, and never lose or rewrite the rows it was given.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from lb_helpers import results, run_tiny

from ipp_bench.eval.results_csv import RESULTS_CSV
from ipp_bench.eval.run_json import RUN_JSON, ResultsMismatchError

REPO = Path(__file__).resolve().parents[2]


def _lines(out: Path) -> list[str]:
    return (out / RESULTS_CSV).read_text().splitlines()


def _refused(out: Path, match: str) -> str:
    """Resume ``out``; it must be refused in one line matching ``match``, touching no file."""
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    with pytest.raises(ResultsMismatchError) as info:
        run_tiny(out)
    text = str(info.value)
    assert "\n" not in text and match in text, text
    after = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert after == before  # nothing rewritten, nothing dropped
    return text


# -- 1. a hand-edited or torn results.csv -----------------------------------------------------------
def _edit_cell(out: Path, line: int, column: str, value: str) -> None:
    lines = _lines(out)
    header = lines[0].split(",")
    cells = lines[line - 1].split(",")
    cells[header.index(column)] = value
    lines[line - 1] = ",".join(cells)
    (out / RESULTS_CSV).write_text("\n".join(lines) + "\n")


def test_a_number_edited_by_hand_is_named_by_line(reference_copy):
    """Still a valid number, so only the digest run.json keeps of every row can tell."""
    old = float(_lines(reference_copy)[5].split(",")[6])
    _edit_cell(reference_copy, 6, "uncertainty_reduction_pct", repr(old + 0.5))
    text = _refused(reference_copy, f"{reference_copy / RESULTS_CSV}:6: ")
    assert "not a row this run wrote" in text


@pytest.mark.parametrize("column, value, what", [
    ("uncertainty_reduction_pct", "nan", "uncertainty_reduction_pct = nan is not a finite number"),
    ("rmse_roi", "inf", "rmse_roi = inf is not a finite number"),
    ("trace_roi", "abc", "trace_roi = 'abc' is not a number"),
    ("seed", "1.5", "seed = '1.5' is not an integer"),
    ("planner", "sneaky", "planner 'sneaky' is not a planner of this run"),
    ("task", "ipp_bench/Grid30Eval-v1", "task 'ipp_bench/Grid30Eval-v1' is not a task of this run"),
    ("seed", "999999", "seed 999999 is not an episode seed of this run"),
    ("time_s", "33.0", "time_s = 33.0 is not a report time of"),
], ids=["nan", "inf", "text", "seed-float", "planner", "task", "seed", "time"])
def test_a_bad_cell_is_named_by_line_and_column(reference_copy, column, value, what):
    _edit_cell(reference_copy, 4, column, value)
    text = _refused(reference_copy, f"{reference_copy / RESULTS_CSV}:4: ")
    assert what in text, text


def test_a_short_row_in_the_middle_is_named(reference_copy):
    lines = _lines(reference_copy)
    lines[2] = lines[2][: len(lines[2]) // 2]
    (reference_copy / RESULTS_CSV).write_text("\n".join(lines) + "\n")
    assert "fields, expected" in _refused(reference_copy, f"{reference_copy / RESULTS_CSV}:3: ")


def test_a_duplicated_row_is_named_with_its_first_line(reference_copy):
    lines = _lines(reference_copy)
    (reference_copy / RESULTS_CSV).write_text("\n".join(lines[:4] + [lines[2]] + lines[4:]) + "\n")
    assert "repeats line 3" in _refused(reference_copy, f"{reference_copy / RESULTS_CSV}:5: ")


def test_a_folder_without_row_digests_still_checks_every_row_and_resumes(reference_run, reference_copy):
    """run.json of an older folder has no digests: the rows are still checked, then it resumes."""
    meta = json.loads((reference_copy / RUN_JSON).read_text())
    meta.pop("rows", None)
    (reference_copy / RUN_JSON).write_text(json.dumps(meta, indent=2) + "\n")
    before = (reference_copy / RESULTS_CSV).read_bytes()
    run_tiny(reference_copy)  # already complete: nothing to do
    assert (reference_copy / RESULTS_CSV).read_bytes() == before
    _edit_cell(reference_copy, 4, "rmse_roi", "nan")
    _refused(reference_copy, "rmse_roi = nan is not a finite number")


def test_a_torn_last_line_and_a_deleted_episode_still_resume(reference_run, reference_copy):
    """What a kill leaves (a torn last line) and a row deleted by hand (its episode runs again)."""
    lines = _lines(reference_copy)
    text = "\n".join(lines[:3] + lines[4:]) + "\n" + lines[4][:10]
    (reference_copy / RESULTS_CSV).write_text(text)
    summary = run_tiny(reference_copy)
    assert summary.ran == 1
    assert len(results(reference_copy)) == len(lines) - 1


def test_rows_appended_after_the_last_recorded_digest_are_one_episode_at_most(reference_run, tmp_path):
    """A kill between an episode's append and run.json's update leaves that episode's rows without
    a digest: accepted (checked like any row); two episodes without one are not a crash's."""
    out = tmp_path / "run"
    shutil.copytree(reference_run[0], out)
    meta = json.loads((out / RUN_JSON).read_text())
    n = len(meta["rows"]["digests"]) // 8
    per_episode = 2  # report times of the tiny plan
    meta["rows"] = {"count": n - per_episode, "digests": meta["rows"]["digests"][: 8 * (n - per_episode)]}
    (out / RUN_JSON).write_text(json.dumps(meta))
    assert run_tiny(out).ran == 0  # the last episode's two rows, unrecorded
    meta["rows"] = {"count": n - 2 * per_episode, "digests": meta["rows"]["digests"][: 8 * (n - 2 * per_episode)]}
    (out / RUN_JSON).write_text(json.dumps(meta))
    _refused(out, "not a row this run wrote")


def test_a_non_finite_metric_is_never_written(reference_copy, monkeypatch):
    import ipp_bench.eval.leaderboard as lb

    lines = _lines(reference_copy)
    (reference_copy / RESULTS_CSV).write_text("\n".join(lines[:-2]) + "\n")  # one episode to fly again
    real = lb.run_job

    def nan_job(job):
        rows = real(job)
        rows[0]["rmse_reduction_pct"] = math.nan
        return rows

    monkeypatch.setattr(lb, "run_job", nan_job)
    with pytest.raises(lb.EpisodeFailed, match="rmse_reduction_pct = nan is not a finite number"):
        run_tiny(reference_copy)
    assert _lines(reference_copy) == lines[:-2]


# -- 2. folders where files belong, a dangling --out link -------------------------------------------
@pytest.mark.parametrize("name", [RESULTS_CSV, RUN_JSON])
def test_a_folder_in_place_of_a_file_is_one_line(reference_copy, name):
    (reference_copy / name).unlink()
    (reference_copy / name).mkdir()
    assert "is a folder, not a file" in _refused(reference_copy, str(reference_copy / name))


def test_a_dangling_out_link_is_named_as_such(tmp_path):
    link = tmp_path / "out"
    link.symlink_to(tmp_path / "gone")
    with pytest.raises(ResultsMismatchError) as info:
        run_tiny(link)
    text = str(info.value)
    assert "symbolic link" in text and str(tmp_path / "gone") in text and "another leaderboard run" not in text
    assert not (tmp_path / "gone").exists()


def test_the_command_line_says_so_in_one_line(reference_run, tmp_path):
    from lb_helpers import EPISODES, PLANNERS, TASKS

    out = tmp_path / "run"
    shutil.copytree(reference_run[0], out)
    _edit_cell(out, 4, "rmse_roi", "nan")
    argv = [sys.executable, "-m", "ipp_bench.cli", "leaderboard", "--tasks", *TASKS, "--planners", *PLANNERS,
            "--episodes", str(EPISODES), "--seed", "7", "--env", "budget_s=40", "--env", "report_times=[20,40]",
            "--backend", "serial", "--no-progress", "--out", str(out)]
    proc = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.count("\n") == 1 and f"{out / RESULTS_CSV}:4: rmse_roi = nan" in proc.stderr, proc.stderr


# -- 6. where the rows were made -------------------------------------------------------------------
def test_run_json_records_the_machine_and_the_report_says_it_in_one_line(reference_run):
    out = reference_run[0]
    meta = json.loads((out / RUN_JSON).read_text())
    machine = meta["machine"]
    assert machine["cores"] == os.cpu_count() and machine["python"] == sys.version.split()[0]
    assert {"numpy", "scipy"} <= set(machine["packages"]) and isinstance(machine["cpu_flags"], list)
    flags = Path("/proc/cpuinfo").read_text().split() if Path("/proc/cpuinfo").exists() else []
    assert ("avx2" in machine["cpu_flags"]) == ("avx2" in flags)
    assert "machine" not in json.dumps(meta["fingerprint"])  # results never depend on where they were made
    report = (out / "leaderboard.md").read_text().splitlines()
    made_on = [line for line in report if line.startswith("Made on ")]
    assert len(made_on) == 1 and machine["cpu"] in made_on[0] and f"numpy {machine['packages']['numpy']}" in made_on[0]


def test_a_run_json_without_the_machine_still_resumes(reference_copy):
    meta = json.loads((reference_copy / RUN_JSON).read_text())
    for key in ("machine", "rows"):
        meta.pop(key, None)
    (reference_copy / RUN_JSON).write_text(json.dumps(meta, indent=2) + "\n")
    before = (reference_copy / RUN_JSON).read_bytes()
    assert run_tiny(reference_copy).ran == 0
    assert (reference_copy / RUN_JSON).read_bytes() == before  # a complete older folder is left as it is


# -- 4. SIGTERM while the process pool starts --------------------------------------------------------
_SIGTERM_IN_SPAWN = textwrap.dedent("""
    import multiprocessing.context as ctx, os, signal, sys, time
    from ipp_bench.cli import _SigtermAsInterrupt
    from ipp_bench.eval.executors import ProcessExecutor

    signal.signal(signal.SIGTERM, _SigtermAsInterrupt())
    real = ctx.ForkServerProcess.start
    state = {"sent": False}

    def start(self):  # SIGTERM the moment a worker is forked, before the pool has recorded it
        real(self)
        if not state["sent"]:
            state["sent"] = True
            os.kill(os.getpid(), signal.SIGTERM)

    ctx.ForkServerProcess.start = start
    ex = ProcessExecutor(2)
    try:
        for _ in ex.imap_unordered(abs, [-1] * 8):
            pass
        print("not interrupted")
    except KeyboardInterrupt:
        ex.close(abort=True)
        time.sleep(2.0)  # a worker left mid-start would print its traceback by now
        print("interrupted")
""")


@pytest.mark.skipif("forkserver" not in __import__("multiprocessing").get_all_start_methods(),
                    reason="needs the forkserver start method")
def test_sigterm_while_the_pool_starts_its_workers_prints_no_traceback(tmp_path):
    for _ in range(3):
        proc = subprocess.run([sys.executable, "-c", _SIGTERM_IN_SPAWN], capture_output=True, text=True,
                              timeout=120, cwd=tmp_path)
        assert proc.stdout.strip() == "interrupted", proc.stdout + proc.stderr
        assert "Traceback" not in proc.stderr, proc.stderr


# -- 5. no process outlives its run ------------------------------------------------------------------
def _group_alive(pgid: int) -> dict[int, str]:
    """Live (not zombie) processes of process group ``pgid``: pid -> command line."""
    alive = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        if fields[0] != "Z" and int(fields[2]) == pgid:
            alive[int(entry.name)] = cmd[:80]
    return alive


@pytest.mark.slow
@pytest.mark.ray
@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc (Linux)")
@pytest.mark.timeout(300)
def test_sigkill_of_a_run_on_a_local_ray_leaves_no_ray_process(tmp_path):
    """SIGKILL gives the run no chance to clean up: the local Ray it started (raylet, GCS, workers,
    dashboard and runtime-env agents) must still be gone within seconds, not after Ray's own
    minute-long timeouts."""
    pytest.importorskip("ray")
    out = tmp_path / "lb"
    argv = [sys.executable, "-m", "ipp_bench.cli", "leaderboard", "--tasks", "Grid15Eval-v1", "--planners", "greedy",
            "--episodes", "6", "--backend", "ray", "--workers", "1", "--no-progress", "--out", str(out),
            "--env", "budget_s=60", "--env", "report_times=[30,60]"]
    proc = subprocess.Popen(argv, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline:
            if (out / RESULTS_CSV).exists() and len(_lines(out)) > 1:
                break
            assert proc.poll() is None
            time.sleep(0.2)
        rays = {p: c for p, c in _group_alive(proc.pid).items() if p != proc.pid}
        assert any("Agent" in c for c in rays.values()), rays  # the helpers that used to linger
        proc.kill()
        proc.wait(timeout=30)
        deadline = time.monotonic() + 12
        while set(rays) & set(_group_alive(proc.pid)) and time.monotonic() < deadline:
            time.sleep(0.3)
        left = {p: c for p, c in _group_alive(proc.pid).items() if p in rays}
        assert not left, f"outlived the run by 12 s: {left}"
    finally:
        for pid in _group_alive(proc.pid):
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass


def test_power_on_a_hand_edited_folder_names_the_row(reference_run, tmp_path, capsys):
    """``ipp-bench power`` (and the report) read results.csv too: a bad row is named, never skipped."""
    from ipp_bench.cli import main

    out = tmp_path / "run"
    shutil.copytree(reference_run[0], out)
    _edit_cell(out, 5, "uncertainty_reduction_pct", "oops")
    assert main(["power", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{out / RESULTS_CSV}:5: uncertainty_reduction_pct = 'oops' is not a number" in err
