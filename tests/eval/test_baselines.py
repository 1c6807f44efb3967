"""The committed reference folders (``baselines/*/run.json``) rerun as documented.

Every folder with a ``run.json`` is copied, with the rest of ``baselines/``, into a temporary
checkout layout, and the command its ``run.json`` records and the command its row in
``baselines/README.md`` gives are run there as a user would (a subprocess, from the folder above
``baselines/``): both must find every episode already complete, leave ``results.csv`` byte for byte
as committed, and exit 0. Folders are found by globbing, so one added later is covered; a folder
whose command is legitimately not rerunnable is listed in :data:`NOT_RERUNNABLE` with the reason
(also said in its README row) and the refusal its command must give.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

BASELINES = Path(__file__).resolve().parents[2] / "baselines"
FOLDERS = sorted(p.parent.relative_to(BASELINES).as_posix() for p in BASELINES.glob("**/run.json"))

#: folder -> (why its command cannot complete it, what the README command must say instead)
NOT_RERUNNABLE = {
    "v0": ("made before planner fingerprints: its attention rows' checkpoint is unknown",
           "predates planner fingerprints and holds rows of attention"),
    "v0/quick": ("made before planner fingerprints: its attention rows' checkpoint is unknown",
                 "predates planner fingerprints and holds rows of attention"),
}


def readme_commands() -> dict[str, str]:
    """folder -> the command of its row in baselines/README.md."""
    rows = {}
    for line in (BASELINES / "README.md").read_text().splitlines():
        m = re.match(r"\|\s*\[`([^`]+)/`\]\([^)]*\)\s*\|.*\|\s*`([^`]+)`\s*\|\s*$", line)
        if m:
            rows[m.group(1)] = m.group(2)
    return rows


def _argv(command: str) -> tuple[dict[str, str], list[str]]:
    """(environment assignments, arguments after ``ipp-bench``) of a documented command line."""
    words = shlex.split(command)
    env = {}
    while words and re.fullmatch(r"[A-Z_]+=\S*", words[0]):
        key, _, value = words.pop(0).partition("=")
        env[key] = value
    assert words[0] == "ipp-bench", command
    return env, words[1:]


def _run(command: str, cwd: Path) -> subprocess.CompletedProcess:
    env_vars, args = _argv(command)
    env = {**os.environ, "MUJOCO_GL": "egl", **env_vars}
    return subprocess.run([sys.executable, "-m", "ipp_bench.cli", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


def _normalised(command: str) -> tuple[str, ...]:
    """A command without what does not change what it computes (progress display, GL backend)."""
    return tuple(a for a in _argv(command)[1] if a not in ("--no-progress", "--progress"))


def test_the_committed_folders_are_found():
    assert {"quick", "v1", "deployment_v1"} <= set(FOLDERS), FOLDERS


#: folders the default run reruns (the main job's and the newest benchmark's); the others with -m slow
DEFAULT_RUN = {"quick", "v2"}


@pytest.mark.parametrize("folder", [f if f in DEFAULT_RUN else pytest.param(f, marks=pytest.mark.slow)
                                    for f in FOLDERS])
def test_a_committed_folder_reruns_as_already_complete(folder, tmp_path):
    readme = readme_commands()
    assert folder in readme, f"baselines/{folder} has no row in baselines/README.md"
    shutil.copytree(BASELINES, tmp_path / "baselines")
    target = tmp_path / "baselines" / folder
    committed_csv = (BASELINES / folder / "results.csv").read_bytes()
    recorded = json.loads((BASELINES / folder / "run.json").read_text())["command"]
    if folder in NOT_RERUNNABLE:
        reason, refusal = NOT_RERUNNABLE[folder]
        row = next(line for line in (BASELINES / "README.md").read_text().splitlines() if f"[`{folder}/`]" in line)
        assert "not rerunnable into this folder" in row, f"baselines/README.md must say so for {folder}: {reason}"
        proc = _run(readme[folder], tmp_path)  # the recorded command is of an older default task set
        assert proc.returncode == 2 and refusal in proc.stderr, proc.stderr
        assert "Traceback" not in proc.stderr
        assert (target / "results.csv").read_bytes() == committed_csv
        return
    commands = [recorded]
    if _normalised(readme[folder]) != _normalised(recorded):
        commands.append(readme[folder])
    for command in commands:
        proc = _run(command, tmp_path)
        assert proc.returncode == 0, f"{command}:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"
        assert "already complete" in proc.stdout and ", 0 to run" in proc.stdout, proc.stdout
        assert (target / "results.csv").read_bytes() == committed_csv
