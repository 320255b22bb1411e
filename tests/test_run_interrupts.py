"""``simbench run`` and ``simbench sweep`` stopped by SIGTERM or SIGKILL.

* SIGTERM (as SIGINT): exit non-zero, one line and no traceback, no partial folder left,
  an earlier result at ``--out`` untouched, no child process left;
* SIGKILL: the earlier result at ``--out`` is untouched; the partial folder it leaves is
  removed by the next run into the same parent folder; its children (ffmpeg) go too;
* a sweep's pool workers die with the sweep's parent, even when that is SIGKILLed.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

QUICKSTART = str(Path("scenarios/quickstart.toml").resolve())
SMALL = ["--set", "rig.count=2", "--set", "rig.width=320", "--set", "rig.height=240", "--set", "sensor.antialias=1",
         "--set", "markers_pipeline.solve_skeleton=false"]
TINY = ["--set", "duration_s=0.2", *SMALL]
LONG = ["--set", "duration_s=6.0", *SMALL]  # renders for well over the moments the tests signal at


def _run_cmd(out: Path, *sets: str) -> list[str]:
    return [sys.executable, "-m", "simbench.cli", "run", QUICKSTART, "--out", str(out), *sets]


def _tree(root: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None) for p in sorted(root.rglob("*"))}


def _partials(parent: Path) -> list[Path]:
    return sorted(parent.glob(".*.partial-*"))


def _tiny_run(out: Path) -> None:
    """A tiny run in this process (no interpreter start-up to pay for)."""
    from simbench.scenario import parse_overrides
    from simbench.pipelines.run import run_scenario
    from simbench.scenario import load_scenario

    assert run_scenario(load_scenario(QUICKSTART, overrides=parse_overrides(TINY[1::2])), out).ok


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A finished tiny run (the earlier result a killed run must not touch)."""
    out = tmp_path_factory.mktemp("finished") / "result"
    _tiny_run(out)
    return out


def _with_earlier_result(tmp_path: Path, finished: Path) -> Path:
    out = tmp_path / "parent" / "result"
    out.parent.mkdir()
    shutil.copytree(finished, out)
    return out


def _start(cmd: list[str]) -> subprocess.Popen:
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, COLUMNS="300"))


def _wait_for(pred, timeout: float, proc: subprocess.Popen) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        assert proc.poll() is None, f"ended before the signal: {proc.communicate()}"
        assert time.monotonic() < deadline, "timed out waiting"
        time.sleep(0.05)


def _moment(moment: str, proc: subprocess.Popen, parent: Path) -> None:
    """Wait until ``moment``: 'startup' (1 s after start: Python is still importing),
    'rendering' (the partial folder exists and the videos are being written, plus 1 s)."""
    if moment == "startup":
        time.sleep(1.0)
        return
    _wait_for(lambda: any(any(p.glob("videos/*.mp4")) for p in _partials(parent)), 120, proc)
    time.sleep(1.0)


def _children(proc: subprocess.Popen) -> list[psutil.Process]:
    try:
        return psutil.Process(proc.pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []


def _assert_all_gone(procs: list[psutil.Process], timeout: float = 15.0) -> None:
    _, alive = psutil.wait_procs(procs, timeout=timeout)
    assert not alive, f"left running: {[(p.pid, p.cmdline()) for p in alive]}"


@pytest.mark.slow
@pytest.mark.parametrize("moment", ["startup", "rendering"])
def test_sigterm_removes_the_partial_folder_and_keeps_the_earlier_result(tmp_path, finished, moment):
    out = _with_earlier_result(tmp_path, finished)
    before = _tree(out)
    proc = _start(_run_cmd(out, *LONG))
    try:
        _moment(moment, proc, out.parent)
        kids = _children(proc)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    # 143 = 128 + SIGTERM from our handler; -SIGTERM if it arrived before the handler was installed.
    assert proc.returncode in (128 + signal.SIGTERM, -signal.SIGTERM), err
    assert "Traceback" not in err
    if proc.returncode > 0:
        assert err.strip().splitlines()[-1].startswith("interrupted by SIGTERM")
    assert _partials(out.parent) == []
    assert sorted(p.name for p in out.parent.iterdir()) == ["result"]
    assert _tree(out) == before
    _assert_all_gone(kids)


@pytest.mark.slow
def test_sigkill_leaves_the_earlier_result_and_the_next_run_removes_the_stale_partial(tmp_path, finished):
    out = _with_earlier_result(tmp_path, finished)
    before = _tree(out)
    proc = _start(_run_cmd(out, *LONG))
    try:
        _moment("rendering", proc, out.parent)
        kids = _children(proc)
        assert any("ffmpeg" in " ".join(k.cmdline()) for k in kids), "expected the video writers as children"
        proc.kill()
        proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == -signal.SIGKILL
    _assert_all_gone(kids)  # ffmpeg sees the end of its input and exits
    stale = _partials(out.parent)
    assert len(stale) == 1 and (stale[0] / ".simbench-output.json").is_file()
    assert _tree(out) == before

    _tiny_run(out.parent / "other")
    assert _partials(out.parent) == []
    assert sorted(p.name for p in out.parent.iterdir()) == ["other", "result"]
    assert _tree(out) == before



# The stages after the render are short on a tiny take: this script makes the run write a
# flag file when it enters the marker pipeline or the exports and then stay in that stage
# long enough for the test to signal it from outside (the stage then goes on as usual).
PAUSED = """
import sys, time
from pathlib import Path
from simbench.pipelines import run
from simbench.cli import main

where, flag = sys.argv.pop(1), sys.argv.pop(1)
name = {"pipeline": "capture_from_detections", "exports": "export_capture"}[where]
real = getattr(run, name)

def paused(*a, **k):
    Path(flag).write_text(where)
    time.sleep(30.0)
    return real(*a, **k)

setattr(run, name, paused)
main()
"""


@pytest.mark.slow
@pytest.mark.parametrize("where, sig", [("pipeline", signal.SIGTERM), ("exports", signal.SIGTERM), ("exports", signal.SIGKILL)],
                         ids=["pipeline-15", "exports-15", "exports-9"])
def test_a_signal_after_the_render_keeps_the_earlier_result_and_leaves_nothing(tmp_path, finished, where, sig):
    """SIGTERM while the marker pipeline runs or the exports are written, or SIGKILL while the
    exports are written (the frames are rendered and the ground truth is in the partial
    folder): the earlier result at ``--out`` is untouched byte for byte, no process of the run
    is left, and no partial folder is left after the next run (at once for SIGTERM). SIGKILL
    runs no code of the process, whatever stage it is in: the exports stage leaves the fullest
    stale partial folder for the next run to remove (SIGKILL while rendering, with the video
    writers as children, is the test above)."""
    out = _with_earlier_result(tmp_path, finished)
    before = _tree(out)
    flag = tmp_path / "in_stage"
    proc = _start([sys.executable, "-c", PAUSED, where, str(flag), "run", QUICKSTART, "--out", str(out), *TINY])
    try:
        _wait_for(flag.is_file, 120, proc)
        kids = _children(proc)
        partial = _partials(out.parent)
        assert len(partial) == 1 and (partial[0] / "videos").is_dir()
        if where == "exports":
            assert (partial[0] / "ground_truth" / "ground_truth.npz").is_file()
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    _assert_all_gone(kids)
    assert _tree(out) == before
    if sig == signal.SIGTERM:
        assert proc.returncode == 128 + signal.SIGTERM, err
        assert "Traceback" not in err and err.strip().splitlines()[-1].startswith("interrupted by SIGTERM"), err
        assert _partials(out.parent) == []
    else:
        assert proc.returncode == -signal.SIGKILL
        assert len(_partials(out.parent)) == 1  # the stale one, until the next run
    _tiny_run(out.parent / "other")
    assert _partials(out.parent) == []
    assert sorted(p.name for p in out.parent.iterdir()) == ["other", "result"]
    assert _tree(out) == before

SWEEP = f"""
name = "stop_me"
scenario = "{QUICKSTART}"
[set]
"rig.count" = 2
"rig.width" = 320
"rig.height" = 240
duration_s = 4.0
"sensor.antialias" = 1
"markers_pipeline.solve_skeleton" = false
[[factors]]
field = "markers_pipeline.tracker"
values = ["alpha_beta", "kalman"]
"""


def _pool_workers(proc: subprocess.Popen) -> list[psutil.Process]:
    return [k for k in _children(proc) if "multiprocessing" in " ".join(k.cmdline()) and "resource_tracker" not in " ".join(k.cmdline())]


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_sweep_workers_die_with_the_parent(tmp_path, sig):
    sweep = tmp_path / "stop_me.toml"
    sweep.write_text(SWEEP)
    db = tmp_path / "db" / "results.duckdb"
    proc = _start([sys.executable, "-m", "simbench.cli", "sweep", str(sweep), "--db", str(db), "-j", "1"])
    try:
        # a worker is rendering a run: its partial run folder has videos
        _wait_for(lambda: any(any(p.glob("videos/*.mp4")) for p in _partials(db.parent / "runs")), 120, proc)
        workers = _pool_workers(proc)
        kids = _children(proc)
        assert len(workers) == 1
        os.kill(proc.pid, sig)  # the parent only, not its process group
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    _assert_all_gone(kids)
    if sig == signal.SIGTERM:
        assert proc.returncode == 128 + signal.SIGTERM and "Traceback" not in err, err
    # The worker removed its partial run folder on the way out (SIGTERM from the parent,
    # or from the kernel when the parent was SIGKILLed).
    assert _partials(db.parent / "runs") == []


# A signal that lands inside library code can come out as an ordinary exception (ctypes
# turns the handler's exception into ctypes.ArgumentError when it arrives while PyOpenGL
# converts call arguments), or not come out at all (raised in a Python callback called
# from C, as numba's JIT compiler makes, it is printed and dropped). This script sends
# SIGTERM to itself inside the patched stage, either way.
WRAPPED = """
import ctypes, os, signal, sys, time
from simbench.pipelines import run
from simbench.cli import main

def self_sigterm():
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(0.5)

def wrapped(fn):
    def patched(*a, **k):
        try:
            self_sigterm()
        except BaseException as exc:
            raise RuntimeError("a library caught it: " + repr(exc)) from None
        return fn(*a, **k)
    return patched

def swallowed(fn):
    callback = ctypes.CFUNCTYPE(None)(self_sigterm)
    def patched(*a, **k):
        callback()  # the handler's exception dies in the callback; only the record remains
        return fn(*a, **k)
    return patched

where, how = sys.argv.pop(1), sys.argv.pop(1)
patch = {"wrapped": wrapped, "swallowed": swallowed}[how]
if where == "render":
    run.render_frames = patch(run.render_frames)
else:
    run.export_capture = patch(run.export_capture)
main()
"""


@pytest.mark.slow
@pytest.mark.parametrize("where, how", [("render", "wrapped"), ("exports", "wrapped"), ("render", "swallowed"),
                                        ("exports", "swallowed")])
def test_a_signal_that_library_code_catches_still_stops_the_run(tmp_path, where, how):
    out = tmp_path / "result"
    r = subprocess.run([sys.executable, "-c", WRAPPED, where, how, "run", QUICKSTART, "--out", str(out), *TINY],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 128 + signal.SIGTERM, r.stderr
    assert "Traceback" not in r.stderr and "Exception ignored" not in r.stderr, r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith("interrupted by SIGTERM")
    assert not out.exists() and _partials(tmp_path) == []  # not committed, not even as a run with a failed stage
