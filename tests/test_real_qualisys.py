"""Real walking capture (Qualisys.c3d, 55 markers, 200 Hz) through a virtual 4-camera rig:
detections -> 2D tracking -> reconstruction, scored against the C3D itself.

Geometry only: the C3D markers are projected into four 1280x960 cameras around the
walkway (mild lens distortion), with 0.1 px detection noise, occlusion by distance
ordering (a marker whose blob overlaps a nearer marker's blob is hidden in that camera)
and shuffled detection order. Labels are given at frame 0 from the true projections, as
a user's manual labelling would (the first frame is mid-walk, not a T-pose).
"""

from __future__ import annotations


import ezc3d
import numpy as np
import pytest

from mocap.calibration import Calibration, Camera
from mocap.reconstruction import ReconstructionParams, reconstruct
from mocap.tracking import track_cameras
from mocap.types import Detections
from mocap.calib.synthetic import look_at

RATE_HZ = 200.0
NOISE_PX = 0.1
MARKER_RADIUS_M = 0.007


@pytest.fixture(scope="module")
def capture(shared_data):
    """C3D markers, the rig, and every camera's shuffled noisy detections."""
    c3d = ezc3d.c3d(str(shared_data / "c3d" / "Qualisys.c3d"))
    assert c3d["parameters"]["POINT"]["UNITS"]["value"][0] == "mm"
    assert float(c3d["parameters"]["POINT"]["RATE"]["value"][0]) == RATE_HZ
    labels = list(c3d["parameters"]["POINT"]["LABELS"]["value"])
    xyz = c3d["data"]["points"][:3].transpose(2, 1, 0) / 1000.0          # (F, M, 3) m
    F, M, _ = xyz.shape
    assert M == 55 and np.isfinite(xyz).all()

    # Four cameras at the corners of the walkway, 2.6 m up, aimed at its middle.
    lo, hi = xyz.reshape(-1, 3).min(axis=0), xyz.reshape(-1, 3).max(axis=0)
    centre = 0.5 * (lo + hi)
    cams = []
    for i, (dx, dy) in enumerate([(-3.5, -3.0), (3.5, -3.0), (3.5, 3.0), (-3.5, 3.0)]):
        R, t = look_at([centre[0] + dx, centre[1] + dy, 2.6], [centre[0], centre[1], 0.8])
        K = [[950.0, 0, 640.5], [0, 951.0, 479.5], [0, 0, 1]]
        cams.append(Camera(f"cam{i}", (1280, 960), K, [-0.06, 0.015, 0.0005, -0.0005, 0.0], R, t))
    cal = Calibration(tuple(cams))

    rng = np.random.default_rng(2024)
    true_px = np.stack([cal.project(x) for x in xyz])                       # (F, C, M, 2)
    assert all(cam.in_image(true_px[:, c].reshape(-1, 2), 5).all() for c, cam in enumerate(cal))
    depth = np.stack([np.stack([cam.to_camera(x)[:, 2] for cam in cal]) for x in xyz])   # (F, C, M)
    radius_px = 950.0 * MARKER_RADIUS_M / depth
    gap = np.linalg.norm(true_px[:, :, :, None] - true_px[:, :, None, :], axis=-1)
    overlap = gap < radius_px[..., :, None] + radius_px[..., None, :]
    hidden = (overlap & (depth[..., None, :] < depth[..., :, None])).any(axis=-1)  # a nearer blob covers it
    observed = true_px + rng.normal(0.0, NOISE_PX, true_px.shape)
    detections = []
    for c in range(len(cal)):
        per_frame = []
        for f in range(F):
            order = rng.permutation(np.flatnonzero(~hidden[f, c]))
            per_frame.append(Detections.from_points(observed[f, c, order]))
        detections.append(per_frame)
    initial = np.where(hidden[0][..., None], np.nan, observed[0])           # manual labels, frame 0
    return dict(labels=labels, xyz=xyz, cal=cal, hidden=hidden, detections=detections,
                initial=initial, times=np.arange(F) / RATE_HZ, true_px=true_px)


def test_occlusion_is_realistic(capture) -> None:
    hidden = capture["hidden"]
    # Some markers are hidden in some views, but every marker-frame stays visible in >= 2.
    assert 0.005 < hidden.mean() < 0.1
    assert ((~hidden).sum(axis=1) >= 2).all()


def test_tracking_and_reconstruction_recover_the_c3d(capture) -> None:
    labels, xyz, cal = capture["labels"], capture["xyz"], capture["cal"]
    tracks = track_cameras(capture["detections"], capture["initial"], labels, cal.names,
                           tracker="kalman", dt=1.0 / RATE_HZ, rng=np.random.default_rng(7))
    # Thresholds matched to the detection noise (0.1 px): ~6 sigma.
    params = ReconstructionParams(epipolar_threshold_px=1.0, max_residual_px=0.6, max_gap_frames=10)
    traj = reconstruct(tracks, cal, params, capture["times"], detections=capture["detections"])
    assert traj.labels == labels

    err = np.linalg.norm(traj.xyz - xyz, axis=2)                          # (F, M) metres
    rmse_mm = 1e3 * np.sqrt(np.nanmean(err**2))
    print(f"Qualisys: RMSE {rmse_mm:.3f} mm, max {1e3 * np.nanmax(err):.2f} mm, "
          f"reconstructed {np.isfinite(err).mean():.4f}, filled {int(traj.filled.sum())}")
    assert rmse_mm <= 1.0
    # No label lost for good: every label is reconstructed in the last frames.
    assert np.isfinite(traj.xyz[-10:]).all()
    assert np.isfinite(err).mean() > 0.99
    # No swaps: no label is ever reconstructed near another marker instead of its own.
    assert np.nanmax(err) < 0.006
    # The views used are the markers' own detections (labels right in 2D as well).
    assert np.nanmax(traj.residual_px) < 0.6


def test_reconstruction_from_labelled_views(capture) -> None:
    """Reconstruction alone (no tracker in the loop): the RMSE matches the noise floor."""
    true_px, hidden, cal = capture["true_px"], capture["hidden"], capture["cal"]
    from mocap.types import Tracks2D

    xy = true_px + np.random.default_rng(3).normal(0.0, NOISE_PX, true_px.shape)
    xy[hidden] = np.nan
    tracks = Tracks2D(capture["labels"], xy, xy.copy(), np.where(hidden, 0, 1).astype(np.int8), cal.names)
    traj = reconstruct(tracks, cal, ReconstructionParams(relabel_gate_px=0.0), capture["times"])
    err = np.linalg.norm(traj.xyz - capture["xyz"], axis=2)
    assert np.isfinite(err).all()
    assert 1e3 * np.sqrt(np.mean(err**2)) < 0.8
    assert np.all(traj.n_views == (~hidden).sum(axis=1))
