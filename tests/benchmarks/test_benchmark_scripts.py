"""Smoke tests of the scripts in ``benchmarks/``: each runs its real command line with tiny arguments in a
fresh process and must exit 0 having printed its figures, so that no script rots unnoticed.

The figures themselves are machine-dependent and never checked against a value; what is checked is that
each line the script promises appears with a number in it. ``bench_twin_gap.py`` is the exception: it is
a pure function of two committed result files, so its output must equal the committed ``gap.md``.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BENCH = ROOT / "benchmarks"
NUMBER = r"[-+]?\d+(\.\d+)?"

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not BENCH.is_dir(), reason="benchmarks/ is not beside the package (an installed copy)"),
]


def run_script(name: str, *args: str, timeout: float = 600.0) -> str:
    """Run ``python benchmarks/NAME ARGS`` from the repository root; return its output, asserting exit 0."""
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    proc = subprocess.run([sys.executable, str(BENCH / name), *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=timeout, check=False)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, f"{name} {' '.join(args)} exited {proc.returncode}:\n{out[-3000:]}"
    return out


def assert_lines(out: str, *patterns: str) -> None:
    """Every regular expression in ``patterns`` matches some line of ``out``."""
    for pattern in patterns:
        assert re.search(pattern, out, re.MULTILINE), f"no line matches {pattern!r} in:\n{out[-3000:]}"


def needs(*modules: str) -> list:
    return [pytest.mark.skipif(importlib.util.find_spec(m) is None, reason=f"needs {m}") for m in modules]


def needs_commit(rev: str) -> list:
    """The script builds a git worktree of ``rev``: a clone without that commit (a shallow one) cannot."""
    try:
        known = subprocess.run(["git", "cat-file", "-e", f"{rev}^{{commit}}"], cwd=ROOT, capture_output=True,
                               timeout=30).returncode == 0
    except (OSError, subprocess.SubprocessError):
        known = False
    return [pytest.mark.skipif(not known, reason=f"needs commit {rev} in the clone (git fetch --unshallow)")]


# (script, tiny arguments, patterns its output must match, extra markers)
CASES = [
    ("bench_core.py", ["--sizes", "15", "--steps", "5"],
     [rf"^\s*15x15\s+dense\s+225\s+450(\s+{NUMBER}){{10}}\s*$",
      rf"^\s*15x15\s+window\s+225\s+450(\s+{NUMBER}){{10}}\s*$"],
     []),
    ("bench_belief_scale.py", ["--sizes", "15", "--looks", "5", "--flight", "20"],
     [rf"15x15\s+dense GPBelief(\s+{NUMBER}){{5}}", rf"15x15\s+WindowBelief w=\d+(\s+{NUMBER}){{5}}",
      rf"random-walk flight of 20 looks: update median {NUMBER} ms", rf"process peak memory: {NUMBER} MB"],
     []),
    ("bench_roadmap_scale.py", ["--sizes", "15"],
     [rf"^\| 15 x 15 \| 450 \| dense \(auto\) \| {NUMBER} \| {NUMBER} \|",
      rf"^\| 15 x 15 \| 450 \| sparse \| {NUMBER} \|"],
     []),
    ("bench_large_episode.py", ["--budget-s", "20"],
     [r"Hotspots128Eval-v2, greedy, seed 0: budget 20 s", rf"decisions: \d+, median {NUMBER} ms",
      rf"belief updates: \d+ .*median {NUMBER} ms", rf"process peak {NUMBER} MB"],
     []),
    ("bench_planners.py", ["--tasks", "Grid15Eval-v1", "--planners", "random", "greedy", "--episodes", "1"],
     [rf"^Grid15Eval-v1\s+random\s+\d+(\s+{NUMBER}){{3}}\s*$",
      rf"^Grid15Eval-v1\s+greedy\s+\d+(\s+{NUMBER}){{3}}\s*$"],
     []),
    ("bench_search.py", ["--tasks", "ipp_bench/Grid15Eval-v1", "--decisions", "1"],
     [rf"^ipp_bench/Grid15Eval-v1\s+mcts\s+1\s+{NUMBER}\s+{NUMBER}\s+{NUMBER}x",
      rf"^ipp_bench/Grid15Eval-v1\s+cmaes\s+1\s+{NUMBER}\s+{NUMBER}\s+{NUMBER}x"],
     []),
    ("bench_team.py", ["--episodes", "1", "--budget-s", "30"],
     [rf"greedy, one UAV\s+{NUMBER} \(\d+\)", rf"team-greedy, Hotspots30Team4Eval-v2\s+{NUMBER} \(\d+\): fusion ahead",
      rf"team-greedy, Hotspots30Team2Eval-v2\s+{NUMBER}\s+\({NUMBER}x one UAV's\)"],
     []),
    ("bench_policy.py", ["--skip-training", "--decisions", "3", "--mcts-decisions", "1"],
     [rf"attention, 450 nodes, 1 thread\(s\): median {NUMBER} ms",
      rf"attention, 1800 nodes, 1 thread\(s\): median {NUMBER}",
      rf"greedy, 1800 nodes: median {NUMBER} ms", rf"mcts:simulations=24 / attention .* at 450 nodes: {NUMBER}x"],
     needs("torch")),
    ("bench_policy.py", ["--decisions", "3", "--mcts-decisions", "0", "--train-threads", "1", "--ppo-rollouts", "1",
                         "--n-epochs", "1"],
     [rf"PPO env-steps/s .*1 thread\(s\)\): {NUMBER} over \d+ steps"],
     needs("torch", "sb3_contrib")),
    ("bench_train.py", ["--tiny"],
     [rf"^Grid15Train-v1 \+ Hotspots15Train-v2\s+new / old: {NUMBER}x",
      rf"^15 x 15 new\s+main\s+{NUMBER} = forward {NUMBER}",
      rf"^episodes: \d+, metrics max rel. diff {NUMBER}(e[-+]\d+)? \(equal",
      rf"^training transitions: \d+, observations and rewards max rel. diff {NUMBER}(e[-+]\d+)? \(equal",
      rf"^network grad\s*: max \|old - new\| {NUMBER}"],
     needs("torch", "sb3_contrib") + needs_commit("4e9f32f")),
    ("bench_isolation.py", ["--planners", "random", "--episodes", "1", "--budget-s", "30"],
     [rf"^random: \d+ decisions; wall per decision in-process {NUMBER} ms, isolated {NUMBER} ms, overhead {NUMBER} %",
      rf"CPU per decision in-process {NUMBER} ms, isolated \(both processes\) {NUMBER} ms", r"same reports: True"], []),
    ("bench_vision.py", ["--frames", "3", "--sizes", "128"],
     [rf"^\s*128x128\s+8m\s+1 \|(\s+{NUMBER} ms \(\s*\d+/s\) \|){{4}}", r"^\s*128x128\s+14m\s+2 \|",
      rf"projections on the same mask: \d+ cells, max \|diff\| {NUMBER}", rf"shadow map\s+0:\s+{NUMBER} ms"],
     needs("mujoco", "cv2")),
    ("bench_sim.py", ["--frames", "3", "--steps", "300", "--seeds", "1", "--planners", "random",
                      "--tasks", "ipp_bench/MuJoCoWeed15-v1"],
     [rf"320x320\s+8 m:\s+{NUMBER} ms", rf"bare mj_step:\s+{NUMBER} steps/s",
      rf"controller \+ mj_step .*{NUMBER} steps/s",
      rf"random: median {NUMBER}x real time"],
     needs("mujoco", "cv2")),
    ("bench_rotor.py", ["--seeds", "1", "--planners", "random"],
     [rf"calm thrust: {NUMBER} / {NUMBER} / {NUMBER} m", rf"wind \+ estimator  speed: {NUMBER}",
      rf"mean thrust: uncertainty red. {NUMBER} %", rf"mean  speed: uncertainty red. {NUMBER} %"],
     needs("mujoco", "cv2")),
    ("bench_deployment.py", ["--planners", "random", "--seeds", "1"],
     [rf"camera: uncertainty reduction {NUMBER} / {NUMBER} / {NUMBER} / {NUMBER} %",
      rf"truth: uncertainty reduction {NUMBER}", rf"pooled NIS per degree of freedom .*: {NUMBER}"],
     needs("mujoco", "cv2")),
    ("bench_camera_error.py", ["--planners", "random", "--seeds", "1"],
     [rf"f = 1: \d+ cell reads, mean {NUMBER}", rf"f=1 & f=2: \d+ pairs, E\[e1 e2\] {NUMBER}, corr {NUMBER}",
      rf"^\s*random: {NUMBER} \| {NUMBER} \| {NUMBER}"],
     needs("mujoco", "cv2")),
]


@pytest.mark.parametrize(
    "script, args, patterns",
    [pytest.param(s, a, p, marks=m, id=f"{s}[{' '.join(a)}]") for s, a, p, m in CASES],
)
def test_script_prints_its_figures(script, args, patterns):
    assert_lines(run_script(script, *args), *patterns)


def test_every_script_has_a_smoke_test():
    """A script added to benchmarks/ needs a case here (helpers imported by the scripts excepted)."""
    helpers = {"timing.py"}
    scripts = {p.name for p in BENCH.glob("*.py")} - helpers
    covered = {case[0] for case in CASES} | {"bench_twin_gap.py"}
    assert scripts <= covered, f"benchmarks without a smoke test: {sorted(scripts - covered)}"


def test_twin_gap_regenerates_the_committed_page(tmp_path):
    """``bench_twin_gap.py`` on the committed result files writes the committed ``gap.md`` (its own
    command line aside), and prints the same table."""
    deploy = ROOT / "baselines" / "deployment_v1"
    committed = deploy / "gap.md"
    if not committed.is_file():
        pytest.skip("baselines/deployment_v1/gap.md is not in this copy")
    out_file = tmp_path / "gap.md"
    out = run_script("bench_twin_gap.py", "--mujoco", str(deploy / "results.csv"),
                     "--twin", str(deploy / "twin" / "results.csv"), "--out", str(out_file))

    def body(text: str) -> list[str]:
        return [line for line in text.splitlines() if not line.startswith("Made by")]

    assert body(out_file.read_text()) == body(committed.read_text())
    assert_lines(out, r"^\| 200 s \| greedy - random \|", r"The twin orders \d+ of the \d+ separated pairs")
