"""Fixtures of the eval tests: one finished tiny leaderboard run, shared by the session."""

from __future__ import annotations

import shutil

import pytest
from lb_helpers import run_tiny


@pytest.fixture(scope="session")
def reference_run(tmp_path_factory):
    """A finished serial run (report included); copy it before changing anything."""
    out = tmp_path_factory.mktemp("lb") / "reference"
    summary = run_tiny(out)
    return out, summary


@pytest.fixture
def reference_copy(reference_run, tmp_path):
    out = tmp_path / "run"
    shutil.copytree(reference_run[0], out)
    return out
