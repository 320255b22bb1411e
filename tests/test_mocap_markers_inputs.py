"""`mocap markers` refuses inputs it would misread, with one line and exit code 2, and writes
nothing: videos at another size than their calibration, videos of unequal length, a bad frame
rate, videos without a single marker, an --out that is a file or a folder of the user's, and a
calibration file that is not one.

Each case runs the command's typer app in-process (``typer.testing.CliRunner``, as
``tests/fuzz_inputs.py`` does: the same code path without a new interpreter's imports, about
3 CPU-s a case); the first case also runs as a real ``python -m mocap.cli`` process."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from mocap.calibration import Calibration, Camera
from mocap.labelling import LabelTemplate, save_template

W, H = 64, 48


def _video(path: Path, n: int, size=(W, H), value: int = 0) -> Path:
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, size)
    for _ in range(n):
        vw.write(np.full((size[1], size[0], 3), value, np.uint8))
    vw.release()
    return path


@pytest.fixture
def inputs(tmp_path):
    cams = []
    for i, x in enumerate((-3.0, 3.0, 0.0)):
        eye = np.array([x, -3.0, 1.5])
        z = np.array([0.0, 0.0, 1.0]) - eye
        z /= np.linalg.norm(z)
        xa = np.cross(z, [0, 0, 1.0])
        xa /= np.linalg.norm(xa)
        R = np.stack([xa, np.cross(z, xa), z])
        cams.append(Camera(f"cam{i}", (W, H), [[50, 0, 31.5], [0, 50, 23.5], [0, 0, 1]], [0] * 5, R, -R @ eye))
    cal = tmp_path / "cal.yml"
    Calibration(tuple(cams)).save_opencv_yaml(cal)
    tmpl = save_template(LabelTemplate(("A", "B", "C"), np.array([[0, 0, 1.0], [0.2, 0, 1.0], [0, 0.2, 1.2]])), tmp_path / "t.csv")
    return tmp_path, cal, tmpl


def _markers(videos, cal, tmpl, out, *extra, process: bool = False) -> subprocess.CompletedProcess:
    """``mocap markers`` on the inputs: in-process through its typer app, or (``process``) as
    a new ``python -m mocap.cli`` process."""
    args = ["markers", *map(str, videos), "--calibration", str(cal), "--template", str(tmpl), "--out", str(out), *extra]
    if process:
        return subprocess.run([sys.executable, "-m", "mocap.cli", *args], capture_output=True, text=True, timeout=120)
    from typer.testing import CliRunner

    from mocap.cli.app import app

    r = CliRunner().invoke(app, args, catch_exceptions=True)
    # an exception other than the exit is what a process would have printed as a traceback
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    return subprocess.CompletedProcess(args, r.exit_code, r.stdout, r.stderr)


def _one_clear_line(r: subprocess.CompletedProcess, *words: str) -> None:
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
    text = " ".join(ln.strip() for ln in lines)
    assert text.startswith("error:"), r.stderr
    for w in words:
        assert w in text, (w, r.stderr)


def _nothing_written(d: Path, out: Path) -> None:
    assert not out.exists()
    assert not list(d.glob(f".{out.name}.partial-*"))


def test_video_of_another_size_than_its_calibration(inputs) -> None:
    d, cal, tmpl = inputs
    vids = [_video(d / "cam0.avi", 5), _video(d / "cam1.avi", 5, size=(2 * W, 2 * H)), _video(d / "cam2.avi", 5)]
    for process in (False, True):  # the real command line once
        r = _markers(vids, cal, tmpl, d / "cap", process=process)
        _one_clear_line(r, "cam1.avi", "128x96", "64x48")
        _nothing_written(d, d / "cap")


def test_videos_of_unequal_length(inputs) -> None:
    d, cal, tmpl = inputs
    vids = [_video(d / "cam0.avi", 5), _video(d / "cam1.avi", 9), _video(d / "cam2.avi", 5)]
    r = _markers(vids, cal, tmpl, d / "cap")
    _one_clear_line(r, "differ in length", "cam1.avi 9")
    _nothing_written(d, d / "cap")


@pytest.mark.parametrize("fps", ["0", "-5", "nan"])
def test_bad_frame_rate(inputs, fps: str) -> None:
    d, cal, tmpl = inputs
    vids = [_video(d / f"cam{i}.avi", 4) for i in range(3)]
    r = _markers(vids, cal, tmpl, d / "cap", "--fps", fps)
    _one_clear_line(r, "--fps", fps)
    _nothing_written(d, d / "cap")


@pytest.mark.parametrize("value", [0, 255])
def test_videos_without_a_single_marker(inputs, value: int) -> None:
    """All-black and all-white videos: no capture to report, rather than 'reconstructed 0.000'."""
    d, cal, tmpl = inputs
    vids = [_video(d / f"cam{i}.avi", 4, value=value) for i in range(3)]
    r = _markers(vids, cal, tmpl, d / "cap")
    _one_clear_line(r, "no marker blob", "--mode")
    _nothing_written(d, d / "cap")


def test_out_that_is_a_file_or_a_users_folder_is_refused_and_kept(inputs) -> None:
    d, cal, tmpl = inputs
    vids = [_video(d / f"cam{i}.avi", 4) for i in range(3)]
    f = d / "notes.txt"
    f.write_text("mine")
    _one_clear_line(_markers(vids, cal, tmpl, f), "notes.txt", "is a file")
    assert f.read_text() == "mine"
    folder = d / "thesis"
    folder.mkdir()
    (folder / "thesis.tex").write_text("chapter 1")
    _one_clear_line(_markers(vids, cal, tmpl, folder), "thesis", "not written by mocap")
    assert (folder / "thesis.tex").read_text() == "chapter 1"


@pytest.mark.parametrize("content", ["", "%YAML:1.0\n---\nfoo: 1\n", "\x00\x01garbage"])
def test_calibration_that_is_not_one(inputs, content: str) -> None:
    d, _, tmpl = inputs
    bad = d / "bad.yml"
    bad.write_text(content)
    vids = [_video(d / f"cam{i}.avi", 4) for i in range(3)]
    _one_clear_line(_markers(vids, bad, tmpl, d / "cap"), "bad.yml")
    _nothing_written(d, d / "cap")


def test_labelled_trial_refused_before_any_work(inputs) -> None:
    """--labelled-trial with --subject, of another file type, or without the template's markers: one line
    naming the option or the file, before the videos are read (they hold no marker here)."""
    from mocap.exports import write_trc
    from mocap.types import Trajectories

    d, cal, tmpl = inputs
    vids = [_video(d / f"cam{i}.avi", 4) for i in range(3)]
    r = _markers(vids, cal, tmpl, d / "cap", "--labelled-trial", str(d / "t.trc"), "--subject", str(d / "s.toml"))
    _one_clear_line(r, "--labelled-trial", "given with --subject")
    (d / "trial.txt").write_text("A,B,C\n")
    _one_clear_line(_markers(vids, cal, tmpl, d / "cap", "--labelled-trial", str(d / "trial.txt")), "trial.txt", "file type '.txt'")
    other = write_trc(d / "other.trc", Trajectories(["X", "Y", "Z"], np.random.default_rng(0).normal(size=(5, 3, 3)), np.arange(5) / 30))
    _one_clear_line(_markers(vids, cal, tmpl, d / "cap", "--labelled-trial", str(other)), "other.trc", "holds 0 of the template's 3 markers")
    _nothing_written(d, d / "cap")
