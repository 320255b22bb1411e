"""Real captures as scenarios (``[motion] c3d`` / ``trc``): the rendered ground truth is the
capture (resampled, recentred), absent samples are absent markers, marker blobs sit on the
projections, and seeded gaps are reproducible with the requested fraction and lengths."""

from __future__ import annotations

from pathlib import Path

import cv2
import ezc3d
import numpy as np
import pytest

from mocap.exports import write_c3d
from mocap.types import Trajectories
from simbench.stage.build import build_stage
from simbench.errors import ScenarioError
from simbench.render import ids as idc
from simbench.stage.rendering import render_frames
from simbench.scenario import CaptureGapsConfig, load_scenario
from simbench.stage.capture import load_capture_clip, seeded_gaps
from simbench.stage.renderer import mid_exposure_times

from helpers import blob_centroid

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
QUALISYS = DATA / "c3d" / "Qualisys.c3d"
pytestmark = pytest.mark.skipif(not QUALISYS.is_file(), reason=f"shared real data not found at {DATA}")

RIG = """
[sensor]
mode = "ir"
exposure_ms = 2.0
motion_blur = false
shot_noise = false
read_noise_e = 0.0

[rig]
count = 4
radius_m = 3.0
height_m = 2.3
look_at = [0.3, -0.2, 0.9]
hfov_deg = 50.0
"""


def _scenario(tmp_path: Path, motion: str, head: str = "", name: str = "cap"):
    p = tmp_path / f"{name}.toml"
    p.write_text(f'name = "{name}"\n{head}\n[motion]\n{motion}\n{RIG}')
    return load_scenario(p)


def _raw_qualisys_m() -> tuple[list[str], np.ndarray, float]:
    c = ezc3d.c3d(str(QUALISYS))
    labels = [s.strip() for s in c["parameters"]["POINT"]["LABELS"]["value"]]
    return labels, c["data"]["points"][:3].transpose(2, 1, 0) / 1000.0, float(c["parameters"]["POINT"]["RATE"]["value"][0])


@pytest.fixture(scope="module")
def qualisys_render(tmp_path_factory):
    """12 frames at 100 fps from 0.5 s into Qualisys.c3d, 4 cameras, seeded gaps of 2-4 frames in 20 % of the markers."""
    sc = _scenario(tmp_path_factory.mktemp("q"), f'c3d = "{QUALISYS}"\nstart_s = 0.5\n'
                   "gaps = { fraction = 0.2, min_frames = 2, max_frames = 4 }", "seed = 5\nfps = 100.0\nduration_s = 0.12")
    bench = build_stage(sc)
    seq = render_frames(bench, keep_frames=True, keep_ids=True)
    return sc, bench, seq


def test_ground_truth_is_the_capture_resampled_and_recentred(qualisys_render):
    sc, bench, seq = qualisys_render
    gt = seq.ground_truth
    labels, raw, rate = _raw_qualisys_m()
    assert gt.marker_names == labels and gt.n_frames == 12
    # Independent resampling: per-coordinate linear interpolation of the file at capture
    # time start_s + t (the file has no gaps), then the horizontal shift that puts the
    # middle of the window's extent under the rig's look_at.
    u = 0.5 + gt.times
    src_t = np.arange(len(raw)) / rate
    expected = np.stack([np.stack([np.interp(u, src_t, raw[:, m, a]) for a in range(3)], -1)
                         for m in range(len(labels))], axis=1)  # (F, M, 3)
    mid = 0.5 * (expected[..., :2].reshape(-1, 2).min(0) + expected[..., :2].reshape(-1, 2).max(0))
    expected[..., :2] += np.array([0.3, -0.2]) - mid
    gaps = bench.clip.gap_mask
    assert gaps.any(axis=0).sum() == round(0.2 * 55)
    absent = np.isnan(gt.markers_3d).any(axis=2)
    np.testing.assert_array_equal(absent, gaps)  # the file has no gaps: only the seeded ones
    np.testing.assert_allclose(gt.markers_3d[~absent], expected[~absent], atol=1e-12)
    np.testing.assert_allclose(bench.clip.shift_xy, np.array([0.3, -0.2]) - mid)
    # No humanoid: its qpos and joint centres are absent from the truth.
    assert np.isnan(gt.qpos).all() and np.isnan(gt.joint_centres).all()
    # The reference a subject calibration gives: the file, without the seeded gaps.
    ref = bench.capture_reference()
    assert ref.labels == tuple(labels)
    np.testing.assert_allclose(ref.xyz, expected, atol=1e-12)


def test_absent_samples_are_not_rendered(qualisys_render):
    sc, bench, seq = qualisys_render
    gt = seq.ground_truth
    absent = np.isnan(gt.markers_3d).any(axis=2)  # (F, M)
    assert absent.sum() >= 11 * 2
    for c, name in enumerate(gt.camera_names):
        ids = gt.id_maps[name].astype(np.int64) - idc.MARKER_BASE  # (F, H, W)
        for f in range(gt.n_frames):
            counts = np.bincount(ids[f][ids[f] >= 0], minlength=len(gt.marker_names))
            assert (counts[absent[f]] == 0).all(), f"absent marker drawn in {name} frame {f}"
            assert not gt.marker_visible[f, c, absent[f]].any()
            assert (gt.marker_visible_frac[f, c, absent[f]] == 0).all()
    # The others are seen: most markers by at least two of the four cameras.
    seen2 = gt.marker_visible.sum(axis=1) >= 2
    assert seen2[~absent].mean() > 0.8


def test_marker_blobs_sit_on_the_projections(qualisys_render):
    """cv2.projectPoints of every visible capture marker vs its blob's intensity centroid."""
    sc, bench, seq = qualisys_render
    gt = seq.ground_truth
    cal = gt.calibration()
    errors = []
    for f in range(gt.n_frames):
        for c, cam in enumerate(cal):
            for m in np.flatnonzero(gt.marker_visible[f, c]):
                uv, _ = cv2.projectPoints(gt.markers_3d[f, m][None], cam.rvec, cam.t, cam.K, cam.dist)
                cen = blob_centroid(seq.frames[f, c], gt.id_maps[cam.name][f], m)
                assert cen is not None, f"visible marker {gt.marker_names[m]} has no blob in {cam.name} frame {f}"
                errors.append(np.hypot(*(np.array(cen) - uv.ravel())))
    errors = np.array(errors)
    print(f"\nQualisys markers vs blob centroids over {len(errors)} blobs: median {np.median(errors):.3f} px, "
          f"95th pct {np.percentile(errors, 95):.3f} px")
    assert len(errors) > 1000
    assert np.median(errors) <= 0.25 and np.percentile(errors, 95) <= 0.5


def test_seeded_gaps_fraction_lengths_and_reproducibility(tmp_path):
    """The whole Qualisys trial at its own 200 Hz: 20 % of 55 markers lose runs of 2-70 frames."""
    motion = f'c3d = "{QUALISYS}"\ngaps = {{ fraction = 0.2, min_frames = 2, max_frames = 70, runs = 2 }}'
    head = "fps = 200.0\nduration_s = 1.69"
    a = load_capture_clip(_scenario(tmp_path, motion, head + "\nseed = 11", "a"))
    again = load_capture_clip(_scenario(tmp_path, motion, head + "\nseed = 11", "a2"))
    other = load_capture_clip(_scenario(tmp_path, motion, head + "\nseed = 12", "b"))
    np.testing.assert_array_equal(a.gap_mask, again.gap_mask)
    assert not np.array_equal(a.gap_mask, other.gap_mask)
    F, M = a.gap_mask.shape
    assert (F, M) == (338, 55)
    for mask in (a.gap_mask, other.gap_mask):
        chosen = np.flatnonzero(mask.any(axis=0))
        assert len(chosen) == 11
        assert not mask[0].any() and not mask[-1].any()  # inside the window: real gaps
        lengths = []
        for m in chosen:
            padded = np.concatenate([[False], mask[:, m], [False]]).astype(np.int8)
            starts, ends = np.flatnonzero(np.diff(padded) == 1), np.flatnonzero(np.diff(padded) == -1)
            assert len(starts) == 2  # two runs, never touching
            lengths += list(ends - starts)
        assert min(lengths) >= 2 and max(lengths) <= 70
        assert max(lengths) > 30  # drawn over the range, not stuck at one end
    # Positions in a gap are NaN, elsewhere the file's.
    times = (np.arange(F) + 0.5 * 2.0 / 1000 * 200) / 200.0
    xyz = a.positions_at(times)
    np.testing.assert_array_equal(np.isnan(xyz).any(axis=2), a.gap_mask)


def test_seeded_gaps_directly():
    rng = np.random.default_rng(0)
    mask = seeded_gaps(CaptureGapsConfig(fraction=0.5, min_frames=3, max_frames=3, runs=3), 100, 10, rng)
    assert mask.any(axis=0).sum() == 5 and (mask.sum(axis=0)[mask.any(axis=0)] == 9).all()
    assert not seeded_gaps(CaptureGapsConfig(fraction=0.01), 100, 10, rng).any()  # round(0.1) = 0 markers


def test_resampling_missing_if_a_neighbour_used_is_missing(tmp_path):
    """A 100 Hz file with one missing sample, rendered at 50 fps with the shutter between samples."""
    t = np.arange(40) / 100.0
    xyz = np.zeros((40, 2, 3))
    xyz[:, 0] = [1.0, 0.0, 1.0]
    xyz[:, 1, 0] = t  # moves 1 m/s along X
    xyz[:, 1, 2] = 0.5
    xyz[10, 1] = np.nan
    path = write_c3d(tmp_path / "syn.c3d", Trajectories(["A", "B"], xyz, t), rate_hz=100.0)
    sc = _scenario(tmp_path, f'c3d = "{path.name}"', "fps = 50.0\nduration_s = 0.3")
    clip = load_capture_clip(sc)
    # Exactly on a sample: that sample only, so the neighbours of the gap are present.
    on = clip.file_positions_at(np.array([0.09, 0.10, 0.11]))
    assert np.isfinite(on[0, 1]).all() and np.isnan(on[1, 1]).all() and np.isfinite(on[2, 1]).all()
    # Between samples: missing if either neighbour is.
    between = clip.file_positions_at(np.array([0.095, 0.105, 0.115, 0.125]))
    assert np.isnan(between[:2, 1]).all() and np.isfinite(between[2:, 1]).all()
    np.testing.assert_allclose(between[2:, 1, 0] - clip.shift_xy[0], [0.115, 0.125], atol=1e-12)
    assert np.isfinite(between[:, 0]).all()
    # The scenario's frames (mid-exposure 1 ms after k / 50 s) fall between samples 2k and 2k + 1.
    frames = clip.positions_at(mid_exposure_times(sc.n_frames, sc.fps, sc.sensor.exposure_ms))
    assert np.isnan(frames[5, 1]).all() and np.isfinite(np.delete(frames[:, 1], 5, axis=0)).all()


def test_trc_scenario_y_up_to_z_up(tmp_path):
    ballet = DATA / "trc" / "ballet_reduced.trc"
    sc = _scenario(tmp_path, f'trc = "{ballet}"\nlabels = ["LFHD", "LTOE", "RFHD"]', "fps = 30.0\nduration_s = 1.0")
    clip = load_capture_clip(sc)
    assert clip.labels == ("RFHD", "LTOE", "LFHD")  # file order
    assert clip.source_up_axis == "y"
    z = clip.positions_at(mid_exposure_times(sc.n_frames, sc.fps, sc.sensor.exposure_ms))[..., 2]
    assert z[:, 0].min() > 1.4 and z[:, 1].max() < 0.3


def test_user_errors_name_the_field(tmp_path):
    with pytest.raises(ScenarioError, match=r"motion.labels.*L_NOPE.*choose from"):
        load_capture_clip(_scenario(tmp_path, f'c3d = "{QUALISYS}"\nlabels = ["L_IAS", "L_NOPE"]'))
    with pytest.raises(ScenarioError, match=r"duration_s.*runs past the end.*1.695 s"):
        load_capture_clip(_scenario(tmp_path, f'c3d = "{QUALISYS}"\nstart_s = 1.0', "duration_s = 1.0"))
    walking2 = DATA / "c3d" / "walking2.c3d"
    with pytest.raises(ScenarioError, match=r"motion.labels.*LAJC.*set aside: model output: joint centre"):
        load_capture_clip(_scenario(tmp_path, f'c3d = "{walking2}"\nlabels = ["LAJC"]'))
    p = tmp_path / "gone.toml"
    for motion, match in [
        ('c3d = "../../shared/nowhere/X.c3d"', r"motion.c3d.*file not found.*put shared/ beside the repository"),
        ('c3d = "a.c3d"\nbvh = "b.bvh"', r"one motion source"),
        ("gaps = { fraction = 0.2 }", r"capture file only"),
        ("marker_diameter_mm = 5.0", r"marker_diameter_mm.*capture file only"),
        ('subject_trial = "rest"', r"subject_trial.*capture file only"),
    ]:
        p.write_text(f'name = "gone"\n[motion]\n{motion}\n')
        with pytest.raises(ScenarioError, match=match):
            load_scenario(p)
    for bad in ("0.5", "120.0", "-5.0"):
        with pytest.raises(ScenarioError, match=r"motion.marker_diameter_mm"):
            _scenario(tmp_path, f'c3d = "{QUALISYS}"\nmarker_diameter_mm = {bad}')


def test_marker_diameter_is_the_rendered_and_expected_marker_size(tmp_path):
    """`motion.marker_diameter_mm`: a capture rendered with its system's marker size (here 5 mm
    LEDs, not the bench's 14 mm spheres). The spheres drawn have that size (the ground truth's
    visible fraction, drawn area over the area a sphere of that size covers, is about 1 for
    unoccluded markers, where the 14 mm expectation would give 0.13), the marker pipeline is
    given the same size, the IR detector finds the 1.1-1.3 px blobs, and a scenario without the
    field keeps the 14 mm spheres and its content hash."""
    from mocap.detection import DetectionParams, detect_markers
    from simbench.pipelines.markers import pipeline_params
    from simbench.scenes.markers import MARKER_RADIUS_M

    head = "seed = 5\nfps = 100.0\nduration_s = 0.03"
    sc = _scenario(tmp_path, f'c3d = "{QUALISYS}"\nstart_s = 0.5\nmarker_diameter_mm = 5.0', head, name="led")
    bench = build_stage(sc)
    assert bench.marker_radius_m == pytest.approx(0.0025)
    params = pipeline_params(sc)
    assert params.marker_radius_m == pytest.approx(0.0025) and params.reassociation.marker_radius_m == pytest.approx(0.0025)
    seq = render_frames(bench, keep_frames=True, keep_ids=True)
    gt = seq.ground_truth
    frac = gt.marker_visible_frac[gt.marker_visible_frac > 0]
    assert 0.85 <= np.median(frac) <= 1.15, np.median(frac)
    assert (gt.marker_visible.sum(axis=1) >= 2).mean() > 0.8  # as at 14 mm (test_absent_samples_are_not_rendered)
    found = visible = 0
    for f in range(gt.n_frames):
        for c in range(len(gt.camera_names)):
            det = detect_markers(seq.frames[f, c], DetectionParams(mode="ir"))
            truth = gt.markers_2d[f, c, gt.marker_visible[f, c]]
            visible += len(truth)
            if len(det):
                found += int((np.linalg.norm(truth[:, None] - det.xy[None], axis=2).min(axis=1) < 1.0).sum())
    print(f"\n5 mm markers: 2D recall {found}/{visible}, median visible fraction {np.median(frac):.2f}")
    assert found >= 0.95 * visible
    plain = _scenario(tmp_path, f'c3d = "{QUALISYS}"\nstart_s = 0.5', head, name="plain")
    assert build_stage(plain).marker_radius_m == MARKER_RADIUS_M and pipeline_params(plain).marker_radius_m == MARKER_RADIUS_M
    assert "marker_diameter_mm" not in plain.model_dump(mode="json")["motion"]
    assert "marker_diameter_mm" in sc.model_dump(mode="json")["motion"]


def test_reference_frame_and_label_template():
    """The template comes from the first frame with the most markers; a marker missing there
    is carried over from its nearest frame by the motion of the markers seen in both."""
    from simbench.scenes.capture_motion import CaptureReference

    xyz = np.full((4, 3, 3), np.nan)
    base = np.array([[0.0, 0.0, 1.0], [0.2, 0.0, 1.2], [0.0, 0.3, 0.5]])
    for f in range(4):
        xyz[f] = base + [0.1 * f, 0.0, 0.0]  # walking along X
    xyz[0, 1] = np.nan  # frame 0: 2 markers
    xyz[1, 2] = np.nan  # frames 1 and 3: 2 markers; frame 2: all 3
    xyz[3, 0] = np.nan
    ref = CaptureReference(("A", "B", "C"), xyz, np.arange(4) / 10.0)
    assert ref.reference_frame() == 2
    tpl = ref.label_template()
    expected = xyz[2] - [*xyz[2, :, :2].mean(axis=0), 0.0]
    np.testing.assert_allclose(tpl.positions, expected, atol=1e-12)
    xyz[2, 1] = np.nan  # now no frame has all three: frame 0 is the first with two
    ref = CaptureReference(("A", "B", "C"), xyz, np.arange(4) / 10.0)
    assert ref.reference_frame() == 0
    tpl = ref.label_template()
    # B from frame 1 (nearest with B), moved back by the 0.1 m the markers seen in both moved.
    pos = np.array([xyz[0, 0], xyz[1, 1] - [0.1, 0.0, 0.0], xyz[0, 2]])
    np.testing.assert_allclose(tpl.positions, pos - [*pos[:, :2].mean(axis=0), 0.0], atol=1e-12)


def test_run_scores_a_capture_without_a_humanoid(tmp_path):
    """simbench run on a capture scenario: no subject model or skeleton, the capture's markers
    labelled and scored against the capture."""
    import json

    from simbench.pipelines.run import run_scenario

    sc = _scenario(tmp_path, f'c3d = "{QUALISYS}"\nstart_s = 0.2', "seed = 2\nfps = 100.0\nduration_s = 0.15")
    result = run_scenario(sc, tmp_path / "out")
    out = tmp_path / "out"
    assert not (out / "exports" / "subject.toml").exists()
    names = [line.split(",")[0] for line in (out / "exports" / "label_template.csv").read_text().splitlines()[1:]]
    labels, _, _ = _raw_qualisys_m()
    assert names == labels
    metrics = json.loads((out / "metrics.json").read_text())
    assert not any(k.startswith("skeleton.") for k in metrics)
    print(f"\ncapture run: rmse {metrics['markers.rmse_mm']:.2f} mm, p95 {metrics['markers.p95_error_mm']:.2f} mm, "
          f"reconstructed {metrics['markers.reconstructed_fraction']:.3f}")
    assert metrics["markers.reconstructed_fraction"] > 0.9
    assert metrics["markers.p95_error_mm"] < 5.0
    assert result.capture is not None and result.capture.skeleton is None
    # What a user of real videos does: `mocap markers` on the run's MP4s with the real file as the labelled
    # trial (all of it, its own world frame) labels them as the run did (there: the frames' window)
    from typer.testing import CliRunner

    from mocap.cli.app import app
    from mocap.exports import read_c3d
    from simbench.stage.ground_truth import load_ground_truth

    r = CliRunner().invoke(app, ["markers", *sorted(str(v) for v in (out / "videos").glob("*.mp4")),
                                 "--calibration", str(out / "calibration_ground_truth.yml"),
                                 "--template", str(out / "exports" / "label_template.csv"),
                                 "--labelled-trial", str(QUALISYS), "--out", str(tmp_path / "cli")])
    assert r.exit_code == 0, r.stderr
    assert json.loads((tmp_path / "cli" / "summary.json").read_text())["labelling"] == "model"
    traj, gt = read_c3d(tmp_path / "cli" / "markers.c3d"), load_ground_truth(out)
    err = np.linalg.norm(traj.xyz[:, [traj.labels.index(n) for n in gt.marker_names]] - gt.markers_3d, axis=-1)
    assert np.isfinite(err).mean() >= metrics["markers.reconstructed_fraction"] - 0.02
    assert np.nanpercentile(err, 95) < 0.005
    # without --template: the trial's fullest frame is the template (its markers, in the file's order)
    r = CliRunner().invoke(app, ["markers", *sorted(str(v) for v in (out / "videos").glob("*.mp4")),
                                 "--calibration", str(out / "calibration_ground_truth.yml"),
                                 "--labelled-trial", str(QUALISYS), "--out", str(tmp_path / "cli_no_template")])
    assert r.exit_code == 0, r.stderr
    traj2 = read_c3d(tmp_path / "cli_no_template" / "markers.c3d")
    assert list(traj2.labels) == list(read_c3d(QUALISYS).labels)
    err2 = np.linalg.norm(traj2.xyz[:, [traj2.labels.index(n) for n in gt.marker_names]] - gt.markers_3d, axis=-1)
    assert np.isfinite(err2).mean() >= metrics["markers.reconstructed_fraction"] - 0.02
    assert np.nanpercentile(err2, 95) < 0.005


def test_source_label_swaps_are_exchanged_back_and_reported():
    """Swap repair of a capture's own labels: a label that jumps onto the path another label's
    run continues (a handover where that run ends, a takeover where it starts) is exchanged with
    it over that run. Synthetic: two markers 60 mm apart moving 5 mm a sample; the file calls
    marker P "b" in samples 0-9 and "a" from 10 on, and marker Q "a" in samples 0-9 and nothing
    after; then "b" takes P again in samples 30-39."""
    from mocap.swap_repair import repair_source_swaps

    t = np.arange(40)[:, None] * np.array([0.005, 0.0, 0.0])
    P, Q = t + [0.0, 0.0, 1.0], t + [0.0, 0.06, 1.0]
    a, b = P.copy(), np.full_like(P, np.nan)
    a[:10], b[:10] = Q[:10], P[:10]      # handover at sample 10
    b[30:], a[30:] = P[30:], Q[30:]      # takeover at sample 30
    fixed, events = repair_source_swaps(np.stack([a, b], axis=1))
    assert [(e[0], e[1], e[2], e[3]) for e in events] == [(0, 1, 0, 9), (0, 1, 30, 39)]
    assert events[0][4] == pytest.approx(0.06)           # the jump: Q to P
    np.testing.assert_allclose(fixed[:, 0], P)            # "a" follows P throughout
    np.testing.assert_allclose(fixed[:10, 1], Q[:10])     # "b" carries Q where the file had it
    np.testing.assert_allclose(fixed[30:, 1], Q[30:])
    assert np.isnan(fixed[10:30, 1]).all()
    # Continuous paths are left alone, gaps or not.
    b2 = Q.copy()
    b2[12:20] = np.nan
    assert repair_source_swaps(np.stack([P, b2], axis=1))[1] == []


@pytest.mark.skipif(not (DATA / "c3d" / "kinematics_basket_sprint.c3d").is_file(), reason="shared real data not found")
def test_basket_sprint_truth_has_its_forearm_swap_repaired():
    """c3d_basket_sprint: in the file, ForearmL:Marker4 is at the place ForearmL:Marker1 holds in
    frames 24-175 of the window in frames 0-23 and 176 only, while "Marker1" is there a point 73
    mm away. The truth exchanges the two over those frames (one line says so); Marker1 then has no
    jump in the window, and nothing else in the twelve captures is exchanged."""
    scenarios = Path(__file__).resolve().parents[1] / "scenarios"
    clip = load_capture_clip(load_scenario(scenarios / "c3d_basket_sprint.toml"))
    assert clip.label_repairs.count("ForearmL:Marker1 <-> ForearmL:Marker4") == 2, clip.label_repairs
    assert "\n" not in clip.label_repairs and "73 mm" in clip.label_repairs
    sc = load_scenario(scenarios / "c3d_basket_sprint.toml")
    times = mid_exposure_times(sc.n_frames, sc.fps, sc.sensor.exposure_ms)
    xyz = clip.file_positions_at(times)
    m1, m4 = clip.labels.index("ForearmL:Marker1"), clip.labels.index("ForearmL:Marker4")
    step = np.linalg.norm(np.diff(xyz[:, m1], axis=0), axis=1)
    assert np.isfinite(xyz[:, m1]).all() and step.max() < 0.03   # 73 mm at frames 23-24 and 175-176 before
    assert np.flatnonzero(np.isfinite(xyz[:, m4]).all(axis=1)).tolist() == list(range(24)) + [176]
    for name in ("c3d_qualisys_gaps", "c3d_codamotion_walk", "c3d_racing_propulsion", "trc_sprint_start"):
        assert load_capture_clip(load_scenario(scenarios / f"{name}.toml")).label_repairs == ""


@pytest.mark.skipif(not (DATA / "c3d" / "ADemo1_rewrite_c3d_pc_float.c3d").is_file(), reason="shared real data not found")
def test_codamotion_scenario_leaves_out_exactly_the_wand_markers_that_cross():
    """c3d_codamotion_walk renders 22 of the file's 24 markers. The two left out, the sacral wand's,
    cross through each other within the scenario's window: their offset along the pelvis's
    left-right axis (L.PSIS - R.PSIS) changes sign and they come within 5 mm, so passive markers
    (what the bench renders) cannot keep their identity; every other pair stays 25 mm or more apart."""
    from mocap.exports.c3d import read_c3d

    scenarios = Path(__file__).resolve().parents[1] / "scenarios"
    sc = load_scenario(scenarios / "c3d_codamotion_walk.toml")
    cap = read_c3d(DATA / "c3d" / "ADemo1_rewrite_c3d_pc_float.c3d")
    names = list(cap.labels)
    assert sorted(set(names) - set(sc.motion.labels)) == ["L.Sac.Wand", "R.Sac.Wand"]
    xyz = np.asarray(cap.xyz, float)
    t = np.asarray(cap.times) - cap.times[0]
    win = xyz[(t >= sc.motion.start_s) & (t <= sc.motion.start_s + sc.duration_s)]
    lr = win[:, names.index("L.PSIS")] - win[:, names.index("R.PSIS")]
    lr /= np.linalg.norm(lr, axis=1, keepdims=True)
    wand = win[:, names.index("L.Sac.Wand")] - win[:, names.index("R.Sac.Wand")]
    lateral = np.einsum("ij,ij->i", wand, lr)
    assert lateral.max() > 0.015 and lateral.min() < -0.010      # +33 mm at the start, -15 mm later
    assert np.nanmin(np.linalg.norm(wand, axis=1)) < 0.005       # 2.9 mm apart where they meet
    kept = win[:, [names.index(n) for n in sc.motion.labels]]
    d = np.linalg.norm(kept[:, :, None] - kept[:, None], axis=3)
    d[:, np.arange(d.shape[1]), np.arange(d.shape[1])] = np.inf
    assert np.nanmin(d) > 0.025


def test_rest_trial_is_the_files_samples_outside_the_window(tmp_path):
    """motion.subject_trial = "rest": the labelled trial the pipeline calibrates the subject from is the file's
    samples outside the rendered window (another trial of the same subject), not the window's frames; a window
    that leaves fewer than two such samples is refused, naming the field."""
    labels, raw, rate = _raw_qualisys_m()
    sc = _scenario(tmp_path, f'c3d = "{QUALISYS}"\nstart_s = 0.5\nsubject_trial = "rest"', "fps = 100.0\nduration_s = 0.5")
    bench = build_stage(sc)
    ref = bench.capture_reference()
    t_file = np.arange(len(raw)) / rate
    outside = (t_file < 0.5 - 1e-9) | (t_file > 1.0 + 1e-9)
    np.testing.assert_allclose(ref.times, t_file[outside])
    assert ref.labels == bench.clip.labels
    # the file's own positions there (the scene's horizontal shift applied, as to every position of the clip)
    idx = [labels.index(n) for n in ref.labels]
    expect = raw[outside][:, idx]
    expect = expect + np.r_[bench.clip.shift_xy, 0.0]
    np.testing.assert_allclose(ref.xyz, expect, atol=1e-9)
    take = build_stage(_scenario(tmp_path, f'c3d = "{QUALISYS}"\nstart_s = 0.5', "fps = 100.0\nduration_s = 0.5",
                                 name="take")).capture_reference()
    assert len(take.times) == 50 and take.times.max() < 0.5 + 1e-9  # scenario time, the window's frames
    with pytest.raises(ScenarioError, match=r"motion.subject_trial.*has 1 sample with 3 markers or more outside the window 0-1.69 s") as err:
        load_capture_clip(_scenario(tmp_path, f'c3d = "{QUALISYS}"\nsubject_trial = "rest"', "fps = 100.0\nduration_s = 1.69",
                                    name="all"))
    assert err.value.path == tmp_path / "all.toml"  # the scenario file (it named its folder)


def test_subject_trial_at_its_default_keeps_the_scenario_hash():
    """`motion.subject_trial` came after the baselines and sweep databases: at its default ("take", what every
    run before it did) it is left out of the content hash, so their hashes of the same scenarios stay; "rest"
    is another scenario."""
    import hashlib
    import json

    sc = load_scenario(Path(__file__).resolve().parents[1] / "scenarios" / "c3d_qualisys_gaps.toml")
    data = sc.model_dump(mode="json")
    data.pop("seeds", None)
    del data["motion"]["subject_trial"]
    before = hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]
    assert sc.content_hash() == before
    assert sc.with_overrides({"motion.subject_trial": "rest"}).content_hash() != before
