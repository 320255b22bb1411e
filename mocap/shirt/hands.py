"""The hands as two more centroid targets of step 4: an addition to seed 001.

Why: the wrists carry most of the shirt pipeline's error.  A forearm's one patch gives one
point of the forearm in each camera, so the wrist, a forearm's length from the elbow, moves
twice as far as that point's error, and where a camera looks along the forearm nothing in that
camera says how it tilts (issue 18: on shirt_office seeds 1-2 the wrists were 3.1-4.6 cm RMS
against 1-2 cm for every other joint; on shirt_jumping_jacks the wrists alone failed the 5 cm
bar on 37-43 % of the frames).  The bare hand beyond the sleeve is a blob of skin about a
forearm's length from the elbow: its centroid is one more point of the forearm, far out.

Inputs and outputs, per frame and camera:

* in: the crop's foreground pixels and step-1 classification, the white balance ``W``, the
  pose being solved (its render and its patch split), and the session's skin colour
  (:func:`fit_skin_colour`, fitted once to the pixels around the first frame's head);
* out: up to two IK constraints (:meth:`HandModel.constraints`): each hand's skin centroid in
  the image, anchored at the hand's centre of mass (the pipeline's kinematics locks the wrists,
  so a hand moves with its forearm).

The skin pieces are the 8-connected pieces of foreground pixels that no shirt colour claims in
step 1 and that lie within ``skin_threshold`` Mahalanobis units of the skin colour.  A hand takes
the piece that borders its own forearm's pixels of the patch split (the sleeve's end) more than
the other's, of ``hand_min_pixels`` or more, not under the head, nearest to where the pose puts
the hand within ``hand_gate`` shirt sizes.  Skin also joins the not-shirt colours, so that no
step classifies a hand as its sleeve.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass

import cv2
import numpy as np

from mocap.calibration import Camera
from mocap.errors import MocapInputError
from mocap.shirt.colour_model import ColourModel
from mocap.shirt.ik import Constraints
from mocap.shirt.shirt_model import CropView, ShirtModel

__all__ = ["HAND_SIDES", "HandModel", "fit_skin_colour", "widened_skin", "HandTargets", "skin_pieces", "find_hands", "HandTracking"]

HAND_SIDES: tuple[str, str] = ("l", "r")


def _centre_of_mass(mjcf_text: str, body: str) -> np.ndarray:
    """An MJCF body's centre of mass in its own frame (its ``<inertial pos>``), metres."""
    el = ET.fromstring(mjcf_text).find(f".//body[@name='{body}']/inertial")
    if el is None:
        raise MocapInputError(f"humanoid MJCF: no <inertial> in body {body!r}; give the standalone humanoid of docs/humanoid_spec.md "
                              "(or pass ShirtPipelineParams(hand_constraints=False))")
    return np.array([float(v) for v in el.get("pos", "0 0 0").split()])


@dataclass(frozen=True)
class HandModel:
    """Where the hands and the head are on the model's bodies.

    Attributes
    ----------
    hand_body : (2,) int
        Index into the shirt geometry's bodies of each hand (left, right).
    head_body : int
    centre_m : (3, 3) float
        The hands' and the head's centres of mass in their bodies' frames, metres (the humanoid's MJCF).
        A hand's target is anchored there.  Measured against the anchor at the mean vertex of the hand's
        mesh (3.8 cm nearer the wrist) and at the pixel-weighted mean of the faces the rendered pose shows
        (as the patches'), on cached frames: shirt_office seeds 1-2 1.19 / 1.31 cm against 2.32 / 2.13
        and 1.58 / 1.37; step 1 leaves the sleeve's edge of the hand unclassified, so the skin's centroid
        lies beyond the mesh's.
    """

    hand_body: tuple[int, int]
    head_body: int
    centre_m: np.ndarray

    @classmethod
    def from_model(cls, model: ShirtModel) -> "HandModel":
        names = list(model.geometry.body_names)
        missing = [b for b in ("hand_l", "hand_r", "head") if b not in names]
        if missing:
            raise MocapInputError(f"shirt geometry: no mesh for {', '.join(missing)}; the hand constraints need the hands and the "
                                  "head among its bodies (rebuild the pose database, or pass ShirtPipelineParams(hand_constraints=False))")
        idx = [names.index(b) for b in ("hand_l", "hand_r", "head")]
        centres = np.array([_centre_of_mass(model.mjcf_text, b) for b in ("hand_l", "hand_r", "head")])
        return cls((idx[0], idx[1]), idx[2], centres)

    def world_points(self, model: ShirtModel, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The hands' centres ``(2, 3)`` and the head's ``(3,)`` in the world at pose ``q``, metres."""
        names = model.geometry.body_names
        R, p = model.kin.placements(q, (names[self.hand_body[0]], names[self.hand_body[1]], names[self.head_body]))
        X = np.einsum("bij,bj->bi", R, self.centre_m) + p
        return X[:2], X[2]

    def constraints(self, ci: int, targets_px: np.ndarray, std: float, size_px: float, first_patch: int) -> Constraints:
        """IK constraints ``targets_px (2, 2)`` of camera ``ci``, each at its hand's centre (rows with a NaN left out),
        with a residual SD of ``std`` shirt sizes; patch ids ``first_patch + side``."""
        ok = np.flatnonzero(np.all(np.isfinite(targets_px), axis=1))
        n = ok.size
        if n == 0:
            return Constraints.empty()
        info = np.repeat((np.eye(2) / (std * size_px))[None], n, axis=0)
        return Constraints(np.full(n, ci), first_patch + ok, targets_px[ok], info, np.full(n, float(size_px)), np.zeros(n, bool),
                           np.arange(n), np.array(self.hand_body)[ok], self.centre_m[:2][ok], np.ones(n))


def fit_skin_colour(x: np.ndarray, regularisation: float = 1e-5) -> ColourModel | None:
    """The subject's skin colour, one Gaussian ``"skin"`` in white-balanced linear RGB, from pixels ``x (n, 3)`` (white
    balanced) that are mostly skin: the mean and covariance of those within 2.5 robust SDs of the median in every
    channel (the rest: hair, shadow, a sleeve's edge).  None with fewer than 20 such pixels."""
    x = np.asarray(x, float).reshape(-1, 3)
    if len(x) < 20:
        return None
    med = np.median(x, axis=0)
    mad = 1.4826 * np.median(np.abs(x - med), axis=0) + 1e-6
    core = x[np.all(np.abs(x - med) < 2.5 * mad, axis=1)]
    if len(core) < 20:
        return None
    return ColourModel(core.mean(axis=0)[None], (np.cov(core.T) + regularisation * np.eye(3))[None], ("skin",))


def widened_skin(skin: ColourModel, shading: float, floor: float) -> ColourModel:
    """The skin colour ``skin`` (one Gaussian, :func:`fit_skin_colour`) with its covariance widened along its mean by
    ``shading`` of the mean (SD ``shading * |mean|`` in that direction) and every eigenvalue floored at
    ``(floor * |mean|)**2``; the mean unchanged.

    Why: the skin is fitted to one frame's pixels around the head, and as a not-shirt colour (steps 1 and 3) it
    has to hold for the whole take, whose shading and light vary more than that sample shows: fitted to a small,
    evenly lit face it was 0.008-0.016 wide per channel on ``shirt_walk_lamp`` seed 1 (against 0.04-0.06 on
    ``shirt_office``), and skin-like pixels that it did not claim went to the shirt's colours.  Shading scales a
    colour, hence the widening along the mean.  On the cached frames of the seed tables (124 takes) ``shading``
    0.5 and ``floor`` 0.05 moved the full method's medians: office 1.19 -> 1.11 cm (better on 36 of 40 seeds),
    tungsten_off 2.09 -> 1.92 (17 of 20), walk_lamp 4.25 -> 3.75 (16 of 20), jumping jacks 1.44 -> 1.45, outdoor
    1.30 -> 1.35 (worse on 15 of 24).  The hands' own test keeps the fitted colour: widened there it found false
    hands (tungsten_off 2.09 -> 2.62).
    """
    mu = np.asarray(skin.means, float)[0]
    along = shading * mu
    cov = np.asarray(skin.covariances, float)[0] + np.outer(along, along)
    w, V = np.linalg.eigh(cov)
    cov = (V * np.maximum(w, (floor * float(np.linalg.norm(mu))) ** 2)) @ V.T
    return ColourModel(skin.means, cov[None], skin.names)


@dataclass(frozen=True)
class HandTargets:
    """One camera's skin pieces: ``pieces (size, size)`` int32 label map (0: none), their ``centroids (k + 1, 2)``
    working pixels and ``counts (k + 1,)`` (row 0: the background, unused), and ``grown (size, size)``: the label
    map dilated by two pixels (which piece, if any, each pixel borders)."""

    pieces: np.ndarray
    centroids: np.ndarray
    counts: np.ndarray
    grown: np.ndarray

    def bordering(self, pixels: np.ndarray) -> np.ndarray:
        """``(k + 1,)``: how many of the flat pixel indices ``pixels`` border each piece (0 for the background)."""
        n = np.bincount(self.grown.ravel()[pixels], minlength=len(self.counts))[: len(self.counts)]
        n[0] = 0
        return n


def skin_pieces(idx: np.ndarray, x: np.ndarray, colour: np.ndarray, W: np.ndarray, skin: ColourModel, threshold: float) -> HandTargets:
    """The 8-connected pieces of the crop's foreground pixels ``idx (n,)`` (flat, colours ``x (n, 3)``) that no shirt
    colour claims in ``colour (size, size)`` and that are within ``threshold`` of the skin colour (:func:`fit_skin_colour`)."""
    size = colour.shape[0]
    free = colour.ravel()[idx] < 0
    mask = np.zeros(size * size, np.uint8)
    if free.any():
        near = skin.distances(x[free], W)[:, 0] < threshold
        mask[idx[free][near]] = 1
    k, pieces, stats, cents = cv2.connectedComponentsWithStats(mask.reshape(size, size), connectivity=8)
    # (label ids survive a grey dilation; where two pieces are within reach the higher id wins, which only
    # matters for pieces a hand's width apart)
    grown = cv2.dilate(pieces.astype(np.float32), np.ones((5, 5), np.uint8)).astype(np.int64)
    return HandTargets(pieces, cents, stats[:, cv2.CC_STAT_AREA], grown)


def find_hands(found: HandTargets, sleeve: tuple[np.ndarray, np.ndarray], hands_px: np.ndarray, head_px: np.ndarray, gate_px: float,
               min_pixels: int) -> np.ndarray:
    """Each hand's blob centroid ``(2, 2)`` working pixels (NaN where none): of the pieces of ``min_pixels`` or more
    that border the hand's own sleeve (``sleeve[side]``: flat indices of the pixels the patch split gives that
    forearm) and no more of the other's, that are not the piece under the predicted head
    ``head_px`` and are nearer to the hand's predicted position ``hands_px[side]`` than to the head, the nearest
    within ``gate_px``.  The sleeve is what tells the hands apart where they cross: the pose's prediction alone
    took the other hand then and held the wrong one.  A piece both hands take is given to neither."""
    out = np.full((2, 2), np.nan)
    n = len(found.counts)
    if n <= 1:
        return out
    ok = found.counts >= min_pixels
    size = found.pieces.shape[0]
    hx, hy = int(round(head_px[0])), int(round(head_px[1]))
    if 0 <= hx < size and 0 <= hy < size:
        ok[found.pieces[hy, hx]] = False
    ok[0] = False
    head_d = np.linalg.norm(found.centroids - head_px, axis=1)
    chosen = [-1, -1]
    borders = [found.bordering(sleeve[0]), found.bordering(sleeve[1])]
    for s in range(2):
        own, other = borders[s], borders[1 - s]
        d = np.linalg.norm(found.centroids - hands_px[s], axis=1)
        cand = np.flatnonzero(ok & (own > 0) & (own >= other) & (d <= gate_px) & (d < head_d))
        if cand.size:
            chosen[s] = int(cand[np.argmin(d[cand])])
    if chosen[0] >= 0 and chosen[0] == chosen[1]:
        return out
    for s in range(2):
        if chosen[s] >= 0:
            out[s] = found.centroids[chosen[s]]
    return out


def project_to_view(cam: Camera, view: CropView, X: np.ndarray) -> np.ndarray:
    """World points ``(n, 3)`` to the crop's working pixels ``(n, 2)`` (NaN behind the camera)."""
    X = np.asarray(X, float).reshape(-1, 3)
    Xc = X @ cam.R.T + cam.t
    uv = cam.project(X).reshape(-1, 2)
    uv[Xc[:, 2] <= 0.05] = np.nan
    return view.from_image(uv)


class HandTracking:
    """The hand constraints of a :class:`mocap.shirt.pipeline.ShirtTracker` (a part of it: it uses the tracker's
    model, cameras, settings and white balance)."""

    def _init_hands(self) -> None:
        self.hands = HandModel.from_model(self.model) if self.params.hand_constraints else None
        self.skin: ColourModel | None = None
        self._pieces: dict[int, tuple[np.ndarray, HandTargets]] = {}  # camera -> (step-1 map, its skin pieces)
        # each forearm's patch: its sleeve's end borders the hand
        m, names = self.model, list(self.model.geometry.body_names)
        self._sleeve_patches = tuple(int(m.face_patch[(m.face_body == names.index(f"forearm_{s}")) & (m.face_patch >= 0)][0])
                                     for s in HAND_SIDES)

    def _hand_constraints(self, ci: int, o, q: np.ndarray, rend, patch_map: np.ndarray) -> Constraints:
        """Camera ``ci``'s hand constraints for pose ``q``, the hands told apart by where ``q`` puts them and by which forearm's pixels of the patch split ``patch_map`` (patch per working
        pixel, -1 none) border them; none before the skin is known."""
        if self.skin is None or o.step1 is None or o.pixels is None or o.tiny is None:
            return Constraints.empty()
        p = self.params
        kept = self._pieces.get(ci)
        if kept is None or kept[0] is not o.step1.colour:
            found = skin_pieces(o.pixels[0], o.pixels[1], o.step1.colour, self.W[ci], self.skin, p.skin_threshold)
            kept = self._pieces[ci] = (o.step1.colour, found)
        hands, head = self.hands.world_points(self.model, q)
        pts = project_to_view(self.cameras[ci], o.view, np.vstack([hands, head[None]]))
        if not np.all(np.isfinite(pts)):
            return Constraints.empty()
        pm = np.asarray(patch_map).ravel()
        sleeves = (np.flatnonzero(pm == self._sleeve_patches[0]), np.flatnonzero(pm == self._sleeve_patches[1]))
        found_px = find_hands(kept[1], sleeves, pts[:2], pts[2], p.hand_gate * o.tiny.side, p.hand_min_pixels)
        f = rend.face[rend.face >= 0]
        for s, b in enumerate(self.hands.hand_body):
            if not np.any(self.model.face_body[f] == b):
                found_px[s] = np.nan
        return self.hands.constraints(ci, o.view.to_image(found_px), p.hand_std, o.tiny.side * o.view.scale, self.model.n_patches)

    def _learn_skin(self, q: np.ndarray, obs: list) -> None:
        """The skin colour from the pixels around the head of pose ``q`` that no shirt colour claims (the first
        frame's); it also joins the not-shirt colours."""
        if self.hands is None or self.skin is not None or not np.all(np.isfinite(q)):
            return
        _, head = self.hands.world_points(self.model, q)
        xs = []
        for ci, o in enumerate(obs):
            if o.final is None or o.pixels is None or o.tiny is None:
                continue
            c = project_to_view(self.cameras[ci], o.view, head[None])[0]
            idx, x = o.pixels
            ys, xs_ = np.divmod(idx, o.view.size)
            near = (np.hypot(xs_ - c[0], ys - c[1]) < self.params.head_sample * o.tiny.side) & (o.final.colour.ravel()[idx] < 0)
            xs.append(np.asarray(x[near], float) @ np.asarray(self.W[ci], float).T)
        if xs:
            self.skin = fit_skin_colour(np.concatenate(xs))
        if self.skin is not None:
            # skin joins the session's not-shirt colours: a pixel nearer to it than to every shirt colour stays
            # unclassified in steps 1 and 3 (step 3's pose prior otherwise gave the hand's pixels next to a
            # sleeve to that sleeve's colour, shrinking the hand and pulling the forearm's centroid out)
            skin = widened_skin(self.skin, self.params.skin_shading, self.params.skin_floor)
            self.other = skin if self.other is None else ColourModel(np.concatenate([self.other.means, skin.means]),
                                                                     np.concatenate([self.other.covariances, skin.covariances]),
                                                                     tuple(self.other.names) + ("skin",))
