"""The colour shirt of seed 001 (Wang & Popovic, *Practical Color-Based Motion Capture*).

20 patches over the torso, shoulders and arms, in 10 distinct colours each used
twice.  The two patches of one colour are far apart on the body (front/back,
left/right, torso/arm), so that a coarse colour image of the shirt still tells
the pose apart, as in the paper.

Layout (``PATCH_NAMES``), in body frames of the T-pose (X forward, Y left, Z up):

* torso front, 3 rows x 2 sides: ``chest`` (upper thorax), ``ribs`` (lower thorax),
  ``belly`` (abdomen);
* torso back, 3 rows x 2 sides: ``upperback``, ``midback``, ``lowerback``;
* ``flank`` under each arm (sides of the lower thorax and abdomen);
* ``shoulder`` caps (top of the thorax at the shoulder and the proximal upper arm);
* ``upperarm`` (distal two thirds) and ``forearm``, each side.

Patch ids are assigned per surface face from the face centre, so every face of the
shirt region has exactly one id; faces of other bodies get ``-1``.
"""

from __future__ import annotations

import numpy as np

from simbench.scenes.anthropometry import BodyDims

PATCH_NAMES: tuple[str, ...] = (
    "chest_l",
    "chest_r",
    "ribs_l",
    "ribs_r",
    "belly_l",
    "belly_r",
    "upperback_l",
    "upperback_r",
    "midback_l",
    "midback_r",
    "lowerback_l",
    "lowerback_r",
    "shoulder_l",
    "shoulder_r",
    "upperarm_l",
    "upperarm_r",
    "forearm_l",
    "forearm_r",
    "flank_l",
    "flank_r",
)
N_PATCHES = len(PATCH_NAMES)
_P = {n: i for i, n in enumerate(PATCH_NAMES)}

COLOUR_NAMES: tuple[str, ...] = (
    "red",
    "green",
    "blue",
    "yellow",
    "cyan",
    "magenta",
    "orange",
    "purple",
    "light_grey",
    "black",
)

# Linear-RGB albedo (0..1).  Eight hues spread around the chromaticity plane plus a
# light and a dark achromatic colour, kept away from each other in chromaticity
# (r, g) = (R, G) / (R + G + B) so that a Gaussian classifier still separates them
# after a white-balance error of a few hundred kelvin.
SHIRT_COLOURS_RGB = np.array(
    [
        [0.80, 0.04, 0.04],  # red
        [0.05, 0.55, 0.06],  # green
        [0.03, 0.10, 0.80],  # blue
        [0.85, 0.75, 0.04],  # yellow
        [0.04, 0.60, 0.70],  # cyan
        [0.80, 0.05, 0.50],  # magenta
        [0.90, 0.28, 0.02],  # orange
        [0.30, 0.05, 0.55],  # purple
        [0.75, 0.75, 0.75],  # light grey
        [0.02, 0.02, 0.02],  # black
    ],
    dtype=np.float64,
)
SHIRT_COLOURS_RGB.setflags(write=False)

# Colour index of each patch: the two patches of a colour are far apart
# (front vs back, crossed sides, torso vs opposite arm).
PATCH_COLOUR = np.empty(N_PATCHES, dtype=np.int16)
for _colour, (_a, _b) in enumerate(
    (
        ("chest_l", "lowerback_r"),  # red
        ("chest_r", "lowerback_l"),  # green
        ("ribs_l", "forearm_r"),  # blue
        ("ribs_r", "forearm_l"),  # yellow
        ("belly_l", "upperback_r"),  # cyan
        ("belly_r", "upperback_l"),  # magenta
        ("midback_l", "upperarm_r"),  # orange
        ("midback_r", "upperarm_l"),  # purple
        ("shoulder_l", "flank_r"),  # light grey
        ("shoulder_r", "flank_l"),  # black
    )
):
    PATCH_COLOUR[_P[_a]] = _colour
    PATCH_COLOUR[_P[_b]] = _colour
PATCH_COLOUR.setflags(write=False)

SHIRT_BODIES: tuple[str, ...] = ("abdomen", "thorax", "upperarm_l", "forearm_l", "upperarm_r", "forearm_r")

# Fractions that place the patch borders (body-frame geometry, see module docstring).
_SHOULDER_ARM_FRACTION = 0.3  # proximal part of the upper arm that belongs to the shoulder cap
_SHOULDER_INNER_FRACTION = 0.55  # shoulder cap on the thorax starts at this fraction of the shoulder half width
_FLANK_FRACTION = 0.78  # flank: |y| beyond this fraction of the torso half width
_CHEST_SPLIT_FRACTION = 0.5  # upper/lower thorax rows split at this fraction of its length
_SHOULDER_DROP_RADII = 0.8  # shoulder cap reaches this many upper-arm radii below the shoulder centre


def shirt_row_borders_m(dims: BodyDims) -> tuple[float, ...]:
    """Heights of the horizontal patch borders on the torso, metres above the hip centres.

    The surface puts a ring of vertices there so that patch borders are straight.
    """
    thorax_joint = dims.lumbar + dims.abdomen
    return (
        thorax_joint + _CHEST_SPLIT_FRACTION * dims.thorax,
        thorax_joint + dims.shoulder_height - _SHOULDER_DROP_RADII * dims.radius["upperarm_prox"],
    )


def shirt_face_patch(body: str, face_centres_m: np.ndarray, dims: BodyDims) -> np.ndarray:
    """Shirt patch id of each face of one body's surface.

    Parameters
    ----------
    body : str
        Body name (:data:`simbench.scenes.humanoid.BODY_NAMES`).
    face_centres_m : (n, 3) float
        Face centres in that body's frame, metres.
    dims : BodyDims
        The subject's dimensions (the surface was built from them).

    Returns
    -------
    (n,) int16
        Patch id ``0..19`` for faces of the shirt region, ``-1`` elsewhere.
    """
    c = np.asarray(face_centres_m, dtype=np.float64).reshape(-1, 3)
    out = np.full(len(c), -1, dtype=np.int16)
    if body not in SHIRT_BODIES:
        return out
    side = body[-1] if body.endswith(("_l", "_r")) else None
    x, y, z = c[:, 0], c[:, 1], c[:, 2]
    if side == "r":  # mirror to the left side; patch names swap sides below
        y = -y

    def pid(name: str, s: str) -> int:
        return _P[f"{name}_{s}"]

    if body.startswith("forearm"):
        out[:] = pid("forearm", side)
        return out
    if body.startswith("upperarm"):
        prox = y < _SHOULDER_ARM_FRACTION * dims.upper_arm
        out[:] = np.where(prox, pid("shoulder", side), pid("upperarm", side))
        return out

    # torso (not mirrored): left/right by the sign of y, front/back by the sign of x
    r = dims.radius
    front = x >= 0.0
    if body == "thorax":
        shoulder = (np.abs(y) > _SHOULDER_INNER_FRACTION * dims.shoulder_half_width) & (
            z > dims.shoulder_height - _SHOULDER_DROP_RADII * r["upperarm_prox"]
        )
        lower = z < _CHEST_SPLIT_FRACTION * dims.thorax
        flank = (np.abs(y) > _FLANK_FRACTION * r["thorax_half_width"]) & lower
        left_ids = np.select(
            [shoulder, flank, front & ~lower, front, ~lower],
            [_P["shoulder_l"], _P["flank_l"], _P["chest_l"], _P["ribs_l"], _P["upperback_l"]],
            _P["midback_l"],
        )
    else:  # abdomen
        flank = np.abs(y) > _FLANK_FRACTION * r["abdomen_half_width"]
        left_ids = np.select([flank, front], [_P["flank_l"], _P["belly_l"]], _P["lowerback_l"])
    # the right-hand patch of a region is the next id (PATCH_NAMES alternates _l, _r)
    # on the mirrored side
    on_right = (y < 0.0) if side is None else np.full(len(c), side == "r")
    out[:] = np.where(on_right, left_ids + 1, left_ids)
    return out
