"""The bench never deletes what it did not write, and a run never loses its metrics to a late failure.

* ``--out`` on a folder the bench did not write, on a file or a symbolic link, and a
  scenario ``name`` that is not a plain folder name (empty, ``../x``, absolute) are
  refused with exit 2, one line, before anything renders, and nothing on disk changes;
* an earlier bench output (it carries ``.simbench-output.json``) is replaced, an empty
  folder is filled;
* stale partial folders are removed only when they carry the marker and their process is gone;
* a stage failing after rendering (an export, the skeleton solve) still gives
  metrics.json and report.md naming the stage, exit 3, and no message names the
  temporary ``.partial-`` folder;
* user-error messages are printed without rich markup (``[[lighting.lights]]`` survives).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from mocap.errors import MocapInputError
from simbench import output_dir
from simbench.cli import app
from simbench.output_dir import MARKER, OutputMarker, OutputPathError, remove_stale_partials

QUICKSTART = str(Path("scenarios/quickstart.toml").resolve())
# About a second of rendering and pipeline in-process.
TINY = ["--set", "duration_s=0.2", "--set", "rig.count=2", "--set", "rig.width=320", "--set", "rig.height=240",
        "--set", "sensor.antialias=1", "--set", "markers_pipeline.solve_skeleton=false"]


def _tree(root: Path) -> dict[str, bytes | None]:
    """Every path under ``root`` with the bytes of files (None for folders)."""
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None) for p in sorted(root.rglob("*"))}


@pytest.fixture()
def no_render(monkeypatch):
    """Fail the test if anything starts rendering."""
    from simbench.pipelines import run
    from simbench.stage import rendering

    calls: list[str] = []

    def forbidden(*a, **k):
        calls.append("render_frames")
        raise AssertionError("rendering started")

    monkeypatch.setattr(run, "render_frames", forbidden)
    monkeypatch.setattr(rendering, "render_frames", forbidden)
    return calls


def _invoke(*args: str):
    return CliRunner().invoke(app, list(args))


@pytest.mark.parametrize("command", ["run", "render"])
def test_out_on_a_folder_the_bench_did_not_write_is_refused(tmp_path, no_render, command):
    user = tmp_path / "thesis"
    user.mkdir()
    (user / "thesis.tex").write_text("\\documentclass{book} years of work")
    before = _tree(tmp_path)
    r = _invoke(command, QUICKSTART, "--out", str(user), *(TINY if command == "run" else []))
    assert r.exit_code == 2, r.output
    said = " ".join(r.stderr.split())
    assert f"{user}: exists and was not written by simbench" in said and "choose another --out" in said
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.output
    assert _tree(tmp_path) == before and not no_render


@pytest.mark.parametrize("make", ["file", "symlink"])
def test_out_on_a_file_or_a_link_is_refused(tmp_path, no_render, make):
    target = tmp_path / "data.csv"
    target.write_text("1,2,3\n")
    out = target
    if make == "symlink":
        bench_like = tmp_path / "real"
        bench_like.mkdir()
        (bench_like / MARKER).write_text(OutputMarker.for_this_process("q", "run").to_json())
        out = tmp_path / "link"
        out.symlink_to(bench_like)
    before = _tree(tmp_path)
    r = _invoke("run", QUICKSTART, "--out", str(out), *TINY)
    assert r.exit_code == 2, r.output
    assert str(out) in " ".join(r.stderr.split())
    assert _tree(tmp_path) == before and not no_render


@pytest.mark.parametrize("name, why", [
    ('""', "it is empty"),
    ('"../x"', "path separator"),
    ("ABSOLUTE", "path separator"),
    ('"."', "is not a folder name"),
    ('".."', "is not a folder name"),
])
def test_scenario_names_that_are_not_plain_folder_names_are_refused(tmp_path, monkeypatch, no_render, name, why):
    work = tmp_path / "work"
    (work / "out" / "quickstart").mkdir(parents=True)
    (work / "out" / "notes.txt").write_text("mine")
    (work / "x").mkdir()
    (work / "x" / "keep.txt").write_text("mine too")
    absolute = tmp_path / "elsewhere"
    absolute.mkdir()
    (absolute / "data.bin").write_bytes(b"\x00\x01")
    monkeypatch.chdir(work)
    before = _tree(tmp_path)
    value = f'"{absolute}"' if name == "ABSOLUTE" else name
    r = _invoke("run", QUICKSTART, "--set", f"name={value}", *TINY)
    assert r.exit_code == 2, r.output
    said = " ".join(r.stderr.split())
    assert "field 'name'" in said and why in said and "--out" in said, said
    assert _tree(tmp_path) == before and not no_render


def test_check_plain_name_accepts_ordinary_names():
    for ok in ("quickstart", "blur_zigzag.v2", "run-1", ".hidden"):
        assert output_dir.check_plain_name(ok, "s.toml") == ok
    with pytest.raises(OutputPathError, match="s.toml: field 'name'"):
        output_dir.check_plain_name("a/b", "s.toml")


def test_a_bench_output_is_replaced_and_an_empty_folder_filled(tmp_path):
    out = tmp_path / "run"
    r = _invoke("run", QUICKSTART, "--out", str(out), *TINY)
    assert r.exit_code == 0, r.output
    marker = json.loads((out / MARKER).read_text())
    assert marker["tool"] == "simbench" and marker["scenario"] == "quickstart" and marker["kind"] == "run"
    first = json.loads((out / "metrics.json").read_text())
    assert first["failed_stages"] == [] and first["run.frames"] == 6
    umask = os.umask(0)
    os.umask(umask)
    assert (out.stat().st_mode & 0o777) == (0o777 & ~umask)  # not tempfile's 0700
    (out / "leftover.txt").write_text("from the earlier run")
    r = _invoke("run", QUICKSTART, "--out", str(out), *TINY, "--set", "duration_s=0.3")
    assert r.exit_code == 0, r.output
    assert not (out / "leftover.txt").exists()  # replaced as a whole
    assert json.loads((out / "metrics.json").read_text())["run.frames"] == 9
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no partial or old folder left

    tiny = tmp_path / "tiny.toml"  # `render` has no --set
    tiny.write_text(Path(QUICKSTART).read_text().replace("duration_s = 2.0", "duration_s = 0.2")
                    .replace("count = 4", "count = 2\nwidth = 320\nheight = 240")
                    .replace("motion_blur = false", "motion_blur = false\nantialias = 1"))
    empty = tmp_path / "made_by_user"
    empty.mkdir()
    r = _invoke("render", str(tiny), "--out", str(empty))
    assert r.exit_code == 0, r.output
    assert (empty / "contact_sheet.png").is_file() and json.loads((empty / MARKER).read_text())["kind"] == "render"


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_stale_partials_removed_only_with_the_marker_and_a_dead_writer(tmp_path):
    def partial(name: str, pid: int | None) -> Path:
        d = tmp_path / f".{name}.partial-{name}"
        (d / "videos").mkdir(parents=True)
        (d / "videos" / "cam0.mp4").write_bytes(b"x" * 100)
        if pid is not None:
            m = OutputMarker.for_this_process(name, "run")
            (d / MARKER).write_text(json.dumps({**m.__dict__, "pid": pid}))
        return d

    dead = partial("dead", _dead_pid())
    alive = partial("alive", os.getppid())
    unmarked = partial("unmarked", None)
    user = tmp_path / ".notes.partial-x"
    user.mkdir()
    (user / "notes.txt").write_text("not the bench's")
    assert remove_stale_partials(tmp_path) == [dead]
    assert not dead.exists() and alive.is_dir() and unmarked.is_dir() and (user / "notes.txt").is_file()


def _fail_exports(monkeypatch):
    from simbench.pipelines import run

    def failing_export(capture, out_dir, calibration, subject=None):
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        raise MocapInputError(f"{Path(out_dir) / 'skeleton.bvh'}: no frame of the fit was solved, nothing to write; "
                              f"check the marker labels and min_markers")

    monkeypatch.setattr(run, "export_capture", failing_export)


def test_a_failing_export_keeps_metrics_and_report_and_exits_3(tmp_path, monkeypatch):
    _fail_exports(monkeypatch)
    out = tmp_path / "bw"
    r = _invoke("run", QUICKSTART, "--out", str(out), *TINY)
    assert r.exit_code == 3, r.output
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1
    assert f"exports failed: {out}/exports/skeleton.bvh: no frame of the fit was solved" in errors[0]
    assert ".partial-" not in r.output
    metrics = json.loads((out / "metrics.json").read_text())
    # the run's metrics are all there (their values are the pipeline's business, not this test's)
    assert 0.0 <= metrics["markers.reconstructed_fraction"] <= 1.0 and metrics["run.frames"] == 6
    assert {"markers.rmse_mm", "markers.label_swaps", "run.cameras"} <= set(metrics)
    assert metrics["failed_stages"] == [{"stage": "exports", "cause": f"{out}/exports/skeleton.bvh: no frame of the fit "
                                         "was solved, nothing to write; check the marker labels and min_markers"}]
    report = (out / "report.md").read_text()
    assert "## Failed stages" in report and f"**exports**: {out}/exports/skeleton.bvh" in report
    assert ".partial-" not in report + (out / "metrics.json").read_text()
    assert (out / "contact_sheet.png").is_file() and (out / "exports" / "label_template.csv").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bw"]


def test_a_failing_skeleton_solve_keeps_the_markers(tmp_path, monkeypatch):
    from simbench.pipelines import run
    from simbench.scenario import load_scenario

    real = run.capture_from_detections

    def capture(*args, **kwargs):
        params = args[4]
        if params.solve_skeleton:
            raise FloatingPointError("singular Jacobian in the first frame")
        return real(*args, **kwargs)

    monkeypatch.setattr(run, "capture_from_detections", capture)
    sc = load_scenario(QUICKSTART, overrides={"duration_s": 0.2, "rig.count": 2, "rig.width": 320, "rig.height": 240,
                                              "sensor.antialias": 1, "markers_pipeline.solve_skeleton": True})
    result = run.run_scenario(sc, tmp_path / "sk")
    assert [(f.stage, f.cause) for f in result.failures] == [("skeleton solve", "FloatingPointError: singular Jacobian in the first frame")]
    assert result.capture is not None and result.capture.skeleton is None
    saved = json.loads((tmp_path / "sk" / "metrics.json").read_text())
    assert saved["markers.rmse_mm"] == pytest.approx(result.metrics["markers.rmse_mm"])
    assert saved["failed_stages"][0]["stage"] == "skeleton solve"
    assert (tmp_path / "sk" / "exports" / "markers.c3d").is_file()


def test_user_error_messages_keep_square_brackets(tmp_path, no_render):
    r = _invoke("run", QUICKSTART, "--set", 'lighting.preset="custom"', "--out", str(tmp_path / "o"))
    assert r.exit_code == 2
    assert "needs at least one [[lighting.lights]] entry" in " ".join(r.stderr.split())
