"""Model-based labelling on real captures with real gaps, through a virtual rig (geometry only).

Every shared C3D whose physical markers have gaps, and Qualisys.c3d with seeded gaps in 20 % of
its markers (runs of 2-70 frames), is projected into four 1280x960 cameras around the capture
(mild distortion, 0.1 px noise, a marker hidden where a nearer marker's blob covers it, shuffled
detection order). Nothing is labelled by hand: unlabelled points come from epipolar voting and
labels from a rigid-cluster model learned from the capture itself (a subject calibration). Scored
against the capture: RMSE over measured samples, every gap re-labelled, no swaps.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from eval.marker_metrics import gap_recovery, label_swaps
from mocap.calibration import Calibration, Camera
from mocap.correspondence import UnlabelledPoints, reconstruct_unlabelled
from mocap.exports import read_c3d
from mocap.labelling import LabelTemplate
from mocap.marker_pipeline import MarkerPipelineParams, capture_from_detections
from mocap.cluster_labelling import ClusterMarkerModel
from mocap.model_labelling import assign_to_predictions, label_points
from mocap.reconstruction import ReconstructionParams
from mocap.types import Detections

C3D_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "c3d"
NOISE_PX = 0.1
MARKER_RADIUS_M = 0.007
# Real captures whose physical markers have gaps (shared/data/README.md), with a window that keeps
# the subject inside a 4-camera ring: (file, first frame, frames).
_KNOWN_GAP = pytest.mark.xfail(reason="known gap (issue 12): markers on several rigid objects close together (wheelchair, "
                               "glove, arm clusters) or on soft tissue seed wrong neighbour groups", strict=False)
GAPPED = [
    pytest.param("BTS.c3d", 0, 675, marks=_KNOWN_GAP),                           # measured 52 mm, 26/30 gaps, 2 swaps
    # frames 720-840 hold the same swap (max error 73.8 mm) as 600-960 did, in half the time of 720-960 (2026-11-27
    # at e3f2757: 720-840 4.86 mm, 1 swap, 16.6 s; 720-960 29 s; 600-960: 6.1 mm, 1 swap); 600-840 pass
    pytest.param("kinematics_basket_sprint.c3d", 720, 120, marks=_KNOWN_GAP),
    # the first 20 frames (0.29 s) fail the same way as the whole take, at a twelfth of the time (2026-11-27:
    # 216 mm, 4/6 gaps, 33 swaps in 7 CPU-s; frames 0-700: 228 mm, 48/224 gaps, 317 swaps in 91 CPU-s); 10 frames pass
    pytest.param("kinematics_racing_propulsion.c3d", 0, 20, marks=_KNOWN_GAP),
    # the first 256 frames: 11 CPU-s rather than 19 (2026-11-27: 1.9 mm, 23/44 gaps, 3 swaps; all 512: 1.7 mm,
    # 42/54 gaps, 1 swap)
    pytest.param("ADemo1_rewrite_c3d_pc_float.c3d", 0, 256, marks=_KNOWN_GAP),
    ("Res16bits.c3d", 0, 100),                                                   # 0.57 mm, 1/1, 0 swaps
]


def _look_at(eye, target, up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    eye = np.asarray(eye, float)
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z]), -np.stack([x, np.cross(z, x), z]) @ eye


def virtual_capture(xyz: np.ndarray, seed: int) -> dict:
    """Project ``(F, M, 3)`` metres (NaN = absent) into four cameras around the capture."""
    F, M, _ = xyz.shape
    pts = xyz.reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = 0.5 * (lo + hi)
    # The rig of tests/test_real_qualisys.py, widened for captures that travel further.
    reach = max(3.5, 0.6 * float(np.max(hi[:2] - lo[:2])) + 2.5)
    cams = []
    for i, (dx, dy) in enumerate([(-1, -0.86), (1, -0.86), (1, 0.86), (-1, 0.86)]):
        R, t = _look_at([centre[0] + dx * reach, centre[1] + dy * reach, 2.6], [centre[0], centre[1], 0.8])
        K = [[950.0, 0, 640.5], [0, 951.0, 479.5], [0, 0, 1]]
        cams.append(Camera(f"cam{i}", (1280, 960), K, [-0.06, 0.015, 0.0005, -0.0005, 0.0], R, t))
    cal = Calibration(tuple(cams))
    rng = np.random.default_rng(seed)
    present = np.isfinite(xyz).all(axis=2)
    true_px = np.stack([cal.project(x) for x in xyz])                                    # (F, C, M, 2)
    depth = np.stack([np.stack([cam.to_camera(x)[:, 2] for cam in cal]) for x in xyz])    # (F, C, M)
    radius_px = 950.0 * MARKER_RADIUS_M / depth
    gap = np.linalg.norm(true_px[:, :, :, None] - true_px[:, :, None, :], axis=-1)
    overlap = gap < radius_px[..., :, None] + radius_px[..., None, :]
    hidden = (overlap & (depth[..., None, :] < depth[..., :, None])).any(axis=-1)
    inside = np.stack([cam.in_image(true_px[:, c].reshape(-1, 2), 5).reshape(F, M) for c, cam in enumerate(cal)], axis=1)
    seen = present[:, None, :] & ~hidden & inside
    observed = true_px + rng.normal(0.0, NOISE_PX, true_px.shape)
    detections = []
    for c in range(len(cal)):
        per_frame = []
        for f in range(F):
            order = rng.permutation(np.flatnonzero(seen[f, c]))
            per_frame.append(Detections.from_points(observed[f, c, order]))
        detections.append(per_frame)
    return dict(cal=cal, detections=detections, seen=seen)


def run_model_labelling(labels: list[str], xyz: np.ndarray, rate_hz: float, seed: int) -> dict:
    rig = virtual_capture(xyz, seed)
    F = len(xyz)
    model = ClusterMarkerModel(labels, xyz)
    template = LabelTemplate(tuple(labels), np.nan_to_num(np.nanmedian(xyz, axis=0)))
    params = MarkerPipelineParams(
        reconstruction=ReconstructionParams(epipolar_threshold_px=1.0, max_residual_px=0.6, max_gap_frames=10),
        solve_skeleton=False)
    cap = capture_from_detections(rig["detections"], rig["cal"], template, np.arange(F) / rate_hz, params,
                                  np.random.default_rng(seed), None, marker_model=model)
    est = cap.trajectories.xyz
    err = np.linalg.norm(est - xyz, axis=2)
    measured = np.isfinite(err) & ~cap.trajectories.filled
    recovered, gaps = gap_recovery(est, xyz, rig["seen"])
    return dict(rmse_mm=1e3 * float(np.sqrt(np.mean(err[measured] ** 2))), max_mm=1e3 * float(np.nanmax(err)),
                swaps=label_swaps(est, xyz), recovered=recovered, gaps=gaps,
                reconstructed=float(np.isfinite(err).sum() / max((rig["seen"].sum(axis=1) >= 2).sum(), 1)))


def _seeded_gaps(xyz: np.ndarray, fraction: float, rng: np.random.Generator) -> np.ndarray:
    F, M, _ = xyz.shape
    out = xyz.copy()
    for m in rng.choice(M, size=int(round(fraction * M)), replace=False):
        f = int(rng.integers(5, 60))
        while f < F - 5:
            n = int(rng.integers(2, 71))
            out[f:f + n, m] = np.nan
            f += n + int(rng.integers(20, 80))
    return out


def test_unlabelled_points_from_epipolar_voting() -> None:
    """Every marker seen by three or more cameras comes back once, at its place; almost no ghosts."""
    traj = read_c3d(C3D_DIR / "Qualisys.c3d")
    xyz = traj.xyz[::10]
    rig = virtual_capture(xyz, seed=3)
    found = ghosts = expected = 0
    errors = []
    for f in range(len(xyz)):
        pts = reconstruct_unlabelled([d[f] for d in rig["detections"]], rig["cal"])
        d, i = cKDTree(xyz[f]).query(pts.xyz)
        ok = d < 0.003
        ghosts += int((~ok).sum())
        three = rig["seen"][f].sum(axis=0) >= 3
        expected += int(three.sum())
        found += int(np.isin(np.flatnonzero(three), i[ok]).sum())
        errors.extend(d[ok])
        assert len(np.unique(i[ok])) == ok.sum()  # one point per marker
    print(f"found {found}/{expected} markers seen by >= 3 cameras, {ghosts} ghosts, rmse {1e3 * np.sqrt(np.mean(np.square(errors))):.3f} mm")
    assert found >= 0.975 * expected
    assert ghosts <= 0.03 * expected
    assert np.sqrt(np.mean(np.square(errors))) < 0.001  # 0.1 px noise, 2.5 px residual gate


def test_close_markers_are_not_merged_into_a_ghost() -> None:
    """bvh_walk with 4 cameras (frames 64, 72, 100 of its render, stored in tests/data): the
    four head markers lie 5-7 px apart in the images and each is seen by three cameras. Support
    gathered from the neighbours' detections made 4-view ghosts midway between two markers (about
    50 mm from each, 1 px of residual) that took the true points' detections; ranking candidates
    by the views that agree within a pixel finds every head marker."""
    data = Path(__file__).parent / "data"
    cal = Calibration.load_opencv_yaml(data / "walk4_calibration.yml")
    z = np.load(data / "walk4_head_detections.npz")
    for f in (64, 72, 100):
        dets = [Detections(z[f"f{f}_cam{c}"], np.full(len(z[f"f{f}_cam{c}"]), 2.0), np.full(len(z[f"f{f}_cam{c}"]), 200.0))
                for c in range(len(cal))]
        pts = reconstruct_unlabelled(dets, cal)
        nearest, _ = cKDTree(pts.xyz).query(z[f"f{f}_head_xyz"])
        assert nearest.max() < 0.005, f"frame {f}: head markers {np.round(nearest * 1e3, 1)} mm from the nearest point"


def test_a_marker_seen_in_few_frames_still_gets_its_neighbours() -> None:
    """A marker seen in 25 of 180 frames (c3d_basket_sprint's ForearmL:Marker4) is predicted from its
    rigid neighbours: 20 frames together are enough for the distance statistics, 15 are not."""
    rng = np.random.default_rng(4)
    local = np.array([[0.0, 0, 0], [0.08, 0, 0], [0, 0.06, 0], [0, 0, 0.05], [0.05, 0.05, 0.02]])
    F = 180
    xyz = np.empty((F, len(local), 3))
    for f in range(F):
        R = Rotation.from_rotvec(0.02 * f * np.array([0.3, 1.0, 0.2])).as_matrix()
        xyz[f] = local @ R.T + np.array([0.01 * f, 0.0, 1.0]) + rng.normal(0.0, 2e-4, local.shape)
    labels = ["A", "B", "C", "D", "E"]
    for seen, predicted in ((25, True), (15, False)):
        part = xyz.copy()
        part[seen:, 4] = np.nan                      # E only in the first frames
        model = ClusterMarkerModel(labels, part)
        pos = xyz[100].copy()
        pos[4] = np.nan
        p = model.predict(pos, np.array([4]))[0]
        assert np.isfinite(p).all() == predicted
        if predicted:
            assert np.linalg.norm(p - xyz[100, 4]) < 0.002


def test_assignment_gives_one_point_per_label() -> None:
    pred = np.array([[0.0, 0, 0], [0.02, 0, 0], [1.0, 0, 0]])
    pts = np.array([[0.019, 0, 0], [0.001, 0, 0], [5.0, 0, 0]])
    assert assign_to_predictions(pred, pts, 0.05).tolist() == [1, 0, -1]
    # A neighbour 20 mm away never takes a lost marker's point: its own prediction is nearer.
    assert assign_to_predictions(pred[:2], pts[:1], 0.05).tolist() == [-1, 0]


@pytest.mark.slow
def test_qualisys_with_seeded_gaps() -> None:
    traj = read_c3d(C3D_DIR / "Qualisys.c3d")
    # the gaps seeded over the whole capture, its first 200 frames labelled (16 CPU-s rather than 26); 22 of 22
    # gaps, 0 swaps, 0.64 mm (xfail before the 20-frame floor of ClusterMarkerModel's statistics: 18/22, 1, 2.6)
    xyz = _seeded_gaps(traj.xyz, 0.2, np.random.default_rng(5))[:200]
    r = run_model_labelling(list(traj.labels), xyz, traj.rate_hz, seed=2024)
    print(f"Qualisys with seeded gaps: rmse {r['rmse_mm']:.3f} mm, gaps recovered {r['recovered']}/{r['gaps']}, "
          f"swaps {r['swaps']}, reconstructed {r['reconstructed']:.3f}")
    assert r["gaps"] >= 20
    assert r["recovered"] == r["gaps"]
    assert r["swaps"] == 0
    assert r["rmse_mm"] <= 1.0


@pytest.mark.slow
@pytest.mark.parametrize("name,first,count", GAPPED)
def test_real_captures_with_gaps(name: str, first: int, count: int) -> None:
    traj = read_c3d(C3D_DIR / name)
    xyz = traj.xyz[first:first + count]
    keep = np.isfinite(xyz).all(axis=2).any(axis=0)
    labels = [n for n, k in zip(traj.labels, keep) if k]
    r = run_model_labelling(labels, xyz[:, keep], traj.rate_hz, seed=11)
    print(f"{name}: rmse {r['rmse_mm']:.3f} mm (max {r['max_mm']:.1f}), gaps recovered {r['recovered']}/{r['gaps']}, "
          f"swaps {r['swaps']}, reconstructed {r['reconstructed']:.3f}")
    assert r["swaps"] == 0
    assert r["recovered"] == r["gaps"]
    assert r["rmse_mm"] <= 1.0


def _codamotion_points(name: str) -> list[UnlabelledPoints]:
    """c3d_codamotion_walk's unlabelled points of every frame, stored in tests/data (8 cameras)."""
    z = np.load(Path(__file__).parent / "data" / name)
    ends = np.cumsum(z["counts"])
    frames = []
    for a, b in zip(ends - z["counts"], ends):
        n = int(b - a)
        frames.append(UnlabelledPoints(z["xyz"][a:b].astype(float), np.full((n, 8), -1), z["n_views"][a:b].astype(int),
                                       np.zeros(n), z["ambiguous"][a:b]))
    return frames


def _codamotion_labelling(points_file: str) -> dict:
    """Label a stored set of the take's points with the rigid-cluster model learned from the
    capture (codamotion_points.npz): reconstructed markers labelled right, and labels on a point
    more than 10 mm from their marker."""
    z = np.load(Path(__file__).parent / "data" / "codamotion_points.npz")
    frames = _codamotion_points(points_file)
    model = ClusterMarkerModel([str(s) for s in z["labels"]], z["reference_xyz"].astype(float))
    result = label_points(frames, model)
    truth = z["truth_xyz"].astype(float)
    wrong = labelled = right = there = 0
    for f, fr in enumerate(frames):
        seen = np.isfinite(truth[f]).all(axis=1)
        near, nearest = cKDTree(fr.xyz).query(np.where(seen[:, None], truth[f], 1e3))
        there += int((near < 0.005).sum())  # markers the cameras reconstructed
        for m, i in enumerate(result.point_index[f]):
            if i >= 0 and seen[m]:
                labelled += 1
                wrong += int(np.linalg.norm(fr.xyz[i] - truth[f, m]) > 0.01)
                right += int(near[m] < 0.005 and i == nearest[m])
    return dict(right=right, there=there, wrong=wrong, labelled=labelled, start_ms=result.start_search_ms)


def test_start_is_a_fit_that_explains_every_point() -> None:
    """c3d_codamotion_walk's unlabelled points (8 cameras, stored in tests/data) labelled by the
    rigid-cluster model learned from the capture. The right thigh and shank clusters look alike:
    on 10 of the 16 frames where the global search leaves one point unexplained, it has them
    swapped, and starting from such a frame (the best of five spread frames, 22 of 23 points)
    carried the swap through the take: 244 wrong labels. The search goes on until a fit explains
    every point (right on every such frame of this take). Tracking then must not let a label grow
    onto an ambiguous two-view point outside the tight gate (a knee marker's point 32 mm from a
    shank marker lost behind a merged blob, frame 50)."""
    r = _codamotion_labelling("codamotion_points.npz")
    # 3281 of 3381 here (3275 before the neighbour exchange); most of the rest is the sacral
    # wand's left marker: the wand's two markers are 3-25 mm apart (14 mm spheres, one blob in
    # most frames) and the right label takes their one point. The swapped start gave 2516, the
    # start alone fixed 2867 (the growth then crossed a knee and a shank label).
    assert r["right"] >= 0.96 * r["there"], f"{r['right']} of {r['there']} reconstructed markers labelled"
    assert r["wrong"] <= 0.01 * r["labelled"], f"{r['wrong']} of {r['labelled']} labels more than 10 mm off"
    assert r["start_ms"] > 0.0  # the start search's time is reported (simbench bench pipeline prints it apart)


def test_close_neighbours_take_back_crossed_points() -> None:
    """The same take's points with the IR centroids weighted by light (801b00f; the points above
    are those of the encoded-level weights). Frame 61: the right knee and shank markers, 32 mm
    apart, give one point merged from both (7 of 8 views, 16 mm from either), and the shank label
    takes it. Extrapolated at that point's velocity it took the knee marker's point at frame 62
    and the knee label the shank's; their neighbours' predictions then vetoed the leg's right
    labels and it never recovered (2915 of 3388 right, 160 labels on a wrong point, 15.3 mm
    through the pipeline). Two neighbours closer than their gates now exchange their points when
    the neighbour model fits the exchange by at least one gate better."""
    r = _codamotion_labelling("codamotion_points_srgb.npz")
    assert r["right"] >= 0.96 * r["there"], f"{r['right']} of {r['there']} reconstructed markers labelled"
    assert r["wrong"] <= 0.01 * r["labelled"], f"{r['wrong']} of {r['labelled']} labels more than 10 mm off"


def _soft_tissue_cluster(gap_m: float) -> tuple[np.ndarray, ClusterMarkerModel]:
    """Six markers, the first two ``gap_m`` apart, and their model learned from 100 random
    poses with 4 mm of soft-tissue noise (gates 35-80 mm, wider than the first two's distance)."""
    local = np.array([[0, 0, 0], [gap_m, 0, 0], [0.0, 0.12, 0.0], [0.05, 0.25, 0.02], [-0.04, 0.1, 0.1],
                      [0.0, 0.3, -0.05]])
    R = Rotation.random(100, random_state=1).as_matrix()
    trial = np.einsum("fij,mj->fmi", R, local) + np.random.default_rng(0).normal(0.0, 0.004, (100, 6, 3))
    return local, ClusterMarkerModel([f"m{i}" for i in range(6)], trial)


def test_neighbours_exchange_points_only_where_the_model_clearly_fits_better() -> None:
    right, crossed = np.arange(6), np.array([1, 0, 2, 3, 4, 5])
    local, model = _soft_tissue_cluster(0.03)
    points = local @ Rotation.from_euler("xyz", [0.3, -0.5, 1.0]).as_matrix().T + [0.2, 0.1, 0.9]
    assert model.gate_m[:2].min() > 0.03
    assert model.exchange_neighbours(crossed, points).tolist() == right.tolist()
    assert model.exchange_neighbours(right, points).tolist() == right.tolist()
    # 3 mm apart, the two fit either way about as well: left as the motion assigned them.
    local, model = _soft_tissue_cluster(0.003)
    points = local @ Rotation.from_euler("xyz", [0.3, -0.5, 1.0]).as_matrix().T + [0.2, 0.1, 0.9]
    assert model.exchange_neighbours(crossed, points).tolist() == crossed.tolist()


SPRINT_SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "trc_sprint_start.toml"
SPRINT_TRC = C3D_DIR.parent / "trc" / "SprintMotion.trc"


def _sprint_points() -> tuple[object, list[UnlabelledPoints], int]:
    """trc_sprint_start's capture reference, and its unlabelled points of frames 270-311 (6 cameras,
    stored in tests/data from the scenario's run at 243a633)."""
    from simbench.scenario import load_scenario
    from simbench.stage.build import build_stage

    ref = build_stage(load_scenario(SPRINT_SCENARIO)).capture_reference()
    z = np.load(Path(__file__).parent / "data" / "sprint_points_270_312.npz")
    ends = np.cumsum(z["counts"])
    frames = [UnlabelledPoints(z["xyz"][a:b].astype(float), np.full((b - a, 6), -1), z["n_views"][a:b].astype(int),
                               np.zeros(b - a), z["ambiguous"][a:b]) for a, b in zip(ends - z["counts"], ends)]
    return ref, frames, int(z["first"])


def _wrong_labels(frames: list[UnlabelledPoints], truth: np.ndarray, model: ClusterMarkerModel) -> list[tuple[int, str]]:
    """(frame, label) of every label on a point more than 20 mm (the swap radius) from its marker (at
    frame 305 R.Wrist.Uln's own point, seen by three cameras, is 11 mm off)."""
    result = label_points(frames, model)
    return [(f, model.labels[m]) for f, fr in enumerate(frames) for m, i in enumerate(result.point_index[f])
            if i >= 0 and np.isfinite(truth[f, m]).all() and np.linalg.norm(fr.xyz[i] - truth[f, m]) > 0.02]


@pytest.mark.skipif(not SPRINT_TRC.is_file(), reason="shared real data not found")
def test_far_markers_are_neighbours_only_when_too_few_are_near() -> None:
    """trc_sprint_start: R.Wrist.Rad's four least varying distances included L.AA, the left
    acromion 73 cm away (distance SD 2.6 mm over the take). As the sprinter rises (frames 300-304)
    those four predicted the wrist 27-29 mm from its place even from their true positions (4-6 mm
    without L.AA), the veto took R.Wrist.Rad's label at frame 301 (gate 29.0 mm), and R.Wrist.Uln,
    predicted from three neighbours nearly along the forearm, took its point 53-62 mm away for
    frames 304-309: the take's one swap. Neighbours are now taken first among the markers within
    0.5 m on average (``max_reach_m``)."""
    ref, frames, first = _sprint_points()
    truth = ref.xyz[first:first + len(frames)]
    model = ref.marker_model()
    L = model.labels
    rad, uln = L.index("R.Wrist.Rad"), L.index("R.Wrist.Uln")
    assert "L.AA" not in [L[k] for k in model.neighbours[rad]]
    for f in range(300, 305):  # from their neighbours' true positions, the wrist markers are predicted inside their gates
        err = np.linalg.norm(model.predict(ref.xyz[f], [rad, uln]) - ref.xyz[f, [rad, uln]], axis=1)
        assert err[0] < 0.5 * model.gate_m[rad] and err[1] < model.gate_m[uln], (f, err)
    assert _wrong_labels(frames, truth, model) == []
    # The least varying distances alone, however far, give the old neighbours and the swap, without
    # rigid groups (rigid_std_m=0; with the rigid groups (368aa80) these points no longer give it
    # even with the old neighbours: the right elbow triad is one, the wrist markers are in none).
    old = ClusterMarkerModel(L, ref.xyz, max_reach_m=None, rigid_std_m=0.0)
    assert "L.AA" in [L[k] for k in old.neighbours[rad]]
    wrong = _wrong_labels(frames, truth, old)
    assert {n for _, n in wrong} == {"R.Wrist.Uln"} and len(wrong) >= 5


@pytest.mark.skipif(not (C3D_DIR / "Sample_Static.c3d").is_file(), reason="shared real data not found")
def test_labelled_members_anchor_a_seed() -> None:
    """c3d_sample_static's unlabelled points (stored in tests/data from the scenario's run at
    243a633), labelled by the model learned from the capture. The four head markers are each
    predicted from the other three and one torso marker; a torso seed takes that marker first, so
    the head group could not be matched among the free points (four markers needed, and the head's
    near-rectangle alone fits two ways) nor grown (three labelled neighbours needed): the head
    stayed unlabelled in all 50 frames (0.771 reconstructed; the left arm likewise at 243a633,
    0.886). Labelled members of a group now anchor its match on their own points."""
    from simbench.scenario import load_scenario
    from simbench.stage.build import build_stage

    ref = build_stage(load_scenario(SPRINT_SCENARIO.parent / "c3d_sample_static.toml")).capture_reference()
    z = np.load(Path(__file__).parent / "data" / "sample_static_points.npz")
    ends = np.cumsum(z["counts"])
    C = int(z["n_cameras"])
    frames = [UnlabelledPoints(z["xyz"][a:b].astype(float), np.full((b - a, C), -1), z["n_views"][a:b].astype(int),
                               np.zeros(b - a), z["ambiguous"][a:b]) for a, b in zip(ends - z["counts"], ends)]
    model = ref.marker_model()
    result = label_points(frames, model)
    right = there = 0
    for f, fr in enumerate(frames):
        near, nearest = cKDTree(fr.xyz).query(ref.xyz[f])
        there += int((near < 0.005).sum())
        right += int(((near < 0.005) & (result.point_index[f] == nearest)).sum())
    assert right == there, f"{right} of {there} reconstructed markers labelled right"
    assert there >= 0.99 * ref.xyz.shape[0] * ref.xyz.shape[1]


@pytest.mark.skipif(not (C3D_DIR / "Res16bits.c3d").is_file(), reason="shared real data not found")
def test_a_near_static_trial_keeps_its_labels() -> None:
    """c3d_res16bits_static's unlabelled points at the real_motion suite's settings (its first 0.9 s,
    one sample a pixel; stored in tests/data from the scenario's run at 23d00b0), labelled by the model
    learned from the same 0.9 s. Over a near-static trial a group's largest turn relative to its
    partners is 0.1-3 deg, less than points within the shape tolerance can turn it (2-9 deg): the
    reconstructed points turned correctly labelled groups "outside the trial", and a partner group
    gave their labels away (a460cb9: 2 swaps, 90.7 mm at most, in the suite's run). A partner's limit
    is now at least the two groups' turn noise together."""
    from simbench.scenario import load_scenario
    from simbench.stage.build import build_stage

    sc = load_scenario(SPRINT_SCENARIO.parent / "c3d_res16bits_static.toml",
                       overrides={"duration_s": 0.9, "sensor.antialias": 1})
    ref = build_stage(sc).capture_reference()
    z = np.load(Path(__file__).parent / "data" / "res16bits_points.npz")
    ends = np.cumsum(z["counts"])
    C = int(z["n_cameras"])
    frames = [UnlabelledPoints(z["xyz"][a:b], np.full((b - a, C), -1), z["n_views"][a:b].astype(int),
                               np.zeros(b - a), z["ambiguous"][a:b]) for a, b in zip(ends - z["counts"], ends)]
    result = label_points(frames, ref.marker_model())
    right = there = wrong = 0
    for f, fr in enumerate(frames):
        seen = np.isfinite(ref.xyz[f]).all(axis=1)
        near, nearest = cKDTree(fr.xyz).query(np.where(seen[:, None], ref.xyz[f], 1e3))
        there += int((near < 0.005).sum())
        for m, i in enumerate(result.point_index[f]):
            if i >= 0 and seen[m]:
                wrong += int(np.linalg.norm(fr.xyz[i] - ref.xyz[f, m]) > 0.02)
                right += int(near[m] < 0.005 and i == nearest[m])
    assert wrong == 0, f"{wrong} labels more than 20 mm from their marker (2 at a460cb9)"
    assert right >= 0.99 * there, f"{right} of {there} reconstructed markers labelled right (now 3541 of 3565)"


RACING_SCENARIO = SPRINT_SCENARIO.parent / "c3d_racing_propulsion.toml"


@pytest.mark.skipif(not (C3D_DIR / "kinematics_racing_propulsion.c3d").is_file(), reason="shared real data not found")
def test_symmetric_triads_keep_their_labels_by_turning_least() -> None:
    """c3d_racing_propulsion's unlabelled points of frames 100-139 (6 cameras, stored in tests/data
    from the scenario's run at 60e2a1f), labelled by the model learned from the capture. Its
    markers sit in equilateral triads (42.8-43.3 mm sides): a triad fits its own shape, and its
    neighbours' predictions, as well with its labels permuted. At 70 Hz a glove triad moves up to
    92 mm and turns up to 46 deg between frames, and each marker's constant-velocity prediction
    misses by up to 65 mm, so motion per marker permuted the gloves' labels (frame 124 on the
    capture's own points). Now a triad's points go to the labels that turn it least since the
    previous frame (a permuted triad turns at least 86 deg), or that put its surroundings where
    the trial had them. At 60e2a1f: 877 of 1137 reconstructed markers labelled right, 44 labels
    more than 20 mm from their marker; now 957 and 4. Most of the rest was the right scapula
    triad, lost whole in frames 103-110 and predicted by nothing after
    (:func:`test_a_rigid_group_lost_whole_is_found_again_by_its_shape`)."""
    right, there, wrong = _racing_window(100, 140)
    assert right >= 0.82 * there, f"{right} of {there} reconstructed markers labelled right"
    assert wrong <= 0.01 * there, f"{wrong} labels more than 20 mm from their marker"


@functools.lru_cache(maxsize=None)
def _racing_labelled(first: int, last: int) -> tuple:
    """c3d_racing_propulsion's capture reference, its stored unlabelled points of frames ``first``
    to ``last`` (exclusive) and their labelling by the model learned from the capture. Kept for
    the module: several tests score the same window over different markers, and labelling a
    40-frame window takes tens of seconds."""
    from simbench.scenario import load_scenario
    from simbench.stage.build import build_stage

    # The points were stored from a run with the scenario's earlier 4 ms shutter: the truth at that
    # run's mid-exposure instants (the glove moves up to 11 mm in the 1.75 ms between the two).
    sc = load_scenario(RACING_SCENARIO, overrides={"sensor.exposure_ms": 4.0, "sensor.ring_light": 6.0})
    ref = build_stage(sc).capture_reference()
    z = np.load(Path(__file__).parent / "data" / "racing_points.npz")
    ends = np.cumsum(z["counts"])
    C = int(z["n_cameras"])
    frames = [UnlabelledPoints(z["xyz"][a:b].astype(float), np.full((b - a, C), -1), z["n_views"][a:b].astype(int),
                               np.zeros(b - a), z["ambiguous"][a:b]) for a, b in zip(ends - z["counts"], ends)]
    return ref, frames[first:last], label_points(frames[first:last], ref.marker_model())


def _racing_window(first: int, last: int, markers: tuple[str, ...] = ()) -> tuple[int, int, int]:
    """c3d_racing_propulsion's stored unlabelled points of frames ``first`` to ``last`` (exclusive)
    labelled by the model learned from the capture: ``(labelled right, reconstructed within 5 mm,
    labelled more than 20 mm off)`` over ``markers`` (default every marker)."""
    ref, frames, result = _racing_labelled(first, last)
    truth = ref.xyz[first:last]
    which = [list(ref.labels).index(n) for n in markers] if markers else list(range(len(ref.labels)))
    right = there = wrong = 0
    for f, fr in enumerate(frames):
        seen = np.isfinite(truth[f]).all(axis=1)
        near, nearest = cKDTree(fr.xyz).query(np.where(seen[:, None], truth[f], 1e3))
        for m in which:
            i = result.point_index[f, m]
            there += int(near[m] < 0.005)
            if i >= 0 and seen[m]:
                wrong += int(np.linalg.norm(fr.xyz[i] - truth[f, m]) > 0.02)
                right += int(near[m] < 0.005 and i == nearest[m])
    return right, there, wrong


@pytest.mark.skipif(not (C3D_DIR / "kinematics_racing_propulsion.c3d").is_file(), reason="shared real data not found")
@pytest.mark.parametrize("first, last, group, before", [
    (95, 140, ("ScapulaR1", "ScapulaR2", "ScapulaR3"), "0 of 76"),
    (20, 60, ("ForearmL1", "ForearmL2", "ForearmL3", "LateralEpicondyleL"), "66 of 146, 83 more than 20 mm off"),
])
def test_a_rigid_group_lost_whole_is_found_again_by_its_shape(first: int, last: int, group: tuple[str, ...],
                                                             before: str) -> None:
    """c3d_racing_propulsion's stored points. A triad lost whole was predicted by nothing (its
    members are each other's neighbours) and stayed where it was lost: the right scapula triad,
    lost in frames 103-110, was never labelled again, and the left forearm triad, lost in frames
    41-42 and labelled backward from frame 59, came back on the glove's points (and the
    epicondyle's label on the forearm's), a one-segment slide. Now such a group takes no point by
    motion (within the tight gate before 4b38eb3), and comes back where its shape appears once among the free
    points with its surroundings where the trial had them. Before (0ea1bf3): ``before`` of the
    group's reconstructed samples labelled right (now 64 of 76, and 142 of 146 with none off);
    over every marker 1105 of 1282 (41 more than 20 mm off) in frames 95-139 and 969 of 1151
    (104) in frames 20-59; now 1264 (7) and 1103 (22)."""
    right, there, wrong = _racing_window(first, last, group)
    assert right >= 0.8 * there, f"{right} of {there} reconstructed samples of {group} labelled right (before: {before})"
    assert wrong == 0, f"{wrong} labels of {group} more than 20 mm from their marker"
    right, there, wrong = _racing_window(first, last)
    assert right >= 0.9 * there, f"{right} of {there} reconstructed markers labelled right"
    assert wrong <= 0.025 * there, f"{wrong} labels more than 20 mm from their marker"


@pytest.mark.skipif(not (C3D_DIR / "kinematics_racing_propulsion.c3d").is_file(), reason="shared real data not found")
def test_a_partner_group_tells_apart_what_the_surroundings_cannot() -> None:
    """c3d_racing_propulsion's stored points of frames 20-59, labelled backward from frame 59. The
    left glove triad, lost in frames 41-43, has one marker around it (the hand marker NAG), and
    that one fits two of the triad's labellings about as well in frames 36-40 (near the triad's
    axis): the triad was left unlabelled there, and filled 51 mm RMS off in the run. The forearm
    triad, whose orientation relative to the glove's stayed within 77 deg of its mean over the
    trial, tells the two apart. Before: 86 of the glove's 105 reconstructed samples labelled right
    (1103 of 1151 over every marker); now 96 (1113), with 1 label of the glove more than 20 mm off
    as before. In the replayed run: 12.35 -> 8.35 mm."""
    right, there, wrong = _racing_window(20, 60, ("GloveL1", "GloveL2", "GloveL3"))
    assert right >= 0.9 * there, f"{right} of {there} reconstructed samples of the left glove labelled right (before: 86)"
    assert wrong <= 1, f"{wrong} labels of the left glove more than 20 mm from their marker"


@pytest.mark.skipif(not (C3D_DIR / "kinematics_racing_propulsion.c3d").is_file(), reason="shared real data not found")
def test_a_partner_group_undoes_two_exchanged_labels() -> None:
    """c3d_racing_propulsion's stored points of frames 0-39, labelled backward from frame 24. There
    the right glove triad's points are up to 5 mm off (a bent triad, which no placement of its
    shape matches), two of its labels exchange points, and every earlier frame kept the exchange
    by turning the triad least: GloveR2 and GloveR3 on each other's marker in frames 7-24, with the
    hand marker NAR, the glove's only surroundings, unseen. Relative to the forearm triad the glove
    then turns about twice as far as it ever did in the trial, while its right labels stay within
    that; the labels are given back. Before: 52 of the glove's 96 reconstructed samples labelled
    right, 39 labels more than 20 mm off (1095 of 1156 and 44 over every marker); now 82 and 5
    (1129 and 8)."""
    right, there, wrong = _racing_window(0, 40, ("GloveR1", "GloveR2", "GloveR3"))
    assert right >= 0.8 * there, f"{right} of {there} reconstructed samples of the right glove labelled right (before: 52)"
    assert wrong <= 0.1 * there, f"{wrong} labels of the right glove more than 20 mm from their marker (before: 39)"
    right, there, wrong = _racing_window(0, 40)
    assert right >= 0.95 * there, f"{right} of {there} reconstructed markers labelled right (before: 1095)"
    assert wrong <= 0.01 * there, f"{wrong} labels more than 20 mm from their marker (before: 44)"


def _racing_exposure05(frame: int) -> tuple:
    """c3d_racing_propulsion at its 0.5 ms strobe exposure: the unlabelled points of one frame
    (``frame`` 23, 64, 164 or 203, stored in tests/data from the detections of its run at 54daf96),
    the capture reference and the model learned from it. Frames 23 and 64 come with the state and
    the last two frames' labelled positions that tracking, backward from frame 104, brought there
    at 54daf96; frames 164 and 203 with the labels it gave there."""
    from simbench.scenario import load_scenario
    from simbench.stage.build import build_stage

    ref = build_stage(load_scenario(RACING_SCENARIO)).capture_reference()
    z = np.load(Path(__file__).parent / "data" / "racing_exposure05_frames.npz")
    pts = z[f"xyz_{frame}"]
    fr = UnlabelledPoints(pts, np.full((len(pts), 6), -1), z[f"n_views_{frame}"].astype(int), np.zeros(len(pts)),
                          z[f"ambiguous_{frame}"])
    extra = {k.rsplit("_", 1)[0]: z[k] for k in z.files if k.endswith(f"_{frame}")}
    return ref, ref.marker_model(), fr, extra


@pytest.mark.skipif(not (C3D_DIR / "kinematics_racing_propulsion.c3d").is_file(), reason="shared real data not found")
@pytest.mark.parametrize("frame", [23, 64])
def test_a_group_lost_whole_takes_no_point_by_motion_nor_another_groups_points(frame: int) -> None:
    """c3d_racing_propulsion, both scapula triads lost since frames 25 and 65 (tracking backward).
    Their members' predictions are where they were last seen, 31-48 mm off, and at 54daf96
    ScapulaL2 took ScapulaL1's point there (42 mm off; 3 of the run's 6 swaps in frames 23, 63 and
    64). Now such a member takes no point by motion; and the shape search that brings a group back
    (:meth:`reacquire_groups`) no longer puts the right triad, two of its markers seen, on the left
    triad's three points (225-241 mm off at frame 23), which turn it relative to its partner head
    triad beyond anything the trial had."""
    ref, model, fr, extra = _racing_exposure05(frame)
    trusted = (fr.n_views >= 3) | ~fr.ambiguous
    _, idx, _ = model.track(fr.xyz, trusted, extra["state"], list(extra["previous"]), (0.08, 0.02))
    truth = ref.xyz[frame]
    for m in np.flatnonzero(idx >= 0):
        off = np.linalg.norm(fr.xyz[idx[m]] - truth[m])
        assert not off > 0.01, f"{model.labels[m]} on a point {off * 1e3:.0f} mm off"
    assert (idx >= 0).sum() >= 25


@pytest.mark.skipif(not (C3D_DIR / "kinematics_racing_propulsion.c3d").is_file(), reason="shared real data not found")
@pytest.mark.parametrize("frame", [164, 203])
def test_surroundings_undo_an_exchange_on_a_bent_triad(frame: int) -> None:
    """c3d_racing_propulsion, the right glove at full speed: its three points are 6-7 mm off the
    triad's shape (no labelling fits it within the 5 mm tolerance), and at 54daf96 GloveR1 and
    GloveR2 stayed exchanged (40-43 mm off), since the surroundings' test took only labellings
    within the tolerance. Among those that keep the shape as well as the present one, the hand
    marker NAR puts the right labels first (a score of 6 against 142)."""
    ref, model, fr, extra = _racing_exposure05(frame)
    idx = extra["index"].astype(np.intp)
    gi = next(i for i, g in enumerate(model.rigid_groups) if model.labels[g[0]] == "GloveR1")
    g = model.rigid_groups[gi]
    off = lambda ix: np.linalg.norm(fr.xyz[ix[g]] - ref.xyz[frame, g], axis=1)  # noqa: E731
    assert off(idx).max() > 0.04  # the exchange, as tracking left it
    assert off(model._fit_surroundings(gi, idx, fr.xyz)).max() < 0.01
