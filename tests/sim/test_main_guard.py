"""A script without a main guard that makes an async vector env of a MuJoCo task: its workers import the script
anew, and the error says how to fix it, in one line."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

pytest.importorskip("mujoco")

SCRIPT = """
import gymnasium as gym

import ipp_bench.envs  # noqa: F401

envs = gym.make_vec("ipp_bench/MuJoCoWeed15-v1", 2, vectorization_mode="async")
envs.close()
"""


def test_a_script_without_a_main_guard_is_told_to_add_one(tmp_path):
    script = tmp_path / "no_guard.py"
    script.write_text(SCRIPT)
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120, cwd=tmp_path,
                         env={**os.environ, "MUJOCO_GL": "egl"})
    assert run.returncode != 0
    lines = [x for x in run.stderr.splitlines() if 'if __name__ == "__main__":' in x]
    assert lines and lines[0].startswith("ipp-bench: ") and "vector env" in lines[0], run.stderr[-2000:]
