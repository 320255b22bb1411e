"""A small z-buffer for the shirt's id maps (:func:`rasterise_faces`).

Triangles are back-face culled and set up (edge functions, depth planes, boxes) with
numpy, then a compiled (numba) loop tests the pixel centres of every box and keeps the
nearest triangle per pixel.  It is hand-written rather than borrowed from OpenGL because
the pipeline must run without a GL context (the ``mocap`` side never imports the
renderer), and at the tiny resolutions used here (40-128 px) a pass over a few thousand
triangles costs about a millisecond, less than a GL round trip; ``cv2.fillPoly`` has no
depth test.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["NEAR_M", "rasterise_faces", "rasterise_faces_over"]

#: Vertices nearer than this to the camera (metres) drop their triangles.
NEAR_M = 0.05
_MAX_BOX_PIXELS = 4096  # triangles covering more pixel centres than this are dropped (only ever when absurdly close)


def rasterise_faces(uv: np.ndarray, depth: np.ndarray, faces: np.ndarray, width: int, height: int,
                    cull_back: bool = True, face_layer: np.ndarray | None = None, n_layers: int = 1) -> np.ndarray:
    """Index of the nearest triangle covering every pixel centre (a z-buffer).

    Parameters
    ----------
    uv : (V, 2) float
        Vertex image positions, pixels, OpenCV convention (x right, y down, pixel
        centres at integers).
    depth : (V,) float
        Vertex depth along the viewing direction (metres; larger is farther).  Vertices
        with depth below 5 cm drop their triangles.
    faces : (T, 3) int
        Counter-clockwise seen from outside; with ``cull_back`` triangles seen from
        behind are skipped (closed meshes: they are hidden anyway).
    width, height : int
        Image size in pixels.
    face_layer : (T,) int, optional
        Image (of ``n_layers``) each triangle is drawn into: many small renders in one call.

    Returns
    -------
    (height, width) int32, or (n_layers, height, width) with ``face_layer``
        Triangle index per pixel, ``-1`` where none covers the pixel centre.

    Notes
    -----
    Triangles are grouped by the pixel centres their bounding boxes span: up to 2x2
    and up to 4x4 (nearly all of them at the pipeline's resolutions; edge functions in
    float32), larger ones (float64); the set-up and the z-buffer (:func:`_rasterise`,
    :func:`_zbuffer`) are compiled, the groups drawn in that order.
    Each triangle carries its three edge functions and its depth plane as
    ``a x + b y + c``.
    """
    npix = height * width
    shape = (height, width) if face_layer is None else (n_layers, height, width)
    out = np.full(npix * (1 if face_layer is None else n_layers), -1, np.int32)
    if len(faces) == 0:
        return out.reshape(shape)
    base = np.zeros(len(faces), np.int64) if face_layer is None else np.asarray(face_layer, np.int64) * npix
    _rasterise(np.ascontiguousarray(uv, np.float64), np.ascontiguousarray(depth, np.float64), np.ascontiguousarray(faces, np.int64),
               int(width), int(height), bool(cull_back), base, out, np.full(out.size, np.inf), np.arange(len(faces), dtype=np.int32))
    return out.reshape(shape)


def rasterise_faces_over(uv: np.ndarray, depth: np.ndarray, faces: np.ndarray, face_ids: np.ndarray,
                         face_layer: np.ndarray, face_map: np.ndarray, depth_map: np.ndarray, cull_back: bool = True) -> None:
    """Draw triangles into existing z-buffered images, in place: more of a scene over what is drawn.

    Parameters
    ----------
    uv, depth, faces, cull_back
        As :func:`rasterise_faces`.
    face_ids : (T,) int32
        The id written for each triangle (e.g. its index in the whole mesh).
    face_layer : (T,) int
        Image of ``face_map`` each triangle is drawn into.
    face_map : (L, H, W) int32, C-contiguous
        Ids drawn so far (-1 none); updated in place.
    depth_map : (L, H, W) float64, C-contiguous
        Their depths (``inf`` none); updated in place.

    Drawing a mesh in two parts this way gives the pixels of one :func:`rasterise_faces`
    call over the whole mesh wherever no triangle of one part ties in depth to the last
    bit with one of the other (the tie would go the other way); the shirt's separate
    bodies do not share vertices.
    """
    if not (face_map.flags.c_contiguous and depth_map.flags.c_contiguous and face_map.shape == depth_map.shape
            and face_map.dtype == np.int32 and depth_map.dtype == np.float64 and face_map.ndim == 3):
        raise ValueError("rasterise_faces_over: face_map (L, H, W) int32 and depth_map float64 of one shape, C-contiguous")
    if len(faces) == 0:
        return
    L, H, W = face_map.shape
    _rasterise(np.ascontiguousarray(uv, np.float64), np.ascontiguousarray(depth, np.float64), np.ascontiguousarray(faces, np.int64),
               int(W), int(H), bool(cull_back), np.asarray(face_layer, np.int64) * (H * W), face_map.reshape(-1),
               depth_map.reshape(-1), np.ascontiguousarray(face_ids, np.int32))


@numba.njit(cache=True, nogil=True)
def _rasterise(uv, depth, faces, width, height, cull_back, base, out, zbuf, ids):  # pragma: no cover
    """Set-up of every triangle (as the vectorised form had it, operation for operation) and :func:`_zbuffer`."""
    n = len(faces)
    keep = np.zeros(n, np.bool_)
    xmin = np.empty(n, np.int64)
    ymin = np.empty(n, np.int64)
    nx = np.empty(n, np.int64)
    ny = np.empty(n, np.int64)
    tier = np.empty(n, np.int64)
    ec = np.empty((n, 3))
    ea = np.empty((n, 3))
    eb = np.empty((n, 3))
    zc = np.empty(n)
    za = np.empty(n)
    zb = np.empty(n)
    X = np.empty(3)
    Y = np.empty(3)
    Z = np.empty(3)
    for f in range(n):
        for j in range(3):
            v = faces[f, j]
            X[j] = uv[v, 0]
            Y[j] = uv[v, 1]
            Z[j] = depth[v]
        area = (X[1] - X[0]) * (Y[2] - Y[0]) - (Y[1] - Y[0]) * (X[2] - X[0])
        # seen from the front, an outward-facing counter-clockwise triangle has negative
        # signed area in image coordinates (y points down)
        if cull_back:
            if not area < -1e-9:
                continue
        elif not abs(area) > 1e-9:
            continue
        if not min(min(Z[0], Z[1]), Z[2]) > NEAR_M:
            continue
        fxmin = np.ceil(min(min(X[0], X[1]), X[2]))
        fxmax = np.floor(max(max(X[0], X[1]), X[2]))
        fymin = np.ceil(min(min(Y[0], Y[1]), Y[2]))
        fymax = np.floor(max(max(Y[0], Y[1]), Y[2]))
        if not (fxmax >= 0 and fymax >= 0 and fxmin <= width - 1 and fymin <= height - 1 and fxmax >= fxmin and fymax >= fymin):
            continue
        fxmin, fxmax = max(fxmin, 0.0), min(fxmax, width - 1.0)
        fymin, fymax = max(fymin, 0.0), min(fymax, height - 1.0)
        fnx = fxmax - fxmin + 1
        fny = fymax - fymin + 1
        if not fnx * fny <= _MAX_BOX_PIXELS:
            continue
        keep[f] = True
        xmin[f], ymin[f], nx[f], ny[f] = int(fxmin), int(fymin), int(fnx), int(fny)
        tier[f] = 2 if (fnx <= 2 and fny <= 2) else (4 if (fnx <= 4 and fny <= 4) else 0)
        # edge function of edge (i -> j), positive inside: sign(area) * ((xj - xi)(y - yi) - (yj - yi)(x - xi)),
        # and the depth plane, both at the box corner (xmin, ymin)
        sg = np.sign(area)
        for e in range(3):
            i0 = (e + 1) % 3
            i1 = (e + 2) % 3
            ea[f, e] = -(Y[i1] - Y[i0]) * sg
            eb[f, e] = (X[i1] - X[i0]) * sg
            ec[f, e] = ea[f, e] * (fxmin - X[i0]) + eb[f, e] * (fymin - Y[i0])
        w = 1.0 / area
        za[f] = ((Z[1] - Z[0]) * (Y[2] - Y[0]) - (Z[2] - Z[0]) * (Y[1] - Y[0])) * w
        zb[f] = ((X[1] - X[0]) * (Z[2] - Z[0]) - (X[2] - X[0]) * (Z[1] - Z[0])) * w
        zc[f] = Z[0] + za[f] * (fxmin - X[0]) + zb[f] * (fymin - Y[0])
    _zbuffer(keep, tier, nx, ny, xmin, ymin, base, ec, ea, eb, zc, za, zb, width, out, zbuf, ids)


@numba.njit(cache=True, nogil=True)
def _zbuffer(keep, tier, nx, ny, xmin, ymin, base_pix, ec, ea, eb, zc, za, zb, width, out, zbuf, ids):  # pragma: no cover
    """The z-buffer of :func:`rasterise_faces`, compiled: a loop over triangles and the pixel centres of their boxes.

    Why compiled: the vectorised form spends most of its time building and filtering
    candidate (triangle, pixel) arrays, a few thousand tiny triangles per render, many
    renders per frame.  The same arithmetic as that form (edge functions of boxes up to
    4 x 4 in float32, larger ones in float64; depth planes in float64) and the same order
    (boxes up to 2 x 2, then up to 4 x 4, then larger; each row by row), so the same
    triangle wins every pixel, ties included (the last one drawn at the least depth).

    It walks the kept triangles of the set-up's arrays in place (their float32 edge
    functions converted where used), as fast as it gets without copying them out first.
    ``zbuf`` holds the depths drawn so far (``inf`` where none) and ``ids[f]`` is written for triangle ``f``.
    """
    tol32 = np.float32(-1e-6)
    for g in (2, 4, 0):
        for f in range(len(tier)):
            if not keep[f] or tier[f] != g:
                continue
            w = nx[f]
            h = ny[f]
            if g:
                ec0, ec1, ec2 = np.float32(ec[f, 0]), np.float32(ec[f, 1]), np.float32(ec[f, 2])
                ea0, ea1, ea2 = np.float32(ea[f, 0]), np.float32(ea[f, 1]), np.float32(ea[f, 2])
                eb0, eb1, eb2 = np.float32(eb[f, 0]), np.float32(eb[f, 1]), np.float32(eb[f, 2])
            for cy in range(h):
                for cx in range(w):
                    if g:
                        fx = np.float32(cx)
                        fy = np.float32(cy)
                        if not (ec0 + ea0 * fx + eb0 * fy >= tol32 and ec1 + ea1 * fx + eb1 * fy >= tol32
                                and ec2 + ea2 * fx + eb2 * fy >= tol32):
                            continue
                    else:
                        dx = np.float64(cx)
                        dy = np.float64(cy)
                        if not (ec[f, 0] + ea[f, 0] * dx + eb[f, 0] * dy >= -1e-6 and ec[f, 1] + ea[f, 1] * dx + eb[f, 1] * dy >= -1e-6
                                and ec[f, 2] + ea[f, 2] * dx + eb[f, 2] * dy >= -1e-6):
                            continue
                    z = zc[f] + za[f] * np.float64(cx) + zb[f] * np.float64(cy)
                    pix = base_pix[f] + (ymin[f] + cy) * width + xmin[f] + cx
                    if z <= zbuf[pix]:
                        zbuf[pix] = z
                        out[pix] = ids[f]
