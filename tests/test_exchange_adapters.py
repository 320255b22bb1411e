"""Third-party adapters in their own environments (issue 14, part 3): aniposelib and Pose2Sim
run their own code on the bench's exported inputs. Skipped, saying why, where
scripts/setup_adapters.sh has not made the environment."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from mocap.calibration_formats import save_calibration
from mocap.triangulation import triangulate_dlt
from simbench.pipelines.exchange.adapters import adapter_python, run_adapter
from simbench.pipelines.exchange.inputs import export_inputs
from simbench.pipelines.exchange.results import read_results, score_results
from simbench.scenario import load_scenario
from simbench.stage.rendering import render_scenario

TINY = {"duration_s": 0.3, "rig.count": 3, "rig.start_deg": -60.0, "rig.span_deg": 120.0, "sensor.antialias": 1}


def _need(name: str):
    if adapter_python(name) is None:
        pytest.skip(f"adapter environment .venv-{name} is absent: run scripts/setup_adapters.sh {name}")
    return adapter_python(name)


def test_aniposelib_reads_the_anipose_file_as_written(tmp_path):
    """aniposelib's own CameraGroup.load + project lands within 1e-6 px of the bench's cameras."""
    py = _need("aniposelib")
    from tests.test_exchange_formats import _rig

    truth = _rig(11)  # 11 cameras: aniposelib sorts its table names as strings
    save_calibration(truth, tmp_path, "anipose")
    pts = np.random.default_rng(3).uniform([-1, -1, 0], [1, 1, 2], (50, 3))
    np.save(tmp_path / "pts.npy", pts)
    code = ("import numpy as np, sys; from aniposelib.cameras import CameraGroup; "
            f"g = CameraGroup.load('{tmp_path / 'calibration.toml'}'); "
            f"np.save('{tmp_path / 'uv.npy'}', g.project(np.load('{tmp_path / 'pts.npy'}'))); "
            f"open('{tmp_path / 'names.txt'}', 'w').write(' '.join(g.get_names()))")
    subprocess.run([str(py), "-c", code], check=True, capture_output=True)
    assert (tmp_path / "names.txt").read_text().split() == truth.names
    uv = np.load(tmp_path / "uv.npy")
    for c, cam in enumerate(truth):
        ok = np.isfinite(cam.project(pts)).all(axis=1)
        assert np.abs(uv[c][ok] - cam.project(pts)[ok]).max() < 1e-6


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    d = tmp_path_factory.mktemp("adapters")
    sc = load_scenario("scenarios/quickstart.toml", TINY)
    gt = render_scenario(sc, d / "gt").ground_truth
    return sc, gt, d


@pytest.mark.parametrize("name, fmt", [("aniposelib", "anipose"), ("pose2sim", "pose2sim")])
def test_adapter_triangulates_the_exported_detections(quick, name, fmt):
    """The tool's own triangulation on the labelled detections, scored against the truth: its plain
    DLT agrees with the project's triangulate_dlt on the same points; every variant is written."""
    _need(name)
    sc, gt, d = quick
    ex = export_inputs(sc, d / f"in_{fmt}", fmt)
    timings = run_adapter(name, "triangulate", d / f"in_{fmt}", d / f"out_{name}", timeout_s=900)
    assert timings["frames"] == gt.n_frames
    F, C, M, _ = ex.points_px.shape
    ours = triangulate_dlt(np.transpose(ex.points_px, (1, 0, 2, 3)).reshape(C, F * M, 2), gt.calibration()).reshape(F, M, 3)
    for variant in {"aniposelib": ("triangulate", "triangulate_ransac", "triangulate_optim"),
                    "pose2sim": ("pose2sim", "pose2sim_gaps_nan")}[name]:
        if variant in timings.get("failed", {}) and variant != "triangulate":
            assert timings["failed"][variant]  # the tool's own error, recorded (triangulate_ransac: 3 cameras)
            continue
        traj = read_results(d / f"out_{name}" / f"{variant}.csv")
        m = score_results(traj, gt.markers_3d, gt.marker_visible, gt.marker_names, gt.times)
        assert m["markers.reconstructed_fraction"] > 0.9, (variant, m)
        if variant in ("triangulate", "pose2sim_gaps_nan"):
            assert m["markers.rmse_mm"] < 2.0, (variant, m)
        if variant == "triangulate":  # both are linear DLT on the same undistorted points
            both = np.isfinite(ours).all(-1) & np.isfinite(traj.xyz).all(-1)
            assert both.sum() > 0.9 * np.isfinite(ours).all(-1).sum()
            assert np.abs(traj.xyz[both] - ours[both]).max() < 1e-4  # metres
    assert json.loads((d / f"out_{name}" / "timings.json").read_text())["version"]
