"""reconstruct(): labelled 2D tracks of a rig -> 3D trajectories, against ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.calibration import Calibration, Camera
from mocap.reconstruction import ReconstructionParams, reconstruct, relabel_views
from mocap.types import Detections, Tracks2D
from mocap.calib.synthetic import look_at

RATE = 100.0
F, M = 150, 8


def ring_rig(n: int = 4) -> Calibration:
    cams = []
    for i, a in enumerate(np.linspace(0, 2 * np.pi, n, endpoint=False) + 0.3):
        R, t = look_at([4.0 * np.cos(a), 4.0 * np.sin(a), 2.0], [0.0, 0.0, 1.0])
        cams.append(Camera(f"cam{i}", (640, 480), [[550, 0, 321], [0, 552, 238], [0, 0, 1]], [-0.1, 0.02, 0.0005, -0.001, 0.0], R, t))
    return Calibration(tuple(cams))


def motion(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Times (F,) s and smooth marker paths (F, M, 3) m inside the volume."""
    t = np.arange(F) / RATE
    base = rng.uniform([-0.5, -0.5, 0.3], [0.5, 0.5, 1.7], (M, 3))
    amp = rng.uniform(0.05, 0.3, (M, 3))
    freq = rng.uniform(0.3, 1.5, (M, 3))
    phase = rng.uniform(0, 2 * np.pi, (M, 3))
    return t, base + amp * np.sin(2 * np.pi * freq * t[:, None, None] + phase)


def make_tracks(cal: Calibration, xyz: np.ndarray, rng: np.random.Generator, noise_px: float) -> Tracks2D:
    C = len(cal)
    xy = np.stack([cal.project(x) for x in xyz]) + rng.normal(0, noise_px, (F, C, M, 2))
    status = np.where(np.isfinite(xy).all(axis=3), 1, 0).astype(np.int8)
    return Tracks2D([f"m{k}" for k in range(M)], xy, xy.copy(), status, cal.names)


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    d = np.linalg.norm(a - b, axis=-1)
    return float(np.sqrt(np.nanmean(d**2)))


def test_reconstruct_with_occlusion_swaps_and_gaps() -> None:
    rng = np.random.default_rng(0)
    cal = ring_rig()
    t, xyz = motion(rng)
    # 0.1 px at ~4 m with f = 550 px: ~0.7 mm per view, ~0.85 mm 3D RMSE from 4 views.
    tracks = make_tracks(cal, xyz, rng, noise_px=0.1)
    # Occlusions: marker 3 seen by 2 cameras only for a while (still triangulated).
    tracks.xy[20:60, :2, 3] = np.nan
    # Marker 4: seen by one camera for 6 frames (short gap) and 15 frames (long gap).
    tracks.xy[40:46, 1:, 4] = np.nan
    tracks.xy[90:105, 1:, 4] = np.nan
    # A label swap in camera 2 for markers 0 and 1 during 10 frames.
    tracks.xy[70:80, 2, [0, 1]] = tracks.xy[70:80, 2, [1, 0]]
    traj = reconstruct(tracks, cal, ReconstructionParams(max_gap_frames=10), t)

    assert traj.xyz.shape == (F, M, 3) and traj.labels == tracks.labels
    measured = ~traj.filled & np.isfinite(traj.xyz).all(axis=2)
    assert rmse(traj.xyz[measured], xyz[measured]) < 0.0011
    # The swap is undone by the 3D-guided label correction: all four views used.
    assert np.all(traj.n_views[70:80, :2] == 4)
    assert rmse(traj.xyz[70:80, :2], xyz[70:80, :2]) < 0.0012
    # Without it, the epipolar check drops the swapped view; the others give the point.
    plain = reconstruct(tracks, cal, ReconstructionParams(max_gap_frames=10, relabel_gate_px=0.0), t)
    assert np.all(plain.n_views[70:80, :2] == 3)
    assert rmse(plain.xyz[70:80, :2], xyz[70:80, :2]) < 0.0012
    assert np.all(traj.n_views[20:60, 3] == 2)
    assert rmse(traj.xyz[20:60, 3], xyz[20:60, 3]) < 0.002
    # Short gap filled and flagged; long gap left NaN; nothing else filled.
    assert traj.filled[40:46, 4].all() and traj.filled.sum() == 6
    assert np.abs(traj.xyz[40:46, 4] - xyz[40:46, 4]).max() < 0.002
    assert np.isnan(traj.xyz[90:105, 4]).all() and np.all(traj.n_views[90:105, 4] == 0)
    assert np.isnan(traj.residual_px[40:46, 4]).all()
    assert np.nanmax(traj.residual_px) < 1.0 and np.isfinite(traj.residual_px[measured]).all()
    np.testing.assert_allclose(traj.times, t)


def test_camera_order_follows_track_names() -> None:
    rng = np.random.default_rng(1)
    cal = ring_rig()
    t, xyz = motion(rng)
    tracks = make_tracks(cal, xyz, rng, noise_px=0.3)
    ref = reconstruct(tracks, cal, times=t)
    order = [2, 0, 3, 1]
    shuffled = Tracks2D(tracks.labels, tracks.xy[:, order], tracks.predicted_xy[:, order], tracks.status[:, order], [cal.names[i] for i in order])
    out = reconstruct(shuffled, cal, times=t)
    np.testing.assert_allclose(out.xyz, ref.xyz, atol=1e-9)
    bad = Tracks2D(tracks.labels, tracks.xy, tracks.predicted_xy, tracks.status, ["a", "b", "c", "d"])
    with pytest.raises(ValueError, match="no calibration for"):
        reconstruct(bad, cal, times=t)
    with pytest.raises(ValueError, match="times"):
        reconstruct(tracks, cal)


@pytest.mark.parametrize("smoothing", ["butterworth", "rts"])
def test_smoothing_reduces_error(smoothing: str) -> None:
    rng = np.random.default_rng(2)
    cal = ring_rig()
    t, xyz = motion(rng)
    tracks = make_tracks(cal, xyz, rng, noise_px=1.0)
    raw = reconstruct(tracks, cal, ReconstructionParams(max_residual_px=5.0), t)
    params = ReconstructionParams(max_residual_px=5.0, smoothing=smoothing, cutoff_hz=6.0, rts_accel_std=5.0, rts_meas_std_m=0.003)
    smooth = reconstruct(tracks, cal, params, t)
    e_raw, e_smooth = rmse(raw.xyz, xyz), rmse(smooth.xyz, xyz)
    assert e_smooth < 0.6 * e_raw, (e_raw, e_smooth)


def test_coasting_predictions_only_when_asked() -> None:
    rng = np.random.default_rng(3)
    cal = ring_rig()
    t, xyz = motion(rng)
    tracks = make_tracks(cal, xyz, rng, noise_px=0.1)
    # Marker 5 measured in camera 0 only during 10 frames; camera 1 coasts on a good
    # prediction (here the true projection), cameras 2-3 lost it.
    tracks.predicted_xy[:] = np.stack([cal.project(x) for x in xyz])
    tracks.xy[50:60, 1:, 5] = np.nan
    tracks.status[50:60, 1, 5] = Tracks2D.COASTING
    tracks.status[50:60, 2:, 5] = 0
    tracks.predicted_xy[50:60, 2:, 5] = np.nan
    off = reconstruct(tracks, cal, ReconstructionParams(max_gap_frames=0), t)
    assert np.isnan(off.xyz[50:60, 5]).all()
    on = reconstruct(tracks, cal, ReconstructionParams(max_gap_frames=0, coasting_weight=0.5), t)
    assert np.all(on.n_views[50:60, 5] == 2)
    assert rmse(on.xyz[50:60, 5], xyz[50:60, 5]) < 0.002


def test_relabelling_undoes_swaps_that_become_a_majority() -> None:
    """Labels 0 and 1 swap in camera 0 at frame 20, camera 1 at frame 60 and camera 2 at
    frame 100, for good: from frame 100 three of four cameras are wrong. Each swap is
    caught while it is a minority and the correction is carried forward."""
    rng = np.random.default_rng(4)
    cal = ring_rig()
    t, xyz = motion(rng)
    tracks = make_tracks(cal, xyz, rng, noise_px=0.1)
    for cam, start in ((0, 20), (1, 60), (2, 100)):
        tracks.xy[start:, cam, [0, 1]] = tracks.xy[start:, cam, [1, 0]]
    fixed = relabel_views(tracks, cal, gate_px=3.0, max_residual_px=2.0)
    truth = make_tracks(cal, xyz, np.random.default_rng(4), noise_px=0.0).xy
    assert np.abs(fixed.xy - truth).max() < 1.0          # every view back on its marker
    traj = reconstruct(tracks, cal, ReconstructionParams(), t)
    assert rmse(traj.xyz[:, :2], xyz[:, :2]) < 0.0012
    # Without the correction the labels follow the wrong majority after frame 100.
    plain = reconstruct(tracks, cal, ReconstructionParams(relabel_gate_px=0.0), t)
    assert np.nanmin(np.linalg.norm(plain.xyz[110:, 0] - xyz[110:, 0], axis=1)) > 0.05


def test_relabelling_recovers_lost_labels_from_detections() -> None:
    """The trackers of cameras 0-2 lose label 2 at frame 30; the raw detections still
    hold its blob. From its 3D motion and the one camera still tracking it, the label
    is picked up again in every camera."""
    rng = np.random.default_rng(5)
    cal = ring_rig()
    t, xyz = motion(rng)
    tracks = make_tracks(cal, xyz, rng, noise_px=0.1)
    detections = [[Detections.from_points(tracks.xy[f, c][rng.permutation(M)]) for f in range(F)] for c in range(4)]
    tracks.xy[30:, :3, 2] = np.nan
    tracks.status[30:, :3, 2] = 0
    blind = reconstruct(tracks, cal, ReconstructionParams(max_gap_frames=0), t)
    assert np.isnan(blind.xyz[30:, 2]).all()
    found = reconstruct(tracks, cal, ReconstructionParams(max_gap_frames=0), t, detections=detections)
    assert np.all(found.n_views[30:, 2] == 4)
    assert rmse(found.xyz[:, 2], xyz[:, 2]) < 0.0012


def test_params_validation() -> None:
    with pytest.raises(ValueError, match="smoothing"):
        ReconstructionParams(smoothing="median")
    with pytest.raises(ValueError, match="min_views"):
        ReconstructionParams(min_views=1)
