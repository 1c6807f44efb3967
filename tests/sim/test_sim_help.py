"""The ``--help`` of the deployment's commands: every option has a text, and the demo's shows its defaults."""

import re

import pytest

pytest.importorskip("mujoco")


def _help(main, argv, capsys) -> str:
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 0
    return capsys.readouterr().out


def options_without_help(text: str) -> list[str]:
    """The options of an argparse ``--help`` listed with no help text."""
    entries: list[list[str]] = []
    for line in text.split("options:\n", 1)[1].splitlines():
        if re.match(r"^  -", line):
            entries.append([line])
        elif line.startswith("   ") and entries:
            entries[-1].append(line)
    return [e[0].strip() for e in entries if len(re.split(r"\s{2,}", e[0].strip())) == 1 and len(e) == 1]


def test_options_without_help_finds_one():
    assert options_without_help("options:\n  -h, --help  show this\n  --task TASK\n  --fields FIELDS\n"
                                "                        calibration fields\n") == ["--task TASK"]


def test_calibrate_help_has_a_text_for_every_option(capsys, monkeypatch):
    from ipp_bench.sim.calibrate import main

    monkeypatch.setenv("COLUMNS", "100")
    text = _help(main, ["--help"], capsys)
    assert "--task" in text and "--write" in text
    assert options_without_help(text) == []


def test_demo_help_shows_the_defaults_of_seed_and_out(capsys, monkeypatch):
    from ipp_bench.cli import main

    monkeypatch.setenv("COLUMNS", "200")  # one line per option
    text = _help(main, ["demo", "--help"], capsys)
    assert options_without_help(text) == []
    lines = {line.split()[0]: line for line in text.splitlines() if line.startswith("  --")}
    assert "(default: 0)" in lines["--seed"]
    assert "(default: demo.mp4)" in lines["--out"]
