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


# -- nothing lost, no hang ----------------------------------------------------------------------
OLD = b"the video of an earlier run"


def _left_beside(folder):
    """The files in ``folder`` besides the old video (a temporary file left behind would be one)."""
    return sorted(p.name for p in folder.iterdir() if p.name != "demo.mp4")


@pytest.mark.parametrize("bad, message", [
    (["--fps", "100000"], "--fps = 100000 is invalid: expected an integer in [1, 60]"),
    (["--hold", "1e9"], "--hold = 1000000000.0 is invalid: expected a finite number in [0, 60] [s]"),
    (["--hold", "nan"], "--hold = nan is invalid"),
    (["--speedup", "1e-9"], "--speedup = 1e-09 is invalid: expected a finite number in [0.1, 100]"),
    (["--budget", "nan"], "--budget = nan is invalid"),
], ids=["fps", "hold", "hold-nan", "speedup", "budget-nan"])
def test_settings_that_would_never_finish_are_one_line_before_flying(bad, message, tmp_path, capsys, monkeypatch):
    import ipp_bench.eval.demo as demo

    flown = []
    monkeypatch.setattr(demo, "record", lambda *a, **k: flown.append(1))
    assert run_demo(_args(*SHORT, "--out", str(tmp_path / "d.mp4"), *bad)) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1 and not flown, err


def test_a_planner_that_raises_leaves_the_old_video_and_says_where(tmp_path, capsys, monkeypatch):
    from ipp_bench.planners.simple import RandomPlanner

    real, calls = RandomPlanner.act, []

    def act_then_raise(self, obs):
        calls.append(1)
        if len(calls) == 2:  # after some frames of the new video were written
            raise ZeroDivisionError("the planner's own bug")
        return real(self, obs)

    monkeypatch.setattr(RandomPlanner, "act", act_then_raise)
    out = tmp_path / "demo.mp4"
    out.write_bytes(OLD)
    assert run_demo(_args(*SHORT, "--out", str(out), "--budget", "20")) == 1
    err = capsys.readouterr().err
    assert len(calls) == 2
    assert "episode MuJoCoWeed15-v1 random seed 1 failed: ZeroDivisionError: the planner's own bug (at " in err
    assert "in act_then_raise)" in err and len(err.strip().splitlines()) == 1, err
    assert out.read_bytes() == OLD and _left_beside(tmp_path) == []


def test_a_video_that_cannot_be_finished_leaves_the_old_one(tmp_path, capsys, monkeypatch):
    """The encoder failing at the end (ffmpeg's exit status, which imageio-ffmpeg never checks)."""
    from ipp_bench.sim import video

    real = video.H264Writer.close

    def encoder_failed(self):
        self._proc.kill()  # as ffmpeg dies on a write error
        real(self)

    monkeypatch.setattr(video.H264Writer, "close", encoder_failed)
    out = tmp_path / "demo.mp4"
    out.write_bytes(OLD)
    assert run_demo(_args(*SHORT, "--out", str(out))) == 1
    err = capsys.readouterr().err
    assert f"cannot write {out}" in err and "the old file is left as it was" in err and "Traceback" not in err
    assert out.read_bytes() == OLD and _left_beside(tmp_path) == []


def test_ctrl_c_right_after_the_first_frame_leaves_the_old_video(tmp_path, monkeypatch):
    """Ctrl-C the moment ffmpeg has opened its temporary file (after the first frame, before the episode's
    first step): the partial video is removed, the old one left."""
    import time

    from ipp_bench.sim import video

    real = video.H264Writer.send

    def first_frame_then_ctrl_c(self, frame):
        real(self, frame)
        deadline = time.monotonic() + 60
        while not self.tmp.exists():  # ffmpeg opens its output once it has the first frame
            assert time.monotonic() < deadline
            time.sleep(0.01)
        raise KeyboardInterrupt

    monkeypatch.setattr(video.H264Writer, "send", first_frame_then_ctrl_c)
    out = tmp_path / "demo.mp4"
    out.write_bytes(OLD)
    with pytest.raises(KeyboardInterrupt):
        run_demo(_args(*SHORT, "--out", str(out)))
    assert out.read_bytes() == OLD and _left_beside(tmp_path) == []


def _demo_process(out, *extra, preexec_fn=None):
    import subprocess
    import sys

    code = "import sys\nfrom ipp_bench.cli import main\nsys.exit(main(sys.argv[1:]))\n"
    argv = [sys.executable, "-c", code, "demo", *SHORT, "--out", str(out), *extra]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=preexec_fn, env={**__import__("os").environ, "MUJOCO_GL": "egl"})


@pytest.fixture
def small_disk(tmp_path):
    """(folder, preexec_fn): a 256 KiB file system (tmpfs, where this process may mount one: ENOSPC as
    on a full disk), else a file size limit of 256 KiB on the process (RLIMIT_FSIZE)."""
    import resource
    import subprocess

    folder = tmp_path / "disk"
    folder.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(folder)],
                             capture_output=True).returncode == 0

    def file_size_limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (256 * 1024, 256 * 1024))

    yield folder, (None if mounted else file_size_limit)
    if mounted:
        subprocess.run(["umount", str(folder)], check=True)


@pytest.mark.timeout(240)
def test_a_full_disk_is_exit_1_and_leaves_the_old_video(small_disk):
    folder, preexec_fn = small_disk
    out = folder / "demo.mp4"
    out.write_bytes(OLD)
    proc = _demo_process(out, "--budget", "30", "--size", "640x368", "--crf", "0", preexec_fn=preexec_fn)
    stdout, stderr = proc.communicate(timeout=200)
    assert proc.returncode == 1, (stdout, stderr)
    assert f"cannot write {out}" in stderr, stderr
    assert any(cause in stderr for cause in ("No space left on device", "File too large", "SIGXFSZ")), stderr
    assert "Traceback" not in stderr and len(stderr.strip().splitlines()) == 1, stderr
    assert out.read_bytes() == OLD and _left_beside(folder) == []


@pytest.mark.timeout(240)
@pytest.mark.parametrize("sig, status", [pytest.param("SIGINT", 130, marks=pytest.mark.slow), ("SIGTERM", 143),
                                         pytest.param("SIGKILL", -9, marks=pytest.mark.slow)])
def test_a_signal_during_the_video_leaves_the_old_one(sig, status, tmp_path):
    import signal
    import time

    out = tmp_path / "demo.mp4"
    out.write_bytes(OLD)
    # Ctrl-C as at a terminal, even where this test runs in a background job that ignores SIGINT (a child
    # inherits that, and Python then raises no KeyboardInterrupt)
    proc = _demo_process(out, "--budget", "120", preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 180
        # the signal comes once the new video has been opened (beside the old one, or over it), well before
        # the flight ends: waiting for ffmpeg's first bytes raced with a fast machine finishing the video
        while not ([p for p in tmp_path.iterdir() if ".tmp" in p.name] or out.read_bytes() != OLD):
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.1)
        proc.send_signal(getattr(signal, sig))
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == status, stderr
    assert out.read_bytes() == OLD
    if sig != "SIGKILL":  # no cleanup runs after SIGKILL: the hidden temporary file stays beside the old one
        assert _left_beside(tmp_path) == [] and "Traceback" not in stderr
        assert len(stderr.strip().splitlines()) == 1, stderr
