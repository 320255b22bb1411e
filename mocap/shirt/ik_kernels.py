"""Compiled inner loops of the shirt IK's energy (:mod:`mocap.shirt.ik`).

A frame evaluates the energy some fifty times on a few dozen anchors; as numpy expressions
each evaluation was some forty calls on arrays of that size, where the calls' overhead cost
many times the arithmetic.  These loops do the same arithmetic in the same order, so the
results are bit for bit those of the numpy expressions they replace (each function names
its expression).  One order is not obvious: numpy's ``einsum("aij,aj->ai", R, p)`` sums a
3-term row as ``(R0 p0 + R2 p2) + R1 p1`` (its two-lane inner loop), and so do these.
Matrix products (BLAS) stay in numpy.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["place_anchors", "project_anchors", "whitened_errors", "huber_rows", "anchor_jacobians", "projection_jacobians",
           "silhouette_field"]


@numba.njit(cache=True, nogil=True)
def place_anchors(H, inv, points):  # pragma: no cover
    """Levers ``r (A, 3)`` and world anchors ``X (A, 3)`` from the bodies' placements ``H (F, 4, 4)``:
    ``r = einsum("aij,aj->ai", H[inv, :3, :3], points)``, ``X = r + H[inv, :3, 3]``."""
    A = inv.shape[0]
    r = np.empty((A, 3))
    X = np.empty((A, 3))
    for a in range(A):
        f = inv[a]
        for i in range(3):
            r[a, i] = (H[f, i, 0] * points[a, 0] + H[f, i, 2] * points[a, 2]) + H[f, i, 1] * points[a, 1]
            X[a, i] = r[a, i] + H[f, i, 3]
    return r, X


@numba.njit(cache=True, nogil=True)
def project_anchors(X, Rc, tc, fx, fy, skew, c):  # pragma: no cover
    """Pinhole pixels ``uv (A, 2)``, depths ``z`` and normalised ``x, y`` of world anchors ``X (A, 3)``:
    ``Xc = einsum("aij,aj->ai", Rc, X) + tc``, ``z = maximum(Xc[:, 2], 1e-3)``, ``x = Xc[:, 0] / z``,
    ``uv[:, 0] = fx * x + skew * y + c[:, 0]``, ``uv[:, 1] = fy * y + c[:, 1]``."""
    A = X.shape[0]
    uv = np.empty((A, 2))
    z = np.empty(A)
    x = np.empty(A)
    y = np.empty(A)
    for a in range(A):
        xc = ((Rc[a, 0, 0] * X[a, 0] + Rc[a, 0, 2] * X[a, 2]) + Rc[a, 0, 1] * X[a, 1]) + tc[a, 0]
        yc = ((Rc[a, 1, 0] * X[a, 0] + Rc[a, 1, 2] * X[a, 2]) + Rc[a, 1, 1] * X[a, 1]) + tc[a, 1]
        zc = ((Rc[a, 2, 0] * X[a, 0] + Rc[a, 2, 2] * X[a, 2]) + Rc[a, 2, 1] * X[a, 1]) + tc[a, 2]
        za = zc if not zc < 1e-3 else 1e-3  # (a NaN stays NaN, as with np.maximum)
        z[a] = za
        x[a] = xc / za
        y[a] = yc / za
        uv[a, 0] = (fx[a] * x[a] + skew[a] * y[a]) + c[a, 0]
        uv[a, 1] = fy[a] * y[a] + c[a, 1]
    return uv, z, x, y


@numba.njit(cache=True, nogil=True)
def whitened_errors(cen, target, present, info):  # pragma: no cover
    """Pixel errors ``e (n, 2)`` of the present centroids (0 for the others) and the whitened ``r (n, 2)``:
    ``e = where(present, cen - target, 0)``, ``r = einsum("nij,nj->ni", info, e)``."""
    n = cen.shape[0]
    e = np.empty((n, 2))
    r = np.empty((n, 2))
    for k in range(n):
        if present[k]:
            e0 = cen[k, 0] - target[k, 0]
            e1 = cen[k, 1] - target[k, 1]
        else:
            e0 = 0.0
            e1 = 0.0
        e[k, 0] = e0
        e[k, 1] = e1
        r[k, 0] = info[k, 0, 0] * e0 + info[k, 0, 1] * e1
        r[k, 1] = info[k, 1, 0] * e0 + info[k, 1, 1] * e1
    return e, r


@numba.njit(cache=True, nogil=True)
def huber_rows(r, huber, out):  # pragma: no cover
    """Huber-weighted rows of ``r (n, 2)`` into ``out[:2n]``, and the weights ``(n,)``:
    ``norm = sqrt(einsum("ni,ni->n", r, r))``, ``w = where(norm > huber, sqrt(huber / maximum(norm, 1e-12)), 1)``,
    ``out = (r * w[:, None]).ravel()``."""
    n = r.shape[0]
    w = np.empty(n)
    for k in range(n):
        norm = math.sqrt(r[k, 0] * r[k, 0] + r[k, 1] * r[k, 1])
        wk = math.sqrt(huber / max(norm, 1e-12)) if norm > huber else 1.0
        w[k] = wk
        out[2 * k] = r[k, 0] * wk
        out[2 * k + 1] = r[k, 1] * wk
    return w


@numba.njit(cache=True, nogil=True)
def anchor_jacobians(Jb, inv, r):  # pragma: no cover
    """The anchors' point Jacobians ``(A, 3, nv)`` from their bodies' frame Jacobians ``Jb (F, 6, nv)``
    (LOCAL_WORLD_ALIGNED) and levers ``r (A, 3)``: ``v = Jl - [r]x Ja``, each row as
    ``Jl[0] - (r1 Ja[2] - r2 Ja[1])`` and so on."""
    A, nv = inv.shape[0], Jb.shape[2]
    JX = np.empty((A, 3, nv))
    for a in range(A):
        f = inv[a]
        r0, r1, r2 = r[a, 0], r[a, 1], r[a, 2]
        for k in range(nv):
            JX[a, 0, k] = Jb[f, 0, k] - (r1 * Jb[f, 5, k] - r2 * Jb[f, 4, k])
            JX[a, 1, k] = Jb[f, 1, k] - (r2 * Jb[f, 3, k] - r0 * Jb[f, 5, k])
            JX[a, 2, k] = Jb[f, 2, k] - (r0 * Jb[f, 4, k] - r1 * Jb[f, 3, k])
    return JX


@numba.njit(cache=True, nogil=True)
def projection_jacobians(z, x, y, fx, fy):  # pragma: no cover
    """The pinhole projection's derivative ``(A, 2, 3)`` in camera coordinates: ``[[fx / z, 0, -fx * x / z],
    [0, fy / z, -fy * y / z]]`` (the lens distortion's is left out: it is close to identity)."""
    A = z.shape[0]
    Jp = np.zeros((A, 2, 3))
    for a in range(A):
        Jp[a, 0, 0] = fx[a] / z[a]
        Jp[a, 0, 2] = -fx[a] * x[a] / z[a]
        Jp[a, 1, 1] = fy[a] / z[a]
        Jp[a, 1, 2] = -fy[a] * y[a] / z[a]
    return Jp


@numba.njit(cache=True, nogil=True)
def silhouette_field(dist, scale):  # pragma: no cover
    """``(h * w, 3)`` float64: per pixel ``D``, ``gx / scale`` and ``gy / scale``, with ``D = dist (h, w)`` as float64 and
    ``gy, gx = np.gradient(D)`` (central differences halved inside, one-sided at the edges; ``h, w >= 2``): the
    field :class:`mocap.shirt.ik.Silhouette` interpolates, in one pass instead of numpy's six over the crop."""
    h, w = dist.shape
    out = np.empty((h * w, 3))
    for y in range(h):
        ya, yb = max(y - 1, 0), min(y + 1, h - 1)
        dy = 2.0 if 0 < y < h - 1 else 1.0
        for x in range(w):
            xa, xb = max(x - 1, 0), min(x + 1, w - 1)
            dx = 2.0 if 0 < x < w - 1 else 1.0
            i = y * w + x
            out[i, 0] = np.float64(dist[y, x])
            out[i, 1] = (np.float64(dist[y, xb]) - np.float64(dist[y, xa])) / dx / scale
            out[i, 2] = (np.float64(dist[yb, x]) - np.float64(dist[ya, x])) / dy / scale
    return out
