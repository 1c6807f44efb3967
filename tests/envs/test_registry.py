"""The task registry: the paper's tasks, tags, idempotent registration, episode-seed ranges."""

import warnings

import gymnasium as gym
import numpy as np
import pytest

import ipp_bench.envs as envs
from ipp_bench.envs import tagged


def test_registry_has_the_paper_tasks():
    v0 = {"ipp_bench/Grid15-v0", "ipp_bench/Grid15Eval-v0", "ipp_bench/Grid20Eval-v0"}
    assert v0 <= set(tagged("v0"))
    assert "ipp_bench/Grid15-v0" in tagged("train")
    v1 = {"ipp_bench/Grid15Eval-v1", "ipp_bench/Grid20Eval-v1", "ipp_bench/Grid30Eval-v1"}
    v2 = {"ipp_bench/Hotspots15Eval-v2", "ipp_bench/Hotspots30Eval-v2"}
    assert set(tagged("benchmark")) == v1 | v2  # the leaderboard's default task list: v1 and v2
    assert v2 <= set(tagged("v2"))
    assert {"ipp_bench/Grid15Train-v1", "ipp_bench/Grid30Train-v1", "ipp_bench/Hotspots15Train-v2",
            "ipp_bench/Hotspots30Train-v2"} <= set(tagged("train"))


def test_v2_tasks_are_sparse_hotspots_with_a_fitted_mean():
    """Weed patches whose ROI (truth >= mu_th) is a minority of the cells, a prior mean fitted far below
    the paper's 0.5, and a belief ROI that covers the whole map before the first look."""
    from ipp_bench.core.fields import make_field
    for task in ("ipp_bench/Hotspots15Eval-v2", "ipp_bench/Hotspots30Eval-v2"):
        cfg = envs.TASKS[task].config
        assert cfg.mission.field == "weed_patches" and cfg.gp.prior_mean < 0.1
        fractions = [np.mean(make_field("weed_patches", cfg.grid, np.random.default_rng(s)) >= cfg.mission.mu_th)
                     for s in range(50)]
        assert 0 < min(fractions) and max(fractions) < 0.5
        sigma = np.sqrt(cfg.gp.signal_variance + cfg.gp.nugget)
        assert cfg.gp.prior_mean + cfg.mission.beta * sigma > cfg.mission.mu_th + 0.1
        train = envs.TASKS[task.replace("Eval", "Train")].config
        assert train.replace(episode_seeds=cfg.mission.episode_seeds) == cfg  # the same task on other seeds


def test_registration_is_idempotent():
    before = {k: gym.registry[k] for k in envs.TASKS}
    envs.register_all()
    assert {k: gym.registry[k] for k in envs.TASKS} == before


def test_gym_make_of_a_team_task_says_it_is_a_pettingzoo_env_in_one_line():
    with pytest.raises(ValueError, match=r"ipp_bench/Hotspots30Team2Eval-v2 is a team task: a PettingZoo AEC "
                                         r"environment, not a gymnasium one; make it with ipp_bench.envs.make_env"):
        gym.make("ipp_bench/Hotspots30Team2Eval-v2")


def test_import_ipp_bench_registers_the_tasks():
    import subprocess
    import sys
    code = ("import gymnasium as gym, ipp_bench; gym.register_envs(ipp_bench); "
            "e = gym.make('ipp_bench/Grid15Eval-v1'); print(e.unwrapped.config.grid.rows)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "15"


def test_training_seeds_never_meet_evaluation_seeds():
    """Every v1 training task plays episode seeds that no evaluation task (nor the leaderboard) can."""
    from ipp_bench.eval.plan import episode_seeds
    train = [envs.TASKS[t].config.mission.episode_seeds for t in tagged("train")
             if {"v1", "v2"} & set(envs.TASKS[t].tags)]
    evals = [envs.TASKS[t].config.mission.episode_seeds for t in tagged("benchmark")]
    assert train and evals
    for lo, hi in train:
        for elo, ehi in evals:
            assert hi <= elo or ehi <= lo, f"training seeds [{lo}, {hi}) overlap evaluation [{elo}, {ehi})"
    drawn = episode_seeds(0, 1000) + episode_seeds(12345, 1000)
    assert all(elo <= s < ehi for s in drawn for elo, ehi in evals)
    env = gym.make("ipp_bench/Grid15Train-v1").unwrapped
    played = [env.reset(seed=s)[1]["episode_seed"] for s in (0, 7, 2**31 - 1, None, None)]
    lo, hi = env.config.mission.episode_seeds
    assert all(lo <= s < hi for s in played)
    ev = gym.make("ipp_bench/Grid15Eval-v1").unwrapped
    assert not np.array_equal(env.reset(seed=7)[0]["node_features"], ev.reset(seed=7)[0]["node_features"])


def test_task_lookup_and_overrides():
    assert envs.resolve_task("Grid15Eval-v0") == "ipp_bench/Grid15Eval-v0"
    assert envs.short_task_id("ipp_bench/Grid15Eval-v0") == "Grid15Eval-v0"
    assert envs.task_spec("Grid15Eval-v0").id == "ipp_bench/Grid15Eval-v0"
    assert envs.task_config("Grid15Eval-v0", {"budget_s": 60}).mission.budget_s == 60
    assert envs.parse_overrides(["budget_s=60", "report_times=[20, 40]", "field=regions"]) == {
        "budget_s": 60, "report_times": [20, 40], "field": "regions"}
    with pytest.raises(ValueError, match="unknown task 'Nope-v0'"):
        envs.task_spec("Nope-v0")
    with pytest.raises(ValueError, match="is not KEY=VALUE"):
        envs.parse_overrides(["budget_s"])


def test_make_env_is_the_one_way_to_a_tasks_env():
    """A short id resolves to the task's bare env; overrides and their errors as gym.make's."""
    env = envs.make_env("Grid15Eval-v1", budget_s=60.0)
    assert isinstance(env, envs.GraphIPPEnv) and env.config.mission.budget_s == 60.0
    with pytest.raises(ValueError, match="unknown task 'Nope-v1'"):
        envs.make_env("Nope-v1")
    with pytest.raises(ValueError, match="budget_s"):
        envs.make_env("Grid15Eval-v1", budget_s=-1.0)


def test_gym_make_adds_gymnasiums_default_wrappers_and_make_env_returns_the_env_inside():
    """Order enforcing and the passive checker, as gymnasium registers by default (the checker has
    nothing to say on the suite's spaces); make_env gives the env they wrap, whose own attributes its
    callers read."""
    from gymnasium.error import ResetNeeded
    from gymnasium.wrappers import OrderEnforcing, PassiveEnvChecker

    for task in ("ipp_bench/Grid15Eval-v1", "ipp_bench/Hotspots15Eval-v2", "ipp_bench/Weed15Twin-v1"):
        spec = gym.spec(task)
        assert spec.order_enforce and not spec.disable_env_checker
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            env = gym.make(task)
            assert isinstance(env, OrderEnforcing) and isinstance(env.env, PassiveEnvChecker)
            with pytest.raises(ResetNeeded):
                env.step(0)
            obs, _ = env.reset(seed=0)
            for _ in range(3):
                obs, *_ = env.step(int(np.flatnonzero(obs["action_mask"])[0]))
        bare = envs.make_env(task)
        assert type(bare) is type(env.unwrapped) and bare is bare.unwrapped
        with pytest.raises(RuntimeError, match=r"call reset\(\) before step\(\)"):
            bare.step(0)


# -- task files ----------------------------------------------------------------------------------
import os  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

from ipp_bench.envs.registry import TaskFileError, TaskFileWarning, discover, load_task  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
GOOD = (REPO / "tasks" / "grid15_eval_v1.toml").read_text()

BROKEN = {  # file content -> (line, what the report says)
    "syntax": ("id = 'ipp_bench/A-v0'\nentry_point = [\n", 2, "TOML syntax error"),
    "binary": (b"\x89PNG\r\n\x1a\n\x00\xff", None, "not a UTF-8 text file"),
    "no-id": (GOOD.replace('id = "ipp_bench/Grid15Eval-v1"\n', ""), None, "lacks ['id']"),
    "id-not-string": (GOOD.replace('id = "ipp_bench/Grid15Eval-v1"', "id = 5"), 1, "id = 5 is invalid"),
    "duplicate-id": (GOOD, 1, "is already defined by"),
    "unknown-key": ("budget = 3\n" + GOOD, 1, "unknown key 'budget'"),
    "float-k": (GOOD.replace("k = 20", "k = 20.0"), GOOD.splitlines().index("k = 20") + 1,
                "graph.k = 20.0 is invalid: expected an integer"),
    "unknown-field": (GOOD.replace("k = 20", "kk = 20"), GOOD.splitlines().index("k = 20") + 1,
                      "unknown fields ['kk']"),
    # nested past the parser's recursion (its RecursionError), or past a task file's depth
    "nested-array": (GOOD + "[sim]\ndeep = " + "[" * 5000 + "]" * 5000 + "\n", None,
                     "nests its tables or arrays too deeply to read"),
    "nested-table": (GOOD + "[sim]\ndeep = " + "{a = " * 5000 + "1" + "}" * 5000 + "\n", None,
                     "nests its tables or arrays too deeply to read"),
    "nested-deep": (GOOD.replace("k = 20", "k = " + "[" * 20 + "]" * 20), GOOD.splitlines().index("k = 20") + 1,
                    "config.graph.k nests more than 6 tables or arrays deep"),
    "endless": (GOOD + "# padding\n" * 200_000, None, "a task file has at most 1048576 bytes"),
}


def _write(folder, name, content):
    path = folder / f"{name}.toml"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    return path


@pytest.mark.parametrize("case", list(BROKEN))
def test_a_broken_task_file_is_reported_and_the_others_still_load(case, tmp_path):
    content, line, what = BROKEN[case]
    _write(tmp_path, "a_good", GOOD)
    bad = _write(tmp_path, f"b_{case}", content)
    with pytest.warns(TaskFileWarning, match="this task file is skipped"):
        specs, errors = discover(tmp_path)
    assert list(specs) == ["ipp_bench/Grid15Eval-v1"]
    assert len(errors) == 1 and what in errors[0], errors
    assert errors[0].startswith(f"{bad}:{line}: " if line else f"{bad}: ")


@pytest.fixture
def registry_restored():
    """Tasks a test loads are unregistered afterwards (other tests see the suite's tasks only)."""
    before = dict(envs.TASKS)
    yield
    for task in set(envs.TASKS) - set(before):
        gym.registry.pop(task, None)
    envs.TASKS.clear()
    envs.TASKS.update(before)


def test_a_users_task_file_loads_from_anywhere_and_runs(tmp_path, registry_restored):
    path = _write(tmp_path, "mine", GOOD.replace("Grid15Eval-v1", "MyGrid-v0").replace("budget_s = 200.0",
                                                                                      "budget_s = 30.0"))
    task = load_task(path)
    assert task == "ipp_bench/MyGrid-v0" and load_task(path) == task  # idempotent
    env = envs.make_env(str(path))  # the file's path stands for its task
    env.reset(seed=0)
    assert env.config.mission.budget_s == 30.0
    other = _write(tmp_path, "other", GOOD.replace("Grid15Eval-v1", "MyGrid-v0"))
    with pytest.raises(TaskFileError, match="is already registered"):
        load_task(other)
    with pytest.raises(TaskFileError, match=r"mine2.toml:\d+: graph.k = 20.0"):
        load_task(_write(tmp_path, "mine2", GOOD.replace("Grid15Eval-v1", "My2-v0").replace("k = 20", "k = 20.0")))


def test_the_command_line_works_beside_a_broken_task_file_and_takes_a_task_path(tmp_path):
    """A copy of the suite with a broken file in tasks/: --help, tasks and evaluate still work and
    reading the tasks names the broken file; --task path/to/mine.toml runs a user's task."""
    root = tmp_path / "suite"
    shutil.copytree(REPO / "ipp_bench", root / "ipp_bench", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(REPO / "tasks", root / "tasks")
    shutil.copytree(REPO / "assets", root / "assets")
    (root / "tasks" / "zz_broken.toml").write_text(GOOD.replace("k = 20", "k = 20.0").replace("Grid15Eval", "B"))
    mine = _write(tmp_path, "mine", GOOD.replace("Grid15Eval-v1", "Mine-v0").replace("budget_s = 200.0",
                                                                                     "budget_s = 30.0"))
    env = {"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin", "MUJOCO_GL": "egl"}

    def cli(*argv):
        return subprocess.run([sys.executable, "-m", "ipp_bench.cli", *argv], cwd=root, env=env,
                              capture_output=True, text=True, timeout=120)

    helped = cli("--help")
    assert helped.returncode == 0 and "leaderboard" in helped.stdout and "Traceback" not in helped.stderr
    listed = cli("tasks")
    assert listed.returncode == 0 and "ipp_bench/Grid15Eval-v1" in listed.stdout
    assert "skipped task file" in listed.stderr and "zz_broken.toml:" in listed.stderr
    assert "graph.k = 20.0 is invalid" in listed.stderr
    ran = cli("evaluate", "--task", str(mine), "--planner", "greedy")
    assert ran.returncode == 0 and "ipp_bench/Mine-v0" in ran.stdout and "Traceback" not in ran.stderr, ran.stderr


@pytest.mark.timeout(60)
@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs (POSIX)")
def test_a_task_file_that_is_a_fifo_is_refused_without_waiting_for_a_writer(tmp_path):
    """Reading a FIFO waits for a writer for ever: it is refused from its type, never opened."""
    fifo = tmp_path / "mine.toml"
    os.mkfifo(fifo)
    with pytest.raises(TaskFileError, match=r"mine.toml: cannot be read: it is a FIFO \(named pipe\), not a regular"):
        load_task(fifo)
    with pytest.raises(TaskFileError, match="it is a device"):
        load_task("/dev/zero")  # endless
    with pytest.raises(TaskFileError, match="it is a folder"):
        load_task(tmp_path)


@pytest.mark.parametrize("path", [None, 5, ""], ids=["None", "int", "empty"])
def test_load_task_names_its_argument(path):
    with pytest.raises(ValueError, match=r"load_task\(path\) = .* is invalid: expected the path of a task file"):
        load_task(path)


def test_a_setting_given_twice_is_refused():
    with pytest.raises(ValueError, match=r"--env budget_s is given twice \(budget_s=20 and budget_s=30\): give each "
                                         "setting once"):
        envs.parse_overrides(["budget_s=20", "budget_s=30"])


def test_gym_make_names_a_config_of_the_wrong_type():
    with pytest.raises(ValueError, match=r"config = 5 is invalid: expected an ipp_bench.core.config.IPPConfig, a dict"):
        gym.make("ipp_bench/Grid15Eval-v1", config=5)


def test_an_outdated_task_is_said_once_in_plain_text_and_never_by_the_workers(tmp_path):
    """gymnasium's own notice is in colour, in the run's process and again in every worker (9 times a board)."""
    out = tmp_path / "lb"
    proc = subprocess.run([sys.executable, "-m", "ipp_bench.cli", "leaderboard", "--tasks", "Grid15Eval-v0",
                           "Grid20Eval-v0", "--planners", "random", "--episodes", "2", "--backend", "process",
                           "--workers", "2", "--no-progress", "--out", str(out), "--env", "budget_s=20", "--env",
                           "report_times=[20]"], cwd=REPO, capture_output=True, text=True, timeout=240,
                          env={**os.environ, "MUJOCO_GL": "egl"})
    assert proc.returncode == 0, proc.stderr[-2000:]
    for task in ("Grid15Eval", "Grid20Eval"):
        said = [ln for ln in proc.stderr.splitlines() if f"ipp_bench/{task}-v0 is out of date" in ln]
        assert len(said) == 1, proc.stderr
        assert f"the current version of the task is ipp_bench/{task}-v1" in said[0]
    assert "\x1b[" not in proc.stderr and "You should consider upgrading" not in proc.stderr


@pytest.mark.parametrize("entry", ["this:s", "os:system", "ipp_bench_evil.envs:Env", "ipp_bench.envs.graph:",
                                   "ipp_bench..graph:GraphIPPEnv"])
def test_an_entry_point_outside_the_suite_is_refused_before_any_import(entry, tmp_path):
    """A task file names the class its env is built from; only the suite's own modules (ipp_bench.*)
    may be imported, and only once the whole file is valid: anything else is one line naming the
    file, the line and the entry points allowed, and nothing is imported (``this`` prints a poem)."""
    path = _write(tmp_path, "mine", GOOD.replace("Grid15Eval-v1", "Mine-v0").replace(
        '"ipp_bench.envs.graph:GraphIPPEnv"', repr(entry).replace("'", '"')))
    line = path.read_text().splitlines().index(f'entry_point = "{entry}"') + 1
    code = ("import sys; from ipp_bench.envs.registry import load_task, TaskFileError\n"
            f"try:\n    load_task({str(path)!r})\nexcept TaskFileError as err:\n    print('ERR', err)\n"
            "print('imported' if {'this', 'ipp_bench_evil'} & set(sys.modules) else 'not imported')\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    lines = proc.stdout.strip().splitlines()
    assert lines[-1] == "not imported" and "Beautiful is better" not in proc.stdout, proc.stdout
    assert len(lines) == 2 and lines[0].startswith(f"ERR {path}:{line}: entry_point = {entry!r}"), proc.stdout
    assert "ipp_bench.envs.graph:GraphIPPEnv" in lines[0] and "ipp_bench." in lines[0]


def test_the_command_line_refuses_a_foreign_entry_point_in_one_line(tmp_path):
    path = _write(tmp_path, "mine", GOOD.replace("Grid15Eval-v1", "Mine-v0").replace(
        "ipp_bench.envs.graph:GraphIPPEnv", "this:s"))
    proc = subprocess.run([sys.executable, "-m", "ipp_bench.cli", "evaluate", "--task", str(path), "--planner",
                           "random"], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 2 and "Beautiful is better" not in proc.stdout + proc.stderr
    assert proc.stderr.count("\n") == 1 and "entry_point = 'this:s'" in proc.stderr, proc.stderr


def test_an_entry_point_is_checked_where_the_env_is_built_too():
    """make_task_env imports only the suite's classes, whatever built its kwargs."""
    with pytest.raises(ValueError, match="entry_point = 'this:s' is invalid"):
        envs.registry.make_task_env(env_class="this:s")
    assert "this" not in sys.modules
