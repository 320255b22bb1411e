"""Exact Euclidean distance transforms of the shirt pipeline's small masks, many at once (:func:`exact_distances`).

The same values as :func:`mocap.distance_transform.exact_distance_transform`, bit for bit:
that function rounds OpenCV's exact transform to the integer squared distance between
pixel centres and takes the square root again (float64, then float32).  Here the squared
distances are computed in integers (Meijster, Roerdink & Hesselink 2000: a column pass,
then the lower envelope of parabolas along each row, with integer separators), so no
rounding happens before that same square root.  Compiled, and a stack of masks per call:
step 3 transforms a mask per rendered patch (16-20 of 48 x 48 cells) several times a
frame, where OpenCV's per-call overhead and the float round trip cost more than the
transform.  A mask with no zero pixel goes to :func:`exact_distance_transform` (OpenCV's
value there is not a distance).
"""

from __future__ import annotations

import numba
import numpy as np

from mocap.distance_transform import exact_distance_transform

__all__ = ["exact_distances", "not_patch_cells"]


def exact_distances(not_target: np.ndarray) -> np.ndarray:
    """:func:`mocap.distance_transform.exact_distance_transform` of each mask of a stack ``(m, h, w)`` (or of one ``(h, w)``).

    ``not_target``: non-zero away from the target, zero on it.  Returns float32 of the same shape.
    """
    a = np.ascontiguousarray(not_target, np.uint8)
    one = a.ndim == 2
    stack = a[None] if one else a
    out = np.empty(stack.shape, np.float32)
    if stack.size:
        empty = _exact_distances(stack, out)
        for i in np.flatnonzero(empty):
            out[i] = exact_distance_transform(stack[i])
    return out[0] if one else out


@numba.njit(cache=True, nogil=True)
def _exact_distances(masks, out):  # pragma: no cover
    """Fills ``out (m, h, w)`` float32; returns ``(m,)`` bool: the masks without a zero pixel (left for the caller)."""
    m, h, w = masks.shape
    inf = h + w
    g = np.empty((h, w), np.int64)
    g2 = np.empty(w, np.int64)
    s = np.empty(w, np.int64)
    t = np.empty(w, np.int64)
    empty = np.zeros(m, np.bool_)
    for k in range(m):
        any_zero = False
        # column pass (row by row, down then up): distance to the nearest zero pixel in the same column
        for x in range(w):
            if masks[k, 0, x] == 0:
                g[0, x] = 0
                any_zero = True
            else:
                g[0, x] = inf
        for y in range(1, h):
            for x in range(w):
                if masks[k, y, x] == 0:
                    g[y, x] = 0
                    any_zero = True
                else:
                    g[y, x] = min(g[y - 1, x] + 1, inf)
        if not any_zero:
            empty[k] = True
            continue
        for y in range(h - 2, -1, -1):
            for x in range(w):
                if g[y + 1, x] + 1 < g[y, x]:
                    g[y, x] = g[y + 1, x] + 1
        # row pass: lower envelope of the parabolas (x - i)^2 + g(i)^2
        for y in range(h):
            for x in range(w):
                g2[x] = g[y, x] * g[y, x]
            q = 0
            s[0] = 0
            t[0] = 0
            for u in range(1, w):
                while q >= 0 and (t[q] - s[q]) * (t[q] - s[q]) + g2[s[q]] > (t[q] - u) * (t[q] - u) + g2[u]:
                    q -= 1
                if q < 0:
                    q = 0
                    s[0] = u
                else:
                    i = s[q]
                    wpos = 1 + (u * u - i * i + g2[u] - g2[i]) // (2 * (u - i))
                    if wpos < w:
                        q += 1
                        s[q] = u
                        t[q] = wpos
            for u in range(w - 1, -1, -1):
                i = s[q]
                out[k, y, u] = np.float32(np.sqrt(np.float64((u - i) * (u - i) + g2[i])))
                if u == t[q]:
                    q -= 1
    return empty


@numba.njit(cache=True, nogil=True)
def not_patch_cells(patch_map, patches, reduce):  # pragma: no cover
    """``(m, r, r)`` uint8, ``r = side // reduce``: 1 where none of a cell's ``reduce x reduce`` pixels of
    ``patch_map (side, side)`` int is patch ``patches[i]`` (m,), 0 where one is (the masks step 3 transforms).
    Pixels of patches not in ``patches`` are ignored."""
    m = patches.shape[0]
    r = patch_map.shape[0] // reduce
    top = 0
    for i in range(m):
        top = max(top, patches[i] + 1)
    slot = np.full(top, -1, np.int64)
    for i in range(m):
        slot[patches[i]] = i
    out = np.ones((m, r, r), np.uint8)
    for y in range(r * reduce):
        for x in range(r * reduce):
            p = patch_map[y, x]
            if p >= 0 and p < top and slot[p] >= 0:
                out[slot[p], y // reduce, x // reduce] = 0
    return out
