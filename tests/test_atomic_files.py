"""Files written whole or not at all (mocap/atomic_files.py), and every writer that goes through it."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.atomic_files import atomic_target, atomic_write_bytes, atomic_write_text
from mocap.calibration import Calibration, Camera
from mocap.calibration_formats import CALIBRATION_FORMATS, load_calibration, save_calibration
from mocap.errors import MocapInputError
from mocap.exports.c3d import read_c3d, write_c3d
from mocap.exports.csv_table import read_csv, write_csv
from mocap.exports.trc import read_trc, write_trc
from mocap.label_template import LabelTemplate, load_template, save_template
from mocap.types import Trajectories


def _calibration() -> Calibration:
    cams = []
    for i, x in enumerate((-1.0, 1.0)):
        R = np.eye(3)
        cams.append(Camera(f"cam{i}", (640, 480), [[600, 0, 320], [0, 600, 240], [0, 0, 1]], np.zeros(5), R, np.array([x, 0.0, 3.0])))
    return Calibration(tuple(cams))


def _trajectories() -> Trajectories:
    xyz = np.random.default_rng(0).normal(size=(5, 2, 3))
    return Trajectories(["A", "B"], xyz, np.arange(5) / 100.0)


def test_a_failed_write_leaves_the_target_as_it_was_and_no_temporary_file(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("before")
    with pytest.raises(RuntimeError):
        with atomic_target(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed mid-write")
    assert target.read_text() == "before"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_two_writers_of_one_file_at_once_get_their_own_temporary_files(tmp_path):
    target = tmp_path / "db.npz"
    with atomic_target(target, ".npz") as first, atomic_target(target, ".npz") as second:
        assert first != second and first.parent == second.parent == tmp_path
        assert first.name.startswith(".db.npz.") and first.name.endswith(".tmp.npz")
        np.savez(first, x=np.arange(1000))
        np.savez(second, x=np.arange(5))
    # the second writer renamed first, then the first: the file is whole, one writer's
    with np.load(target) as z:
        assert np.array_equal(z["x"], np.arange(1000))
    assert [p.name for p in tmp_path.iterdir()] == ["db.npz"]


def test_a_missing_folder_is_one_clear_error(tmp_path):
    with pytest.raises(MocapInputError, match="does not exist; create it"):
        atomic_write_text(tmp_path / "nowhere" / "x.txt", "x")
    assert list(tmp_path.iterdir()) == []


def _write_and_read(kind: str, folder):
    """Write one file of ``kind`` into ``folder`` through its public writer; return (path, read back, expected)."""
    if kind.startswith("calibration:"):
        cal = _calibration()
        paths = save_calibration(cal, folder, kind.split(":")[1])
        return paths[0], [c.t.tolist() for c in load_calibration(paths[0])], [c.t.tolist() for c in cal]
    if kind == "label template":
        tpl = LabelTemplate(("A", "B"), np.array([[0.0, 0.1, 0.2], [0.3, 0.4, 0.5]]))
        path = save_template(tpl, folder / "template.csv")
        return path, load_template(path).positions.tolist(), tpl.positions.tolist()
    traj = _trajectories()
    writer, reader, name = {"trc": (write_trc, read_trc, "m.trc"), "c3d": (write_c3d, read_c3d, "m.c3d"),
                            "csv": (write_csv, read_csv, "m.csv")}[kind]
    path = writer(folder / name, traj)
    return path, np.round(reader(path).xyz, 4).tolist(), np.round(traj.xyz, 4).tolist()


@pytest.mark.parametrize("kind", [f"calibration:{f}" for f in CALIBRATION_FORMATS] + ["label template", "trc", "c3d", "csv"])
def test_every_writer_leaves_a_users_files_of_temporary_looking_names_alone(tmp_path, kind):
    # a first write tells the file's name; then the user's own files named as the old writers' temporaries
    path, _, _ = _write_and_read(kind, tmp_path)
    path.unlink()
    for p in list(tmp_path.iterdir()):
        p.unlink()
    mine = {path.name + ".tmp": "user's A", path.name + ".tmp.yml": "user's B", "." + path.name + ".tmp": "user's C"}
    for name, text in mine.items():
        (tmp_path / name).write_text(text)
    path, got, expected = _write_and_read(kind, tmp_path)
    assert got == expected
    for name, text in mine.items():
        assert (tmp_path / name).read_text() == text
    assert not [p.name for p in tmp_path.iterdir() if p.name not in mine and ".tmp" in p.name]


def test_atomic_write_bytes_with_fsync_writes_the_bytes(tmp_path):
    atomic_write_bytes(tmp_path / "r.json", b'{"a": 1}', fsync=True)
    assert (tmp_path / "r.json").read_bytes() == b'{"a": 1}'


def test_a_written_file_has_the_mode_a_plain_write_gives(tmp_path):
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    atomic_write_text(tmp_path / "atomic.txt", "x")
    assert (tmp_path / "atomic.txt").stat().st_mode == plain.stat().st_mode


def test_check_output_file_refuses_links_folders_and_files_of_another_kind_before_any_work(tmp_path):
    from mocap.atomic_files import check_output_file

    ours = tmp_path / "ours.md"
    ours.write_text("| seed | a table we wrote\n")
    is_ours = lambda p: p.read_text().startswith("| seed |")  # noqa: E731
    check_output_file(ours, is_ours, "a seed table")  # replaced by a rerun: allowed
    check_output_file(tmp_path / "new.md", is_ours, "a seed table")  # absent: allowed
    (tmp_path / "notes.md").write_text("mine")
    (tmp_path / "link.md").symlink_to(ours)
    (tmp_path / "folder.md").mkdir()
    for name, problem in (("notes.md", "exists and is not a seed table"), ("link.md", "is a symbolic link"),
                          ("folder.md", "exists and is not a file")):
        with pytest.raises(MocapInputError, match=problem):
            check_output_file(tmp_path / name, is_ours, "a seed table")
    assert (tmp_path / "notes.md").read_text() == "mine" and ours.read_text().startswith("| seed |")
