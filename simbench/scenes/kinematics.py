"""The humanoid driven kinematically: the :class:`Motion` type and :class:`HumanoidKinematics`.

A :class:`Motion` is a function of time: ``motion.qpos(t)`` gives the MuJoCo ``qpos``
``(..., 40)`` (root ``x y z``, root quaternion ``w x y z``, then the 33 hinges in
:data:`simbench.scenes.humanoid.HINGE_NAMES` order) at any time, sub-frame times
included. :class:`HumanoidKinematics` gives a subject's joint ranges, T-pose, forward
kinematics and sole points, which clips (procedural: :mod:`simbench.scenes.motions`; BVH:
:mod:`simbench.scenes.bvh`) use to stay in range and keep the feet on the floor.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import mujoco
import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.spatial.transform import Rotation, RotationSpline

from simbench.scenes.humanoid import BODY_NAMES, HINGE_NAMES, NQ, BodyParams, humanoid_mjcf, joint_qpos_index

__all__ = ["Motion", "HumanoidKinematics"]

# Ball of the foot (metatarsophalangeal joints): 73 % of the foot length from the heel and a
# quarter of the ankle height above the sole (typical adult foot proportions).  The humanoid's
# foot is a box, so this point is not in the MJCF; BVH toe-base joints mark it.
_BALL_FRACTION_OF_LENGTH = 0.73
_BALL_FRACTION_OF_ANKLE_HEIGHT = 0.25

_N_HINGES = len(HINGE_NAMES)
_HINGE_INDEX = {name: i for i, name in enumerate(HINGE_NAMES)}


@dataclass(frozen=True, eq=False)
class Motion:
    """A clip that drives the humanoid, evaluable at any time.

    Attributes
    ----------
    name : str
        Clip name (``"wave_slow"``, ``"bvh:131_01"`` ...).
    duration_s : float
        Length in seconds; times outside ``[0, duration_s]`` hold the first / last pose.
    evaluate : callable
        ``(N,) seconds in [0, duration_s] -> (N, 40)`` qpos; use :meth:`qpos` instead.
    description : str
        One line for listings.
    """

    name: str
    duration_s: float
    evaluate: Callable[[np.ndarray], np.ndarray]
    description: str = ""

    def qpos(self, t: float | np.ndarray) -> np.ndarray:
        """MuJoCo qpos at time(s) ``t``.

        Parameters
        ----------
        t : float or array (...) of float
            Seconds from the start of the clip.

        Returns
        -------
        (..., 40) float
            Root position (metres), root quaternion ``w x y z``, 33 hinge angles (radians).
        """
        times = np.asarray(t, dtype=np.float64)
        if not np.all(np.isfinite(times)):
            raise ValueError(f"Motion '{self.name}': times must be finite seconds, got {t!r}")
        flat = np.clip(times.reshape(-1), 0.0, self.duration_s)
        return self.evaluate(flat).reshape(times.shape + (NQ,))

    def sample(self, fps: float) -> tuple[np.ndarray, np.ndarray]:
        """Frame times ``(F,)`` seconds at ``fps`` from 0 to ``duration_s`` and their qpos ``(F, 40)``."""
        if not fps > 0:
            raise ValueError(f"fps must be positive, got {fps!r}")
        times = np.arange(int(np.floor(self.duration_s * fps + 1e-9)) + 1) / fps
        return times, self.qpos(times)

    @classmethod
    def from_samples(
        cls,
        name: str,
        times_s: np.ndarray,
        qpos: np.ndarray,
        kinematics: "HumanoidKinematics",
        description: str = "",
    ) -> "Motion":
        """A motion that interpolates key poses (e.g. a 120 Hz BVH clip).

        Root position and hinges use monotone cubic (PCHIP) interpolation: C1, and no
        overshoot between keys, so keys inside the joint ranges stay inside.  The root
        orientation uses a cubic rotation spline (C2, scipy ``RotationSpline``).

        Parameters
        ----------
        times_s : (K,) float
            Strictly increasing key times, seconds; the first is taken as ``t = 0``.
        qpos : (K, 40) float
            Key poses; hinge angles must be continuous (unwrapped) over time.
        kinematics : HumanoidKinematics
            Supplies the joint ranges used to clamp the hinges.
        """
        times_s = np.asarray(times_s, dtype=np.float64)
        qpos = np.asarray(qpos, dtype=np.float64)
        if times_s.ndim != 1 or len(times_s) < 2 or np.any(np.diff(times_s) <= 0):
            raise ValueError("times_s must be a strictly increasing (K,) array with K >= 2")
        if qpos.shape != (len(times_s), NQ):
            raise ValueError(f"qpos must have shape ({len(times_s)}, {NQ}), got {qpos.shape}")
        if not np.all(np.isfinite(qpos)):
            raise ValueError(f"Motion '{name}': qpos keys contain NaN or inf")
        rel = times_s - times_s[0]
        position = PchipInterpolator(rel, qpos[:, :3], axis=0)
        hinges = PchipInterpolator(rel, kinematics.clamp(qpos[:, 7:]), axis=0)
        # Key quaternions made sign-continuous, so that evaluated ones can follow their sign.
        keys = qpos[:, 3:7] / np.linalg.norm(qpos[:, 3:7], axis=1, keepdims=True)
        flips = np.cumsum(np.concatenate([[0], np.sum(keys[1:] * keys[:-1], axis=1) < 0])) % 2
        keys = keys * np.where(flips[:, None] == 1, -1.0, 1.0)
        orientation = RotationSpline(rel, Rotation.from_quat(keys, scalar_first=True))

        def evaluate(t: np.ndarray) -> np.ndarray:
            out = np.empty((len(t), NQ))
            out[:, :3] = position(t)
            quat = orientation(t).as_quat(scalar_first=True)
            nearest = keys[np.clip(np.searchsorted(rel, t), 0, len(rel) - 1)]
            out[:, 3:7] = quat * np.where(np.sum(quat * nearest, axis=1, keepdims=True) < 0, -1.0, 1.0)
            out[:, 7:] = kinematics.clamp(hinges(t))
            return out

        return cls(name=name, duration_s=float(rel[-1]), evaluate=evaluate, description=description)


class HumanoidKinematics:
    """The humanoid's MuJoCo model and what motions need from it.

    Joint ranges and the sole geometry are read from the model built by
    :func:`simbench.scenes.humanoid.humanoid_mjcf`, never re-typed.

    Attributes
    ----------
    params : BodyParams
    model : mujoco.MjModel
    hinge_lo, hinge_hi : (33,) float
        Joint ranges in radians, :data:`HINGE_NAMES` order.
    standing_height_m : float
        Pelvis height in the T-pose with the soles on the floor, metres.
    sole_points_local : (8, 3) float
        Four sole corners of each foot (``foot_l`` then ``foot_r``) in the foot body frame, metres.
    ball_of_foot_local : (3,) float
        Ball of the left foot in its body frame, metres (the right one has the same coordinates).
    """

    def __init__(self, params: BodyParams) -> None:
        self.params = params
        self.model = mujoco.MjModel.from_xml_string(humanoid_mjcf(params))
        self._data = mujoco.MjData(self.model)
        address = joint_qpos_index(self.model)
        self.hinge_qposadr = np.array([address[n] for n in HINGE_NAMES])
        if not np.array_equal(self.hinge_qposadr, 7 + np.arange(_N_HINGES)):
            raise RuntimeError("humanoid MJCF hinge order differs from HINGE_NAMES; update simbench.scenes.kinematics")
        joint_ids = [self.model.joint(n).id for n in HINGE_NAMES]
        self.hinge_lo = self.model.jnt_range[joint_ids, 0].copy()
        self.hinge_hi = self.model.jnt_range[joint_ids, 1].copy()
        self.body_ids = np.array([self.model.body(n).id for n in BODY_NAMES])
        self._foot_ids = np.array([self.model.body(n).id for n in ("foot_l", "foot_r")])
        corners = []
        for foot in ("foot_l", "foot_r"):
            geom = self.model.geom(f"{foot}_col")
            if geom.type[0] != mujoco.mjtGeom.mjGEOM_BOX:
                raise RuntimeError(f"expected a box geom '{foot}_col' for the sole; update simbench.scenes.kinematics")
            (cx, cy, cz), (hx, hy, hz) = geom.pos, geom.size
            corners.append([[cx + sx * hx, cy + sy * hy, cz - hz] for sx in (-1, 1) for sy in (-1, 1)])
        self.sole_points_local = np.array(corners, dtype=np.float64).reshape(8, 3)
        (cx, _, cz), (hx, _, hz) = self.model.geom("foot_l_col").pos, self.model.geom("foot_l_col").size
        heel, toe, sole = cx - hx, cx + hx, cz - hz
        self.ball_of_foot_local = np.array(
            [heel + _BALL_FRACTION_OF_LENGTH * (toe - heel), 0.0, sole * (1.0 - _BALL_FRACTION_OF_ANKLE_HEIGHT)]
        )
        at_origin = np.zeros(NQ)
        at_origin[3] = 1.0
        self.standing_height_m = float(-self.sole_points(at_origin[None])[0, :, 2].min())

    def tpose_qpos(self) -> np.ndarray:
        """qpos ``(40,)`` of the standing T-pose: identity root, soles on the floor."""
        q = np.zeros(NQ)
        q[2] = self.standing_height_m
        q[3] = 1.0
        return q

    def hinge_range(self, name: str) -> tuple[float, float]:
        """``(lo, hi)`` radians of hinge ``name``."""
        i = _HINGE_INDEX[name]
        return float(self.hinge_lo[i]), float(self.hinge_hi[i])

    def clamp(self, hinges: np.ndarray) -> np.ndarray:
        """Hinge angles ``(..., 33)`` clipped to the model's joint ranges."""
        return np.clip(hinges, self.hinge_lo, self.hinge_hi)

    def forward(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Body origins (joint centres) and orientations for poses ``(N, 40)``.

        Returns
        -------
        positions : (N, 16, 3) float
            ``data.xpos`` of the bodies in :data:`BODY_NAMES` order, metres.
        rotations : (N, 16, 3, 3) float
            ``data.xmat`` (world-from-body) of the same bodies.
        """
        qpos = np.atleast_2d(qpos)
        positions = np.empty((len(qpos), len(self.body_ids), 3))
        rotations = np.empty((len(qpos), len(self.body_ids), 3, 3))
        # One mj_kinematics call per pose (~10 us): MuJoCo is the authority on the tree.
        for k, q in enumerate(qpos):
            self._data.qpos[:] = q
            mujoco.mj_kinematics(self.model, self._data)
            positions[k] = self._data.xpos[self.body_ids]
            rotations[k] = self._data.xmat[self.body_ids].reshape(-1, 3, 3)
        return positions, rotations

    def sole_points(self, qpos: np.ndarray) -> np.ndarray:
        """World positions ``(N, 8, 3)`` (metres) of the sole corners for poses ``(N, 40)``."""
        positions, rotations = self.forward(qpos)
        feet = [BODY_NAMES.index("foot_l"), BODY_NAMES.index("foot_r")]
        local = self.sole_points_local.reshape(2, 4, 3)
        world = positions[:, feet, None, :] + np.einsum("nfij,fpj->nfpi", rotations[:, feet], local)
        return world.reshape(len(qpos), 8, 3)
