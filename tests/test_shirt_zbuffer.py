"""The shirt pipeline's z-buffer (mocap/shirt/zbuffer.py) against a brute-force z-buffer written from its contract."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.shirt.zbuffer import NEAR_M, rasterise_faces, rasterise_faces_over

_W, _H = 23, 17


def _brute_force(uv: np.ndarray, depth: np.ndarray, faces: np.ndarray, width: int, height: int,
                 cull_back: bool) -> np.ndarray:
    """Every pixel centre against every triangle: kept if front-facing (or any non-degenerate one without
    ``cull_back``) and nearer than ``NEAR_M`` nowhere; covered if inside or on its edges; the least depth wins.

    Exact for the inputs of the test below: vertices on a 1/8-pixel grid make every edge function at a
    pixel centre a multiple of 1/64 (zero or clearly signed), and the depths are distinct enough for no ties.
    """
    ys, xs = np.mgrid[0:height, 0:width].astype(float)
    best = np.full((height, width), np.inf)
    out = np.full((height, width), -1, np.int32)
    for f, (a, b, c) in enumerate(faces):
        (x0, y0), (x1, y1), (x2, y2) = uv[a], uv[b], uv[c]
        area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
        if (cull_back and area >= 0) or area == 0 or min(depth[a], depth[b], depth[c]) <= NEAR_M:
            continue
        s = np.sign(area)
        e0 = s * ((x2 - x1) * (ys - y1) - (y2 - y1) * (xs - x1))
        e1 = s * ((x0 - x2) * (ys - y2) - (y0 - y2) * (xs - x2))
        e2 = s * ((x1 - x0) * (ys - y0) - (y1 - y0) * (xs - x0))
        # depth plane through the three vertices
        za = ((depth[b] - depth[a]) * (y2 - y0) - (depth[c] - depth[a]) * (y1 - y0)) / area
        zb = ((x1 - x0) * (depth[c] - depth[a]) - (x2 - x0) * (depth[b] - depth[a])) / area
        z = depth[a] + za * (xs - x0) + zb * (ys - y0)
        win = (e0 >= 0) & (e1 >= 0) & (e2 >= 0) & (z < best)
        best[win], out[win] = z[win], f
    return out


@st.composite
def _soups(draw):
    """A few triangles, small and large, partly outside the image, at distinct depths."""
    n = draw(st.integers(1, 12))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    centres = rng.uniform([-3, -3], [_W + 3, _H + 3], size=(n, 1, 2))
    sizes = rng.choice([0.6, 1.5, 3.0, 8.0, 20.0], size=(n, 1, 1))  # boxes of every tier: up to 2x2, 4x4, larger
    uv = np.round((centres + rng.uniform(-1, 1, size=(n, 3, 2)) * sizes) * 8) / 8
    # each triangle a plane at its own depth band: no two meet within the image
    depth = (1.0 + np.arange(n)[rng.permutation(n)][:, None] + rng.uniform(0, 0.3, size=(n, 3))).ravel()
    return uv.reshape(-1, 2), depth, np.arange(3 * n).reshape(n, 3), draw(st.booleans())


@settings(max_examples=150, deadline=None)
@given(_soups())
def test_rasteriser_equals_a_brute_force_z_buffer(soup):
    uv, depth, faces, cull_back = soup
    got = rasterise_faces(uv, depth, faces, _W, _H, cull_back=cull_back)
    assert np.array_equal(got, _brute_force(uv, depth, faces, _W, _H, cull_back))


@settings(max_examples=60, deadline=None)
@given(_soups(), st.integers(0, 11))
def test_drawing_a_mesh_in_two_parts_equals_drawing_it_whole(soup, split):
    uv, depth, faces, cull_back = soup
    split = min(split, len(faces))
    whole = rasterise_faces(uv, depth, faces, _W, _H, cull_back=cull_back)
    face_map = np.full((1, _H, _W), -1, np.int32)
    depth_map = np.full((1, _H, _W), np.inf)
    layer = np.zeros(len(faces), np.int64)
    ids = np.arange(len(faces), dtype=np.int32)
    for part in (slice(0, split), slice(split, None)):
        rasterise_faces_over(uv, depth, faces[part], ids[part], layer[part], face_map, depth_map, cull_back)
    assert np.array_equal(face_map[0], whole)


def test_layers_are_separate_renders():
    rng = np.random.default_rng(3)
    uv = np.round(rng.uniform(0, 20, size=(30, 2)) * 8) / 8
    depth = rng.uniform(1, 3, size=30)
    faces = rng.integers(0, 30, size=(40, 3))
    layer = np.arange(40) % 2
    both = rasterise_faces(uv, depth, faces, _W, _H, cull_back=False, face_layer=layer, n_layers=2)
    for k in (0, 1):
        alone = rasterise_faces(uv, depth, faces[layer == k], _W, _H, cull_back=False)
        assert np.array_equal(both[k], np.where(alone >= 0, np.flatnonzero(layer == k)[alone], -1))
