"""Boards: object points, the printable texture and its frame, and corner detection.

Detection is checked against exact corners: the board texture is mapped through a
camera with lens distortion at a known pose (``mocap.calib.synthetic``), blurred and
noised, and the detected corners are compared with the projected object points. This
also checks that the texture's documented origin and axes are where the detector and
``board_object_points`` put them.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocap.calib.board_detection import detect_board
from mocap.calib.boards import BoardSpec, board_object_points, board_texture_layout, render_board_texture
from mocap.calib.synthetic import board_corners_in_image, render_board_view
from mocap.calibration import Camera

CAM = Camera("c", (640, 480), [[600, 0, 322], [0, 600, 238], [0, 0, 1]], [-0.15, 0.05, 0.0005, -0.0003, 0.0])
CHECKER = BoardSpec("checkerboard", (9, 6), 0.03)
CHARUCO = BoardSpec("charuco", (7, 5), 0.04, 0.03)


def test_spec_validation_names_the_field():
    with pytest.raises(ValueError, match="marker_length_m"):
        BoardSpec("charuco", (7, 5), 0.04)
    with pytest.raises(ValueError, match="inner corners"):
        BoardSpec("checkerboard", (1, 6), 0.03)
    with pytest.raises(ValueError, match="dictionary"):
        BoardSpec("charuco", (7, 5), 0.04, 0.03, dictionary="DICT_NOPE")
    with pytest.raises(ValueError, match="square_length_m"):
        BoardSpec("checkerboard", (9, 6), -1.0)


def test_object_points():
    p = board_object_points(CHECKER)
    assert p.shape == (54, 3)
    np.testing.assert_allclose(p[0], [0, 0, 0])
    np.testing.assert_allclose(p[1], [0.03, 0, 0])  # along a row: +x
    np.testing.assert_allclose(p[9], [0, 0.03, 0])  # next row: +y
    q = board_object_points(CHARUCO)
    assert q.shape == (24, 3) and CHARUCO.n_corners == 24
    np.testing.assert_allclose(q[0], [0.04, 0.04, 0])  # ChArUco origin: outer corner of the board
    np.testing.assert_allclose(q[-1], [0.24, 0.16, 0])


@pytest.mark.parametrize("spec", [CHECKER, CHARUCO], ids=["checkerboard", "charuco"])
def test_texture_layout_puts_the_origin_at_a_corner(spec):
    ppm = 2000.0
    tex = render_board_texture(spec, ppm)
    lay = board_texture_layout(spec, ppm)
    assert tex.shape == (lay.size_px[1], lay.size_px[0]) and tex.dtype == np.uint8
    sq = int(round(spec.square_length_m * ppm))
    assert lay.size_m[0] == pytest.approx(lay.size_px[0] / lay.px_per_m)
    ox, oy = lay.origin_px
    # Sample 1/16 of a square from the origin in each diagonal direction (ChArUco markers
    # leave a white border of 1/8 square inside their squares).
    q = sq / 16

    def at(dx, dy):
        return int(tex[int(round(oy + dy)), int(round(ox + dx))])

    if spec.kind == "checkerboard":
        # Origin = first inner corner: black squares up-left and down-right of it.
        assert at(-q, -q) == 0 and at(q, q) == 0 and at(q, -q) == 255 and at(-q, q) == 255
    else:
        # Origin = outer top-left corner of the board: white margin outside, black square inside.
        assert at(-q, -q) == 255 and at(q, -q) == 255 and at(q, q) == 0
    # The last corner is where the object points say, in texture pixels.
    last = board_object_points(spec)[-1]
    u, v = ox + last[0] * lay.px_per_m, oy + last[1] * lay.px_per_m
    assert int(tex[int(round(v - q)), int(round(u - q))]) != int(tex[int(round(v - q)), int(round(u + q))])
    np.testing.assert_allclose(lay.texture_to_board(np.array([[u, v]]))[0], last, atol=1e-12)


def _pose(spec: BoardSpec, tilt_xy_deg, spin_deg: float, dist_m: float, offset=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    centre = board_object_points(spec).mean(axis=0)
    R = Rotation.from_euler("xyz", [tilt_xy_deg[0], tilt_xy_deg[1], spin_deg], degrees=True).as_matrix()
    t = np.array([offset[0], offset[1], dist_m]) - R @ centre
    return R, t


@pytest.mark.parametrize("spec", [CHECKER, CHARUCO], ids=["checkerboard", "charuco"])
def test_detected_corners_match_exact_projections(spec):
    rng = np.random.default_rng(7)
    errors = []
    # Includes a board upside down (spin 180 deg): the corner numbering must follow the board.
    for tilt, spin, dist in [((25, -30), 10.0, 0.55), ((-35, 20), 180.0, 0.6), ((10, 40), -95.0, 0.5)]:
        R, t = _pose(spec, tilt, spin, dist)
        img = render_board_view(CAM, R, t, spec, px_per_m=4000, blur_sigma_px=0.7, noise_sigma=2.0, rng=rng)
        det = detect_board(img, spec)
        assert det.found, det.detail
        truth = board_corners_in_image(CAM, R, t, spec)
        assert det.n_corners == spec.n_corners
        err = np.linalg.norm(det.corners_px - truth[det.corner_ids], axis=1)
        errors.append(err)
    err = np.concatenate(errors)
    print(f"\n{spec.kind}: corner error mean {err.mean():.3f} px, max {err.max():.3f} px over {err.size} corners")
    assert err.mean() < 0.06
    assert err.max() < 0.3


def test_charuco_partial_view_keeps_true_ids():
    rng = np.random.default_rng(8)
    R, t = _pose(CHARUCO, (15, -20), 5.0, 0.45, offset=(0.17, 0.0))  # right part beyond the image edge
    truth = board_corners_in_image(CAM, R, t, CHARUCO)
    inside = CAM.in_image(truth, margin_px=15)
    assert 6 <= inside.sum() < CHARUCO.n_corners
    img = render_board_view(CAM, R, t, CHARUCO, px_per_m=4000, blur_sigma_px=0.6, noise_sigma=1.0, rng=rng)
    det = detect_board(img, CHARUCO)
    assert det.found and det.n_corners < CHARUCO.n_corners
    assert set(det.corner_ids.tolist()) <= set(np.flatnonzero(CAM.in_image(truth)).tolist())
    err = np.linalg.norm(det.corners_px - truth[det.corner_ids], axis=1)
    assert err.max() < 0.3


def test_charuco_board_cut_off_is_diagnosed():
    rng = np.random.default_rng(9)
    R, t = _pose(CHARUCO, (0, 0), 0.0, 0.45, offset=(0.33, 0.0))  # mostly outside, a few markers visible
    img = render_board_view(CAM, R, t, CHARUCO, px_per_m=4000, noise_sigma=1.0, rng=rng)
    det = detect_board(img, CHARUCO)
    assert not det.found
    assert det.problem == "cut off" and "right" in det.detail
