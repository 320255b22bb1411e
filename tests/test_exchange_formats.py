"""Exchange formats (issue 14, part 5): every calibration format's round trip reproduces the
cameras (ground-truth points project within 1e-6 px), loaders refuse what they would misread,
and read_trc's axes put Pose2Sim's and OpenSim's files the right way round."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.calibration import Calibration, Camera
from mocap.calibration_formats import CALIBRATION_FILE_NAMES, CALIBRATION_FORMATS, load_calibration, save_calibration
from mocap.calib.synthetic import look_at
from mocap.errors import CalibrationFileError
from mocap.exports import read_trc, write_trc
from mocap.types import Trajectories


def _rig(n: int = 11) -> Calibration:
    """``n`` distorted cameras on a circle (11: anipose's cam_10 must not sort before cam_2)."""
    rng = np.random.default_rng(5)
    cams = []
    for i in range(n):
        az = 2 * np.pi * i / n
        R, t = look_at(np.array([3.0 * np.cos(az), 3.0 * np.sin(az), 1.5 + 0.1 * i]), np.array([0.0, 0.0, 1.0]))
        f = 600.0 + 13.0 * i
        K = np.array([[f, 0.0, 320.0 + i], [0.0, f * 1.001, 240.0 - i], [0.0, 0.0, 1.0]])
        dist = rng.normal(0.0, [0.05, 0.01, 0.001, 0.001, 0.002])
        if i % 2:
            dist[4] = 0.0  # Pose2Sim's 4-term files
        cams.append(Camera(f"cam{i}", (640, 480), K, dist, R, t))
    return Calibration(tuple(cams))


@pytest.mark.parametrize("fmt", CALIBRATION_FORMATS)
def test_round_trip_projects_within_1e6_px(tmp_path, fmt):
    truth = _rig()
    files = save_calibration(truth, tmp_path, fmt)
    assert files[0].name == CALIBRATION_FILE_NAMES[fmt]
    back = load_calibration(files[0])
    assert back.names == truth.names
    pts = np.random.default_rng(1).uniform([-1.0, -1.0, 0.0], [1.0, 1.0, 2.0], (500, 3))
    for a, b in zip(truth, back):
        assert b.size == a.size
        uv_a, uv_b = a.project(pts), b.project(pts)
        ok = np.isfinite(uv_a).all(axis=1)
        assert ok.sum() > 400
        assert np.abs(uv_a[ok] - uv_b[ok]).max() < 1e-6


def test_fisheye_is_refused_by_every_toml_loader(tmp_path):
    save_calibration(_rig(2), tmp_path, "pose2sim")
    p = tmp_path / "Calib.toml"
    p.write_text(p.read_text().replace("fisheye = false", "fisheye = true"))
    with pytest.raises(CalibrationFileError, match=r"cam0\.fisheye.*value True.*recalibrate"):
        load_calibration(p)
    with pytest.raises(CalibrationFileError, match=r"fisheye"):
        Calibration.load_toml(p)  # the older loader read it as a pinhole


def test_loaders_refuse_what_they_would_misread(tmp_path):
    save_calibration(_rig(2), tmp_path, "anipose")
    p = tmp_path / "calibration.toml"
    text = p.read_text()
    p.write_text(text.replace("distortions = [", "distortions = [0.0, 0.0, 0.0, 0.0, ", 1))
    with pytest.raises(CalibrationFileError, match=r"cam_0.*9 distortion terms"):
        load_calibration(p)
    save_calibration(_rig(2), tmp_path, "easymocap")
    (tmp_path / "intri.yml").write_text((tmp_path / "intri.yml").read_text().replace("H_cam0", "Hx_cam0"))
    with pytest.raises(CalibrationFileError, match=r"H_cam0.*missing"):
        load_calibration(tmp_path)
    with pytest.raises(CalibrationFileError, match=r"unknown calibration file type"):
        load_calibration(tmp_path / "calib.txt")


def test_read_trc_axes_pose2sim_and_opensim(tmp_path):
    """A point in front (+x), to the left (+y) and up (+z) of the world comes back where it was
    from both Y-up conventions; a Pose2Sim file read as OpenSim's is turned 90 deg about Z."""
    world = np.array([[[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 1.5]]])
    traj = Trajectories(["front", "left", "up"], np.repeat(world, 2, axis=0), np.array([0.0, 0.01]))
    for axes in ("opensim", "pose2sim", "world"):
        write_trc(tmp_path / f"{axes}.trc", traj, axes=axes)
        back = read_trc(tmp_path / f"{axes}.trc", axes=axes)
        np.testing.assert_allclose(back.xyz, traj.xyz, atol=1e-9)
    # Pose2Sim's zup2yup puts world y in the file's X: the 'left' point is the file's X = 2000 mm
    row = (tmp_path / "pose2sim.trc").read_text().splitlines()[6].split("\t")
    assert [float(v) for v in row[5:8]] == [2000.0, 0.0, 0.0]
    wrong = read_trc(tmp_path / "pose2sim.trc", axes="opensim").xyz[0]
    np.testing.assert_allclose(wrong[0], [0.0, -1.0, 0.0], atol=1e-9)  # front came back as right: 90 deg yaw


@pytest.mark.parametrize("fmt", ["anipose", "pose2sim"])
def test_scenario_rig_from_calibration_renders_the_files_cameras(tmp_path, fmt):
    """``[rig] from_calibration``: the rendered ground-truth cameras are the file's (same K, dist,
    R, t: points project identically), and the rendered markers land where they project."""
    from simbench.scenario import load_scenario
    from simbench.stage.rendering import render_scenario

    truth = Calibration(tuple(c.replace(size=(160, 120), K=c.K * [[0.25], [0.25], [1.0]]) for c in _rig(3)))
    file = save_calibration(truth, tmp_path / "calib", fmt)[0]
    (tmp_path / "lab.toml").write_text(
        f'name = "lab"\nduration_s = 0.1\n[rig]\nfrom_calibration = "calib/{file.name}"\n'
        '[sensor]\nmode = "ir"\nexposure_ms = 4.0\nmotion_blur = false\nantialias = 1\n')
    seq = render_scenario(load_scenario(tmp_path / "lab.toml"), tmp_path / "out")
    gt = seq.ground_truth
    assert gt.camera_names == truth.names
    pts = np.random.default_rng(2).uniform([-1.0, -1.0, 0.0], [1.0, 1.0, 2.0], (200, 3))
    for a, b in zip(truth, gt.calibration()):
        np.testing.assert_array_equal(b.K, a.K)
        np.testing.assert_array_equal(b.dist, a.dist)
        uv_a, uv_b = a.project(pts), b.project(pts)
        ok = np.isfinite(uv_a).all(axis=1)
        assert np.abs(uv_a[ok] - uv_b[ok]).max() < 1e-6
    # the rendered 2D ground truth is the file's projection of the rendered 3D ground truth
    for c, cam in enumerate(truth):
        uv = cam.project(gt.markers_3d[0])
        vis = gt.marker_visible[0, c]
        assert vis.any()
        np.testing.assert_allclose(gt.markers_2d[0, c][vis], uv[vis], atol=1e-6)


def test_scenario_rig_from_a_fisheye_file_is_refused(tmp_path):
    from simbench.errors import ScenarioError
    from simbench.scenario import load_scenario

    save_calibration(_rig(2), tmp_path, "pose2sim")
    p = tmp_path / "Calib.toml"
    p.write_text(p.read_text().replace("fisheye = false", "fisheye = true"))
    (tmp_path / "lab.toml").write_text('name = "lab"\n[rig]\nfrom_calibration = "Calib.toml"\n')
    with pytest.raises(ScenarioError, match=r"lab\.toml.*rig.*fisheye"):
        load_scenario(tmp_path / "lab.toml")
