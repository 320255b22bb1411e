"""simbench export-inputs (issue 14, part 1): the inputs folder another system reads."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mocap.calibration_formats import load_calibration
from mocap.labelling import load_template
from simbench.pipelines.exchange.inputs import LABEL_GATE_PX, export_inputs, read_detections_csv
from simbench.scenario import load_scenario


@pytest.mark.parametrize("fmt", ["pose2sim"])
def test_export_inputs_quickstart(tmp_path, fmt):
    sc = load_scenario("scenarios/quickstart.toml", {"duration_s": 0.2, "rig.count": 2, "rig.start_deg": -40.0,
                                                     "rig.span_deg": 80.0, "sensor.antialias": 1})
    ex = export_inputs(sc, tmp_path / "in", fmt)
    d = tmp_path / "in"
    man = json.loads((d / "inputs.json").read_text())
    assert man["cameras"] == ["cam0", "cam1"] and len(man["markers"]) == 39 and man["n_frames"] == 6
    assert not (d / "ground_truth").exists()  # the system never sees the truth
    cal = load_calibration(d / man["calibration"][0])
    # detections: CSV == OpenPose JSON == the returned arrays
    pts, conf = read_detections_csv(d / "detections_2d.csv", man["cameras"], man["markers"], man["n_frames"])
    np.testing.assert_allclose(pts, ex.points_px, atol=1e-6, equal_nan=True)
    kp = json.loads((d / "pose" / "cam1_json" / "cam1_000003_keypoints.json").read_text())["people"][0]["pose_keypoints_2d"]
    kp = np.asarray(kp).reshape(-1, 3)
    np.testing.assert_allclose(kp[:, 2], conf[3, 1])
    np.testing.assert_allclose(kp[conf[3, 1] > 0, :2], pts[3, 1][conf[3, 1] > 0], atol=1e-6)
    # labelled blobs lie on the exact projections of the true markers (re-rendered ground truth)
    from simbench.stage.rendering import render_scenario

    gt = render_scenario(sc, tmp_path / "gt").ground_truth
    assert [c.name for c in cal] == gt.camera_names
    ok = conf > 0
    assert ok.sum() > 0.8 * gt.marker_visible.sum()
    err = np.linalg.norm(pts[ok] - gt.markers_2d[ok], axis=-1)
    assert err.max() < LABEL_GATE_PX and np.median(err) < 0.3
    tpl = load_template(d / "label_template.csv")
    assert list(tpl.names) == man["markers"]


def test_export_inputs_of_a_calibration_scene_has_its_board_pictures(tmp_path):
    """A [calibration_scene]: the board's description (inner corners and squares), its pictures per
    camera (PNG) and one video per camera, for systems that calibrate themselves; the anipose file."""
    sc = load_scenario("scenarios/calibration.toml", {"calibration_scene.n_views": 3, "calibration_scene.wand": False,
                                                      "sensor.antialias": 1})
    export_inputs(sc, tmp_path / "in", "anipose")
    d = tmp_path / "in"
    man = json.loads((d / "inputs.json").read_text())
    assert man["markers"] == [] and man["detections"] is None
    board = man["calibration_board"]
    assert board["inner_corners"] == [9, 6] and board["squares"] == [10, 7] and board["square_m"] == 0.08
    assert board["views"] == 4  # 3 in the air + the floor view
    for cam in man["cameras"]:
        assert len(list((d / "calibration_board" / cam).glob("view_*.png"))) == 4
        assert (d / "calibration_board" / f"{cam}.mp4").stat().st_size > 1000
    assert [c.name for c in load_calibration(d / "calibration" / "calibration.toml")] == man["cameras"]
