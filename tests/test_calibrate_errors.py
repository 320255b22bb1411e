"""Calibration errors say what went wrong, where, and what to change.

Each situation is built on purpose: damaged copies of OpenCV's sample chessboard
images (blurred, cut off, shrunk, blank), and exact synthetic projections for
fronto-parallel views, cameras that never see the board together, and a camera whose
views are out of sync.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocap.calib.boards import BoardSpec, board_object_points
from mocap.calib.bundle_adjustment import BundleAdjustmentOptions
from mocap.calib.errors import (
    BoardNotFoundError,
    BundleAdjustmentError,
    CalibrationError,
    DegenerateViewsError,
    DisconnectedCamerasError,
)
from mocap.calib.intrinsics import calibrate_intrinsics
from mocap.calib.observations import BoardObservations
from mocap.calib.synthetic import look_at, observe_board
from mocap.calibrate import calibrate_cameras, calibrate_from_observations
from mocap.calibration import Calibration, Camera
from mocap.errors import InputFileError, MocapInputError

CHECKER = BoardSpec("checkerboard", (9, 6), 0.025)
CHARUCO = BoardSpec("charuco", (7, 5), 0.10, 0.075)


def _shift(img: np.ndarray, dx: float, dy: float) -> np.ndarray:
    return cv2.warpAffine(img, np.float32([[1, 0, dx], [0, 1, dy]]), (img.shape[1], img.shape[0]),
                          borderMode=cv2.BORDER_REPLICATE)


def _shrink(img: np.ndarray, scale: float) -> np.ndarray:
    small = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    out = np.full_like(img, int(np.median(img)))
    y, x = (img.shape[0] - small.shape[0]) // 2, (img.shape[1] - small.shape[1]) // 2
    out[y:y + small.shape[0], x:x + small.shape[1]] = small
    return out


@pytest.fixture(scope="module")
def damaged_folder(tmp_path_factory, shared_data) -> Path:
    """3 good views and 5 spoiled ones of OpenCV's sample board."""
    d = tmp_path_factory.mktemp("cam_left")
    samples = shared_data / "calib_opencv_left"
    img = {n: cv2.imread(str(samples / f"{n}.jpg"), cv2.IMREAD_GRAYSCALE) for n in ("left01", "left03", "left04", "left05", "left06", "left07")}
    cv2.imwrite(str(d / "a_good1.png"), img["left01"])
    cv2.imwrite(str(d / "a_good2.png"), img["left03"])
    cv2.imwrite(str(d / "a_good3.png"), img["left07"])
    cv2.imwrite(str(d / "b_blurred.png"), cv2.GaussianBlur(img["left04"], (0, 0), 8))
    cv2.imwrite(str(d / "c_cut_off.png"), _shift(img["left01"], 250, 0))
    cv2.imwrite(str(d / "d_too_small.png"), _shrink(img["left06"], 0.1))
    cv2.imwrite(str(d / "e_blank.png"), np.full_like(img["left01"], 128))
    return d


def test_board_found_in_too_few_images_lists_each_file_and_cause(damaged_folder):
    with pytest.raises(BoardNotFoundError) as info:
        calibrate_cameras({"left": damaged_folder}, CHECKER)
    err = info.value
    msg = str(err)
    print("\n" + msg)
    assert isinstance(err, MocapInputError)
    assert "camera 'left'" in msg and "only 3 of 7 images" in msg and "at least 5" in msg
    causes = {f.label: f.problem for f in err.failures}
    assert causes == {"b_blurred.png": "blurred", "c_cut_off.png": "cut off",
                      "d_too_small.png": "too small", "e_blank.png": "not found"}
    line = {ln.split(":")[0].strip(): ln for ln in msg.splitlines() if ln.startswith("  ")}
    assert "variance of Laplacian" in line["b_blurred.png"]
    assert "right edge" in line["c_cut_off.png"] and "5x6 of the 9x6" in line["c_cut_off.png"]
    assert "too small" in line["d_too_small.png"] and "closer" in line["d_too_small.png"]
    assert "uniform" in line["e_blank.png"]


def test_wrong_board_size_is_named(damaged_folder):
    with pytest.raises(BoardNotFoundError) as info:
        calibrate_cameras({"left": [damaged_folder / "a_good1.png", damaged_folder / "a_good2.png"]},
                          BoardSpec("checkerboard", (7, 5), 0.025))
    msg = str(info.value)
    assert "9x6-inner-corner checkerboard is visible, not 7x5" in msg
    assert "--board-size 9x6" in msg


def test_unreadable_and_missing_inputs(tmp_path):
    bad = tmp_path / "x.png"
    bad.write_text("not an image")
    with pytest.raises(InputFileError, match="x.png: not a readable image"):
        calibrate_cameras({"c": [bad]}, CHECKER)
    with pytest.raises(InputFileError, match="not found"):
        calibrate_cameras({"c": tmp_path / "nothing_here.mp4"}, CHECKER)


# ----------------------------------------------------------------------------- synthetic
def _camera(name: str = "cam", f: float = 600.0) -> Camera:
    return Camera(name, (640, 480), [[f, 0, 320], [0, f, 240], [0, 0, 1]], [-0.1, 0.02, 0, 0, 0])


def _views_in_front(cam: Camera, rotations: list[np.ndarray], rng: np.random.Generator, spec: BoardSpec) -> tuple[np.ndarray, np.ndarray]:
    """World-from-board poses 0.9-1.3 m in front of ``cam`` (at the world origin) with the given rotations."""
    centre = board_object_points(spec).mean(axis=0)
    Rs, ts = [], []
    for R in rotations:
        pos = np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.08, 0.08), rng.uniform(0.9, 1.3)])
        Rs.append(R)
        ts.append(pos - R @ centre)
    return np.array(Rs), np.array(ts)


def test_fronto_parallel_views_are_degenerate():
    rng = np.random.default_rng(1)
    cam = _camera("webcam")
    spec = BoardSpec("checkerboard", (9, 6), 0.04)
    rots = [Rotation.from_euler("z", a, degrees=True).as_matrix() for a in rng.uniform(-20, 20, 12)]
    R, t = _views_in_front(cam, rots, rng, spec)
    corners = observe_board(Calibration((cam,)), R, t, spec, rng=rng, noise_px=0.1)[0]
    with pytest.raises(DegenerateViewsError) as info:
        calibrate_intrinsics(corners, board_object_points(spec), cam.size, "webcam")
    msg = str(info.value)
    print("\n" + msg)
    assert "camera 'webcam'" in msg and "fronto-parallel" in msg and "all 12 views" in msg
    assert "tilt the board by 20-45 deg" in msg


def test_parallel_tilted_views_are_degenerate_too():
    rng = np.random.default_rng(2)
    cam = _camera("webcam")
    spec = BoardSpec("checkerboard", (9, 6), 0.04)
    tilt = Rotation.from_euler("y", 30, degrees=True)
    rots = [(tilt * Rotation.from_euler("z", a, degrees=True)).as_matrix() for a in rng.uniform(-20, 20, 10)]
    R, t = _views_in_front(cam, rots, rng, spec)
    corners = observe_board(Calibration((cam,)), R, t, spec, rng=rng, noise_px=0.1)[0]
    with pytest.raises(DegenerateViewsError, match="parallel to each other"):
        calibrate_intrinsics(corners, board_object_points(spec), cam.size, "webcam")
    # The same board turned both ways calibrates.
    rots2 = rots[:5] + [(Rotation.from_euler("x", -30, degrees=True) * Rotation.from_euler("z", a, degrees=True)).as_matrix()
                        for a in rng.uniform(-20, 20, 5)]
    R, t = _views_in_front(cam, rots2, rng, spec)
    corners = observe_board(Calibration((cam,)), R, t, spec, rng=rng, noise_px=0.1)[0]
    res = calibrate_intrinsics(corners, board_object_points(spec), cam.size, "webcam")
    assert abs(res.K[0, 0] / 600.0 - 1) < 0.01


def _two_pairs_rig() -> Calibration:
    """cam0, cam1 look at one spot; cam2, cam3 at another 3 m away."""
    cams = []
    for i, (cx, target) in enumerate([(-0.5, -1.5), (0.5, -1.5), (2.5, 1.5), (3.5, 1.5)]):
        R, t = look_at(np.array([cx, -2.5, 1.5]), np.array([target, 0.0, 1.0]))
        cams.append(Camera(f"cam{i}", (640, 480), [[600, 0, 320], [0, 600, 240], [0, 0, 1]], np.zeros(5), R, t))
    return Calibration(tuple(cams))


def _tilted_poses(rng: np.random.Generator, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    centre = board_object_points(CHARUCO).mean(axis=0)
    facing = Rotation.from_euler("x", -90, degrees=True)
    Rs, ts = [], []
    for c in centres:
        R = (Rotation.from_euler("xyz", rng.uniform(-35, 35, 3), degrees=True) * facing).as_matrix()
        Rs.append(R)
        ts.append(c - R @ centre)
    return np.array(Rs), np.array(ts)


def test_cameras_sharing_no_view_are_named_with_the_fix():
    rng = np.random.default_rng(3)
    rig = _two_pairs_rig()
    centres = np.concatenate([np.array([-1.5, 0, 1.0]) + rng.uniform(-0.3, 0.3, (10, 3)),
                              np.array([1.5, 0, 1.0]) + rng.uniform(-0.3, 0.3, (10, 3))])
    R, t = _tilted_poses(rng, centres)
    corners = observe_board(rig, R, t, CHARUCO, rng=rng, noise_px=0.1)
    # Each pair only ever sees its own spot (the board was never held between them).
    corners[2:, :10] = np.nan
    corners[:2, 10:] = np.nan
    seen = np.isfinite(corners[..., 0]).any(axis=2)
    assert (seen.sum(axis=1) >= 8).all()
    obs = BoardObservations(CHARUCO, rig.names, [c.size for c in rig], corners)
    with pytest.raises(DisconnectedCamerasError) as info:
        calibrate_from_observations(obs)
    msg = str(info.value)
    print("\n" + msg)
    assert "cameras 'cam2', 'cam3' share no board view with camera 'cam0'" in msg
    assert "show the board to cameras cam1 and cam2 at the same time" in msg
    assert info.value.groups == [["cam0", "cam1"], ["cam2", "cam3"]]


def _three_camera_data(rng: np.random.Generator, n: int = 16):
    cams = []
    for i, az in enumerate([-35.0, 0.0, 35.0]):
        a = np.radians(az)
        R, t = look_at(np.array([2.0 * np.sin(a), -2.0 * np.cos(a), 1.6]), np.array([0.0, 0.0, 1.0]))
        cams.append(Camera(f"cam{i}", (640, 480), [[600, 0, 320], [0, 600, 240], [0, 0, 1]], [-0.1, 0.02, 0, 0, 0], R, t))
    rig = Calibration(tuple(cams))
    centres = np.array([0, 0, 1.0]) + rng.uniform(-0.5, 0.5, (n, 3))
    R, t = _tilted_poses(rng, centres)
    return rig, observe_board(rig, R, t, CHARUCO, rng=rng, noise_px=0.1)


def test_bundle_adjustment_failure_names_the_unsynchronised_camera():
    rng = np.random.default_rng(4)
    rig, corners = _three_camera_data(rng)
    corners[2] = np.roll(corners[2], 3, axis=0)  # cam2's views are 3 frames late
    obs = BoardObservations(CHARUCO, rig.names, [c.size for c in rig], corners)
    with pytest.raises(BundleAdjustmentError) as info:
        calibrate_from_observations(obs, ba_options=BundleAdjustmentOptions(max_evaluations=30))
    err = info.value
    msg = str(err)
    print("\n" + msg)
    assert "bundle adjustment did not converge" in msg
    assert "cost" in msg and "function evaluations" in msg
    assert "worst camera 'cam2'" in msg
    assert "same moment" in msg and "synchronise" in msg
    assert err.rms_px["cam2"] > 3.0
    assert err.rms_px["cam2"] == max(err.rms_px.values())


def test_bundle_adjustment_out_of_budget_says_to_raise_it():
    rng = np.random.default_rng(5)
    rig, corners = _three_camera_data(rng, n=12)
    obs = BoardObservations(CHARUCO, rig.names, [c.size for c in rig], corners)
    with pytest.raises(BundleAdjustmentError) as info:
        calibrate_from_observations(obs, ba_options=BundleAdjustmentOptions(max_evaluations=1, max_rms_px=0.05))
    msg = str(info.value)
    assert "after 1 function evaluations" in msg
    assert "raise the evaluation budget" in msg and "--ba-max-evaluations" in msg


def test_floor_view_must_exist():
    rng = np.random.default_rng(6)
    rig, corners = _three_camera_data(rng, n=12)
    obs = BoardObservations(CHARUCO, rig.names, [c.size for c in rig], corners)
    with pytest.raises(CalibrationError, match="floor view 40 is out of range: there are 12 views"):
        calibrate_from_observations(obs, floor_view=40)


def test_cameras_with_different_view_counts(damaged_folder):
    with pytest.raises(InputFileError, match="different numbers of views: a 2, b 1"):
        calibrate_cameras({"a": [damaged_folder / "a_good1.png", damaged_folder / "a_good2.png"],
                           "b": [damaged_folder / "a_good3.png"]}, CHECKER)


def test_symmetric_checkerboard_is_refused_for_several_cameras():
    spec = BoardSpec("checkerboard", (8, 6), 0.03)  # 9x7 squares: same after a half turn
    obs = BoardObservations(spec, ["a", "b"], [(640, 480)] * 2, np.full((2, 3, spec.n_corners, 2), np.nan))
    with pytest.raises(CalibrationError, match="9x7 squares and looks the same turned by 180 deg"):
        calibrate_from_observations(obs)


@pytest.mark.parametrize("taken", ["rig.toml", "rig.yml", "rig.report.json"])
def test_calibrate_out_never_replaces_a_file_it_did_not_write(tmp_path, taken):
    from typer.testing import CliRunner

    from mocap.cli.app import app

    (tmp_path / taken).write_text("the user's own file\n")
    res = CliRunner().invoke(app, ["calibrate", f"cam0={tmp_path / 'nowhere'}", "--out", str(tmp_path / "rig")])
    assert res.exit_code == 2, res.output
    line = " ".join(res.output.split())
    assert f"{tmp_path / taken}: exists and is not a file written by mocap calibrate; it will not be replaced" in line
    assert [p.name for p in tmp_path.iterdir()] == [taken] and (tmp_path / taken).read_text() == "the user's own file\n"


def test_calibrate_out_replaces_its_own_files(tmp_path):
    from mocap.calibrate import calibration_paths, check_calibration_outputs

    cams = tuple(Camera(f"cam{i}", (640, 480), [[600, 0, 320], [0, 600, 240], [0, 0, 1]], np.zeros(5), np.eye(3), [i, 0.0, 3.0])
                 for i in range(2))
    toml_path, yml_path, report_path = calibration_paths(tmp_path / "rig.toml")
    Calibration(cams).save_toml(toml_path)
    Calibration(cams).save_opencv_yaml(yml_path)
    report_path.write_text('{"cameras": ["cam0", "cam1"], "reprojection_rms_px": {}}')
    check_calibration_outputs(tmp_path / "rig")  # a rerun into the same stem: allowed
