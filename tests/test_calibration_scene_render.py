"""Rendered calibration pictures against exact ground truth.

The quickstart's 4-camera rig photographs a printed checkerboard (the floor view and
three poses in the air) and a ChArUco board, and films a wand in IR. The board corners
the calibration tool detects in the rendered frames must land on the exact projections
of the board's corners; cameras that face the back of the board must not find it
(a two-sided print would be found mirrored); wand blobs must land on the exact
projections of the markers with the right labels.
"""

from __future__ import annotations

import numpy as np
import pytest

from mocap.calib.board_detection import DetectionSettings, detect_board
from mocap.calib.boards import board_texture_layout
from simbench.stage.calibration_scene import (
    BOARD_MARGIN_SQUARES,
    BOARD_TEXTURE_PX_PER_M,
    board_spec,
    camera_pairs,
    render_board_views,
    render_calibration_scene,
    sample_board_poses,
    sheet_points,
)
from simbench.errors import ScenarioError
from simbench.render.camera import cameras_from_scenario
from simbench.render.lighting import Lighting
from simbench.scenario import load_scenario

from helpers import calibration_session

RIG = calibration_session("calib_test", """
[rig]
count = 4
radius_m = 3.0
height_m = 2.0
look_at = [0.0, 0.0, 0.95]
hfov_deg = 50.0
""", n_views=4, wand_frames=8)


def _scenario(tmp_path, text: str = RIG, overrides: dict | None = None):
    p = tmp_path / "calib_test.toml"
    p.write_text(text)
    return load_scenario(p, overrides)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    sc = _scenario(tmp_path_factory.mktemp("calib_scene"))
    return render_calibration_scene(sc, np.random.default_rng(3))


@pytest.fixture(scope="module")
def detections(scene):
    """``{(view, camera): BoardDetection}`` (no failure diagnosis: most failures are boards seen from behind)."""
    fast = DetectionSettings(diagnose=False)
    V, C = scene.board_images.shape[:2]
    return {(v, c): detect_board(scene.board_images[v, c], scene.board, fast) for v in range(V) for c in range(C)}


def test_board_corners_land_on_the_exact_projections(scene, detections):
    true = scene.board_corners_true()  # (C, V, N, 2)
    errs, found = [], np.zeros(true.shape[:2], dtype=bool)
    for v in range(scene.board_images.shape[0]):
        for c in range(len(scene.truth)):
            det = detections[v, c]
            if det.found:
                found[c, v] = True
                errs.append(det.corners_px - true[c, v, det.corner_ids])
    e = np.concatenate(errs)
    rms = float(np.sqrt(np.mean(np.sum(e ** 2, axis=1))))
    print(f"\n{len(errs)} boards found, corner error vs exact: rms {rms:.3f} px, max {np.abs(e).max():.3f} px")
    # Sensor noise, optics blur and 2x anti-aliasing leave a few hundredths of a pixel.
    assert rms < 0.1
    assert np.abs(e).max() < 0.4
    # Every pose in the air is found by (at least) both cameras it faces, the floor view by two or more.
    poses = scene.board_poses
    for v, pair in enumerate(poses.pairs):
        if pair is None:
            assert found[:, v].sum() >= 2, v
        else:
            assert found[list(pair), v].all(), (v, pair, found[:, v])


def test_board_seen_from_behind_is_not_found(scene, detections):
    """The print is on the front only: cameras behind the board see its backing, not a mirrored board."""
    poses = scene.board_poses
    behind = 0
    for v in range(poses.n_views):
        normal = -poses.R_wb[v][:, 2]  # out of the printed face
        for c, cam in enumerate(scene.truth):
            if (cam.center - poses.t_wb[v]) @ normal < 0:
                behind += 1
                assert not detections[v, c].found, (v, cam.name)
    assert behind >= 4


def test_floor_view_is_the_world_origin(scene):
    poses = scene.board_poses
    assert poses.floor_view == 0 and poses.pairs[0] is None
    np.testing.assert_allclose(poses.R_wb[0], np.diag([1.0, -1.0, -1.0]))
    np.testing.assert_allclose(poses.t_wb[0], [0.0, 0.0, scene.floor_height_m])


def test_wand_blobs_are_the_markers_with_their_labels(scene):
    px, true = scene.wand_markers_px, scene.wand_true_px
    labelled = np.isfinite(px).all(axis=(2, 3))
    assert labelled.mean() > 0.8
    e = (px - true)[labelled]
    rms = float(np.sqrt(np.mean(np.sum(e ** 2, axis=-1))))
    print(f"\nwand: {labelled.sum()} camera-frames labelled, centroid error rms {rms:.3f} px, max {np.abs(e).max():.3f}")
    assert rms < 0.15
    assert np.abs(e).max() < 0.5  # a label swap would be tens of pixels off
    # The true 3D markers are the configured distances apart.
    d = np.linalg.norm(np.diff(scene.wand_points, axis=1), axis=2)
    np.testing.assert_allclose(d, np.broadcast_to(scene.wand.distances_m[:2], d.shape), atol=1e-9)


def test_board_poses_face_camera_pairs(tmp_path):
    """Pose sampling only (no rendering): whole board in both cameras, view angles, tilts, image coverage."""
    sc = _scenario(tmp_path, overrides={"calibration_scene.n_views": 24})
    cfg = sc.calibration_scene
    cams = cameras_from_scenario(sc)
    spec = board_spec(cfg)
    lay = board_texture_layout(spec, BOARD_TEXTURE_PX_PER_M, BOARD_MARGIN_SQUARES)
    poses = sample_board_poses(cams, cfg, spec, lay, np.random.default_rng(0))
    pairs = camera_pairs(cams, cfg.max_view_angle_deg)
    assert sorted(pairs) == [(0, 1), (0, 3), (1, 2), (2, 3)]  # neighbours on the ring, not opposite cameras
    sheet = sheet_points(lay)
    cells = {c: set() for c in range(len(cams))}
    tilts = []
    for v in range(1, poses.n_views):
        R, t = poses.R_wb[v], poses.t_wb[v]
        pw = sheet @ R.T + t
        assert pw[:, 2].min() > 0.05  # above the floor
        normal = -R[:, 2]
        centre = pw.mean(axis=0)
        bis = 0.0
        for c in poses.pairs[v]:
            cam = cams[c]
            uv = cam.project(pw)
            assert cam.calibration_camera().in_image(uv, 2.0).all(), (v, c)
            sight = (cam.center - centre) / np.linalg.norm(cam.center - centre)
            assert np.degrees(np.arccos(sight @ normal)) <= cfg.max_view_angle_deg + 1e-6
            bis = bis + sight
            u, w = cam.project(centre[None])[0]
            cells[c].add((int(u * 3 // cam.width), int(w * 3 // cam.height)))
        bis /= np.linalg.norm(bis)
        tilts.append(np.degrees(np.arccos(np.clip(bis @ normal, -1, 1))))
    # Tilted away from facing the pair by 15-45 deg (measured from the board centre, so a little wider).
    assert 10.0 < np.min(tilts) and np.max(tilts) < 50.0 and np.ptp(tilts) > 15.0
    # The board is shown all over each camera's image.
    assert all(len(s) >= 5 for s in cells.values()), cells


def test_charuco_board_corners_and_origin(tmp_path):
    """ChArUco's origin is the outer corner (not the first inner corner): the texture mapping must agree."""
    sc = _scenario(tmp_path, overrides={"calibration_scene.board": "charuco", "calibration_scene.board_cols": 5,
                                        "calibration_scene.board_rows": 4, "calibration_scene.square_m": 0.16,
                                        "calibration_scene.n_views": 3, "calibration_scene.wand": False})
    cfg = sc.calibration_scene
    cams = cameras_from_scenario(sc)
    spec = board_spec(cfg)
    lay = board_texture_layout(spec, BOARD_TEXTURE_PX_PER_M, BOARD_MARGIN_SQUARES)
    poses = sample_board_poses(cams, cfg, spec, lay, np.random.default_rng(1))
    images = render_board_views(sc, cams, Lighting(sc.lighting), spec, poses, noise_seed=5)
    from simbench.stage.calibration_scene import CalibrationScene
    from mocap.calibration import Calibration

    truth = Calibration(tuple(c.calibration_camera() for c in cams))
    true = CalibrationScene(spec, truth, images, poses, cfg.board_thickness_m).board_corners_true()
    errs = []
    for v in range(1, poses.n_views):
        for c in poses.pairs[v]:
            det = detect_board(images[v, c], spec)
            assert det.found and det.n_corners >= 8, (v, c, det.problem, det.detail)
            errs.append(det.corners_px - true[c, v, det.corner_ids])
    e = np.concatenate(errs)
    rms = float(np.sqrt(np.mean(np.sum(e ** 2, axis=1))))
    print(f"\nChArUco corners vs exact: rms {rms:.3f} px over {len(e)} corners")
    assert rms < 0.15


def test_scenario_checks_name_the_field(tmp_path):
    bad = RIG.replace("board_cols = 9", "board_cols = 8")  # 8x6 looks the same turned by 180 deg
    with pytest.raises(ScenarioError, match="calibration_scene") as info:
        _scenario(tmp_path, bad)
    assert "180 deg" in str(info.value)
    bad = RIG.replace("wand_frames = 8", "wand_frames = 8\nwand_d01_m = 0.25\nwand_d12_m = 0.27")
    with pytest.raises(ScenarioError, match="too alike"):
        _scenario(tmp_path, bad)
    no_scene = RIG.split("[calibration_scene]")[0] + '[markers_pipeline]\ncalibration = "estimated"\n'
    with pytest.raises(ScenarioError, match=r"calibration_scene\]"):
        _scenario(tmp_path, no_scene)
