"""The MuJoCo task under gymnasium's async vector env, after the parent process has rendered.

A forked worker inherits the GL driver's state without its threads: its first frame would wait for
them for ever (a deadlock inside ``gym.make_vec(..., vectorization_mode="async")``, whose default
start method on Linux is ``fork``). The worker refuses at once, naming the start methods that
work, and with ``forkserver`` the same vector env runs.
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

    def vector(context):
        kwargs = {} if context is None else {"context": context}
        return gym.make_vec(TASK, num_envs=2, vectorization_mode="async", vector_kwargs=kwargs, **SHORT)

    if __name__ == "__main__":
        env = gym.make(TASK, **SHORT)
        env.reset(seed=0)  # the parent renders (the camera's first read-out)
        assert multiprocessing.get_start_method() == "fork"
        vec = vector(None)  # gymnasium's default: fork
        t0 = time.monotonic()
        try:
            vec.reset(seed=0)
            print("DEFAULT: reset worked")
        except RuntimeError as err:
            print(f"DEFAULT: {err} after {time.monotonic() - t0:.1f} s")
        vec.close(terminate=True)
        vec = vector("forkserver")
        obs, _ = vec.reset(seed=0)
        obs, reward, *_ = vec.step([int(m.argmax()) for m in obs["action_mask"]])
        print(f"FORKSERVER: stepped, rewards {reward.tolist()}")
        vec.close()
        env.close()
''')


@pytest.mark.timeout(300)
@pytest.mark.skipif(sys.platform != "linux", reason="fork is the default start method on Linux")
def test_a_forked_async_worker_of_a_rendered_parent_refuses_at_once_and_forkserver_runs(tmp_path):
    script = tmp_path / "vector.py"
    script.write_text(SCRIPT)
    proc = subprocess.run([sys.executable, str(script)], cwd=REPO, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-3000:]
    default = next(ln for ln in proc.stdout.splitlines() if ln.startswith("DEFAULT: "))
    assert "forked from one that had already rendered with OpenGL" in default, default
    assert "vector_kwargs={'context': 'forkserver'}" in default
    assert float(default.rsplit(" after ", 1)[1].split()[0]) < 30.0  # refused, not waited out
    assert "FORKSERVER: stepped, rewards" in proc.stdout
