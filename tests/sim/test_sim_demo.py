"""``ipp-bench demo``: a short mission writes an mp4 that decodes to the expected frames."""

import argparse

import numpy as np
import pytest

pytest.importorskip("mujoco")
iio = pytest.importorskip("imageio.v3")
pytest.importorskip("imageio_ffmpeg")
pytest.importorskip("matplotlib")

from ipp_bench.eval.demo import add_demo_arguments, run_demo  # noqa: E402
from ipp_bench.sim.video import expected_frames  # noqa: E402

SHORT = ["--planner", "random", "--seed", "1", "--budget", "4", "--size", "320x192", "--fps", "5",
         "--speedup", "1", "--hold", "0.4", "--no-progress"]


def _args(*argv):
    return add_demo_arguments(argparse.ArgumentParser()).parse_args(list(argv))


def _decode(path):
    return np.stack(list(iio.imiter(path, plugin="pyav") if _has_pyav() else iio.imiter(path)))


def _has_pyav():
    try:
        import av  # noqa: F401
    except ImportError:
        return False
    return True


def test_short_demo_decodes_to_the_expected_frames(tmp_path, capsys):
    out = tmp_path / "demo.mp4"
    assert run_demo(_args(*SHORT, "--out", str(out))) == 0
    printed = capsys.readouterr().out
    frames = _decode(str(out))
    t_end = float(printed.split(" flew ")[1].split(" s ")[0])
    assert frames.shape[1:] == (192, 320, 3)
    assert frames.shape[0] == int(printed.split(": ")[1].split(" frames")[0])
    assert frames.shape[0] == expected_frames(t_end, fps=5, speedup=1.0, hold_s=0.4)
    assert frames.std() > 10  # not blank
    with open(out, "rb") as fh:
        head = fh.read(64)
    assert b"ftyp" in head  # mp4 container, moov first (+faststart)
    again = tmp_path / "again.mp4"
    assert run_demo(_args(*SHORT, "--out", str(again))) == 0
    np.testing.assert_array_equal(_decode(str(again)), frames)  # same seed, same video
    assert out.read_bytes() == again.read_bytes()


def test_compare_writes_the_plot(tmp_path):
    out = tmp_path / "demo.mp4"
    assert run_demo(_args(*SHORT, "--out", str(out), "--compare", "coverage")) == 0
    png = tmp_path / "demo_compare.png"
    img = iio.imread(png)
    assert img.ndim == 3 and img.shape[0] > 200


@pytest.mark.parametrize("bad", [["--size", "321x180"], ["--out", "x.gif"], ["--planner", "nope"],
                                 ["--task", "ipp_bench/Grid15Eval-v0"]])
def test_bad_arguments_exit_2(tmp_path, bad, capsys):
    argv = [*SHORT, "--out", str(tmp_path / "d.mp4"), *bad]
    assert run_demo(_args(*argv)) == 2
    assert "error" in capsys.readouterr().err


@pytest.mark.parametrize("bad", [["--crf", "52"], ["--crf", "-1"], ["--compare", "nope"],
                                 ["--compare", "coverage", "--compare-out", "plot.jpg"]])
def test_bad_crf_and_compare_are_refused_before_flying(tmp_path, bad, capsys, monkeypatch):
    import ipp_bench.eval.demo as demo

    flown = []
    monkeypatch.setattr(demo, "record", lambda *a, **k: flown.append(1))  # nothing may fly
    argv = [*SHORT, "--out", str(tmp_path / "d.mp4"), *bad]
    assert run_demo(_args(*argv)) == 2
    assert "error" in capsys.readouterr().err and not flown


def test_unwritable_output_is_refused_before_flying(tmp_path, capsys, monkeypatch):
    import ipp_bench.eval.demo as demo

    flown = []
    monkeypatch.setattr(demo, "record", lambda *a, **k: flown.append(1))
    (tmp_path / "taken").write_text("a file where a folder should be")
    argv = [*SHORT, "--out", str(tmp_path / "taken" / "d.mp4")]
    assert run_demo(_args(*argv)) == 2
    assert "cannot create its folder" in capsys.readouterr().err and not flown
    argv = [*SHORT, "--out", str(tmp_path / "ok.mp4"), "--compare", "coverage", "--compare-out",
            str(tmp_path / "taken" / "c.png")]
    assert run_demo(_args(*argv)) == 2 and not flown


def test_the_progress_bar_reaches_100_percent_when_the_mission_ends(tmp_path, capsys):
    """A mission ends when no leg is affordable, before its last second: the bar still ends full."""
    argv = [a for a in SHORT if a != "--no-progress"]
    assert run_demo(_args(*argv, "--out", str(tmp_path / "demo.mp4"))) == 0
    err = capsys.readouterr().err
    assert "100%" in err and "4/4 s mission" in err, err[-500:]
