"""A cheap check of each arm against the step-1 classification, over many arm configurations.

Centroid IK from a far-off start can settle with an arm pointing the wrong way (at a
camera, hidden in front of the torso), and a forearm can be lost mid-stroke while the
patch centroids that remain still fit (issue 18: a left elbow 43 cm off on the first
frames of shirt_office seed 3; a forearm lost in shirt_tungsten_off seed 2).  Rendering
every candidate arm and comparing id maps costs ~2 ms per candidate and camera; this
scores hundreds of candidates per frame in a few milliseconds instead:

* each arm's shirt patches are sampled once as a few points per (patch, body), in the
  thorax frame, for a fixed set of arm configurations drawn from the pose database;
* on a frame, the points of every candidate are placed with the current pose's thorax
  and projected into each camera's crop, and each point is scored by its distance to the
  nearest step-1 pixel of its colour (a distance transform per colour and camera),
  truncated at a fraction of the shirt's size (occlusion and misclassified pixels cost at
  most that);
* the arm whose mean truncated distance is well below the current arm's is a hypothesis
  for the pipeline to verify by rendering (:meth:`mocap.shirt.pipeline.ShirtTracker._arm_hypotheses`).

This is an addition to seed 001, whose database of realistic poses makes such lock-on
failures rarer.  Occlusion is not modelled here (the verification render does that).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np

from mocap.calibration import Camera
from mocap.shirt.shirt_model import CropView, ShirtModel
from mocap.shirt.zbuffer import NEAR_M

__all__ = ["ARM_SIDES", "TRUNCATE", "ArmSearch", "ArmScores", "colour_distance_maps"]

ARM_SIDES: tuple[str, ...] = ("l", "r")
"""The arms, in the order of the hinges (:data:`mocap.shirt.kinematics.UPPER_HINGES`)."""

_ARM_HINGES = {"l": slice(3, 7), "r": slice(7, 11)}  # shoulder x y z, elbow, in the 11 hinges
_CACHE_ARMS = 4096  # arms whose sample points ArmSearch keeps, per side
TRUNCATE = 0.25
"""A point's cost is truncated at this many shirt sizes (:meth:`ArmSearch.score`)."""


@dataclass(frozen=True)
class ArmScores:
    """Scores of one arm: ``current`` for the pose's own arm and ``(N,)`` for the candidates
    ``arms (N, 4)`` (shoulder x y z, elbow; radians), in shirt sizes (lower is better)."""

    current: float
    scores: np.ndarray
    arms: np.ndarray


def colour_distance_maps(colour: np.ndarray, colours: np.ndarray, reach: float | None = None) -> np.ndarray:
    """``(len(colours), h, w)`` float32: distance (working pixels) from every pixel of a
    classified map ``colour (h, w)`` (-1 unclassified) to the nearest pixel of each colour
    in ``colours``; a colour with no pixel is ``h + w`` everywhere.

    With ``reach``, distances of at least ``reach`` may read ``h + w``: each colour's transform
    runs only over its pixels' box grown by ``reach`` (an arm's colour covers a small part of the
    crop; the screen truncates its costs there anyway).  Inside that box the values are the whole
    map's (the 3 x 3 chamfer distance: a shortest path between two pixels stays in their box),
    to float32 rounding; outside it the chamfer distance is at least 0.955 times the box distance.
    """
    h, w = colour.shape
    out = np.empty((len(colours), h, w), np.float32)
    pad = None if reach is None else int(np.ceil(reach / 0.955)) + 1
    for i, k in enumerate(colours):
        on = colour == k
        rows = np.flatnonzero(on.any(axis=1))
        if rows.size == 0:
            out[i] = float(h + w)
        elif pad is None:
            out[i] = cv2.distanceTransform((~on).view(np.uint8), cv2.DIST_L2, 3)
        else:
            cols = np.flatnonzero(on.any(axis=0))
            y0, y1 = max(rows[0] - pad, 0), min(rows[-1] + pad + 1, h)
            x0, x1 = max(cols[0] - pad, 0), min(cols[-1] + pad + 1, w)
            out[i] = float(h + w)
            out[i, y0:y1, x0:x1] = cv2.distanceTransform(np.ascontiguousarray(~on[y0:y1, x0:x1]).view(np.uint8), cv2.DIST_L2, 3)
    return out


class ArmSearch:
    """Arm configurations scored against a classification by projected sample points.

    Parameters
    ----------
    model : ShirtModel
    hinges : (N, 11) float
        Configurations to draw the fixed candidate arms from (the pose database's).
    n_arms : int
        Fixed candidates per arm, drawn without replacement with ``rng``.
    points_per_part : int
        Sample points per (patch, body) of an arm.
    rng : np.random.Generator
    """

    def __init__(self, model: ShirtModel, hinges: np.ndarray, n_arms: int, points_per_part: int,
                 rng: np.random.Generator) -> None:
        self.model = model
        self.kin = model.kin
        names = model.geometry.body_names
        hinges = np.asarray(hinges, float)
        pick = rng.choice(len(hinges), size=min(n_arms, len(hinges)), replace=False)
        self.fixed = {s: np.unique(hinges[pick, _ARM_HINGES[s]], axis=0) for s in ARM_SIDES}
        self._points = {}   # side -> (body index in the arm (0 upper, 1 fore), point in body frame (P, 3), colour (P,))
        for s in ARM_SIDES:
            bodies = (names.index(f"upperarm_{s}"), names.index(f"forearm_{s}"))
            part, pts, col = [], [], []
            for j, b in enumerate(bodies):
                for patch in np.unique(model.face_patch[(model.face_body == b) & (model.face_patch >= 0)]):
                    faces = np.flatnonzero((model.face_body == b) & (model.face_patch == patch))
                    # evenly spread faces of the part (the mesh lists them in order around and along the limb)
                    sel = faces[np.linspace(0, len(faces) - 1, min(points_per_part, len(faces))).round().astype(int)]
                    pts.append(model.face_centre_body[sel])
                    part += [j] * len(sel)
                    col += [int(model.patch_colour[patch])] * len(sel)
            self._points[s] = (np.asarray(part), np.concatenate(pts), np.asarray(col))
        # the colours each arm's points score against (a distance transform each per camera and
        # frame): the arm's own, 3 of the shirt's 10 (6 for both arms)
        self.colours = {s: np.unique(self._points[s][2]) for s in ARM_SIDES}
        self._bodies = {s: ("thorax", f"upperarm_{s}", f"forearm_{s}") for s in ARM_SIDES}
        self._cache: dict[str, dict[bytes, np.ndarray]] = {s: {} for s in ARM_SIDES}
        self._fixed_rel = {s: self._compute_in_thorax(s, self.fixed[s]) for s in ARM_SIDES}

    def _in_thorax(self, side: str, arms: np.ndarray) -> np.ndarray:
        """``(N, P, 3)``: the arm's sample points in the thorax frame for each arm configuration ``(N, 4)``.

        Each arm's points depend on that arm alone: they are kept per arm (the database
        neighbours' arms come back frame after frame), up to ``_CACHE_ARMS`` of them.
        """
        part, pts, _ = self._points[side]
        arms = np.asarray(arms, float)
        out = np.empty((len(arms), len(pts), 3))
        cache = self._cache[side]
        keys = [a.tobytes() for a in arms]
        todo = [i for i, k in enumerate(keys) if k not in cache]
        for i, k in enumerate(keys):
            if k in cache:
                out[i] = cache[k]
        if todo:
            fresh = self._compute_in_thorax(side, arms[todo])
            out[todo] = fresh
            # (filled before the cache may be cleared: a full cache emptied here held some of these
            # arms, and reading them back afterwards was a KeyError on a long take)
            if len(cache) + len(todo) > _CACHE_ARMS:
                cache.clear()
            for j, i in enumerate(todo):
                cache[keys[i]] = fresh[j]
        return out

    def _compute_in_thorax(self, side: str, arms: np.ndarray) -> np.ndarray:
        """:meth:`_in_thorax` computed."""
        part, pts, _ = self._points[side]
        q = self.kin.neutral()
        sl = _ARM_HINGES[side]
        R = np.empty((len(arms), 3, 3, 3))  # thorax, upper arm, forearm of each arm
        p = np.empty((len(arms), 3, 3))
        for i, a in enumerate(arms):
            q[7 + sl.start: 7 + sl.stop] = a
            R[i], p[i] = self.kin.placements(q, self._bodies[side])
        # all arms' points at once: per arm the same matrix products as one arm's
        # (pts @ R_part.T + p_part - p_thorax) @ R_thorax, the same values (a third of the time for 20 arms)
        out = np.empty((len(arms), len(pts), 3))
        for j in (0, 1):
            m = part == j
            lever = np.matmul(pts[m], R[:, 1 + j].transpose(0, 2, 1)) + p[:, 1 + j, None] - p[:, 0, None]
            out[:, m] = np.matmul(lever, R[:, 0])
        return out

    def score(self, q: np.ndarray, side: str, shots: list[tuple[Camera, CropView, np.ndarray, float]],
              extra_arms: np.ndarray | None = None, truncate: float = TRUNCATE) -> ArmScores:
        """Scores of the arm ``side`` of pose ``q (18,)`` and of every candidate arm on ``q``'s thorax.

        ``shots`` : per camera ``(camera, crop view, distance maps (K, h, w) from
        :func:`colour_distance_maps` over ``colours[side]``, shirt size in working pixels)``.
        ``extra_arms`` : ``(M, 4)`` more candidates (e.g. the database neighbours of this frame).
        Each point costs its distance in shirt sizes, truncated at ``truncate``; a point
        outside a crop costs ``truncate``.
        """
        sl = _ARM_HINGES[side]
        own = np.asarray(q, float)[7 + sl.start: 7 + sl.stop][None]
        arms = [own] + ([np.asarray(extra_arms, float)] if extra_arms is not None and len(extra_arms) else [])
        rel = np.concatenate([self._in_thorax(side, np.concatenate(arms)), self._fixed_rel[side]])
        all_arms = np.concatenate(arms + [self.fixed[side]])
        R, p = self.kin.placements(q, ("thorax",))
        N, P = rel.shape[:2]
        col_index = np.searchsorted(self.colours[side], self._points[side][2])
        total = np.zeros(N)
        world = None
        for cam, view, dmaps, size in shots:
            K = cam.K
            if not np.any(cam.dist != 0) and K[0, 1] == 0 and K[1, 0] == 0:
                # a pinhole: thorax -> camera in one transform, projection and costs in one compiled pass
                # (the numpy form's passes over all candidates' points were most of the screen's cost)
                M = cam.R @ R[0]
                total += _arm_costs(np.ascontiguousarray(rel), M, cam.R @ p[0] + cam.t,
                                    K[0, 0], K[1, 1], K[0, 2], K[1, 2], float(view.x0), float(view.y0), float(view.scale),
                                    col_index, dmaps, np.float32(max(size, 1.0)), np.float32(truncate), float(truncate))
                continue
            world = rel @ R[0].T + p[0] if world is None else world   # (N, P, 3)
            uv, z = self.model._project(world.reshape(-1, 3), cam, view)
            # (float32 arithmetic, as numpy's on the float32 maps with Python floats)
            d = _point_costs(uv, z, col_index, dmaps, np.float32(max(size, 1.0)), np.float32(truncate), float(truncate))
            total += d.reshape(N, P).mean(axis=1)
        total /= max(len(shots), 1)
        return ArmScores(float(total[0]), total[1:], all_arms[1:])


@numba.njit(cache=True, nogil=True)
def _point_costs(uv, z, col_index, dmaps, size, truncate32, truncate):  # pragma: no cover
    """Each projected point's cost ``(n,)``: at its nearest pixel ``rint(uv)`` inside the map and in front
    (``z > 0``), ``min(dmaps[colour, y, x] / size, truncate)`` in float32, else ``truncate``; point ``t``
    has colour ``col_index[t % len(col_index)]`` (the candidates' points in order).  Compiled: the numpy form's
    passes over all candidates' points were most of :meth:`ArmSearch.score`'s cost."""
    h, w = dmaps.shape[1], dmaps.shape[2]
    P = col_index.shape[0]
    d = np.empty(uv.shape[0])
    for t in range(uv.shape[0]):
        x = np.rint(uv[t, 0])
        y = np.rint(uv[t, 1])
        # (compared as floats: a NaN or a coordinate beyond int64 is outside, as numpy's cast makes it)
        if x >= 0 and x < w and y >= 0 and y < h and z[t] > 0:
            v = dmaps[col_index[t % P], np.int64(y), np.int64(x)] / size
            d[t] = truncate32 if v > truncate32 else v
        else:
            d[t] = truncate
    return d


@numba.njit(cache=True, nogil=True)
def _arm_costs(rel, M, b, fx, fy, cx, cy, x0, y0, scale, col_index, dmaps, size, truncate32, truncate):  # pragma: no cover
    """Mean cost ``(N,)`` of each arm's points ``rel (N, P, 3)`` (thorax frame) seen by a pinhole camera:
    ``Xc = M x + b``, pixel ``(fx X/Z + cx, fy Y/Z + cy)`` in the crop view ``((u - x0) / scale, ...)``, then the
    cost of :func:`_point_costs` (``Z`` at most :data:`mocap.shirt.zbuffer.NEAR_M` divides as 1, as the model's projection)."""
    N, P = rel.shape[0], rel.shape[1]
    h, w = dmaps.shape[1], dmaps.shape[2]
    out = np.empty(N)
    for n in range(N):
        acc = 0.0
        for t in range(P):
            X = rel[n, t, 0]
            Y = rel[n, t, 1]
            Z = rel[n, t, 2]
            xc = M[0, 0] * X + M[0, 1] * Y + M[0, 2] * Z + b[0]
            yc = M[1, 0] * X + M[1, 1] * Y + M[1, 2] * Z + b[1]
            zc = M[2, 0] * X + M[2, 1] * Y + M[2, 2] * Z + b[2]
            zs = zc if zc > NEAR_M else 1.0
            x = np.rint(((xc / zs) * fx + cx - x0) / scale)
            y = np.rint(((yc / zs) * fy + cy - y0) / scale)
            if x >= 0 and x < w and y >= 0 and y < h and zc > 0:
                v = dmaps[col_index[t], np.int64(y), np.int64(x)] / size
                acc += truncate32 if v > truncate32 else v
            else:
                acc += truncate
        out[n] = acc / P
    return out
