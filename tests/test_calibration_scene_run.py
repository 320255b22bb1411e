"""Calibration in the loop: rendered pictures -> the calibration tool -> scores against the exact cameras.

Two neighbouring webcams (one with a distorted lens) photograph a checkerboard in ten
poses plus once on the floor, and film a wand. The calibration tool, run on those
pixels exactly as a user would run it (in process, and as ``mocap calibrate`` on PNG
folders), must recover the exact cameras; the floor board must put the world where
the simulator has it, with no alignment. ``simbench run`` must report it.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from eval.calibration_metrics import compare_calibrations
from mocap.calibration import Calibration
from mocap.cli import app
from simbench.pipelines.calibration import calibrate_scene, score_calibration
from simbench.stage.calibration_scene import render_calibration_scene
from simbench.pipelines.run import run_scenario
from simbench.scenario import load_scenario

from helpers import calibration_session

PAIR = calibration_session("calib_pair", """
[[cameras]]
name = "left"
position = [2.3, -1.93, 2.0]
look_at = [0.0, 0.0, 0.95]
hfov_deg = 50.0
[[cameras]]
name = "right"
position = [2.3, 1.93, 2.1]
look_at = [0.0, 0.0, 1.0]
hfov_deg = 54.0
distortion = [-0.12, 0.05, 0.0, 0.0, 0.0]
""", n_views=10, wand_frames=24, extra="volume_half_m = [0.4, 0.4, 0.4]   # where both cameras see the wand\n")


def _scenario(tmp_path, overrides: dict | None = None):
    p = tmp_path / "calib_pair.toml"
    p.write_text(PAIR)
    return load_scenario(p, overrides)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return render_calibration_scene(_scenario(tmp_path_factory.mktemp("pair")), np.random.default_rng(7))


@pytest.fixture(scope="module")
def calibrated(scene):
    return calibrate_scene(scene)


def _distortion_error_where_seen(calibrated, scene, name: str) -> float:
    """Worst px displacement between the estimated and true distortion at the detected corners (true K)."""
    c = calibrated.observations.camera_names.index(name)
    px = calibrated.observations.corners_px[c]
    px = px[np.isfinite(px).all(axis=-1)].reshape(-1, 1, 2)
    true, est = scene.truth[name], calibrated.result.calibration[name]
    xy = cv2.undistortPoints(px, true.K, true.dist, None, None, None,
                             (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)).reshape(-1, 2)
    rays = np.column_stack([xy, np.ones(len(xy))])
    a, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), true.K, est.dist)
    b, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), true.K, true.dist)
    return float(np.max(np.linalg.norm(a.reshape(-1, 2) - b.reshape(-1, 2), axis=1)))


def test_calibration_recovers_the_exact_cameras(scene, calibrated):
    metrics, rigid, floor = score_calibration(calibrated, scene)
    print("\n2-camera rig:", {k: round(v, 4) for k, v in metrics.items()})
    assert calibrated.world == "floor"
    assert metrics["calib.corner_error_rms_px"] < 0.1  # what the tool was fed
    assert metrics["calib.reprojection_rms_px"] < 0.2
    assert metrics["calib.focal_error_pct"] < 0.5
    assert metrics["calib.principal_point_error_px"] < 3.0
    # The distorted lens (k1 = -0.12: up to 9 px at the image corners) is recovered where the
    # board was seen (beyond, the fitted polynomial extrapolates: reported, not asserted).
    assert _distortion_error_where_seen(calibrated, scene, "right") < 0.5
    assert metrics["calib.rotation_error_deg"] < 0.2
    assert metrics["calib.translation_error_mm"] < 5.0
    # No alignment at all: the floor board (lowered by its thickness) is the true world.
    assert floor["summary"]["rotation_error_deg"] < 0.3
    assert floor["summary"]["translation_error_mm"] < 10.0
    assert metrics["calib.wand_distance_rms_mm"] < 1.0
    # Adjusted wand markers sit on the true ones, in the true world.
    est = calibrated.result.wand_points_world
    ok = np.isfinite(est).all(axis=(1, 2))
    assert ok.sum() >= 8  # frames whose three markers both cameras labelled
    assert np.sqrt(np.mean(np.sum((est[ok] - scene.wand_points[ok]) ** 2, axis=2))) < 0.005


def test_mocap_calibrate_cli_on_rendered_pictures(scene, calibrated, tmp_path):
    folders = scene.write_images(tmp_path / "pictures")
    out = tmp_path / "rig"
    args = ["calibrate", *[f"{n}={p}" for n, p in folders.items()], "--board-size", "9x6", "--square-mm", "80",
            "--floor-view", "view_000.png", "--out", str(out)]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    assert "left" in res.output and "right" in res.output
    for suffix in (".toml", ".yml", ".report.json"):
        assert out.with_suffix(suffix).exists() or (tmp_path / f"rig{suffix}").exists()
    cli = Calibration.load(tmp_path / "rig.toml")
    s = compare_calibrations(cli, scene.truth, align="rigid")["summary"]
    assert s["focal_error_pct"] < 0.5 and s["rotation_error_deg"] < 0.2
    # Board only (no wand file), world from the floor view at its printed face: the same
    # intrinsics as the in-process run to well under a pixel.
    for cam in cli:
        np.testing.assert_allclose(cam.K, calibrated.result.calibration[cam.name].K, atol=1.0)
    report = json.loads((tmp_path / "rig.report.json").read_text())
    assert min(report["views_used"].values()) >= 9  # of 11


def test_simbench_run_reports_the_calibration(tmp_path):
    sc = _scenario(tmp_path, {"calibration_scene.n_views": 8, "calibration_scene.wand": False})
    run_scenario(sc, tmp_path / "out")
    out = tmp_path / "out"
    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("calib.focal_error_pct", "calib.principal_point_error_px", "calib.distortion_error_px",
                "calib.rotation_error_deg", "calib.translation_error_mm", "calib.reprojection_rms_px"):
        assert np.isfinite(metrics[key]), key
    assert metrics["calib.focal_error_pct"] < 1.0
    report = (out / "report.md").read_text()
    assert "## Camera calibration" in report
    assert "| left |" in report and "| right |" in report
    assert (out / "plots" / "calibration_residuals.png").stat().st_size > 10_000
    est = Calibration.load(out / "calibration" / "estimated.toml")
    assert est.names == ["left", "right"]
