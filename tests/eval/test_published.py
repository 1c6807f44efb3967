"""A published board is verified before it is used: ``--against FOLDER`` and ``ipp-bench power DIR``
check its ``run.json`` (format, fields) and every row of its ``results.csv`` (the digest run.json
records of it, its episode and report time, no repeat, none missing) and refuse a board that fails,
in one line naming the row (task, planner, seed, time) or the field. A board without digests is used
only with ``--trust-unverified``, and the report says so."""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import pytest
from lb_helpers import results

from ipp_bench.cli import main
from ipp_bench.eval.results_csv import COLUMNS, RESULTS_CSV
from ipp_bench.eval.run_json import RUN_JSON

NEW = "coverage:overlap=0.5"
BASELINES = Path(__file__).resolve().parents[2] / "baselines"


def against(published, out, *extra):
    return main(["leaderboard", "--planners", NEW, "--against", str(published), "--out", str(out),
                 "--backend", "serial", "--no-progress", *extra])


def _lines(folder: Path) -> list[str]:
    return (folder / RESULTS_CSV).read_text().splitlines()


def _write_lines(folder: Path, lines: list[str]) -> None:
    (folder / RESULTS_CSV).write_text("\n".join(lines) + "\n")


def _meta(folder: Path) -> dict:
    return json.loads((folder / RUN_JSON).read_text())


def _write_meta(folder: Path, meta: dict) -> None:
    (folder / RUN_JSON).write_text(json.dumps(meta, indent=2) + "\n")


def _cell(line: str, column: str) -> str:
    return line.split(",")[COLUMNS.index(column)]


def _set_cell(line: str, column: str, value: str) -> str:
    cells = line.split(",")
    cells[COLUMNS.index(column)] = value
    return ",".join(cells)


def _row_name(line: str) -> str:
    """How a refusal names a row: task, planner, seed and report time."""
    return (f"{_cell(line, 'task')} {_cell(line, 'planner')} seed {_cell(line, 'seed')} at "
            f"{float(_cell(line, 'time_s')):g} s")


# each tampering returns what the one-line refusal must say
def random_rows_at_95(folder: Path) -> str:
    lines = _lines(folder)
    first = None
    for i, line in enumerate(lines[1:], start=2):
        if _cell(line, "task").endswith("Grid15Eval-v1") and _cell(line, "planner") == "random":
            lines[i - 1] = _set_cell(line, "uncertainty_reduction_pct", "95.0")
            first = first or (i, lines[i - 1])
    _write_lines(folder, lines)
    return f"{folder / RESULTS_CSV}:{first[0]}: {_row_name(first[1])}: not a row"


def one_trace_edited(folder: Path) -> str:
    lines = _lines(folder)
    lines[3] = _set_cell(lines[3], "trace_roi", repr(float(_cell(lines[3], "trace_roi")) * 0.9))
    _write_lines(folder, lines)
    return f"{folder / RESULTS_CSV}:4: {_row_name(lines[3])}: not a row"


def rows_key_deleted(folder: Path) -> str:
    meta = _meta(folder)
    del meta["rows"]
    _write_meta(folder, meta)
    return "--trust-unverified"


def a_foreign_seed(folder: Path) -> str:
    lines = _lines(folder)
    lines[5] = _set_cell(lines[5], "seed", "12345")
    _write_lines(folder, lines)
    return f"{folder / RESULTS_CSV}:6: {_row_name(lines[5])}: seed 12345 is not among the"


def one_row_deleted(folder: Path) -> str:
    lines = _lines(folder)
    gone = lines.pop(7)
    _write_lines(folder, lines)
    return f"no row of {_row_name(gone)}"


def one_row_duplicated(folder: Path) -> str:
    lines = _lines(folder)
    _write_lines(folder, lines[:4] + [lines[2]] + lines[4:])
    return f"{folder / RESULTS_CSV}:5: {_row_name(lines[2])}: repeats line 3"


def format_99(folder: Path) -> str:
    meta = _meta(folder)
    meta["format"] = 99
    _write_meta(folder, meta)
    return f'{folder / RUN_JSON}: "format": 99'


def other_seeds_in_run_json(folder: Path) -> str:
    meta = _meta(folder)
    meta["seeds"] = [s + 1 for s in meta["seeds"]]
    _write_meta(folder, meta)
    return "is not among the"


def not_csv(folder: Path) -> str:
    (folder / RESULTS_CSV).write_text("<html><body>not a results file</body></html>\n" * 20)
    return f"{folder / RESULTS_CSV}:1: not a results.csv"


def far_too_big(folder: Path) -> str:
    """A file far bigger than the board's rows can be (sparse: no disk used): refused by its size,
    before any of it is read."""
    path = folder / RESULTS_CSV
    with path.open("r+b") as fh:
        fh.truncate(64 * 1024 * 1024)
    return f"{path}: 67108864 bytes, more than"


TAMPERINGS = [random_rows_at_95, one_trace_edited, rows_key_deleted, a_foreign_seed, one_row_deleted,
              one_row_duplicated, format_99, other_seeds_in_run_json, not_csv, far_too_big]
#: what --trust-unverified does not let through: everything but a board without digests
STRUCTURAL = [a_foreign_seed, one_row_deleted, one_row_duplicated, format_99, other_seeds_in_run_json, not_csv,
              far_too_big]


def _one_line_error(capsys, must: str) -> str:
    captured = capsys.readouterr()
    err = captured.err
    assert "Traceback" not in err and err.count("\n") == 1, err
    assert must in err, err
    return err


@pytest.mark.parametrize("tamper", TAMPERINGS, ids=lambda f: f.__name__)
def test_against_refuses_a_tampered_board_naming_the_row_or_field(reference_copy, tmp_path, capsys, tamper):
    must = tamper(reference_copy)
    before = {p.name: p.read_bytes() for p in reference_copy.iterdir() if p.is_file()}
    assert against(reference_copy, tmp_path / "mine") == 2
    _one_line_error(capsys, must)
    assert not (tmp_path / "mine").exists()
    assert {p.name: p.read_bytes() for p in reference_copy.iterdir() if p.is_file()} == before


@pytest.mark.parametrize("tamper", TAMPERINGS, ids=lambda f: f.__name__)
def test_power_refuses_a_tampered_board_naming_the_row_or_field(reference_copy, capsys, tamper):
    must = tamper(reference_copy)
    assert main(["power", str(reference_copy)]) == 2
    err = _one_line_error(capsys, must)
    assert "names no planner" not in err


@pytest.mark.parametrize("tamper", STRUCTURAL, ids=lambda f: f.__name__)
def test_trust_unverified_skips_the_digests_only(reference_copy, capsys, tamper):
    rows_key_deleted(reference_copy)
    must = tamper(reference_copy)
    assert main(["power", str(reference_copy), "--trust-unverified"]) == 2
    _one_line_error(capsys, must)


def test_a_board_without_digests_is_used_with_trust_unverified_and_the_report_says_so(reference_copy, tmp_path,
                                                                                      capsys):
    rows_key_deleted(reference_copy)
    assert against(reference_copy, tmp_path / "mine") == 2
    _one_line_error(capsys, "--trust-unverified")
    assert against(reference_copy, tmp_path / "mine", "--trust-unverified") == 0
    md = (tmp_path / "mine" / "leaderboard.md").read_text()
    assert "unverified" in md and "--trust-unverified" in md
    assert {r["planner"] for r in results(tmp_path / "mine")} == {NEW}
    capsys.readouterr()
    assert main(["power", str(reference_copy), "--trust-unverified"]) == 0
    assert "unverified" in capsys.readouterr().out


def test_the_issues_case_on_a_copy_of_the_quick_board(tmp_path, capsys):
    """Every ``random`` row of Grid15Eval-v1 in a copy of baselines/quick set to 95.0: refused, by
    --against and by power, naming the first of them."""
    board = tmp_path / "quick"
    shutil.copytree(BASELINES / "quick", board)
    must = random_rows_at_95(board)
    assert against(board, tmp_path / "mine") == 2
    _one_line_error(capsys, must)
    assert main(["power", str(board)]) == 2
    _one_line_error(capsys, must)


def test_a_huge_file_is_refused_without_reading_it(reference_copy, capsys):
    """3 GB (sparse) that is not CSV: refused by its size in well under a second, not read whole."""
    path = reference_copy / RESULTS_CSV
    with path.open("r+b") as fh:
        fh.truncate(3 * 1024 ** 3)
    try:
        t0 = time.perf_counter()
        assert main(["power", str(reference_copy)]) == 2
        assert time.perf_counter() - t0 < 2.0
        _one_line_error(capsys, f"{path}: {3 * 1024 ** 3} bytes, more than")
    finally:
        os.unlink(path)


def test_a_folder_of_ones_own_refuses_a_huge_or_foreign_results_file_by_name(reference_copy):
    """The same size and header checks before a resume reads results.csv."""
    from lb_helpers import run_tiny

    from ipp_bench.eval.run_json import ResultsMismatchError

    must = not_csv(reference_copy)
    with pytest.raises(ResultsMismatchError, match="not a results.csv") as info:
        run_tiny(reference_copy)
    assert must in str(info.value) and "\n" not in str(info.value)
    must = far_too_big(reference_copy)
    with pytest.raises(ResultsMismatchError) as info:
        run_tiny(reference_copy)
    assert must in str(info.value) and "\n" not in str(info.value)


COMMITTED = sorted(p.parent.relative_to(BASELINES).as_posix() for p in BASELINES.glob("**/run.json"))


@pytest.mark.parametrize("folder", COMMITTED)
def test_every_committed_board_verifies(folder):
    """Every committed folder records its rows' digests (those of baselines/v0 and large added after
    the fact, and marked so) and passes the checks a published board must pass."""
    from ipp_bench.eval.verify import read_board

    board = read_board(BASELINES / folder)
    assert board.verified and len(board.rows) == _meta(BASELINES / folder)["rows"]["count"]


def test_a_folder_completed_after_a_kill_records_every_digest_and_verifies(reference_copy):
    """A kill between an episode's append and run.json's update leaves that episode's rows without a
    digest; the run that completes the folder records them, so the board verifies."""
    from lb_helpers import run_tiny

    from ipp_bench.eval.verify import BoardRefused, read_board

    meta = _meta(reference_copy)
    n = meta["rows"]["count"]
    meta["rows"] = {"count": n - 2, "digests": meta["rows"]["digests"][: 8 * (n - 2)]}  # the last episode's 2 rows
    _write_meta(reference_copy, meta)
    with pytest.raises(BoardRefused, match="not a row the board's run wrote"):
        read_board(reference_copy)
    assert run_tiny(reference_copy).ran == 0
    assert read_board(reference_copy).verified and _meta(reference_copy)["rows"]["count"] == n
