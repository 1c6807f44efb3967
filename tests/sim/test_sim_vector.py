"""The MuJoCo task under gymnasium's async vector env, after the parent process has rendered.

A forked worker inherits the GL driver's state without its threads: its first frame would wait for
them for ever (a deadlock inside gymnasium's ``AsyncVectorEnv``, whose default start method on Linux
is ``fork``). ``gym.make_vec(..., vectorization_mode="async")`` of a MuJoCo task starts its workers
with ``forkserver`` (the task's spec says so) and runs; a worker forked by hand refuses at once,
naming the start methods that work.
"""

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytest.importorskip("mujoco")

REPO = Path(__file__).resolve().parents[2]

SCRIPT = textwrap.dedent('''
    import multiprocessing, sys, time
    import gymnasium as gym
    import ipp_bench.envs

    TASK, SHORT = "ipp_bench/MuJoCoWeed15-v1", dict(budget_s=20, report_times=[20])

    def make():
        return gym.make(TASK, **SHORT)

    if __name__ == "__main__":
        env = gym.make(TASK, **SHORT)
        env.reset(seed=0)  # the parent renders (the camera's first read-out)
        assert multiprocessing.get_start_method() == "fork"
        vec = gym.vector.AsyncVectorEnv([make, make], context="fork")  # forked by hand
        t0 = time.monotonic()
        try:
            vec.reset(seed=0)
            print("FORK: reset worked")
        except RuntimeError as err:
            print(f"FORK: {err} after {time.monotonic() - t0:.1f} s")
        vec.close(terminate=True)
        vec = gym.make_vec(TASK, num_envs=2, vectorization_mode="async", **SHORT)  # gymnasium's default call
        obs, _ = vec.reset(seed=0)
        obs, reward, *_ = vec.step([int(m.argmax()) for m in obs["action_mask"]])
        print(f"MAKE_VEC: stepped, rewards {reward.tolist()}")
        vec.close()
        env.close()
''')


@pytest.mark.timeout(300)
@pytest.mark.skipif(sys.platform != "linux", reason="fork is the default start method on Linux")
def test_make_vec_async_runs_after_the_parent_rendered_and_a_hand_forked_worker_refuses_at_once(tmp_path):
    script = tmp_path / "vector.py"
    script.write_text(SCRIPT)
    proc = subprocess.run([sys.executable, str(script)], cwd=REPO, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-3000:]
    fork = next(ln for ln in proc.stdout.splitlines() if ln.startswith("FORK: "))
    assert "forked from one that had already rendered with OpenGL" in fork, fork
    assert "vector_kwargs={'context': 'forkserver'}" in fork
    assert float(fork.rsplit(" after ", 1)[1].split()[0]) < 30.0  # refused, not waited out
    assert "MAKE_VEC: stepped, rewards" in proc.stdout
