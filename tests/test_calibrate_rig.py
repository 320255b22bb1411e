"""Multi-camera calibration on exact synthetic projections (no rendering).

A 4-camera rig watches a ChArUco board moved and tilted through the volume, plus one
view of the board lying on the floor that defines the world frame. Exact projections
plus Gaussian pixel noise go through the whole calibration (Zhang per camera, view
graph, bundle adjustment) and the result is scored against the true cameras with
``eval.calibration_metrics`` without any alignment: the floor board must put the world
where the truth has it.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eval.calibration_metrics import compare_calibrations
from mocap.calib.boards import BoardSpec, board_object_points
from mocap.calib.bundle_adjustment import BundleAdjustmentOptions
from mocap.calib.observations import BoardObservations, WandObservations
from mocap.calib.synthetic import look_at, observe_board
from mocap.calib.wand import WandSpec, label_collinear_wand
from mocap.calib.world_frame import FLOOR_FROM_BOARD
from mocap.calibrate import calibrate_from_observations
from mocap.calibration import Calibration, Camera

NOISE_PX = 0.15
BOARD = BoardSpec("charuco", (7, 5), 0.10, 0.075)
# The world origin is the origin of the board lying on the floor; the rig is centred on
# that board's centre.
CENTRE = FLOOR_FROM_BOARD.T @ board_object_points(BOARD).mean(axis=0)


def make_rig() -> Calibration:
    """Four 640x480 webcams 2 m from the volume centre, spread over 125 deg, with lens distortion."""
    dists = [[-0.12, 0.05, 0.0004, -0.0003, 0.0], [-0.08, 0.02, 0.0, 0.0, 0.0],
             [-0.20, 0.10, 0.0008, 0.0, -0.02], [-0.05, 0.0, 0.0, 0.0005, 0.0]]
    cams = []
    for i, az in enumerate([-60.0, -20.0, 25.0, 65.0]):
        a = np.radians(az)
        centre = CENTRE + np.array([2.0 * np.sin(a), -2.0 * np.cos(a), 1.8 + 0.3 * (i % 2)])
        R, t = look_at(centre, CENTRE + [0.0, 0.0, 0.8])
        f = 600.0 + 25.0 * i
        K = [[f, 0, 320 + 3 * i], [0, f * 1.002, 240 - 2 * i], [0, 0, 1]]
        cams.append(Camera(f"cam{i}", (640, 480), K, dists[i], R, t))
    return Calibration(tuple(cams))


def board_poses(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """View 0: board on the floor defining the world; then ``n`` tilted poses facing the cameras."""
    obj = board_object_points(BOARD)
    centre = obj.mean(axis=0)
    Rs = [FLOOR_FROM_BOARD.T]  # world-from-board of a board lying printed face up at the origin
    ts = [np.zeros(3)]
    facing = Rotation.from_euler("x", -90, degrees=True)  # board +z (into the board) along world +y
    for _ in range(n):
        tilt = Rotation.from_euler("xyz", [rng.uniform(-45, 45), rng.uniform(-45, 45), rng.uniform(-30, 30)], degrees=True)
        R = (tilt * facing).as_matrix()
        pos = CENTRE + np.array([rng.uniform(-0.9, 0.9), rng.uniform(-0.9, 0.9), 1.0 + rng.uniform(-0.9, 0.9)])
        Rs.append(R)
        ts.append(pos - R @ centre)
    return np.array(Rs), np.array(ts)


@pytest.fixture(scope="module")
def rig_and_views():
    rng = np.random.default_rng(5)
    rig = make_rig()
    R_wb, t_wb = board_poses(rng, 60)
    corners = observe_board(rig, R_wb, t_wb, BOARD, rng=rng, noise_px=NOISE_PX)
    return rig, R_wb, t_wb, corners


def test_floor_view_is_seen_by_every_camera(rig_and_views):
    _, _, _, corners = rig_and_views
    seen = np.isfinite(corners[:, 0, :, 0]).sum(axis=1)
    assert (seen >= BOARD.n_corners // 2).all(), seen


@pytest.fixture(scope="module")
def floor_calibration(rig_and_views):
    rig, _, _, corners = rig_and_views
    obs = BoardObservations(BOARD, rig.names, [c.size for c in rig], corners)
    return calibrate_from_observations(obs, floor_view=0)


def test_board_calibration_meets_targets(rig_and_views, floor_calibration):
    rig = rig_and_views[0]
    res = floor_calibration
    scores = compare_calibrations(res.calibration, rig, align="rigid", reprojection_rms_px=res.reprojection_rms_px)
    s = scores["summary"]
    print("\nboard-only 4-camera rig, noise", NOISE_PX, "px, rigid alignment on camera centres:",
          {k: round(v, 4) for k, v in s.items() if not k.endswith("_mean")},
          res.bundle_adjustment["evaluations"], "evaluations")
    assert s["focal_error_pct"] < 0.5
    assert s["rotation_error_deg"] < 0.1
    assert s["translation_error_mm"] < 2.0
    assert s["principal_point_error_px"] < 2.0
    assert s["distortion_error_px"] < 2.0
    # RMS of a 2D residual whose coordinates have noise sigma is sqrt(2) sigma (minus a
    # little for the fitted parameters).
    expected = np.sqrt(2) * NOISE_PX
    for name, rms in res.reprojection_rms_px.items():
        assert 0.85 * expected < rms < 1.1 * expected, (name, rms)
    # The bundle adjustment lowers the error of the chained first guess.
    assert res.bundle_adjustment["cost"] < 0.5 * res.bundle_adjustment["initial_cost"]


def test_floor_view_defines_the_world(rig_and_views, floor_calibration):
    """No alignment at all: the world comes from the one floor view (its pose error is the limit)."""
    rig, R_wb, t_wb, _ = rig_and_views
    res = floor_calibration
    s = compare_calibrations(res.calibration, rig, align="none")["summary"]
    print("\nfloor frame, no alignment:", {k: round(s[k], 4) for k in ("rotation_error_deg", "translation_error_mm")})
    # One floor view seen at grazing angles: a 0.1 deg tilt of the floor plane moves
    # cameras 3 m away by 5 mm.
    assert s["rotation_error_deg"] < 0.2
    assert s["translation_error_mm"] < 6.0
    centres = np.stack([c.center for c in res.calibration])
    true_centres = np.stack([c.center for c in rig])
    np.testing.assert_allclose(centres[:, 2], true_centres[:, 2], atol=0.006)  # heights above the floor
    est = res.board_poses_world
    ok = np.isfinite(est[:, 0, 3])
    assert ok.sum() > 50
    assert np.max(np.linalg.norm(est[ok, :3, 3] - t_wb[ok], axis=1)) < 0.008


def wand_frames(rng: np.random.Generator, n: int, wand: WandSpec) -> np.ndarray:
    """Collinear wand positions ``(n, 3, 3)`` waved through the volume."""
    centre = CENTRE + np.array([0.0, 0.0, 1.0]) + rng.uniform(-0.7, 0.7, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d01, d12, _ = wand.distances_m
    return np.stack([centre, centre + d01 * d, centre + (d01 + d12) * d], axis=1)


def observe_points(rig: Calibration, points: np.ndarray, rng: np.random.Generator, noise_px: float) -> np.ndarray:
    F = points.shape[0]
    px = rig.project(points.reshape(-1, 3)).reshape(len(rig), F, 3, 2)
    for c, cam in enumerate(rig):
        inside = cam.in_image(px[c].reshape(-1, 2), margin_px=3).reshape(F, 3)
        px[c][~inside] = np.nan
    return px + rng.normal(0.0, noise_px, px.shape)


def test_wand_alone_fixes_the_scale():
    """Known intrinsics, no shared board view: the wand gives poses and the metric scale."""
    rng = np.random.default_rng(11)
    rig = make_rig()
    wand = WandSpec.collinear(0.2, 0.3)
    truth_pts = wand_frames(rng, 100, wand)
    px = observe_points(rig, truth_pts, rng, NOISE_PX)
    no_board = BoardObservations(BOARD, rig.names, [c.size for c in rig], np.zeros((4, 0, BOARD.n_corners, 2)))
    res = calibrate_from_observations(no_board, wand=wand, wand_observations=WandObservations(rig.names, px),
                                      known_intrinsics=rig, ba_options=BundleAdjustmentOptions(refine_intrinsics=False))
    sim = compare_calibrations(res.calibration, rig, align="similarity")
    rigid = compare_calibrations(res.calibration, rig, align="rigid")
    print("\nwand only: scale", sim["alignment"]["scale"], "wand distance RMS mm", res.wand_distance_rms_mm,
          {k: round(v, 4) for k, v in rigid["summary"].items() if k in ("rotation_error_deg", "translation_error_mm")})
    assert abs(sim["alignment"]["scale"] - 1.0) < 1e-3
    assert rigid["summary"]["translation_error_mm"] < 2.0
    assert rigid["summary"]["rotation_error_deg"] < 0.1
    assert res.wand_distance_rms_mm < 0.5
    # Reconstructed wand markers match the truth once the worlds are aligned.
    R = np.eye(3)
    c0 = rig[0]
    est = res.wand_points_world  # in cam0's frame
    truth_in_cam0 = truth_pts @ c0.R.T + c0.t
    ok = np.isfinite(est).all(axis=(1, 2))
    assert ok.sum() > 80
    assert np.sqrt(np.mean(np.sum((est[ok] - truth_in_cam0[ok] @ R.T) ** 2, axis=2))) < 0.003


def test_wand_without_scale_info_would_be_wrong_by_the_baseline():
    """The same wand data with wrong distances scales the rig by the same factor (scale comes from the wand)."""
    rng = np.random.default_rng(12)
    rig = make_rig()
    wand = WandSpec.collinear(0.2, 0.3)
    px = observe_points(rig, wand_frames(rng, 40, wand), rng, NOISE_PX)
    no_board = BoardObservations(BOARD, rig.names, [c.size for c in rig], np.zeros((4, 0, BOARD.n_corners, 2)))
    wrong = WandSpec.collinear(0.22, 0.33)  # 10 % too long
    res = calibrate_from_observations(no_board, wand=wrong, wand_observations=WandObservations(rig.names, px),
                                      known_intrinsics=rig, ba_options=BundleAdjustmentOptions(refine_intrinsics=False))
    sim = compare_calibrations(res.calibration, rig, align="similarity")
    assert abs(1.0 / sim["alignment"]["scale"] - 1.1) < 2e-3


def test_board_plus_wand_refinement(rig_and_views):
    """20 board views and an L-shaped wand: the wand points and distances join the bundle adjustment."""
    rig, _, _, corners = rig_and_views
    rng = np.random.default_rng(13)
    wand = WandSpec((0.25, 0.20, 0.35))  # an L-shaped (non-collinear) wand
    d01, d12, d02 = wand.distances_m
    # Build a triangle with these sides and move it through the volume.
    x = (d01 ** 2 + d02 ** 2 - d12 ** 2) / (2 * d01)
    tri = np.array([[0, 0, 0], [d01, 0, 0], [x, np.sqrt(d02 ** 2 - x ** 2), 0.0]])
    n = 40
    rots = Rotation.random(n, random_state=np.random.RandomState(3)).as_matrix()
    pts = np.einsum("fij,mj->fmi", rots, tri) + (CENTRE + np.array([0, 0, 1.0]) + rng.uniform(-0.6, 0.6, (n, 3)))[:, None, :]
    px = observe_points(rig, pts, rng, NOISE_PX)
    obs = BoardObservations(BOARD, rig.names, [c.size for c in rig], corners[:, :21])
    res = calibrate_from_observations(obs, wand=wand, wand_observations=WandObservations(rig.names, px))
    s = compare_calibrations(res.calibration, rig, align="rigid")["summary"]
    print("\nboard (20 views) + wand (40 frames):", {k: round(s[k], 4) for k in ("focal_error_pct", "rotation_error_deg", "translation_error_mm")},
          "wand distance RMS mm", res.wand_distance_rms_mm)
    # Fewer board views than the main test: the principal points (hence the rotations)
    # are less certain; the wand mostly pins the extrinsics and the scale.
    assert s["focal_error_pct"] < 0.5
    assert s["rotation_error_deg"] < 0.3
    assert s["translation_error_mm"] < 2.0
    assert res.wand_distance_rms_mm < 0.5
    # Wand markers, brought to the true world through cam0's true pose.
    c0 = rig[0]
    ok = np.isfinite(res.wand_points_world).all(axis=(1, 2))
    truth_cam0 = pts @ c0.R.T + c0.t
    err = np.linalg.norm(res.wand_points_world[ok] - truth_cam0[ok], axis=2)
    assert ok.sum() > 30
    assert np.sqrt(np.mean(err ** 2)) < 0.003


def test_collinear_wand_blobs_are_labelled():
    rng = np.random.default_rng(14)
    rig = make_rig()
    wand = WandSpec.collinear(0.2, 0.3)
    px = observe_points(rig, wand_frames(rng, 50, wand), rng, 0.1)
    shuffled = px.copy()
    for c in range(px.shape[0]):
        for f in range(px.shape[1]):
            shuffled[c, f] = px[c, f, rng.permutation(3)]
    labelled = label_collinear_wand(shuffled, wand)
    complete = np.isfinite(px).all(axis=(2, 3))
    got = np.isfinite(labelled).all(axis=(2, 3))
    assert got.sum() >= 0.95 * complete.sum()
    np.testing.assert_array_equal(labelled[got], px[got])
    with pytest.raises(ValueError, match="too alike"):
        label_collinear_wand(shuffled, WandSpec.collinear(0.25, 0.25))
