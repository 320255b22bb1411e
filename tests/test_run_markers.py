"""``simbench run`` end to end on rendered frames: the marker pipeline against ground truth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mocap.exports import read_c3d
from simbench.pipelines.run import run_scenario
from simbench.scenario import load_scenario


@pytest.fixture(scope="module")
def quickstart_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "quickstart"
    sc = load_scenario("scenarios/quickstart.toml", overrides={"duration_s": 1.5})
    return run_scenario(sc, out), out


def test_quickstart_accuracy(quickstart_run):
    """Issue 3's quickstart targets on the first 1.5 s of the clip (labels start from the T-pose)."""
    result, out = quickstart_run
    m = result.metrics
    assert m["markers.rmse_mm"] <= 1.2, m
    assert m["markers.reconstructed_fraction"] >= 0.99, m
    assert m["markers.label_swaps"] == 0, m
    assert m["skeleton.joint_angle_rmse_deg"] <= 2.0, m
    assert m["skeleton.joint_position_rmse_mm"] <= 5.0, m


def test_run_writes_metrics_report_and_exports_that_match(quickstart_run):
    result, out = quickstart_run
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["markers.label_swaps"] == result.metrics["markers.label_swaps"]
    report = (out / "report.md").read_text()
    for png in ("plots/marker_error.png", "plots/reprojection.png", "plots/joint_angles.png"):
        assert png in report and (out / png).stat().st_size > 10_000
    traj = read_c3d(out / "exports" / "markers.c3d")
    est = result.capture.trajectories
    np.testing.assert_allclose(traj.xyz, est.xyz, atol=1e-4, equal_nan=True)
    assert (out / "exports" / "markers.trc").read_text().splitlines()[2].split("\t")[4] == "mm"
    assert (out / "exports" / "skeleton.bvh").read_text().startswith("HIERARCHY")
    assert len(list((out / "videos").glob("*.mp4"))) == 4


def test_mocap_markers_cli_on_the_rendered_videos(quickstart_run, tmp_path):
    """The real-video entry point reads the MP4s simbench wrote and recovers the markers. Through
    the command's typer app in this process (a new interpreter would only add its imports, about
    4 CPU-s; tests/test_mocap_markers_inputs.py runs ``python -m mocap.cli markers`` as a process)."""
    from typer.testing import CliRunner

    from mocap.cli.app import app
    from simbench.stage.ground_truth import load_ground_truth

    result, out = quickstart_run
    r = CliRunner().invoke(app, ["markers", *sorted(str(p) for p in (out / "videos").glob("*.mp4")),
                                 "--calibration", str(out / "calibration_ground_truth.yml"),
                                 "--template", str(out / "exports" / "label_template.csv"),
                                 "--subject", str(out / "exports" / "subject.toml"), "--out", str(tmp_path / "cap")],
                           catch_exceptions=True)
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    assert r.exit_code == 0, r.stderr
    traj = read_c3d(tmp_path / "cap" / "markers.c3d")
    gt = load_ground_truth(out)
    idx = [traj.labels.index(n) for n in gt.marker_names]
    err = np.linalg.norm(traj.xyz[:, idx] - gt.markers_3d, axis=-1)
    # The same pipeline as `simbench run`, but from H.264-compressed videos read back.
    assert np.isfinite(err).mean() > 0.98
    assert np.sqrt(np.nanmean(err**2)) < 0.002
    assert (tmp_path / "cap" / "skeleton.bvh").is_file()


def test_mocap_markers_labelled_trial_on_a_take_that_does_not_start_in_a_t_pose(quickstart_run, tmp_path_factory):
    """Real videos without a subject model: `mocap markers --labelled-trial` labels a take that starts
    mid-wave (clip seconds 1.5-2.5) from the marker clusters of another take of the subject (the
    fixture's seconds 0-1.5, as `simbench run` exported it). Without the trial the labels start from a
    T-pose the first frame does not show, and the command says so."""
    from typer.testing import CliRunner

    from mocap.cli.app import app
    from simbench.stage.ground_truth import load_ground_truth

    _, trial_run = quickstart_run
    take = tmp_path_factory.mktemp("mid") / "take"
    run_scenario(load_scenario("scenarios/quickstart.toml", overrides={"motion.start_s": 1.5, "duration_s": 1.0}), take)
    gt = load_ground_truth(take)
    outs = {}
    for name, extra in (("none", []), ("trial", ["--labelled-trial", str(trial_run / "exports" / "markers.c3d")])):
        out = take.parent / name
        r = CliRunner().invoke(app, ["markers", *sorted(str(p) for p in (take / "videos").glob("*.mp4")),
                                     "--calibration", str(take / "calibration_ground_truth.yml"),
                                     "--template", str(take / "exports" / "label_template.csv"), "--out", str(out), *extra])
        assert r.exit_code == 0, r.stderr
        traj = read_c3d(out / "markers.c3d")
        err = np.linalg.norm(traj.xyz[:, [traj.labels.index(n) for n in gt.marker_names]] - gt.markers_3d, axis=-1)
        outs[name] = (json.loads((out / "summary.json").read_text()), err, r.stderr)
    summary, err, stderr = outs["trial"]
    assert summary["labelling"] == "model" and "note:" not in stderr
    assert np.isfinite(err).mean() >= 0.97
    assert np.sqrt(np.nanmean(err**2)) < 0.002 and np.nanmax(err) < 0.02  # no marker mislabelled
    summary, err_none, stderr = outs["none"]
    assert summary["labelling"] == "tracker" and "no --subject or --labelled-trial" in " ".join(stderr.split())
    # the T-pose fit of a mid-wave first frame finds under half the template (0.44; the T-pose start: 0.75)
    assert 0.2 < summary["first_frame_found"] < 0.6 and "first frame found" in " ".join(stderr.split())
    assert "first_frame_found" not in outs["trial"][0]
    assert np.isfinite(err_none).mean() < np.isfinite(err).mean()


def test_score_markers_script_gives_the_runs_own_figures(quickstart_run, capsys):
    """scripts/score_markers.py on the run's exported C3D: the RMSE and label swaps that metrics.json
    states for the same points (the script's fraction is over all true points, the run's over those
    two cameras saw, so it can only be lower)."""
    from conftest import load_script

    _, out = quickstart_run
    script = load_script("score_markers")
    assert script.main([str(out), str(out / "exports" / "markers.c3d")]) == 0
    line = capsys.readouterr().out
    metrics = json.loads((out / "metrics.json").read_text())
    assert f"RMSE {metrics['markers.rmse_mm']:.2f} mm" in line, line
    assert f"{metrics['markers.label_swaps']} label swaps" in line, line
    fraction = float(line.split("reconstructed ")[1].split(",")[0])
    assert 0.9 < fraction <= metrics["markers.reconstructed_fraction"] + 1e-3, line
