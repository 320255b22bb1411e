"""The row-time triangulation of rolling-shutter views (issue 15, mocap.rolling_shutter): every
view at its own row's instant, a marker's frames solved together with its motion between them."""

from __future__ import annotations

import numpy as np

from mocap.calibration import Calibration, Camera
from mocap.rolling_shutter import _lagrange_rows, _stencils, row_time_trajectories, triangulate_row_times
from mocap.triangulation import pixels_to_normalized, triangulate
from mocap.types import Detections, Tracks2D, Trajectories

READOUT = 0.025                      # s, a 30 fps webcam's
TIMES = np.arange(12) / 30.0         # (F,) s, frame timestamps (row 0's instant)
V = np.array([2.5, -1.5, 1.0])       # m/s, 3.1 m/s: a hand on a fast sweep


def _rig() -> Calibration:
    """Three 640 x 480 cameras 3 m from the origin, 2 m up, looking at (0, 0, 1)."""
    K = np.array([[700.0, 0, 320], [0, 700.0, 240], [0, 0, 1]])
    cams = []
    for i, ang in enumerate((0.0, 1.8, 3.9)):
        c = np.array([3 * np.cos(ang), 3 * np.sin(ang), 2.0])
        z = (np.array([0, 0, 1.0]) - c) / np.linalg.norm(np.array([0, 0, 1.0]) - c)
        x = np.cross(z, [0, 0, 1.0])
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])
        cams.append(Camera(f"c{i}", (640, 480), K, np.zeros(5), R, -R @ c))
    return Calibration(tuple(cams))


def _path(t: np.ndarray) -> np.ndarray:
    """(T, 3) m: a marker at constant velocity ``V``."""
    return np.array([0.1, 0.2, 1.0]) + np.asarray(t, float)[:, None] * V


def _rolling_views(cal: Calibration, path=_path) -> tuple[np.ndarray, np.ndarray]:
    """Where a rolling shutter shows the marker: ``(F, C, 2)`` px and the rows' instants ``(F, C)`` s
    (the fixed point of ``uv = project(X(t + v / H * readout))``)."""
    uv = np.zeros((len(TIMES), len(cal), 2))
    tau = np.zeros((len(TIMES), len(cal)))
    for c, cam in enumerate(cal):
        p = cam.project(path(TIMES))
        for _ in range(30):
            tau[:, c] = TIMES + p[:, 1] / cam.size[1] * READOUT
            p = cam.project(path(tau[:, c]))
        uv[:, c] = p
    return uv, tau


def _rows(cal: Calibration, uv: np.ndarray, depth_at: np.ndarray):
    """The DLT rows ``A (N, 2, 3)`` px/m, ``b (N, 2)`` px of views ``uv (F, C, 2)`` (frame-major),
    scaled by focal / depth of the points ``depth_at (F, 3)``."""
    A, b = [], []
    for k in range(uv.shape[0]):
        for c, cam in enumerate(cal):
            x, y = pixels_to_normalized(cam, uv[k, c][None])[0]
            s = cam.K[0, 0] / cam.to_camera(depth_at[k][None])[0, 2]
            A.append(np.stack([x * cam.R[2] - cam.R[0], y * cam.R[2] - cam.R[1]]) * s)
            b.append(np.array([x * cam.t[2] - cam.t[0], y * cam.t[2] - cam.t[1]]) * s)
    return np.array(A), np.array(b)


def test_row_time_triangulation_recovers_a_constant_velocity_marker_exactly():
    """Views at their rows' instants (9-15 ms after the timestamp): triangulated as if
    simultaneous they put the marker over 20 mm from where it was at the timestamp; solved with
    the instants, at the positions to a hundredth of a millimetre (the prior's pull, at the
    first frame, which only one interval's views see)."""
    cal = _rig()
    uv, tau = _rolling_views(cal)
    truth = _path(TIMES)
    frame_time = triangulate(uv.transpose(1, 0, 2), cal).points            # (F, 3) m
    assert np.linalg.norm(frame_time - truth, axis=1).min() > 0.02
    F, C = tau.shape
    k = np.repeat(np.arange(F), C)
    J = _stencils(np.ones(F, bool))[k]
    w = _lagrange_rows(TIMES, J, tau.reshape(-1))
    A, b = _rows(cal, uv, frame_time)
    solved = triangulate_row_times(J, w, A, b, prior=frame_time)
    assert np.abs(solved - truth).max() < 1e-5


def test_the_fourth_difference_keeps_a_position_alternating_frame_to_frame_out():
    """Every view half-way through the frame interval: the cubic's weights (-1, 9, 9, -1) / 16
    cancel a position alternating from frame to frame, so inside the take the views cannot see
    it, and 0.1 px of noise on them grows into millimetres of it; the fourth-difference term,
    which costs that pattern 16 times its size, takes it out."""
    cal = _rig()
    F, C = 30, len(cal)
    times = np.arange(F) / 30.0
    tau = np.repeat(times + 0.5 / 30.0, C)
    uv = np.stack([cam.project(_path(tau.reshape(F, C)[:, c])) for c, cam in enumerate(cal)], axis=1)
    k = np.repeat(np.arange(F), C)
    J = _stencils(np.ones(F, bool))[k]
    w = _lagrange_rows(times, J, tau)
    inner = (k >= 1) & (k <= F - 3)
    assert np.abs((w * (-1.0) ** J).sum(axis=1)[inner]).max() < 1e-12
    truth = _path(times)
    A, b = _rows(cal, uv + np.random.default_rng(0).normal(0.0, 0.1, uv.shape), truth)

    def rms_mm(smooth):
        return np.sqrt(np.mean(np.sum((triangulate_row_times(J, w, A, b, truth, smooth=smooth) - truth) ** 2, axis=1))) * 1e3

    loose, tight = rms_mm(0.0), rms_mm(10.0)
    assert loose > 1.5 and tight < 0.8


def _capture(cal: Calibration, offsets_px: dict[int, float], gap: range):
    """A capture of one marker as :func:`row_time_trajectories` takes it: raw blobs at their rows,
    the blobs it triangulated (moved to the timestamps; ``offsets_px`` px off along x at some
    frames, as a wrong motion moves them), its points, no views in the frames of ``gap``."""
    uv, _ = _rolling_views(cal)
    F, C = uv.shape[:2]
    moved = np.stack([cam.project(_path(TIMES)) for cam in cal], axis=1)          # (F, C, 2) px
    for f, dx in offsets_px.items():
        moved[f, :, 0] += dx
    moved[list(gap)] = np.nan
    raw = [[Detections(uv[f, c][None], np.full(1, 20.0), np.full(1, 200.0)) for f in range(F)] for c in range(C)]
    used = [[Detections(moved[f, c][None] if f not in gap else np.zeros((0, 2)), np.full(1 if f not in gap else 0, 20.0),
                        np.full(1 if f not in gap else 0, 200.0)) for f in range(F)] for c in range(C)]
    tracks = Tracks2D(["M"], moved[:, :, None], moved[:, :, None], np.ones((F, C, 1), np.int8), cal.names)
    start = Trajectories(["M"], triangulate(moved.transpose(1, 0, 2), cal).points[:, None], TIMES,
                         np.zeros((F, 1), bool), np.zeros((F, 1)), np.where(np.isin(np.arange(F), gap), 0, C)[:, None])
    return raw, used, tracks, start


def test_row_time_trajectories_solves_inside_runs_and_checks_the_edges_of_gaps():
    """Frames 4-5 without views. Inside the runs the raw views give the positions whatever the
    capture's points; at a gap's edge the capture's point stays when the solution agrees within
    ``edge_mm`` (frame 3, about 1 mm off), and is dropped when it does not (frame 6, 20 mm off)."""
    cal = _rig()
    raw, used, tracks, start = _capture(cal, {2: 2.0, 3: 1.0, 6: 3.0, 8: 2.0}, range(4, 6))
    truth = _path(TIMES)
    err = np.linalg.norm(start.xyz[:, 0] - truth, axis=1)
    assert err[2] > 1.5e-3 and 0.5e-3 < err[3] < 5e-3 and err[6] > 10e-3 and err[8] > 1.5e-3
    everywhere = row_time_trajectories(raw, used, tracks, TIMES, READOUT, cal, start)
    assert np.isnan(everywhere.xyz[4:6]).all()
    assert np.abs(everywhere.xyz[[0, 1, 2, 3, 6, 7, 8, 9, 10, 11], 0] - truth[[0, 1, 2, 3, 6, 7, 8, 9, 10, 11]]).max() < 1e-4
    checked = row_time_trajectories(raw, used, tracks, TIMES, READOUT, cal, start, edge_mm=5.0)
    inner = [1, 2, 7, 8, 9, 10]
    assert np.abs(checked.xyz[inner, 0] - truth[inner]).max() < 1e-4
    assert np.array_equal(checked.xyz[[0, 3, 11], 0], start.xyz[[0, 3, 11], 0])    # edges that agree: as they were
    assert np.isnan(checked.xyz[6, 0]).all() and checked.n_views[6, 0] == 0
    # readout 0: a global shutter's capture is returned as it is
    assert row_time_trajectories(raw, used, tracks, TIMES, 0.0, cal, start) is start
