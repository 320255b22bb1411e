"""Anthropometric body parameters: segment lengths, radii and masses from height.

Source of the length fractions: D. A. Winter, *Biomechanics and Motor Control of Human
Movement* (4th ed., 2009), Fig. 4.1, after Drillis & Contini (1966): segment lengths
as fractions of standing height ``H`` (ankle height 0.039 H, knee 0.285 H, hip
0.530 H, shoulder 0.818 H, upper arm 0.186 H, forearm 0.146 H, hand 0.108 H, foot
length 0.152 H, foot breadth 0.055 H, head and neck 0.182 H).  Mass fractions:
Winter Table 4.1 (after Dempster 1955).  Two adaptations, both stated where used:

* the upper arm here runs from the gleno-humeral *joint centre* (not the acromion) to
  the elbow centre, so it is shorter than Winter's acromion-to-elbow 0.186 H;
* the hip-centre separation is not in Winter's figure (its 0.191 H is the
  bi-trochanteric breadth); 0.10 H (about 0.175 m at 1.75 m) matches regression
  estimates of inter-hip-joint-centre distance (e.g. Harrington et al. 2007).

Radii are rough fractions of height for an average adult build (circumferences of
ANSUR-like tables divided by 2 pi), scaled by :attr:`BodyParams.girth`.

:class:`BodyParams` is the user-facing input (height, mass, optional overrides of
the proportions); :func:`body_dimensions` turns it into metres once, so that the
MJCF, the rendered surface and the marker placement all read the same numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

#: The humanoid's 16 bodies (``docs/humanoid_spec.md``), root first: the names every part of
#: the body shares (MJCF, rendered surface, marker placement, ground truth).
BODY_NAMES: tuple[str, ...] = (
    "pelvis",
    "abdomen",
    "thorax",
    "head",
    "upperarm_l",
    "forearm_l",
    "hand_l",
    "upperarm_r",
    "forearm_r",
    "hand_r",
    "thigh_l",
    "shank_l",
    "foot_l",
    "thigh_r",
    "shank_r",
    "foot_r",
)

# --- Winter / Drillis-Contini length fractions of standing height -----------------
ANKLE_HEIGHT_FRAC = 0.039  # floor -> ankle joint centre
SHANK_FRAC = 0.246  # ankle -> knee (0.285 - 0.039)
THIGH_FRAC = 0.245  # knee -> hip (0.530 - 0.285)
HIP_WIDTH_FRAC = 0.10  # hip-centre separation (see module docstring)
LUMBAR_FRAC = 0.045  # hip-centre midpoint -> L5/S1 (lumbar joint)
ABDOMEN_FRAC = 0.100  # L5/S1 -> T12/L1 (thorax joint)
THORAX_FRAC = 0.165  # T12/L1 -> C7/T1 (neck joint) at 0.84 H
SHOULDER_WIDTH_FRAC = 0.20  # gleno-humeral centre separation (~0.35 m at 1.75 m; biacromial 0.259 H minus the acromion overhang)
SHOULDER_DROP_FRAC = 0.040  # neck joint height - shoulder joint centre height (0.84 H - 0.80 H)
UPPER_ARM_FRAC = 0.172  # gleno-humeral centre -> elbow (0.80 H - 0.63 H)
FOREARM_FRAC = 0.146  # elbow -> wrist
HAND_FRAC = 0.108  # wrist -> fingertip
FOOT_LENGTH_FRAC = 0.152  # heel -> toe tip
FOOT_WIDTH_FRAC = 0.055
HEEL_FRAC = 0.22  # fraction of the foot length behind the ankle joint centre
# head (neck joint -> vertex) is what is left of the height: 1 - 0.84 = 0.16 H

# --- Winter Table 4.1 (Dempster) mass fractions of body mass ----------------------
MASS_FRACTIONS = {
    "pelvis": 0.142,
    "abdomen": 0.139,
    "thorax": 0.216,
    "head": 0.081,
    "upperarm": 0.028,
    "forearm": 0.016,
    "hand": 0.006,
    "thigh": 0.100,
    "shank": 0.0465,
    "foot": 0.0145,
}

# --- torso shape ---------------------------------------------------------------------
# Torso cross-sections (superellipses, exponent TORSO_SECTION_EXPONENT) from the crotch
# to the neck: height as a fraction alpha of the hip-centre -> neck-joint distance
# (negative below the hips), half depth (X) and half width (Y) as fractions of height.
# Shaped after ANSUR II breadths/depths of an average adult (hip breadth 0.19 H, waist
# breadth 0.16 H, chest breadth 0.17 H, chest depth 0.14 H, waist depth 0.11 H).
TORSO_SECTIONS = (
    # alpha, half_depth, half_width
    (-0.18, 0.048, 0.070),
    (-0.12, 0.064, 0.088),
    (-0.05, 0.070, 0.094),
    (0.05, 0.068, 0.092),
    (0.15, 0.061, 0.085),
    (0.25, 0.057, 0.078),
    (0.35, 0.056, 0.076),
    (0.45, 0.058, 0.078),
    (0.55, 0.064, 0.082),
    (0.65, 0.068, 0.085),
    (0.75, 0.069, 0.085),
    (0.83, 0.067, 0.083),
    (0.90, 0.059, 0.073),
    (0.95, 0.048, 0.055),
    (1.00, 0.034, 0.035),
)
TORSO_SECTION_EXPONENT = 2.5

# Reference build for girth = 1: a 1.75 m, 70 kg adult.  Radii scale with the square
# root of the ponderal index mass / height^3 relative to it, so the body's volume
# follows its mass for any height.
REFERENCE_PONDERAL_INDEX = 70.0 / 1.75**3

# --- radii as fractions of height (average adult; times the build scale) -------------
RADIUS_FRACTIONS = {
    "upperarm_prox": 0.027,  # at the shoulder (~0.047 m at 1.75 m)
    "upperarm_dist": 0.021,  # at the elbow
    "forearm_prox": 0.021,
    "forearm_dist": 0.015,  # at the wrist (~0.026 m)
    "hand_half_width": 0.025,  # palm half breadth (~0.044 m)
    "hand_half_thickness": 0.0085,
    "thigh_prox": 0.049,  # at the hip (~0.086 m)
    "thigh_dist": 0.031,  # at the knee
    "shank_prox": 0.031,
    "shank_dist": 0.020,  # at the ankle
    "pelvis_half_depth": 0.068,  # the following six: typical values of TORSO_SECTIONS
    "pelvis_half_width": 0.092,
    "abdomen_half_depth": 0.057,
    "abdomen_half_width": 0.078,
    "thorax_half_depth": 0.068,
    "thorax_half_width": 0.085,
    "neck": 0.030,
    "head_half_depth": 0.055,  # ~0.19 m head length
    "head_half_width": 0.044,  # ~0.155 m head breadth
    "head_half_height": 0.064,  # ~0.22 m chin to vertex
    "foot_half_height": 0.020,  # sole-to-instep half thickness
}


@dataclass(frozen=True)
class BodyParams:
    """Subject shape: height, mass and segment proportions.

    Every ``*_frac`` is a fraction of :attr:`height_m` (defaults: Winter /
    Drillis-Contini, see :mod:`simbench.scenes.anthropometry`).  The head (neck joint
    to vertex) takes what the other vertical fractions leave, so the standing height
    is always exactly ``height_m``.

    Attributes
    ----------
    height_m : float
        Standing height in metres (floor to vertex, T-pose).
    mass_kg : float
        Body mass in kilograms (segment masses follow Dempster's fractions).
    girth : float
        Extra scale of all segment radii (1.0 = average build).  Radii already
        follow the mass: they scale with ``sqrt(mass / height^3)`` relative to a
        1.75 m, 70 kg adult, so the body's volume matches its mass.
    """

    height_m: float = 1.75
    mass_kg: float = 70.0
    girth: float = 1.0
    ankle_height_frac: float = ANKLE_HEIGHT_FRAC
    shank_frac: float = SHANK_FRAC
    thigh_frac: float = THIGH_FRAC
    hip_width_frac: float = HIP_WIDTH_FRAC
    lumbar_frac: float = LUMBAR_FRAC
    abdomen_frac: float = ABDOMEN_FRAC
    thorax_frac: float = THORAX_FRAC
    shoulder_width_frac: float = SHOULDER_WIDTH_FRAC
    shoulder_drop_frac: float = SHOULDER_DROP_FRAC
    upper_arm_frac: float = UPPER_ARM_FRAC
    forearm_frac: float = FOREARM_FRAC
    hand_frac: float = HAND_FRAC
    foot_length_frac: float = FOOT_LENGTH_FRAC
    foot_width_frac: float = FOOT_WIDTH_FRAC
    heel_frac: float = HEEL_FRAC

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or not value > 0:
                raise ValueError(f"BodyParams.{f.name} must be a positive number, got {value!r}")
        if not 0.5 <= self.height_m <= 2.5:
            raise ValueError(f"BodyParams.height_m = {self.height_m} is not a human height; use metres (0.5 .. 2.5)")
        if not 10.0 <= self.mass_kg <= 300.0:
            raise ValueError(f"BodyParams.mass_kg = {self.mass_kg} is out of range; use kilograms (10 .. 300)")
        if not 0.5 <= self.girth <= 2.0:
            raise ValueError(f"BodyParams.girth = {self.girth} is out of range (0.5 .. 2.0)")
        if self.head_frac < 0.10:
            raise ValueError(
                f"BodyParams: the vertical fractions (ankle_height, shank, thigh, lumbar, abdomen, thorax) "
                f"sum to {1.0 - self.head_frac:.3f}, leaving {self.head_frac:.3f} of the height for the head; "
                f"reduce them so that at least 0.10 is left"
            )
        if self.shoulder_drop_frac >= self.thorax_frac:
            raise ValueError(
                f"BodyParams.shoulder_drop_frac = {self.shoulder_drop_frac} must be smaller than "
                f"thorax_frac = {self.thorax_frac} (the shoulder joints sit on the thorax)"
            )
        if self.heel_frac >= 1.0:
            raise ValueError(f"BodyParams.heel_frac = {self.heel_frac} must be below 1 (fraction of the foot length)")

    @property
    def head_frac(self) -> float:
        """Neck joint to vertex, fraction of height (what the other fractions leave)."""
        return 1.0 - (
            self.ankle_height_frac + self.shank_frac + self.thigh_frac + self.lumbar_frac + self.abdomen_frac + self.thorax_frac
        )


@dataclass(frozen=True)
class BodyDims:
    """Segment dimensions in metres, derived from :class:`BodyParams`.

    Lengths are between joint centres; ``radius`` holds radii and half breadths
    (``RADIUS_FRACTIONS`` keys), ``mass`` segment masses in kilograms.  All vectors
    are in the T-pose body frames (= world axes).  ``radius_scale`` is the factor
    applied to the tabulated radius fractions times height.
    """

    height: float
    ankle_height: float
    shank: float
    thigh: float
    hip_half_width: float
    lumbar: float
    abdomen: float
    thorax: float
    shoulder_half_width: float
    shoulder_height: float  # shoulder centre above the thorax joint
    upper_arm: float
    forearm: float
    hand: float
    head: float
    foot_length: float
    foot_width: float
    heel: float  # heel behind the ankle joint centre
    radius: dict
    mass: dict
    radius_scale: float

    @property
    def hip_height(self) -> float:
        """Hip joint centres (and pelvis origin) above the floor in the T-pose, metres."""
        return self.ankle_height + self.shank + self.thigh


def body_dimensions(params: BodyParams) -> BodyDims:
    """Segment lengths, radii and masses of a subject, in metres and kilograms."""
    H = params.height_m
    scale = params.girth * float(np.sqrt(params.mass_kg / H**3 / REFERENCE_PONDERAL_INDEX))
    radius = {k: v * H * scale for k, v in RADIUS_FRACTIONS.items()}
    mass = {k: v * params.mass_kg for k, v in MASS_FRACTIONS.items()}
    return BodyDims(
        height=H,
        ankle_height=params.ankle_height_frac * H,
        shank=params.shank_frac * H,
        thigh=params.thigh_frac * H,
        hip_half_width=0.5 * params.hip_width_frac * H,
        lumbar=params.lumbar_frac * H,
        abdomen=params.abdomen_frac * H,
        thorax=params.thorax_frac * H,
        shoulder_half_width=0.5 * params.shoulder_width_frac * H,
        shoulder_height=(params.thorax_frac - params.shoulder_drop_frac) * H,
        upper_arm=params.upper_arm_frac * H,
        forearm=params.forearm_frac * H,
        hand=params.hand_frac * H,
        head=params.head_frac * H,
        foot_length=params.foot_length_frac * H,
        foot_width=params.foot_width_frac * H,
        heel=params.heel_frac * params.foot_length_frac * H,
        radius=radius,
        mass=mass,
        radius_scale=scale,
    )
