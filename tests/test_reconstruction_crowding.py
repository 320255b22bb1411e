"""Crowded views: a blob that shares light with a neighbour's counts less in triangulation."""

from __future__ import annotations

import numpy as np

from mocap.reconstruction import ReconstructionParams, crowded_views, reconstruct
from mocap.types import Tracks2D
from tests.test_reconstruction_triangulation import ring_rig


def _pair_on_camera0_ray(cal, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Points A and, 0.3 m behind each along camera 0's ray, points B: they image within
    a pixel of each other in camera 0 and far apart in the others."""
    c0 = cal.cameras[0]
    centre = -c0.R.T @ c0.t
    A = rng.uniform([-0.5, -0.5, 0.5], [0.5, 0.5, 1.5], (n, 3))
    ray = (A - centre) / np.linalg.norm(A - centre, axis=1, keepdims=True)
    B = A + 0.3 * ray + rng.normal(0.0, 0.0005, (n, 3))
    return A, B


def test_crowded_views_flags_close_images_only_in_that_camera():
    rng = np.random.default_rng(1)
    cal = ring_rig()
    A, B = _pair_on_camera0_ray(cal, rng, 20)
    xyz = np.stack([A, B], axis=1)                                     # (F, M=2, 3)
    p2ds = cal.project(xyz.reshape(-1, 3)).reshape(len(cal), 20, 2, 2)  # (C, F, M, 2)
    crowded = crowded_views(p2ds, xyz, cal, crowd_px=3.0)
    assert crowded[0].all()
    assert not crowded[1:].any()
    # A neighbour whose blob merged into this one is not observed itself: its reprojection counts.
    p2ds[0, :, 1] = np.nan
    crowded = crowded_views(p2ds, xyz, cal, crowd_px=3.0)
    assert crowded[0, :, 0].all() and not crowded[0, :, 1].any()
    assert not crowded_views(p2ds, xyz, cal, crowd_px=0.0).any()


def test_crowded_views_count_less_in_the_triangulation():
    """Two markers merged in camera 0: each centroid pulled 0.6 px towards the other. The
    down-weighted view leaves both points near their clean triangulation."""
    rng = np.random.default_rng(2)
    cal = ring_rig()
    F = 40
    A, B = _pair_on_camera0_ray(cal, rng, F)
    truth = np.stack([A, B], axis=1)
    p2ds = cal.project(truth.reshape(-1, 3)).reshape(len(cal), F, 2, 2)
    p2ds += rng.normal(0.0, 0.05, p2ds.shape)
    # Camera 0's two blobs share light: each centroid moves towards the mean of the pair
    # by 0.6 px in a direction the pair's sub-pixel offset does not fix; model it as a
    # fixed 0.6 px pull along the image x axis in opposite directions.
    p2ds[0, :, 0, 0] += 0.6
    p2ds[0, :, 1, 0] -= 0.6
    tracks = Tracks2D(["A", "B"], p2ds.transpose(1, 0, 2, 3), p2ds.transpose(1, 0, 2, 3),
                      np.ones((F, len(cal), 2), np.int8), list(cal.names))
    times = np.arange(F) / 30.0

    def rmse(params: ReconstructionParams) -> float:
        traj = reconstruct(tracks, cal, params, times=times)
        return float(np.sqrt(np.mean(np.sum((traj.xyz - truth) ** 2, axis=2))))

    plain = rmse(ReconstructionParams(crowd_px=0.0, relabel_gate_px=0, max_gap_frames=0))
    weighted = rmse(ReconstructionParams(crowd_px=3.0, crowded_weight=0.1, relabel_gate_px=0, max_gap_frames=0))
    assert weighted < 0.5 * plain
    assert weighted < 0.0015
