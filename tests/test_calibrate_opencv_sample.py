"""`mocap calibrate` on real images: OpenCV's sample chessboard pictures (left01..14.jpg).

OpenCV's own calibration of these images (``left_intrinsics.yml``, made with
``CALIB_FIX_ASPECT_RATIO``) is the reference: fx = fy = 535.9, RMS 0.39 px.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eval.calibration_metrics import compare_calibrations
from mocap.calibrate import run_calibrate_cli
from mocap.calibration import Calibration



@pytest.fixture(scope="module")
def samples(shared_data) -> Path:
    return shared_data / "calib_opencv_left"


@pytest.fixture(scope="module")
def result(tmp_path_factory, samples):
    out = tmp_path_factory.mktemp("calib") / "left"
    return run_calibrate_cli([f"left={samples}"], str(out), board="checkerboard", board_size="9x6", square_mm=25.0,
                             fix_aspect_ratio=True)


def test_reproduces_opencv_reference(result, samples):
    ref = Calibration.load(samples / "left_intrinsics.yml")[0]
    cam = result.calibration["left"]
    rms = result.reprojection_rms_px["left"]
    scores = compare_calibrations(result.calibration, Calibration((ref.replace(name="left"),)), align="none")
    print(f"\nfx {cam.K[0, 0]:.2f} (OpenCV {ref.K[0, 0]:.2f}, {100 * (cam.K[0, 0] / ref.K[0, 0] - 1):+.2f} %), "
          f"cx {cam.K[0, 2]:.1f} ({ref.K[0, 2]:.1f}), cy {cam.K[1, 2]:.1f} ({ref.K[1, 2]:.1f}), "
          f"RMS {rms:.3f} px (OpenCV 0.39), k = {np.round(cam.dist, 3)}, "
          f"max distortion difference {scores['per_camera']['left']['distortion_error_px']:.2f} px, "
          f"views used {len(result.views_used['left'])}")
    assert abs(cam.K[0, 0] / ref.K[0, 0] - 1) < 0.005
    assert cam.K[1, 1] == pytest.approx(cam.K[0, 0])  # aspect ratio fixed, as in OpenCV's run
    assert rms < 0.5
    assert np.hypot(cam.K[0, 2] - ref.K[0, 2], cam.K[1, 2] - ref.K[1, 2]) < 3.0
    assert len(result.views_used["left"]) == 13


def test_writes_files_that_load_back(result):
    toml_path, yml_path, report = result.written
    assert toml_path.suffix == ".toml" and yml_path.suffix == ".yml" and report.name.endswith(".report.json")
    cam = result.calibration["left"]
    for path in (toml_path, yml_path):
        back = Calibration.load(path)["left"]
        np.testing.assert_allclose(back.K, cam.K, rtol=1e-12)
        np.testing.assert_allclose(back.dist, cam.dist, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(back.R, cam.R, atol=1e-12)
        np.testing.assert_allclose(back.t, cam.t, atol=1e-12)
        assert back.size == (640, 480)
    import json

    doc = json.loads(report.read_text())
    assert doc["reprojection_rms_px"]["left"] == pytest.approx(result.reprojection_rms_px["left"])
    assert doc["views_used"]["left"] == 13


def test_per_view_errors_are_reported(result):
    per_view = result.view_rms_px["left"]
    assert per_view.shape == (13,)
    assert np.all(per_view < 0.5)
    # The overall RMS is the point-weighted mean of the per-view ones (all views have 54 corners).
    assert np.sqrt(np.mean(per_view ** 2)) == pytest.approx(result.reprojection_rms_px["left"], rel=1e-6)
