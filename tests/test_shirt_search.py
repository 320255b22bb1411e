"""Histogram search (seed 001 section 4) and the pose database's normalisation and nearest-neighbour search."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.errors import InputFileError
from mocap.shirt.histogram_search import HistogramSearchParams, naive_search, search_shirt
from mocap.shirt.pose_database import PoseDatabase, blend_poses, blend_weights, encode_tiny, tiny_id_map
from simbench.scenes.anthropometry import BodyParams
from simbench.pipelines.shirt_database import PoseSampling, build_database

_COLOURS = np.array([[200, 30, 30], [30, 170, 40], [30, 50, 200], [220, 200, 30], [30, 190, 200], [200, 30, 150],
                     [240, 120, 20], [110, 30, 170], [210, 210, 210], [40, 40, 40]], np.uint8)


def _scene(rng: np.random.Generator, centre=(400, 220), size=(150, 110)) -> np.ndarray:
    img = np.clip(rng.normal(120, 3, (480, 640, 3)), 0, 255).astype(np.uint8)
    img[:, :, 2] = np.clip(img[:, :, 2].astype(int) + 15, 0, 255)  # a bluish wall
    img[300:420, 40:200] = [180, 40, 40]  # uniform coloured clutter
    img[50:150, 500:620] = [40, 150, 60]
    cx, cy = centre
    h, w = size
    for i in range(0, h, 25):
        for j in range(0, w, 22):
            img[cy - h // 2 + i: cy - h // 2 + i + 25, cx - w // 2 + j: cx - w // 2 + j + 22] = _COLOURS[rng.integers(10)]
    return img


def test_shirt_is_found_among_uniform_clutter_and_naive_search_agrees():
    rng = np.random.default_rng(0)
    img = _scene(rng)
    loc = search_shirt(img)
    # inside the shirt (110 x 150 px around (400, 220)), at a scale below its size
    assert abs(loc.x - 400) < 25 and abs(loc.y - 220) < 40
    assert 48 <= loc.s <= 132 and loc.u_max > 0.5
    ref = naive_search(img)
    assert ref.x == pytest.approx(loc.x, abs=1e-3) and ref.y == pytest.approx(loc.y, abs=1e-3) and ref.s == pytest.approx(loc.s, abs=1e-3)
    # a foreground mask around the shirt keeps the result
    fg = np.zeros((480, 640), bool)
    fg[120:330, 300:500] = True
    loc_fg = search_shirt(img, foreground=fg)
    assert abs(loc_fg.x - 400) < 25 and abs(loc_fg.y - 220) < 40


def test_search_of_a_frame_without_colour_returns_none():
    assert search_shirt(np.zeros((480, 640, 3), np.uint8)) is None
    with pytest.raises(Exception):
        HistogramSearchParams(stride_px=5)


def test_tiny_maps_are_invariant_to_the_position_and_size_of_the_shirt():
    base = np.full((40, 40), -1, np.int16)
    base[5:35, 10:30] = (np.arange(20)[None, :] // 5 + 4 * (np.arange(30)[:, None] // 10)) % 10
    a = np.full((200, 200), -1, np.int16)
    a[20:100, 100:180] = np.kron(base, np.ones((2, 2), np.int16))
    big = np.full((400, 300), -1, np.int16)
    big[100:220, 50:170] = np.kron(base, np.ones((3, 3), np.int16))
    ta, tb = tiny_id_map(a, 10), tiny_id_map(big, 10)
    # cells differ only where a colour border falls at another fraction of a cell; in the
    # (smoothed) encodings the database compares, the two are far closer than another layout
    assert np.mean(ta.ids == tb.ids) > 0.9
    other = big.copy()
    other[other >= 0] = (other[other >= 0] + 3) % 10
    ea, eb, eo = (encode_tiny(t.ids, 10) for t in (ta, tb, tiny_id_map(other, 10)))
    assert np.linalg.norm(ea - eb) < 0.3 * np.linalg.norm(ea - eo)
    assert tb.side == pytest.approx(1.5 * ta.side, rel=0.05)
    # the square maps back onto the source: cell centres to source coordinates and back
    xy = np.array([[3.0, 7.0], [39.0, 0.0]])
    np.testing.assert_allclose(tb.source_to_cell(tb.cell_to_source(xy)), xy, atol=1e-9)
    assert tiny_id_map(np.full((50, 50), -1), 10) is None


def test_blending_averages_hinges_of_the_dominant_orientation_cluster():
    w = blend_weights(np.array([1.0, 1.0, 5.0]))
    assert w[0] == pytest.approx(w[1]) and w[2] < 0.2 * w[0] and w.sum() == pytest.approx(1.0)
    R = np.stack([np.eye(3), np.eye(3), np.diag([-1.0, -1.0, 1.0])])  # the third is turned around
    h, rot, used = blend_poses(np.array([[0.2], [0.4], [3.0]]), R, np.array([0.3, 0.3, 0.4]))
    assert used.tolist() == [True, True, False]
    assert h[0] == pytest.approx(0.3) and np.allclose(rot, np.eye(3))


@pytest.fixture(scope="module")
def small_db(tmp_path_factory):
    db = build_database(BodyParams(), PoseSampling(n_poses=300, seed=5))
    path = db.save(tmp_path_factory.mktemp("db") / "db.npz")
    return db, path


def test_database_finds_its_own_entries_and_survives_a_round_trip(small_db):
    db, path = small_db
    loaded = PoseDatabase.load(path)
    assert len(loaded) == len(db) > 280
    for i in (0, 17, 123):
        nb = loaded.search(loaded.tiny[i], k=10)
        assert nb.index[0] == i and nb.distance[0] == pytest.approx(0.0, abs=1e-5)
        assert np.all(np.diff(nb.distance) >= -1e-6)
        np.testing.assert_allclose(nb.hinges[0], db.hinges[i], atol=1e-6)
    # encodings: a map against itself is at distance 0, against the empty map at the norm of its encoding
    e = encode_tiny(db.tiny[:2], db.n_colours)
    assert e.shape == (2, db.n_colours * 400)


def test_missing_or_foreign_database_files_are_user_errors(tmp_path):
    with pytest.raises(InputFileError, match="build-db"):
        PoseDatabase.load(tmp_path / "nope.npz")
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(InputFileError, match="not a pose database: no array tiny, hinges"):
        PoseDatabase.load(tmp_path / "other.npz")
