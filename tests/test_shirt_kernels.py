"""The colour-shirt pipeline's compiled loops give the values of the numpy expressions they replaced (issue 18).

Each kernel claims the same operations in the same order as a numpy form (its docstring
names it); these compare them on random inputs, bit for bit, edge cases included.
"""

from __future__ import annotations

import numpy as np

from mocap.shirt.arm_search import _point_costs
from mocap.shirt.classify import PatchDistances, assign_patches, nearest_colour, patch_centroids, row_min
from mocap.shirt.ik_kernels import huber_rows, place_anchors, project_anchors, whitened_errors


def test_nearest_colour_is_argmin_and_row_min_nan_and_signed_zeros_included():
    rng = np.random.default_rng(0)
    for t in range(300):
        n, K = int(rng.integers(1, 200)), int(rng.integers(1, 12))
        d = np.round(rng.random((n, K)) * 5).astype([np.float32, np.float64][t % 2])  # ties
        d[rng.random((n, K)) < 0.05] = np.nan
        d[rng.random((n, K)) < 0.05] = np.inf
        d[rng.random((n, K)) < 0.1] = -0.0
        best, score = nearest_colour(d)
        assert np.array_equal(best, d.argmin(axis=1).astype(np.int16))
        expected = row_min(d)
        assert score.dtype == expected.dtype
        assert np.array_equal(score, expected, equal_nan=True) and np.array_equal(np.signbit(score), np.signbit(expected))


def test_assign_patches_per_cell_is_the_per_pixel_form():
    """The compiled path (PatchDistances) against the numpy path on the same distances per pixel."""
    rng = np.random.default_rng(1)
    patch_colour = np.concatenate([np.arange(10), rng.integers(0, 10, 10)])
    for t in range(200):
        h = w = int(rng.integers(4, 40))
        colour = rng.integers(-1, 10, (h, w)).astype(np.int16)
        idx = np.sort(rng.choice(h * w, int(rng.integers(1, h * w)), replace=False))
        cells = np.round(rng.random((20, 64)) * 20).astype(np.float32)
        cells[rng.random(20) < 0.3] = np.inf
        pd = PatchDistances(cells, rng.integers(0, 64, len(idx)))
        gate = [np.inf, float(rng.random() * 20), float(np.float32(5.5)) + 1e-9][t % 3]  # the last between float32 values
        compiled = assign_patches(colour, idx, pd, patch_colour, gate)
        assert np.array_equal(compiled, assign_patches(colour, idx, pd.pixels(), patch_colour, gate))


def test_patch_centroids_are_the_bincount_means():
    rng = np.random.default_rng(2)
    for _ in range(100):
        pm = rng.integers(-1, 22, (int(rng.integers(1, 60)), int(rng.integers(1, 60)))).astype(np.int16)
        c, n = patch_centroids(pm, 20)
        p = pm.ravel().astype(np.int64)
        ys, xs = np.divmod(np.flatnonzero(p >= 0), pm.shape[1])
        cnt = np.bincount(p[p >= 0], minlength=20)
        assert np.array_equal(n, cnt)
        with np.errstate(invalid="ignore", divide="ignore"):
            expect = np.stack([np.bincount(p[p >= 0], weights=v, minlength=20) / cnt for v in (xs, ys)], 1)
        expect[cnt == 0] = np.nan
        assert np.array_equal(c, expect, equal_nan=True)


def test_arm_point_costs_are_the_numpy_form():
    rng = np.random.default_rng(3)
    for _ in range(100):
        h, w = int(rng.integers(5, 100)), int(rng.integers(5, 100))
        dmaps = (rng.random((6, h, w)) * 100).astype(np.float32)
        col_index = rng.integers(0, 6, 18)
        N = int(rng.integers(1, 30))
        uv = rng.normal(size=(N * 18, 2)) * 60 + 40
        half = rng.random(N * 18) < 0.2
        uv[half] = np.floor(uv[half]) + 0.5  # np.rint's ties
        uv[:3] = [[np.nan, 1.0], [1e30, 2.0], [w - 0.5, 0.0]]
        z = rng.normal(size=N * 18) + 0.5
        size, truncate = float(rng.random() * 80 + 0.5), 0.25
        with np.errstate(invalid="ignore"):
            x, y = np.rint(uv[:, 0]).astype(np.int64), np.rint(uv[:, 1]).astype(np.int64)
        inside = (x >= 0) & (x < w) & (y >= 0) & (y < h) & (z > 0)
        expect = np.full(N * 18, truncate)
        ci = np.tile(col_index, N)
        expect[inside] = np.minimum(dmaps[ci[inside], y[inside], x[inside]] / max(size, 1.0), truncate)
        got = _point_costs(uv, z, col_index, dmaps, np.float32(max(size, 1.0)), np.float32(truncate), truncate)
        assert np.array_equal(got, expect)


def test_ik_kernels_are_the_numpy_expressions():
    rng = np.random.default_rng(4)
    for _ in range(100):
        A, F, n = int(rng.integers(1, 60)), int(rng.integers(1, 8)), int(rng.integers(1, 40))
        H = rng.normal(size=(F, 4, 4))
        inv = rng.integers(0, F, A)
        pts = rng.normal(size=(A, 3)) * 0.1
        r, X = place_anchors(H, inv, pts)
        r0 = np.einsum("aij,aj->ai", H[:, :3, :3][inv], pts)
        assert np.array_equal(r, r0) and np.array_equal(X, r0 + H[:, :3, 3][inv])
        Rc, tc = rng.normal(size=(A, 3, 3)), rng.normal(size=(A, 3)) + [0, 0, 3]
        fx, fy, skew, c = rng.random(A) * 500 + 300, rng.random(A) * 500 + 300, rng.random(A), rng.random((A, 2)) * 300
        uv, z, xx, yy = project_anchors(X, Rc, tc, fx, fy, skew, c)
        Xc = np.einsum("aij,aj->ai", Rc, X) + tc
        z0 = np.maximum(Xc[:, 2], 1e-3)
        x0, y0 = Xc[:, 0] / z0, Xc[:, 1] / z0
        assert np.array_equal(z, z0) and np.array_equal(xx, x0) and np.array_equal(yy, y0)
        assert np.array_equal(uv, np.stack([fx * x0 + skew * y0 + c[:, 0], fy * y0 + c[:, 1]], 1))
        cen, target, info = rng.normal(size=(n, 2)) * 50, rng.normal(size=(n, 2)) * 50, rng.normal(size=(n, 2, 2))
        present = rng.random(n) < 0.7
        e, rw = whitened_errors(cen, target, present, info)
        e0 = np.where(present[:, None], cen - target, 0.0)
        assert np.array_equal(e, e0) and np.array_equal(rw, np.einsum("nij,nj->ni", info, e0))
        out = np.empty(2 * n)
        w = huber_rows(rw, 2.5, out)
        norm = np.sqrt(np.einsum("ni,ni->n", rw, rw))
        w0 = np.where(norm > 2.5, np.sqrt(2.5 / np.maximum(norm, 1e-12)), 1.0)
        assert np.array_equal(w, w0) and np.array_equal(out, (rw * w0[:, None]).ravel())


def test_silhouette_field_is_numpy_gradient_stacked():
    from mocap.shirt.ik import Silhouette
    rng = np.random.default_rng(7)
    for t in range(300):
        h, w = (int(v) for v in rng.integers(2, 50, 2))
        D = (rng.random((h, w)) * 50).astype([np.float32, np.float64][t % 2])
        if t % 7 == 0:
            D[:] = 1.8e19  # no classified pixel
        scale = [2.5, np.float32(1.37), 3, 0.1][t % 4]
        Dd = np.asarray(D, np.float64)
        gy, gx = np.gradient(Dd)
        expected = np.stack([Dd, gx / scale, gy / scale], axis=2).reshape(-1, 3)
        got = Silhouette(D, 1.0, 2.0, scale)._field
        assert got.dtype == expected.dtype and np.array_equal(got, expected)


def test_colour_distances_are_the_numpy_passes():
    from mocap.shirt.colour_model import ColourModel
    rng = np.random.default_rng(8)
    for t in range(200):
        K = int(rng.integers(1, 12))
        A = rng.normal(size=(K, 3, 3))
        cov = A @ A.transpose(0, 2, 1) * 10.0 ** rng.uniform(-5, -1) + np.eye(3) * 1e-6
        model = ColourModel(rng.random((K, 3)), cov, tuple(str(i) for i in range(K)))
        x = rng.random((int(rng.integers(0, 2000)), 3)).astype(np.float32)
        x[rng.random(len(x)) < 0.05] = np.nan
        W = None if t % 4 == 0 else np.eye(3) + rng.normal(size=(3, 3)) * 0.1
        rows = model.whiten.transpose(1, 0, 2).reshape(3 * K, 3)
        b = np.einsum("kij,kj->ik", model.whiten, model.means).reshape(3 * K)
        y = x @ (rows if W is None else rows @ W).T.astype(np.float32)
        y -= b.astype(np.float32)
        y *= y
        d = y[:, :K] + y[:, K:2 * K]
        d += y[:, 2 * K:]
        expected = np.sqrt(d, out=d)
        got = model.distances(x, W)
        assert got.dtype == expected.dtype and np.array_equal(got, expected, equal_nan=True)


def test_look_at_view_cross_products_are_numpys():
    from mocap.shirt.shirt_model import _cross3
    rng = np.random.default_rng(9)
    for _ in range(3000):
        a, b = rng.normal(size=(2, 3)) * 10.0 ** rng.uniform(-3, 3, (2, 1))
        assert np.array_equal(_cross3(a, b), np.cross(a, b))


def _stray_thin_bits_by_components(colour):
    """without_stray_thin_bits as it was written with OpenCV's connected components per colour."""
    import cv2
    from mocap.shirt.id_maps import without_thin_bits
    opened = without_thin_bits(colour)
    out = colour.copy()
    for k in np.unique(colour[(colour >= 0) & (opened < 0)]):
        x, y, w, h = cv2.boundingRect((colour == k).astype(np.uint8))
        box = (slice(y, y + h), slice(x, x + w))
        mask = colour[box] == k
        n, lab = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
        thick = np.zeros(n, bool)
        thick[lab[opened[box] == k]] = True
        out[box][mask & ~thick[lab]] = -1
    return out


def test_stray_thin_bits_flood_fill_is_the_connected_components_form():
    from mocap.shirt.id_maps import without_stray_thin_bits
    rng = np.random.default_rng(11)
    for t in range(600):
        h, w = (int(v) for v in rng.integers(1, 150 if t % 10 == 0 else 60, 2))
        K = int(rng.integers(1, 11))
        c = rng.integers(-1, K, (h, w)).astype(np.int16)
        if t % 2:  # blobs, one-pixel rims and stray pixels
            c[:] = -1
            for _ in range(int(rng.integers(1, 8))):
                y0, x0 = rng.integers(0, h), rng.integers(0, w)
                c[y0:y0 + int(rng.integers(1, 20)), x0:x0 + int(rng.integers(1, 20))] = rng.integers(0, K)
            c[rng.random((h, w)) < 0.03] = rng.integers(0, K)
        expected, got = _stray_thin_bits_by_components(c), without_stray_thin_bits(c)
        assert got.dtype == expected.dtype and np.array_equal(got, expected)


def test_tiny_map_percentiles_are_numpys():
    from mocap.shirt.pose_database import _percentiles
    rng = np.random.default_rng(12)
    for t in range(3000):
        n = int(rng.integers(2, 2000 if t % 10 else 30))
        v = rng.integers(0, int(rng.integers(1, 300)), n)
        pc = [1.0, 0.0, 50.0, 2.5, 100.0, 33.3][t % 6]
        expected, got = np.percentile(v, [pc, 100 - pc]), _percentiles(v, pc)
        assert got.dtype == expected.dtype and np.array_equal(got, expected)


def test_pinhole_projection_pass_is_the_numpy_form():
    from mocap.shirt.shirt_model import NEAR_M, _pinhole_to_view
    rng = np.random.default_rng(13)
    for t in range(1000):
        Xc = rng.normal(size=(int(rng.integers(0, 300)), 3)) * [1.0, 1.0, 3.0]
        Xc[rng.random(len(Xc)) < 0.02, 2] = np.nan
        K = np.array([[rng.uniform(100, 2000), 0.0, rng.uniform(0, 1000)], [0.0, rng.uniform(100, 2000), rng.uniform(0, 1000)], [0, 0, 1]])
        x0, y0, scale = rng.normal() * 500, rng.normal() * 500, rng.uniform(0.3, 5)
        z = Xc[:, 2]
        zs = np.where(z > NEAR_M, z, 1.0)
        uv = (Xc[:, :2] / zs[:, None]) @ K[:2, :2].T + K[:2, 2]
        expected = (uv - np.array([x0, y0])) / scale
        got = _pinhole_to_view(Xc, NEAR_M, K[0, 0], K[0, 1], K[1, 0], K[1, 1], K[0, 2], K[1, 2], x0, y0, scale)
        assert np.array_equal(got, expected, equal_nan=True)


def test_layer_maps_are_the_look_ups():
    from mocap.shirt.shirt_model import _layer_maps
    rng = np.random.default_rng(14)
    for t in range(300):
        T, offset = int(rng.integers(1, 500)), int(rng.integers(0, 3)) * 500
        face = np.where(rng.random((24, 24)) < 0.3, -1, rng.integers(offset, offset + T, (24, 24))).astype(np.int32)
        patch_of = rng.integers(-1, 20, T + 1).astype(np.int16)
        colour_of = rng.integers(-1, 10, T + 1).astype(np.int16)
        ids = np.full(face.shape, -1, np.int32)
        np.subtract(face, offset, out=ids, where=face >= 0, casting="unsafe")
        f, patch, colour = _layer_maps(face, offset, patch_of, colour_of)
        for got, expected in ((f, ids), (patch, patch_of[ids + 1]), (colour, colour_of[ids + 1])):
            assert got.dtype == expected.dtype and np.array_equal(got, expected)


def test_half_covered_cells_are_the_mean_test():
    from mocap.shirt.histogram_search import _half_covered
    rng = np.random.default_rng(15)
    for t in range(500):
        c, ny, nx = int(rng.integers(1, 9)), int(rng.integers(1, 30)), int(rng.integers(1, 30))
        fg = rng.random((ny * c, nx * c)) < rng.random()
        expected = fg.reshape(ny, c, nx, c).mean(axis=(1, 3)) >= 0.5
        assert np.array_equal(_half_covered(fg, c, ny, nx), expected)


def test_cell_counts_are_the_per_pixel_bins_counted():
    from mocap.shirt.histogram_search import HistogramSearchParams, _bin_lut, _cell_counts, chromaticity_bins
    rng = np.random.default_rng(16)
    params = HistogramSearchParams()
    lut, nb = _bin_lut(params.bins_per_axis, params.min_brightness)
    for t in range(100):
        c, by, bx = int(rng.integers(1, 6)), int(rng.integers(1, 20)), int(rng.integers(1, 20))
        img = rng.integers(0, 256, (by * c, bx * c, 3)).astype(np.uint8)
        mask = rng.random((by * c, bx * c)) < 0.7
        b, _ = chromaticity_bins(img, params, mask)
        cell = (np.arange(by * c)[:, None] // c) * bx + np.arange(bx * c)[None, :] // c
        ok = b >= 0
        expected = np.bincount(cell[ok] * nb + b[ok], minlength=by * bx * nb).reshape(by, bx, nb).astype(np.float32)
        assert np.array_equal(_cell_counts(img, mask, lut, c, by, bx, nb), expected)


def test_linear_lookup_is_the_table_indexed():
    from mocap.shirt.colour_model import SRGB_TO_LINEAR, linear_lookup
    rng = np.random.default_rng(17)
    for shape in [(144, 144, 3), (0, 3), (5,), (7, 9, 3)]:
        codes = rng.integers(0, 256, shape).astype(np.uint8)
        got, expected = linear_lookup(codes), SRGB_TO_LINEAR[codes]
        assert got.dtype == expected.dtype and got.shape == expected.shape and np.array_equal(got, expected)
    codes = rng.integers(0, 256, (20, 20, 3)).astype(np.uint8)[:, ::2]
    assert np.array_equal(linear_lookup(codes), SRGB_TO_LINEAR[codes])
