"""Motions that drive the humanoid kinematically: the :class:`Motion` type and the procedural clips.

A :class:`Motion` is a function of time: ``motion.qpos(t)`` gives the MuJoCo ``qpos``
``(..., 40)`` (root ``x y z``, root quaternion ``w x y z``, then the 33 hinges in
:data:`simbench.scenes.humanoid.HINGE_NAMES` order) at any time, sub-frame times
included (motion blur integrates over the shutter interval).  Every clip is at least C1 in
``t``, keeps every hinge inside the range written in the MuJoCo model, and keeps the feet on
the floor where the clip stands.

Procedural clips (:data:`MOTIONS`, built by :func:`make_motion`) start in the T-pose and
blend into their movement over ``T_POSE_HOLD_S + T_POSE_BLEND_S`` seconds, so the first
frames show every marker of a full-body set (the marker pipeline initialises its labels by
matching a T-pose template on the first frame).  BVH clips come from
:func:`simbench.scenes.bvh.retarget_bvh`. :class:`Motion` and :class:`HumanoidKinematics` are
defined in :mod:`simbench.scenes.kinematics` and importable from here.

Angles follow ``docs/humanoid_spec.md``: left arm along +Y in the T-pose, ``shoulder_l_x``
raises it (+) or lowers it (-), ``shoulder_l_z < 0`` swings it forward, ``elbow_l < 0``
flexes; the right side is mirrored (``shoulder_r_x > 0`` lowers, ``shoulder_r_z > 0`` swings
forward, ``elbow_r > 0`` flexes); ``hip_y < 0`` flexes the hip, ``knee > 0`` flexes the knee.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Callable, Mapping

import numpy as np
from scipy.interpolate import CubicSpline, PchipInterpolator
from scipy.spatial.transform import Rotation

from simbench.scenes.humanoid import HINGE_NAMES, NQ, BodyParams
from simbench.scenes.kinematics import HumanoidKinematics, Motion

__all__ = [
    "Motion",
    "HumanoidKinematics",
    "ClipSpec",
    "MOTIONS",
    "make_motion",
    "T_POSE_HOLD_S",
    "T_POSE_BLEND_S",
]

T_POSE_HOLD_S = 0.15
"""Procedural clips hold the exact T-pose this long (seconds) ..."""
T_POSE_BLEND_S = 1.0
"""... then blend into their movement over this long (quintic smoothstep, C2)."""

_FLOOR_GRID_HZ = 240.0  # sampling of the feet-on-floor correction (interpolated in between)
_SOFTMIN_M = 0.0015  # temperature of the soft minimum over sole points (keeps the root height C-infinity)

_N_HINGES = len(HINGE_NAMES)
_HINGE_INDEX = {name: i for i, name in enumerate(HINGE_NAMES)}


# --------------------------------------------------------------------------------------
# procedural clips
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _ClipCurves:
    """What a clip builder returns: the movement before the T-pose blend and the floor fit.

    Attributes
    ----------
    hinges : callable
        ``(N,) s -> (N, 33)`` radians.
    root_offset : callable or None
        ``(N,) s -> (N, 3)`` metres added to the standing root position (``z``: a hop).
    root_euler : callable or None
        ``(N,) s -> (N, 3)`` radians: yaw (about Z), pitch (Y), roll (X) of the pelvis.
    on_floor : bool
        Lower/raise the root so the lowest sole point touches the floor (before the hop).
    """

    hinges: Callable[[np.ndarray], np.ndarray]
    root_offset: Callable[[np.ndarray], np.ndarray] | None = None
    root_euler: Callable[[np.ndarray], np.ndarray] | None = None
    on_floor: bool = True


@dataclass(frozen=True)
class ClipSpec:
    """A procedural clip in the registry: name, one-line description, builder."""

    name: str
    description: str
    build: Callable[["HumanoidKinematics", float, "_Variation"], _ClipCurves]


@dataclass(frozen=True)
class _Variation:
    """Per-take variation drawn from the scenario's generator (1.0 = canonical clip)."""

    tempo: float = 1.0
    amplitude: float = 1.0

    @classmethod
    def draw(cls, rng: np.random.Generator | None) -> "_Variation":
        if rng is None:
            return cls()
        return cls(tempo=float(rng.uniform(0.9, 1.1)), amplitude=float(rng.uniform(0.9, 1.1)))


def _pose(n: int, **angles: np.ndarray | float) -> np.ndarray:
    """Hinge array ``(n, 33)`` with the named hinges set (radians), all others 0."""
    out = np.zeros((n, _N_HINGES))
    for name, value in angles.items():
        out[:, _HINGE_INDEX[name]] = value
    return out


def _smootherstep(x: np.ndarray) -> np.ndarray:
    """Quintic 0 -> 1 ramp on [0, 1] with zero first and second derivatives at both ends."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (x * (6.0 * x - 15.0) + 10.0)


def _zigzag(phase: np.ndarray, sharpness: float = 0.95) -> np.ndarray:
    """Smooth triangle wave in [-1, 1] with period 1 (C-infinity, corners rounded by ``1 - sharpness``)."""
    return np.arcsin(sharpness * np.sin(2.0 * np.pi * phase)) / np.arcsin(sharpness)


def _bump(x: np.ndarray) -> np.ndarray:
    """``max(0, x)**2``: zero for half a sine period, a C1 bump for the other half."""
    return np.maximum(x, 0.0) ** 2


def _flat_foot_legs(side: str, hip_x, hip_y, knee, hip_z=0.0) -> dict[str, np.ndarray]:
    """Leg hinges of one side with the ankle keeping the sole parallel to the pelvis (small angles)."""
    return {
        f"hip_{side}_x": hip_x,
        f"hip_{side}_y": hip_y,
        f"hip_{side}_z": hip_z,
        f"knee_{side}": knee,
        f"ankle_{side}_y": -(np.asarray(hip_y) + np.asarray(knee)),
        f"ankle_{side}_x": -np.asarray(hip_x),
    }


def _build_tpose(kin: HumanoidKinematics, duration_s: float, var: _Variation) -> _ClipCurves:
    return _ClipCurves(hinges=lambda t: _pose(len(t)), on_floor=False)


def _build_wave_slow(kin: HumanoidKinematics, duration_s: float, var: _Variation) -> _ClipCurves:
    # Left hand waves beside the head: upper arm a little above horizontal and rotated
    # about its own axis so that elbow flexion lifts the forearm; the wave is the elbow
    # swinging the forearm side to side in the frontal plane.  Right arm hangs relaxed.
    f = 0.6 * var.tempo  # Hz
    a = var.amplitude

    def hinges(t):
        w = np.sin(2.0 * np.pi * f * t)
        lag = np.sin(2.0 * np.pi * f * t - 0.8)
        return _pose(
            len(t),
            shoulder_l_x=0.25 + 0.05 * a * lag,
            shoulder_l_y=-1.2,
            shoulder_l_z=-0.3,
            elbow_l=-1.75 + 0.5 * a * w,
            wrist_l_x=0.2 * a * lag,
            shoulder_r_x=1.45,
            shoulder_r_z=0.1,
            elbow_r=0.25,
            neck_z=0.15,
            lumbar_x=0.03 * a * lag,
        )

    return _ClipCurves(hinges=hinges)


def _build_zigzag_fast(kin: HumanoidKinematics, duration_s: float, var: _Variation) -> _ClipCurves:
    # Both arms sweep forward/back in fast smooth-triangle zigzags (1.75 Hz: 3.5 reversals
    # per second) while going up/down on a second zigzag at 1.25 Hz: the hands draw sharp
    # zigzag paths at up to about 4 m/s.
    f_sweep, f_lift = 1.75 * var.tempo, 1.25 * var.tempo
    a = var.amplitude

    def hinges(t):
        sweep_l = _zigzag(f_sweep * t)
        sweep_r = _zigzag(f_sweep * t + 0.5)
        lift_l = _zigzag(f_lift * t + 0.25)
        lift_r = _zigzag(f_lift * t + 0.75)
        return _pose(
            len(t),
            shoulder_l_z=-0.6 - 0.7 * a * sweep_l,
            shoulder_l_x=0.45 * a * lift_l,
            elbow_l=-0.25 - 0.2 * a * lift_r,
            shoulder_r_z=0.6 + 0.7 * a * sweep_r,
            shoulder_r_x=-0.45 * a * lift_r,
            elbow_r=0.25 + 0.2 * a * lift_l,
            thorax_z=0.12 * a * sweep_l,
        )

    return _ClipCurves(hinges=hinges)


def _build_swing_accelerating(kin: HumanoidKinematics, duration_s: float, var: _Variation) -> _ClipCurves:
    # Right arm swings like a pendulum in the sagittal plane; the swing frequency ramps
    # linearly from f0 to f1 over the clip, so the angular speed grows about 6x.
    f0, f1 = 0.25 * var.tempo, 1.5 * var.tempo
    span = max(duration_s, 1e-6)
    a = var.amplitude

    def hinges(t):
        phase = 2.0 * np.pi * (f0 * t + 0.5 * (f1 - f0) * t * t / span)
        s = np.sin(phase)
        return _pose(
            len(t),
            shoulder_r_x=1.4,
            shoulder_r_z=0.35 + 0.9 * a * s,
            elbow_r=0.2 + 0.1 * a * s,
            shoulder_l_x=-1.45,
            shoulder_l_z=-0.05,
            elbow_l=-0.2,
            thorax_z=-0.08 * a * s,
        )

    return _ClipCurves(hinges=hinges)


def _build_jumping_jacks(kin: HumanoidKinematics, duration_s: float, var: _Variation) -> _ClipCurves:
    # One cycle per second: arms from the sides to overhead and back, legs apart and
    # together, and a hop at each transition (the feet leave the floor briefly).
    f = 1.0 * var.tempo
    a = var.amplitude

    def openness(t):
        return 0.5 * (1.0 - np.cos(2.0 * np.pi * f * t))

    def hinges(t):
        s = openness(t)
        elevation = -1.35 + 2.8 * s  # radians above horizontal
        abduction = 0.2 * a * s
        knee = 0.12 + 0.1 * np.cos(4.0 * np.pi * f * t)  # softer knees on landing
        legs = {
            **_flat_foot_legs("l", abduction, -0.5 * knee, knee),
            **_flat_foot_legs("r", -abduction, -0.5 * knee, knee),
        }
        return _pose(
            len(t),
            shoulder_l_x=elevation,
            shoulder_r_x=-elevation,
            elbow_l=-0.15,
            elbow_r=0.15,
            **legs,
        )

    def root_offset(t):
        out = np.zeros((len(t), 3))
        out[:, 2] = 0.06 * a * np.sin(2.0 * np.pi * f * t) ** 2  # hop, peaks mid-transition
        return out

    return _ClipCurves(hinges=hinges, root_offset=root_offset)


# Forehand keyframes over one stroke cycle (phase 0..1): ready, backswing, contact,
# follow-through, recovery.  Right-handed player; pelvis yaw counter-rotated at the hips so
# the feet keep their heading.
_FOREHAND_PHASES = np.array([0.0, 0.35, 0.5, 0.6, 0.8, 1.0])
_FOREHAND_KEYS = {
    "shoulder_r_x": [1.1, 0.3, 0.7, -0.2, 0.9, 1.1],
    "shoulder_r_y": [0.0, -0.4, 0.0, 0.3, 0.1, 0.0],
    "shoulder_r_z": [0.5, -0.6, 0.5, 1.7, 1.0, 0.5],
    "elbow_r": [0.6, 1.4, 0.3, 1.2, 0.8, 0.6],
    "wrist_r_x": [0.0, 0.3, 0.0, -0.3, 0.0, 0.0],
    "shoulder_l_x": [-1.2, -0.6, -0.9, -1.3, -1.2, -1.2],
    "shoulder_l_z": [-0.3, -1.0, -0.5, 0.2, -0.2, -0.3],
    "elbow_l": [-0.5, -0.4, -0.6, -0.8, -0.5, -0.5],
    "lumbar_z": [0.0, -0.45, 0.05, 0.45, 0.1, 0.0],
    "thorax_z": [0.0, -0.35, 0.05, 0.35, 0.1, 0.0],
    "lumbar_y": [0.1, 0.15, 0.25, 0.3, 0.15, 0.1],
    "neck_z": [0.0, 0.5, 0.0, -0.4, 0.0, 0.0],
    "knee": [0.3, 0.35, 0.55, 0.45, 0.3, 0.3],
    "yaw": [0.0, -0.3, 0.0, 0.3, 0.05, 0.0],
}


def _build_squash_forehand(kin: HumanoidKinematics, duration_s: float, var: _Variation) -> _ClipCurves:
    period = 2.2 / var.tempo
    a = var.amplitude
    # Periodic cubic splines through the keyframes: C2 and smooth across cycles.
    splines = {k: CubicSpline(_FOREHAND_PHASES, np.asarray(v) * (a if k != "knee" else 1.0), bc_type="periodic") for k, v in _FOREHAND_KEYS.items()}

    def key(name, t):
        return splines[name]((t / period) % 1.0)

    def hinges(t):
        knee = key("knee", t)
        yaw = key("yaw", t)
        legs = {
            **_flat_foot_legs("l", 0.08, -0.5 * knee, knee, hip_z=-yaw),
            **_flat_foot_legs("r", -0.08, -0.5 * knee, knee, hip_z=-yaw),
        }
        arms_trunk = {k: key(k, t) for k in _FOREHAND_KEYS if k not in ("knee", "yaw")}
        return _pose(len(t), **arms_trunk, **legs)

    def root_euler(t):
        out = np.zeros((len(t), 3))
        out[:, 0] = key("yaw", t)
        return out

    return _ClipCurves(hinges=hinges, root_euler=root_euler)


def _build_walk_in_place(kin: HumanoidKinematics, duration_s: float, var: _Variation) -> _ClipCurves:
    # Marching on the spot: each leg in turn lifts (hip and knee flexion, toes slightly
    # down) while the opposite arm swings forward; the pelvis shifts over the stance foot.
    period = 1.1 / var.tempo
    omega = 2.0 * np.pi / period
    a = var.amplitude

    def hinges(t):
        s = np.sin(omega * t)
        lift_l, lift_r = _bump(s), _bump(-s)
        legs = {}
        for side, lift in (("l", lift_l), ("r", lift_r)):
            legs.update(
                {
                    f"hip_{side}_y": -0.9 * a * lift,
                    f"knee_{side}": 1.5 * a * lift,
                    # foot level while it leaves the floor, toes pointing down only late in the lift
                    f"ankle_{side}_y": -0.6 * a * lift + 0.3 * a * lift * lift,
                }
            )
        return _pose(
            len(t),
            shoulder_l_x=-1.45,
            shoulder_r_x=1.45,
            shoulder_l_z=0.45 * a * s,
            shoulder_r_z=0.45 * a * s,
            elbow_l=-0.5 + 0.15 * a * s,
            elbow_r=0.5 + 0.15 * a * s,
            lumbar_x=-0.04 * a * s,
            lumbar_z=-0.06 * a * s,
            **legs,
        )

    def root_offset(t):
        out = np.zeros((len(t), 3))
        out[:, 1] = -0.025 * a * np.sin(omega * t)  # weight over the stance foot
        return out

    return _ClipCurves(hinges=hinges, root_offset=root_offset)


MOTIONS: Mapping[str, ClipSpec] = MappingProxyType(
    {
        spec.name: spec
        for spec in (
            ClipSpec("tpose", "static T-pose (arms horizontal, palms down)", _build_tpose),
            ClipSpec("wave_slow", "left hand waves slowly beside the head, right arm relaxed", _build_wave_slow),
            ClipSpec("zigzag_fast", "both arms sweep in fast zigzags (3.5 reversals per second)", _build_zigzag_fast),
            ClipSpec("swing_accelerating", "right arm pendulum swing whose frequency ramps from 0.25 to 1.5 Hz", _build_swing_accelerating),
            ClipSpec("jumping_jacks", "jumping jacks at 1 Hz: arms overhead, legs apart, hop", _build_jumping_jacks),
            ClipSpec("squash_forehand", "repeated squash forehand: backswing, trunk rotation, follow-through", _build_squash_forehand),
            ClipSpec("walk_in_place", "marching on the spot with arm counter-swing", _build_walk_in_place),
        )
    }
)
"""Registry of procedural clips by name (read-only)."""


def make_motion(
    name: str,
    params: BodyParams,
    duration_s: float,
    rng: np.random.Generator | None = None,
) -> Motion:
    """Build a procedural clip for a subject.

    Parameters
    ----------
    name : str
        A key of :data:`MOTIONS`.
    params : BodyParams
        Subject shape (root height and joint ranges come from its MuJoCo model).
    duration_s : float
        Clip length in seconds (> 0).
    rng : numpy.random.Generator, optional
        Draws a per-take variation of tempo and amplitude (+-10 %); ``None`` gives the
        canonical clip.

    Returns
    -------
    Motion
    """
    if name not in MOTIONS:
        raise ValueError(f"unknown motion '{name}'; choose one of: {', '.join(MOTIONS)}")
    if not (np.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"duration_s must be a positive number of seconds, got {duration_s!r}")
    spec = MOTIONS[name]
    kin = HumanoidKinematics(params)
    curves = spec.build(kin, float(duration_s), _Variation.draw(rng))
    standing = kin.standing_height_m

    def raw(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Blended hinges (N, 33), root offset (N, 3), root yaw/pitch/roll (N, 3)."""
        w = _smootherstep((t - T_POSE_HOLD_S) / T_POSE_BLEND_S)[:, None]
        hinges = kin.clamp(w * curves.hinges(t))
        offset = w * curves.root_offset(t) if curves.root_offset else np.zeros((len(t), 3))
        euler = w * curves.root_euler(t) if curves.root_euler else np.zeros((len(t), 3))
        return hinges, offset, euler

    def assemble(t: np.ndarray, floor_dz: np.ndarray) -> np.ndarray:
        hinges, offset, euler = raw(t)
        q = np.empty((len(t), NQ))
        q[:, 0:2] = offset[:, 0:2]
        q[:, 2] = standing + floor_dz + offset[:, 2]
        q[:, 3:7] = Rotation.from_euler("ZYX", euler).as_quat(scalar_first=True)
        q[:, 7:] = hinges
        return q

    if curves.on_floor:
        # Feet on the floor: on a dense grid, lift or lower the root so that a soft minimum
        # of the sole points sits where it sits in the T-pose; C1 interpolation in between.
        grid = np.linspace(0.0, duration_s, max(2, int(np.ceil(duration_s * _FLOOR_GRID_HZ)) + 1))
        q_grid = assemble(grid, np.zeros(len(grid)))
        q_grid[:, 2] -= _root_z_offset(curves, grid, kin)  # evaluate without the hop
        sole_z = kin.sole_points(q_grid)[:, :, 2]
        tpose_sole = kin.sole_points(kin.tpose_qpos()[None])[:, :, 2]
        correction = _softmin(tpose_sole) - _softmin(sole_z)
        floor = PchipInterpolator(grid, correction)
    else:
        floor = None

    def evaluate(t: np.ndarray) -> np.ndarray:
        dz = floor(t) if floor is not None else np.zeros(len(t))
        return assemble(t, dz)

    return Motion(name=name, duration_s=float(duration_s), evaluate=evaluate, description=spec.description)


def _root_z_offset(curves: _ClipCurves, t: np.ndarray, kin: HumanoidKinematics) -> np.ndarray:
    """The blended hop height (N,) of a clip, metres (0 if it has no root offset)."""
    if curves.root_offset is None:
        return np.zeros(len(t))
    w = _smootherstep((t - T_POSE_HOLD_S) / T_POSE_BLEND_S)
    return w * curves.root_offset(t)[:, 2]


def _softmin(z: np.ndarray) -> np.ndarray:
    """Smooth minimum over the last axis (log-sum-exp with temperature ``_SOFTMIN_M``)."""
    m = z.min(axis=-1, keepdims=True)
    return (m - _SOFTMIN_M * np.log(np.exp(-(z - m) / _SOFTMIN_M).sum(axis=-1, keepdims=True)))[..., 0]
