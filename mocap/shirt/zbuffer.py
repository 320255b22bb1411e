"""A small z-buffer for the shirt's id maps (:func:`rasterise_faces`).

Triangles are back-face culled and set up (edge functions, depth planes, boxes), then the
pixel centres of the kept ones' boxes are tested and the nearest triangle per pixel kept,
both in compiled (numba) loops.  It is hand-written rather than borrowed from OpenGL because
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
    """Set-up of every triangle and :func:`_zbuffer`: the kept ones' boxes and planes, packed in face order.

    Each vertex coordinate is read into a local once (scalars, not small arrays), and only the kept
    triangles (a third of them at the pipeline's sizes: the rest face away or cover no pixel centre)
    are stored, so the arrays the z-buffer walks are short; the arithmetic is the same, operation for
    operation, as the vectorised form it replaced.
    """
    n = len(faces)
    kf = np.empty(n, np.int64)       # the kept triangles' indices, in face order
    box = np.empty((n, 5), np.int64)  # xmin, ymin, nx, ny, tier
    par = np.empty((n, 12))           # ea0..2, eb0..2, ec0..2, za, zb, zc
    k = 0
    for f in range(n):
        v0, v1, v2 = faces[f, 0], faces[f, 1], faces[f, 2]
        X0, X1, X2 = uv[v0, 0], uv[v1, 0], uv[v2, 0]
        Y0, Y1, Y2 = uv[v0, 1], uv[v1, 1], uv[v2, 1]
        area = (X1 - X0) * (Y2 - Y0) - (Y1 - Y0) * (X2 - X0)
        # seen from the front, an outward-facing counter-clockwise triangle has negative
        # signed area in image coordinates (y points down)
        if cull_back:
            if not area < -1e-9:
                continue
        elif not abs(area) > 1e-9:
            continue
        Z0, Z1, Z2 = depth[v0], depth[v1], depth[v2]
        if not min(min(Z0, Z1), Z2) > NEAR_M:
            continue
        fxmin = np.ceil(min(min(X0, X1), X2))
        fxmax = np.floor(max(max(X0, X1), X2))
        fymin = np.ceil(min(min(Y0, Y1), Y2))
        fymax = np.floor(max(max(Y0, Y1), Y2))
        if not (fxmax >= 0 and fymax >= 0 and fxmin <= width - 1 and fymin <= height - 1 and fxmax >= fxmin and fymax >= fymin):
            continue
        fxmin, fxmax = max(fxmin, 0.0), min(fxmax, width - 1.0)
        fymin, fymax = max(fymin, 0.0), min(fymax, height - 1.0)
        fnx = fxmax - fxmin + 1
        fny = fymax - fymin + 1
        if not fnx * fny <= _MAX_BOX_PIXELS:
            continue
        kf[k] = f
        box[k, 0], box[k, 1], box[k, 2], box[k, 3] = int(fxmin), int(fymin), int(fnx), int(fny)
        box[k, 4] = 2 if (fnx <= 2 and fny <= 2) else (4 if (fnx <= 4 and fny <= 4) else 0)
        sg = np.sign(area)
        # edge function of edge e = (i -> j), (1 -> 2), (2 -> 0), (0 -> 1), positive inside:
        # sign(area) * ((xj - xi)(y - yi) - (yj - yi)(x - xi)); it and the depth plane at the box corner (xmin, ymin)
        a0, b0 = -(Y2 - Y1) * sg, (X2 - X1) * sg
        a1, b1 = -(Y0 - Y2) * sg, (X0 - X2) * sg
        a2, b2 = -(Y1 - Y0) * sg, (X1 - X0) * sg
        par[k, 0], par[k, 1], par[k, 2] = a0, a1, a2
        par[k, 3], par[k, 4], par[k, 5] = b0, b1, b2
        par[k, 6] = a0 * (fxmin - X1) + b0 * (fymin - Y1)
        par[k, 7] = a1 * (fxmin - X2) + b1 * (fymin - Y2)
        par[k, 8] = a2 * (fxmin - X0) + b2 * (fymin - Y0)
        w = 1.0 / area
        za = ((Z1 - Z0) * (Y2 - Y0) - (Z2 - Z0) * (Y1 - Y0)) * w
        zb = ((X1 - X0) * (Z2 - Z0) - (X2 - X0) * (Z1 - Z0)) * w
        par[k, 9], par[k, 10] = za, zb
        par[k, 11] = Z0 + za * (fxmin - X0) + zb * (fymin - Y0)
        k += 1
    _zbuffer(k, kf, box, par, base, width, out, zbuf, ids)


@numba.njit(cache=True, nogil=True)
def _zbuffer(K, kf, box, par, base_pix, width, out, zbuf, ids):  # pragma: no cover
    """The z-buffer of :func:`rasterise_faces`, compiled: a loop over the ``K`` kept triangles and the pixel centres of their boxes.

    Why compiled: the vectorised form spends most of its time building and filtering
    candidate (triangle, pixel) arrays, a few thousand tiny triangles per render, many
    renders per frame.  The same arithmetic as that form (edge functions of boxes up to
    4 x 4 in float32, larger ones in float64; depth planes in float64) and the same order
    (boxes up to 2 x 2, then up to 4 x 4, then larger; each in face order, row by row), so the same
    triangle wins every pixel, ties included (the last one drawn at the least depth).

    ``kf (K,)``: the kept triangles' face indices; ``box (K, 5)``: x and y of the box's corner, its width,
    height and tier (2, 4 or 0); ``par (K, 12)``: the edge functions' x, y and constant terms (three each)
    at the corner, then the depth plane's.  ``zbuf`` holds the depths drawn so far (``inf`` where none) and
    ``ids[f]`` is written for face ``f``.
    """
    tol32 = np.float32(-1e-6)
    for g in (2, 4, 0):
        for k in range(K):
            if box[k, 4] != g:
                continue
            f = kf[k]
            xmin, ymin, w, h = box[k, 0], box[k, 1], box[k, 2], box[k, 3]
            ea0, ea1, ea2 = par[k, 0], par[k, 1], par[k, 2]
            eb0, eb1, eb2 = par[k, 3], par[k, 4], par[k, 5]
            ec0, ec1, ec2 = par[k, 6], par[k, 7], par[k, 8]
            za, zb, zc = par[k, 9], par[k, 10], par[k, 11]
            p0 = base_pix[f] + ymin * width + xmin
            idf = ids[f]
            if g:
                sa0, sa1, sa2 = np.float32(ea0), np.float32(ea1), np.float32(ea2)
                sb0, sb1, sb2 = np.float32(eb0), np.float32(eb1), np.float32(eb2)
                sc0, sc1, sc2 = np.float32(ec0), np.float32(ec1), np.float32(ec2)
            for cy in range(h):
                for cx in range(w):
                    if g:
                        fx = np.float32(cx)
                        fy = np.float32(cy)
                        if not (sc0 + sa0 * fx + sb0 * fy >= tol32 and sc1 + sa1 * fx + sb1 * fy >= tol32
                                and sc2 + sa2 * fx + sb2 * fy >= tol32):
                            continue
                    else:
                        dx = np.float64(cx)
                        dy = np.float64(cy)
                        if not (ec0 + ea0 * dx + eb0 * dy >= -1e-6 and ec1 + ea1 * dx + eb1 * dy >= -1e-6
                                and ec2 + ea2 * dx + eb2 * dy >= -1e-6):
                            continue
                    z = zc + za * np.float64(cx) + zb * np.float64(cy)
                    pix = p0 + cy * width + cx
                    if z <= zbuf[pix]:
                        zbuf[pix] = z
                        out[pix] = idf
