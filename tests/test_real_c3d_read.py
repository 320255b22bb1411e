"""read_c3d / read_trc on every real capture in ../shared/data: physical markers only, units, axes, rate.

The expected values below are known values, written down from the description of each file
in ../shared/data/README.md and checked against the raw file (ezc3d's view) by hand:
how many entries are physical markers, which labels those are where the README names them,
the file's units, up axis and rate.
"""

from __future__ import annotations

from pathlib import Path

import ezc3d
import numpy as np
import pytest

from mocap.exports import CaptureTrajectories, read_c3d, read_trc, write_c3d
from mocap.types import Trajectories

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
C3D_FILES = sorted((DATA / "c3d").glob("*.c3d"))
TRC_FILES = sorted((DATA / "trc").glob("*.trc"))

pytestmark = pytest.mark.skipif(not C3D_FILES, reason=f"shared real data not found at {DATA}")

# file -> (POINT entries, physical markers kept, frames, rate Hz, units, file's up axis)
KNOWN_C3D = {
    "Qualisys.c3d": (55, 55, 340, 200.0, "mm", "z"),
    "Sample_Static.c3d": (141, 35, 275, 100.0, "mm", "z"),
    "BTS.c3d": (22, 22, 675, 100.0, "mm", "y"),
    "kinematics_basket_sprint.c3d": (26, 26, 3678, 120.0, "m", "z"),
    "kinematics_racing_propulsion.c3d": (41, 35, 700, 69.99261474609375, "m", "y"),
    "walking2.c3d": (44, 30, 1249, 250.0, "mm", "z"),
    "ADemo1_rewrite_c3d_pc_float.c3d": (24, 24, 512, 200.0, "mm", "z"),
    "FunctionalWalk.c3d": (146, 36, 438, 120.0, "mm", "z"),
    "Res16bits.c3d": (44, 40, 100, 100.0, "mm", "z"),
    "sub_labels.c3d": (114, 16, 333, 60.0, "mm", "z"),
}
# file -> (markers kept, frames, DataRate, file's up axis)
KNOWN_TRC = {
    "SprintMotion.trc": (59, 788, 250.0, "z"),
    "ballet_reduced.trc": (41, 100, 30.0, "y"),
}

# Plug-in Gait static trial: the 35 markers of the full-body set as this lab used it
# (no upper-arm/forearm wands LUPA LFRM RUPA RFRM; RBAK only); the 106 other entries are
# 19 segments x 4 axis points, 4 unlabelled '*N' trajectories and 26 angles.
SAMPLE_STATIC_MARKERS = (
    "LFHD RFHD LBHD RBHD C7 T10 CLAV STRN RBAK LSHO LELB LWRA LWRB LFIN RSHO RELB RWRA RWRB RFIN "
    "LASI RASI LPSI RPSI LTHI LKNE LTIB LANK LHEE LTOE RTHI RKNE RTIB RANK RHEE RTOE"
).split()
# FunctionalWalk: the 36 visible marker entries (pelvis, legs and the four 5-marker clusters);
# the other 31 marker entries (upper body, SACR, medial knee/ankle, the two hip centres) are empty.
FUNCTIONAL_WALK_MARKERS = (
    "LASI RASI LPSI RPSI LTHI LKNE LTIB LANK LHEE LTOE RTHI RKNE RTIB RANK RHEE RTOE "
    "LF01 LF02 LF03 LF04 LF05 RF01 RF02 RF03 RF04 RF05 LT01 LT02 LT03 LT04 LT05 RT01 RT02 RT03 RT04 RT05"
).split()
FUNCTIONAL_WALK_EMPTY = (
    "LFHD RFHD LBHD RBHD C7 T10 CLAV STRN LBAK RBAK LSHO LUPA LELB LFRA LWRA LWRB LFIN "
    "RSHO RUPA RELB RFRA RWRA RWRB RFIN SACR LKNEin LANKin RKNEin RANKin"
).split()
WALKING2_VIRTUAL = "RLFC RMFC LLFC LMFC RMMAL RLMAL LMMAL LLMAL LAJC LHJC LKJC RAJC RHJC RKJC".split()


def _raw(path: Path) -> tuple[list[str], np.ndarray]:
    """ezc3d's labels and points ``(F, N, 3)`` in the file's units and axes (NaN where invalid)."""
    c = ezc3d.c3d(str(path))
    labels = [s.strip() for s in c["parameters"]["POINT"]["LABELS"]["value"]]
    pts = c["data"]["points"][:3].transpose(2, 1, 0).copy()
    pts[c["data"]["meta_points"]["residuals"][0].T < 0] = np.nan
    return labels, pts


def test_every_shared_capture_is_known():
    """A capture added to ../shared must get its known values here."""
    assert sorted(p.name for p in C3D_FILES) == sorted(KNOWN_C3D)
    assert sorted(p.name for p in TRC_FILES) == sorted(KNOWN_TRC)


@pytest.mark.parametrize("path", C3D_FILES, ids=[p.name for p in C3D_FILES])
def test_c3d_physical_markers_units_axes_rate(path):
    n_entries, n_kept, n_frames, rate, units, up = KNOWN_C3D[path.name]
    traj = read_c3d(path)
    assert isinstance(traj, CaptureTrajectories) and isinstance(traj, Trajectories)
    raw_labels, raw = _raw(path)
    assert len(raw_labels) == n_entries
    # Exactly the physical markers are kept; every other entry is accounted for, with a reason.
    assert len(traj.labels) == n_kept, sorted(traj.set_aside.items())
    assert len(traj.labels) + len(traj.set_aside) == n_entries
    assert len(set(traj.labels)) == len(traj.labels)
    assert all(traj.set_aside.values())
    # Rate and time: the file's exact POINT:RATE; units and up axis as the file says.
    assert traj.xyz.shape == (n_frames, n_kept, 3)
    assert traj.point_rate_hz == pytest.approx(rate, rel=1e-9)
    np.testing.assert_allclose(np.diff(traj.times), 1.0 / rate, rtol=1e-9)
    assert traj.source_units == units and traj.source_up_axis == up, traj.up_axis_reason
    # Positions: the raw points, in metres, rotated so the file's up axis is world Z.
    scale = 1e-3 if units == "mm" else 1.0
    idx = [raw_labels.index(n) for n in traj.labels]  # a repeated label: its first entry is the one kept
    expected = raw[:, idx] * scale
    if up == "y":
        expected = np.stack([expected[..., 0], -expected[..., 2], expected[..., 1]], axis=-1)
    np.testing.assert_allclose(traj.xyz, expected, atol=1e-12)
    # Markers on people stand above the floor, below 2.6 m, and each has samples.
    assert np.nanmin(traj.xyz[..., 2]) > -0.05 and np.nanmax(traj.xyz[..., 2]) < 2.6
    assert np.isfinite(traj.xyz).all(axis=2).any(axis=0).all()


def test_sample_static_keeps_exactly_the_plugin_gait_markers():
    traj = read_c3d(DATA / "c3d" / "Sample_Static.c3d")
    assert traj.labels == SAMPLE_STATIC_MARKERS
    reasons = traj.set_aside
    assert sum("listed in POINT:ANGLES" in r for r in reasons.values()) == 26
    assert sum("segment origin/axis" in r for r in reasons.values()) == 76  # 19 segments x O, A, L, P
    assert [k for k, r in reasons.items() if r.startswith("unlabelled")] == ["*111", "*112", "*113", "*114"]
    assert "PELO" in reasons and "LHipAngles" in reasons and "TRXP" in reasons


def test_functional_walk_keeps_the_visible_markers_and_says_why_for_the_rest():
    traj = read_c3d(DATA / "c3d" / "FunctionalWalk.c3d")
    assert traj.labels == FUNCTIONAL_WALK_MARKERS
    r = traj.set_aside
    assert [k for k, v in r.items() if v == "empty for the whole trial"] == FUNCTIONAL_WALK_EMPTY
    assert r["LeftHipCenter"].startswith("model output") and r["RightHipCenterScore"].startswith("model output")
    assert r["#"].startswith("virtual point")
    assert sum("POINT:ANGLES" in v for v in r.values()) == 12
    assert sum("POINT:FORCES" in v for v in r.values()) == 10
    assert sum("POINT:MOMENTS" in v for v in r.values()) == 8
    assert sum("POINT:POWERS" in v for v in r.values()) == 6
    assert r["RFEP"].startswith("model output") and r["PELO"].startswith("model output")
    # 67 marker entries (36 kept, 29 empty, the 2 empty hip centres: model outputs by name) and 79 virtual ones.
    assert len(r) - len(FUNCTIONAL_WALK_EMPTY) - 2 == 79
    # The visible markers have no gap.
    assert np.isfinite(traj.xyz).all()


def test_walking2_sets_aside_the_14_model_points():
    traj = read_c3d(DATA / "c3d" / "walking2.c3d")
    assert len(traj.labels) == 30 and sorted(traj.set_aside) == sorted(WALKING2_VIRTUAL)
    assert all("joint centre" in traj.set_aside[n] for n in ("LAJC", "LHJC", "LKJC", "RAJC", "RHJC", "RKJC"))
    assert all("exactly the frames" in traj.set_aside[n] for n in ("RLFC", "LMMAL"))
    # The physical markers appear from frame 206 and are gone by 1229; each in one span.
    present = np.isfinite(traj.xyz).all(axis=2)
    first = present.argmax(axis=0)
    assert first.min() == 206 and first.max() == 423
    all_in = np.flatnonzero(present.all(axis=1))
    assert (all_in[0], all_in[-1]) == (423, 836)
    # Walking along +X, about 6.7 m over the trial.
    with np.errstate(invalid="ignore"):
        centroid = np.nanmean(np.where(present[..., None], traj.xyz, 0.0), axis=1) / present.mean(axis=1)[:, None]
    assert 6.0 < np.nanmax(centroid[:, 0]) - np.nanmin(centroid[:, 0]) < 7.5


def test_sub_labels_dec_file_keeps_its_visible_markers():
    """DEC (VAX) integer storage, subject prefixes, legacy empty labels and model outputs."""
    traj = read_c3d(DATA / "c3d" / "sub_labels.c3d")
    expected = ["Matt:" + n for n in "C7 RCLA LCLA SACR RASI LASI RTHI RTIB RANK RTOE LTHI LTIB LANK LTOE LKNE RKNE".split()]
    assert traj.labels == expected
    r = traj.set_aside
    assert all(r[n] == "empty for the whole trial" for n in ("N", "RS", "LQ", "Matt:RKAX", "Matt:LHEE"))
    assert r["Matt:PELO"].startswith("model output") and "POINT:POWERS" in r["Matt:LHipPower"]
    # 27.9 % of the 14 prefixed visible markers' samples are missing (README).
    prefixed = [traj.labels.index(n) for n in expected[:14]]
    assert np.isnan(traj.xyz[:, prefixed, 0]).mean() == pytest.approx(0.279, abs=0.001)
    # The sacrum about 0.77 m up once decoded from DEC integers with POINT:SCALE (0.0805 mm).
    assert 0.7 < np.nanmedian(traj.xyz[:, traj.labels.index("Matt:SACR"), 2]) < 1.1


def test_res16bits_duplicate_labels_keep_the_first_entry():
    traj = read_c3d(DATA / "c3d" / "Res16bits.c3d")
    dups = {k: v for k, v in traj.set_aside.items() if v.startswith("duplicate label")}
    assert sorted(dups) == ["LCOU (entry 16)", "LMAI (entry 20)", "RCOU (entry 15)", "RMAI (entry 19)"]
    assert "entry 13, which is kept" in dups["RCOU (entry 15)"]
    raw_labels, raw = _raw(DATA / "c3d" / "Res16bits.c3d")
    np.testing.assert_allclose(traj.xyz[:, traj.labels.index("RCOU")], raw[:, 12] / 1000.0)


def test_racing_propulsion_non_integer_rate_metres_and_y_up():
    traj = read_c3d(DATA / "c3d" / "kinematics_racing_propulsion.c3d")
    assert traj.point_rate_hz == pytest.approx(69.9926, abs=1e-4)
    assert traj.times[-1] - traj.times[0] == pytest.approx(699 / 69.99261474609375)
    assert traj.rate_hz == pytest.approx(69.9926, abs=1e-4)
    assert traj.source_units == "m" and "only Y" in traj.up_axis_reason
    assert sorted(traj.set_aside) == [f"Probe{i}" for i in range(1, 7)]
    # Crouched racing posture: after Y -> Z the back (scapula markers) is highest and the
    # wheelchair's front marker lowest.
    z = np.nanmedian(traj.xyz[..., 2], axis=0)
    assert traj.labels[int(np.argmax(z))].startswith("Scapula")
    assert traj.labels[int(np.argmin(z))] == "WheelchairFront"
    assert z.max() - z.min() > 0.4


def test_bts_y_up_walk_stays_along_x():
    traj = read_c3d(DATA / "c3d" / "BTS.c3d")
    assert traj.source_up_axis == "y" and traj.up_axis_reason == "POINT:Y_SCREEN = '+Y'"
    c7 = np.nanmedian(traj.xyz[:, traj.labels.index("c7"), 2])
    heel = np.nanmedian(traj.xyz[:, traj.labels.index("r heel"), 2])
    assert 1.2 < c7 < 1.5 and heel < 0.15
    sacrum = traj.xyz[:, traj.labels.index("sacrum"), 0]
    assert np.nanmax(sacrum) - np.nanmin(sacrum) > 4.0  # +X travel
    # An override reads the same file as Z up (as is).
    as_is = read_c3d(DATA / "c3d" / "BTS.c3d", up_axis="z")
    np.testing.assert_allclose(as_is.xyz[..., 1], traj.xyz[..., 2])


def test_physical_only_false_returns_every_entry():
    path = DATA / "c3d" / "walking2.c3d"
    every = read_c3d(path, physical_only=False)
    assert len(every.labels) == 44 and every.set_aside == {}


def test_own_files_state_z_up(tmp_path):
    """write_c3d writes POINT:X_SCREEN/Y_SCREEN, so its files are read back as Z up whatever the data."""
    xyz = np.zeros((3, 2, 3))
    xyz[..., 1] = 1.0  # every marker 1 m along Y: the data alone would suggest Y up
    traj = Trajectories(["A", "B"], xyz + np.arange(3)[:, None, None] * 0.01, np.arange(3) / 100.0)
    back = read_c3d(write_c3d(tmp_path / "y.c3d", traj))
    assert back.source_up_axis == "z" and back.up_axis_reason == "POINT:Y_SCREEN = '+Z'"
    np.testing.assert_allclose(back.xyz, traj.xyz)


@pytest.mark.parametrize("path", TRC_FILES, ids=[p.name for p in TRC_FILES])
def test_trc_markers_units_axes_rate(path):
    n_kept, n_frames, rate, up = KNOWN_TRC[path.name]
    traj = read_trc(path, axes="auto")
    assert traj.xyz.shape == (n_frames, n_kept, 3) and traj.set_aside == {}
    assert traj.source_up_axis == up and traj.source_units == "mm"
    assert traj.point_rate_hz == rate
    np.testing.assert_allclose(np.diff(traj.times), 1.0 / rate, rtol=1e-9)
    assert np.isfinite(traj.xyz).all()  # both files are gap-filled
    assert 0.0 < np.min(traj.xyz[..., 2]) and np.max(traj.xyz[..., 2]) < 2.0
    # Same numbers as the file's columns, mm -> m, up axis onto Z.
    as_world = read_trc(path, axes="world")
    expected = as_world.xyz if up == "z" else np.stack([as_world.xyz[..., 0], -as_world.xyz[..., 2], as_world.xyz[..., 1]], -1)
    np.testing.assert_allclose(traj.xyz, expected)


def test_sprint_trc_starts_low_and_runs_along_x():
    traj = read_trc(DATA / "trc" / "SprintMotion.trc", axes="auto")
    sacrum = traj.xyz[:, traj.labels.index("Sacral")]
    assert sacrum[0, 2] == pytest.approx(0.616, abs=0.005) and sacrum[-1, 2] == pytest.approx(0.846, abs=0.005)
    assert sacrum[-1, 0] - sacrum[0, 0] == pytest.approx(2.95, abs=0.05)
    assert traj.labels[-4:] == ["StartG", "StartD", "StartAvt", "StartArr"]
    assert "LEIAS" in traj.labels


def test_ballet_trc_rounded_time_column_uses_the_data_rate():
    """The Time column steps by a rounded 0.033 s; DataRate says 30 Hz."""
    path = DATA / "trc" / "ballet_reduced.trc"
    traj = read_trc(path, axes="auto")
    assert traj.rate_hz == pytest.approx(30.0)
    assert traj.times[3] == pytest.approx(0.1) and traj.times[-1] == pytest.approx(99 / 30)
    assert traj.labels[0] == "RFHD" and traj.labels[-1] == "LFHD"
    head = np.median(traj.xyz[:, traj.labels.index("LFHD"), 2])
    toe = np.median(traj.xyz[:, traj.labels.index("LTOE"), 2])
    assert head > 1.4 and toe < 0.2


def test_own_files_keep_every_label(tmp_path):
    """A label the pipeline never reconstructed stays in a round trip through write_c3d."""
    xyz = np.full((4, 2, 3), np.nan)
    xyz[:, 0] = [0.5, 0.2, 1.0]
    traj = Trajectories(["LASI", "RASI"], xyz, np.arange(4) / 100.0)
    back = read_c3d(write_c3d(tmp_path / "empty.c3d", traj))
    assert back.labels == ["LASI", "RASI"] and back.set_aside == {}
    assert np.isnan(back.xyz[:, 1]).all()
