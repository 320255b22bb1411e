"""eval.calibration_metrics against known perturbations of a calibration."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eval.calibration_metrics import align_worlds, compare_calibrations, distortion_error_px
from mocap.calib.synthetic import look_at
from mocap.calibration import Calibration, Camera


def rig(n: int = 4) -> Calibration:
    cams = []
    for i in range(n):
        a = np.radians(-60 + 40 * i)
        R, t = look_at(np.array([3 * np.sin(a), -3 * np.cos(a), 1.5 + 0.2 * i]), np.array([0.0, 0.0, 1.0]))
        f = 800.0 + 10 * i
        cams.append(Camera(f"c{i}", (1280, 720), [[f, 0, 640], [0, f, 360], [0, 0, 1]], [-0.1, 0.03, 0, 0, 0.0], R, t))
    return Calibration(tuple(cams))


def moved_world(cal: Calibration, R: np.ndarray, t: np.ndarray, s: float = 1.0) -> Calibration:
    """The same cameras expressed in a world with ``x_new = s R x_old + t``."""
    out = []
    for c in cal:
        # x_cam = Rc x_old + tc, x_old = R^T (x_new - t) / s  ->  scale the camera frame by s too.
        Rn = c.R @ R.T
        tn = s * c.t - Rn @ t
        out.append(c.replace(R=Rn, t=tn))
    return Calibration(tuple(out))


def test_identical_calibrations_score_zero():
    truth = rig()
    for align in ("none", "rigid", "similarity"):
        s = compare_calibrations(truth, truth, align=align)["summary"]
        for key in ("focal_error_pct", "principal_point_error_px", "distortion_error_px", "projection_error_max_px",
                    "rotation_error_deg", "translation_error_mm"):
            assert s[key] == pytest.approx(0.0, abs=1e-6), (align, key)


def test_focal_and_principal_point_errors():
    truth = rig()
    est_cams = list(truth)
    K = est_cams[1].K.copy()
    K[0, 0] *= 1.01
    K[1, 2] += 3.0
    K[0, 2] -= 4.0
    est_cams[1] = est_cams[1].replace(K=K)
    res = compare_calibrations(Calibration(tuple(est_cams)), truth, align="none", reprojection_rms_px={"c1": 0.2})
    c1 = res["per_camera"]["c1"]
    assert c1["focal_error_pct"] == pytest.approx(1.0)
    assert c1["fx_error_px"] == pytest.approx(8.1)
    assert c1["principal_point_error_px"] == pytest.approx(5.0)
    assert c1["distortion_error_px"] == pytest.approx(0.0, abs=1e-9)  # same coefficients: K errors are not distortion
    assert c1["projection_error_max_px"] > 5.0
    assert c1["reprojection_rms_px"] == 0.2
    assert res["summary"]["focal_error_pct"] == pytest.approx(1.0)
    assert res["summary"]["focal_error_pct_mean"] == pytest.approx(0.25)
    assert res["per_camera"]["c0"]["focal_error_pct"] == 0.0


def test_distortion_error_is_the_worst_radial_displacement():
    f, w, h = 500.0, 640, 480
    truth = Camera("c", (w, h), [[f, 0, 319.5], [0, f, 239.5], [0, 0, 1]], np.zeros(5))
    k1 = 0.01
    est = truth.replace(dist=[k1, 0, 0, 0, 0])
    # With no true distortion, the image corner (0, 0) is the ray of largest radius r, and
    # k1 moves it by f * k1 * r^3 pixels.
    r = np.hypot(319.5, 239.5) / f
    assert distortion_error_px(est, truth) == pytest.approx(f * k1 * r ** 3, rel=1e-9)


def test_rigid_alignment_removes_a_moved_world():
    truth = rig()
    Ra = Rotation.from_euler("xyz", [10, -20, 35], degrees=True).as_matrix()
    ta = np.array([0.3, -1.0, 0.25])
    est = moved_world(truth, Ra, ta)
    raw = compare_calibrations(est, truth, align="none")
    for c in truth:
        e = raw["per_camera"][c.name]
        assert e["rotation_error_deg"] == pytest.approx(np.degrees(Rotation.from_matrix(Ra).magnitude()), abs=1e-6)
        assert e["translation_error_mm"] == pytest.approx(1000 * np.linalg.norm(Ra @ c.center + ta - c.center), rel=1e-9)
        assert e["focal_error_pct"] == 0.0
    aligned = compare_calibrations(est, truth, align="rigid")
    assert aligned["summary"]["rotation_error_deg"] == pytest.approx(0.0, abs=1e-6)
    assert aligned["summary"]["translation_error_mm"] == pytest.approx(0.0, abs=1e-6)
    assert aligned["alignment"]["rotation_deg"] == pytest.approx(np.degrees(Rotation.from_matrix(Ra).magnitude()), abs=1e-6)


def test_similarity_alignment_finds_the_scale():
    truth = rig()
    Ra = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    est = moved_world(truth, Ra, np.array([1.0, 2.0, 0.0]), s=2.0)  # everything twice as large
    R, t, s = align_worlds(est, truth, "similarity")
    assert s == pytest.approx(0.5)
    sim = compare_calibrations(est, truth, align="similarity")["summary"]
    assert sim["translation_error_mm"] == pytest.approx(0.0, abs=1e-6)
    assert sim["rotation_error_deg"] == pytest.approx(0.0, abs=1e-6)
    rigid = compare_calibrations(est, truth, align="rigid")["summary"]
    assert rigid["translation_error_mm"] > 100.0  # a rigid fit cannot undo a scale


def test_two_cameras_align_from_their_orientations():
    truth = rig(2)
    Ra = Rotation.from_euler("xyz", [5, 15, -40], degrees=True).as_matrix()
    est = moved_world(truth, Ra, np.array([0.5, 0.0, -0.2]))
    s = compare_calibrations(est, truth, align="rigid")["summary"]
    assert s["rotation_error_deg"] == pytest.approx(0.0, abs=1e-6)
    assert s["translation_error_mm"] == pytest.approx(0.0, abs=1e-5)


def test_unknown_camera_and_mode():
    truth = rig()
    other = Calibration((truth[0].replace(name="zz"),))
    with pytest.raises(KeyError, match="zz"):
        compare_calibrations(other, truth)
    with pytest.raises(ValueError, match="align"):
        compare_calibrations(truth, truth, align="affine")
