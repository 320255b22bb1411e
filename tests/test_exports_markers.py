"""C3D, TRC and CSV exports of labelled markers: read back, header fields, units, axes, gaps."""

from __future__ import annotations


import ezc3d
import numpy as np
import pytest

from mocap.errors import InputFileError, MocapInputError
from mocap.exports import opensim_to_world, read_c3d, read_csv, read_trc, world_to_opensim, write_c3d, write_csv, write_trc
from mocap.types import Trajectories



@pytest.fixture()
def traj() -> Trajectories:
    """50 frames at 120 Hz (first frame mid-exposure), 7 markers walking about a room, gaps and filled points."""
    rng = np.random.default_rng(7)
    F, M = 50, 7
    t = (np.arange(F) + 0.5) / 120.0
    base = rng.uniform([-2, -2, 0.05], [2, 2, 1.9], (M, 3))
    xyz = base + 0.3 * np.sin(2 * np.pi * 0.7 * t[:, None, None] + rng.uniform(0, 6, (M, 3)))
    xyz[10:14, 2] = np.nan  # a gap
    xyz[0, 6] = np.nan
    filled = np.zeros((F, M), dtype=bool)
    filled[20:23, 4] = True
    residual = rng.uniform(0.05, 1.5, (F, M))
    residual[~np.isfinite(xyz).all(axis=2)] = np.nan
    residual[filled] = np.nan
    labels = ["LASI", "RASI", "LPSI", "RPSI", "C7", "LKNE", "marker with spaces"]
    return Trajectories(labels, xyz, t, filled=filled, residual_px=residual)


def _gaps(traj: Trajectories) -> np.ndarray:
    return ~np.isfinite(traj.xyz).all(axis=2)


# ------------------------------------------------------------------------------ C3D
def test_c3d_round_trip_and_fields(traj, tmp_path):
    """Acceptance: written, read back by ezc3d, matches within 1e-4 m; rate, units, labels right."""
    path = write_c3d(tmp_path / "take.c3d", traj)
    raw = ezc3d.c3d(str(path))
    point = raw["parameters"]["POINT"]
    assert point["RATE"]["value"][0] == pytest.approx(120.0)
    assert point["UNITS"]["value"] == ["mm"]
    assert [s.strip() for s in point["LABELS"]["value"]] == traj.labels
    pts = raw["data"]["points"]
    assert pts.shape == (4, 7, 50)
    gaps = _gaps(traj)
    # ezc3d's raw view: millimetres, NaN and residual -1 in gaps, 0 for filled points.
    mm = pts[:3].transpose(2, 1, 0)
    np.testing.assert_allclose(mm[~gaps], 1000 * traj.xyz[~gaps], atol=0.1)  # 1e-4 m
    assert np.isnan(mm[gaps]).all()
    res = raw["data"]["meta_points"]["residuals"][0].T
    assert (res[gaps] == -1).all() and (res[traj.filled] == 0).all()
    measured = ~gaps & ~traj.filled
    np.testing.assert_allclose(res[measured], traj.residual_px[measured], atol=0.0101)  # stored in 0.01 px steps (truncated)

    back = read_c3d(path)
    assert back.labels == traj.labels
    err = np.abs(back.xyz[~gaps] - traj.xyz[~gaps]).max()
    print(f"\nC3D round trip: max error {err * 1e6:.2f} um")
    assert err < 1e-4
    np.testing.assert_array_equal(_gaps(back), gaps)
    np.testing.assert_array_equal(back.filled, traj.filled)
    np.testing.assert_allclose(back.times, traj.times, atol=1e-7)
    assert back.rate_hz == pytest.approx(120.0)
    np.testing.assert_allclose(back.residual_px[measured], traj.residual_px[measured], atol=0.0101)


def test_c3d_reads_a_real_capture_in_metres(shared_data):
    qualisys = shared_data / "c3d" / "Qualisys.c3d"
    """Qualisys.c3d: 55 labels, 200 Hz, 340 frames, mm -> m; filled flags not invented."""
    traj = read_c3d(qualisys)
    raw = ezc3d.c3d(str(qualisys))
    assert len(traj.labels) == 55 and traj.labels[0] == "L_IAS"
    assert traj.xyz.shape == (340, 55, 3)
    assert traj.rate_hz == pytest.approx(200.0)
    np.testing.assert_allclose(traj.xyz, raw["data"]["points"][:3].transpose(2, 1, 0) / 1000.0)
    assert not traj.filled.any() and np.isnan(traj.residual_px).all()
    # Standing adult: markers between the floor and ~2 m.
    assert 0.0 < np.nanmin(traj.xyz[..., 2]) and np.nanmax(traj.xyz[..., 2]) < 2.0


def test_c3d_errors(tmp_path, traj):
    with pytest.raises(InputFileError, match="no such file"):
        read_c3d(tmp_path / "nope.c3d")
    bad = tmp_path / "bad.c3d"
    bad.write_text("not a c3d")
    with pytest.raises(InputFileError, match="not a readable C3D"):
        read_c3d(bad)
    one = Trajectories(["A"], np.zeros((1, 1, 3)), [0.0])
    with pytest.raises(MocapInputError, match="rate_hz"):
        write_c3d(tmp_path / "one.c3d", one)
    assert not (tmp_path / "one.c3d").exists()
    write_c3d(tmp_path / "one.c3d", one, rate_hz=50.0)
    assert read_c3d(tmp_path / "one.c3d").xyz.shape == (1, 1, 3)
    with pytest.raises(MocapInputError, match="does not exist"):
        write_c3d(tmp_path / "no_dir" / "x.c3d", traj)


# ------------------------------------------------------------------------------ TRC
def test_trc_header_units_and_round_trip(traj, tmp_path):
    path = write_trc(tmp_path / "take.trc", traj)
    lines = path.read_text().split("\n")
    assert lines[0].split("\t") == ["PathFileType", "4", "(X/Y/Z)", "take.trc"]
    keys = lines[1].split("\t")
    assert keys == ["DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units", "OrigDataRate", "OrigDataStartFrame", "OrigNumFrames"]
    meta = dict(zip(keys, lines[2].split("\t")))
    assert float(meta["DataRate"]) == pytest.approx(120.0) and float(meta["CameraRate"]) == pytest.approx(120.0)
    assert meta["NumFrames"] == "50" and meta["NumMarkers"] == "7" and meta["Units"] == "mm"
    assert meta["OrigDataStartFrame"] == "1" and meta["OrigNumFrames"] == "50"
    assert [t for t in lines[3].split("\t") if t] == ["Frame#", "Time"] + traj.labels
    xyz_labels = lines[4].split("\t")
    assert xyz_labels[:2] == ["", ""] and xyz_labels[2:5] == ["X1", "Y1", "Z1"] and xyz_labels[-1] == "Z7"
    assert lines[5] == ""
    first = lines[6].split("\t")
    assert first[0] == "1" and float(first[1]) == pytest.approx(traj.times[0], abs=1e-9)
    assert len(first) == 2 + 3 * 7
    # Values in mm, OpenSim axes: (x, y, z)_trc = (x, z, -y)_world.
    x, y, z = traj.xyz[0, 0]
    np.testing.assert_allclose([float(v) for v in first[2:5]], [1000 * x, 1000 * z, -1000 * y], atol=1e-5)
    assert lines[6 + 10].split("\t")[2 + 3 * 2 : 5 + 3 * 2] == ["NaN"] * 3  # gap of marker 3, frame 10

    back = read_trc(path)
    gaps = _gaps(traj)
    assert back.labels == traj.labels
    np.testing.assert_array_equal(_gaps(back), gaps)
    np.testing.assert_allclose(back.xyz[~gaps], traj.xyz[~gaps], atol=1e-8)
    np.testing.assert_allclose(back.times, traj.times, atol=1e-6)

    world = read_trc(write_trc(tmp_path / "world.trc", traj, axes="world"), axes="world")
    np.testing.assert_allclose(world.xyz[~gaps], traj.xyz[~gaps], atol=1e-8)


def test_trc_reads_empty_fields_as_gaps(tmp_path):
    """Motion Analysis / older OpenSim files leave missing markers empty."""
    text = (
        "PathFileType\t4\t(X/Y/Z)\tx.trc\n"
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n"
        "60.00\t60.00\t2\t2\tm\t60.00\t1\t2\n"
        "Frame#\tTime\tA\t\t\tB\t\t\t\n"
        "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\t\n"
        "\n"
        "1\t0.0\t1.0\t2.0\t3.0\t\t\t\n"
        "2\t0.016667\t1.5\t2.5\t3.5\t4.0\t5.0\t6.0\n"
    )
    path = tmp_path / "x.trc"
    path.write_text(text)
    back = read_trc(path, axes="world")
    assert back.labels == ["A", "B"]
    np.testing.assert_allclose(back.xyz[0, 0], [1.0, 2.0, 3.0])  # Units m
    assert np.isnan(back.xyz[0, 1]).all()
    np.testing.assert_allclose(back.xyz[1, 1], [4.0, 5.0, 6.0])


def test_axis_conversion_is_a_proper_rotation():
    p = np.array([[1.0, 2.0, 3.0]])
    np.testing.assert_allclose(world_to_opensim(p), [[1.0, 3.0, -2.0]])  # Z up -> Y up, left -> -right
    np.testing.assert_allclose(opensim_to_world(world_to_opensim(p)), p)
    a, b = np.eye(3)[0], np.eye(3)[1]
    np.testing.assert_allclose(np.cross(world_to_opensim(a), world_to_opensim(b)), world_to_opensim(np.cross(a, b)))


def test_trc_errors(tmp_path, traj):
    bad = tmp_path / "bad.trc"
    bad.write_text("hello\n")
    with pytest.raises(InputFileError, match="PathFileType"):
        read_trc(bad)
    bad_labels = Trajectories(["A\tB"], np.zeros((2, 1, 3)), [0.0, 0.1])
    existing = write_trc(tmp_path / "keep.trc", traj)
    before = existing.read_text()
    with pytest.raises(MocapInputError, match="label"):
        write_trc(existing, bad_labels)
    # Nothing half-written: the old file is intact and no temporary file is left.
    assert existing.read_text() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.trc", "keep.trc"]


def test_trc_in_the_windows_code_page_or_with_a_byte_order_mark_reads_its_labels(traj, tmp_path):
    """A TRC declares no encoding; Windows capture software writes cp1252, some editors a UTF-8 byte-order mark.
    Read as the locale's text, a cp1252 accent was "not a text file"."""
    named = Trajectories(["genou_gauche_\xe9", "Kn\xf6chel"] + traj.labels[2:], traj.xyz, traj.times, traj.filled)
    utf8 = write_trc(tmp_path / "utf8.trc", named)
    text = utf8.read_text(encoding="utf-8")
    (tmp_path / "cp1252.trc").write_bytes(text.encode("cp1252"))
    (tmp_path / "bom.trc").write_bytes(b"\xef\xbb\xbf" + text.encode("utf-8"))
    want = read_trc(utf8)
    assert want.labels[:2] == ["genou_gauche_\xe9", "Kn\xf6chel"]
    for name in ("cp1252.trc", "bom.trc"):
        got = read_trc(tmp_path / name)
        assert got.labels == want.labels
        np.testing.assert_array_equal(got.xyz, want.xyz)
    (tmp_path / "binary.trc").write_bytes(b"PathFileType\t4\x00\x01\x02")
    with pytest.raises(InputFileError, match="not a text file"):
        read_trc(tmp_path / "binary.trc")


# ------------------------------------------------------------------------------ CSV
def test_csv_columns_and_round_trip(traj, tmp_path):
    path = write_csv(tmp_path / "take.csv", traj)
    header = path.read_text().split("\n")[0].split(",")
    assert header[:5] == ["frame", "time_s", "LASI_x_mm", "LASI_y_mm", "LASI_z_mm"]
    assert header[-7:] == [f"{label}_filled" for label in traj.labels]
    row = path.read_text().split("\n")[1].split(",")
    np.testing.assert_allclose(float(row[2]), 1000 * traj.xyz[0, 0, 0], atol=1e-5)
    back = read_csv(path)
    gaps = _gaps(traj)
    assert back.labels == traj.labels
    np.testing.assert_array_equal(_gaps(back), gaps)
    np.testing.assert_allclose(back.xyz[~gaps], traj.xyz[~gaps], atol=1e-8)
    np.testing.assert_array_equal(back.filled, traj.filled)
    np.testing.assert_allclose(back.times, traj.times, atol=1e-6)


def test_c3d_is_written_in_a_process_that_loaded_the_shirt_pipeline_first(tmp_path):
    """faiss (the shirt's pose database) and ezc3d share SWIG's type table: loaded first,
    faiss owned std::vector<size_t> and every C3D write of the process failed."""
    import subprocess
    import sys

    code = (
        "import mocap.shirt.pose_database\n"
        "import numpy as np\n"
        "from mocap.exports import read_c3d, write_c3d\n"
        "from mocap.types import Trajectories\n"
        "xyz = np.arange(4 * 2 * 3, dtype=float).reshape(4, 2, 3) / 100.0\n"
        f"path = write_c3d({str(tmp_path / 'm.c3d')!r}, Trajectories(['a', 'b'], xyz, np.arange(4) / 100.0))\n"
        "back = read_c3d(path)\n"
        "assert back.labels == ['a', 'b'] and np.allclose(back.xyz, xyz, atol=1e-6), back.xyz\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
