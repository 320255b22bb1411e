"""The upper body's kinematics for the colour-shirt pipeline: Pinocchio's model of the humanoid
(``docs/humanoid_spec.md``, from its MJCF text) reduced to what the shirt shows.

Upper-body configuration
------------------------
Only the shirt is seen, so the pipeline estimates the shirt's bodies: the abdomen's
world pose, the thorax relative to it, both shoulders (3 hinges each) and elbows.  The
kinematics is Pinocchio's model of the humanoid *reduced* (``pinocchio.buildReducedModel``)
by locking every other hinge at zero: lumbar (its rotation is folded into the root,
which then carries the abdomen's orientation), neck, wrists and legs.  Its
configuration ``q`` (:data:`UPPER_NQ` = 18, tangent size :data:`UPPER_NV` = 17) is
``x y z qx qy qz qw`` of that root (Pinocchio's quaternion order) then the hinges of
:data:`UPPER_HINGES`.  :meth:`ShirtKinematics.from_full_qpos` maps a full MuJoCo
``qpos (40,)`` (ground truth) to it exactly for every body of the shirt.
"""

from __future__ import annotations

import os
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin

from mocap.errors import MocapInputError

__all__ = ["UPPER_HINGES", "UPPER_NQ", "UPPER_NV", "UPPER_BODY_JOINTS", "ShirtKinematics"]

UPPER_HINGES: tuple[str, ...] = (
    "thorax_x", "thorax_y", "thorax_z",
    "shoulder_l_x", "shoulder_l_y", "shoulder_l_z", "elbow_l",
    "shoulder_r_x", "shoulder_r_y", "shoulder_r_z", "elbow_r",
)
"""Hinges the pipeline estimates (in the reduced configuration's order)."""
UPPER_NQ = 7 + len(UPPER_HINGES)
UPPER_NV = 6 + len(UPPER_HINGES)

UPPER_BODY_JOINTS: tuple[str, ...] = (
    "abdomen", "thorax", "head", "upperarm_l", "forearm_l", "hand_l", "upperarm_r", "forearm_r", "hand_r",
)
"""Bodies whose origins (joint centres: lumbar, thorax, neck, shoulders, elbows, wrists) the shirt determines."""


def _model_from_mjcf_text(mjcf_text: str) -> pin.Model:
    """Pinocchio model of the humanoid MJCF text (Pinocchio parses MJCF from files only)."""
    fd, path = tempfile.mkstemp(suffix=".xml", prefix="shirt_humanoid_")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(mjcf_text)
        return pin.buildModelFromMJCF(path)
    except Exception as exc:  # Pinocchio raises plain RuntimeError/ValueError on bad MJCF
        raise MocapInputError(f"humanoid MJCF: Pinocchio cannot build a model from it ({exc}); give the standalone humanoid of docs/humanoid_spec.md") from None
    finally:
        Path(path).unlink(missing_ok=True)


class ShirtKinematics:
    """Forward kinematics of the upper-body configuration (Pinocchio reduced model).

    Parameters
    ----------
    mjcf_text : str
        The standalone humanoid MJCF (free root ``root`` on ``pelvis``; hinges as in
        ``docs/humanoid_spec.md``).
    """

    def __init__(self, mjcf_text: str) -> None:
        full = _model_from_mjcf_text(mjcf_text)
        if full.joints[1].shortname() != "JointModelFreeFlyer":
            raise MocapInputError("humanoid MJCF: the root body must carry a free joint (see docs/humanoid_spec.md)")
        # Pinocchio merges the hinges of one body into a composite joint and keeps the
        # MJCF order in q: read the hinge names from the XML in document order.
        names = [j.get("name", "") for j in ET.fromstring(mjcf_text).iter("joint") if j.get("type", "hinge") == "hinge"]
        if len(names) != full.nq - 7:
            raise MocapInputError(f"humanoid MJCF: {len(names)} hinges in the XML but Pinocchio built {full.nq - 7}; use only hinges below the free root")
        missing = [h for h in UPPER_HINGES + ("lumbar_x",) if h not in names]
        if missing:
            raise MocapInputError(f"humanoid MJCF: hinges {missing} are missing; the shirt pipeline needs the humanoid of docs/humanoid_spec.md")
        self.full_model = full
        self.full_data = full.createData()
        self.full_hinge_names = names
        lock = []
        for j in range(2, full.njoints):
            jm = full.joints[j]
            covered = names[jm.idx_q - 7: jm.idx_q - 7 + jm.nq]
            inside = [h in UPPER_HINGES for h in covered]
            if not any(inside):
                lock.append(j)
            elif not all(inside):
                raise MocapInputError(f"humanoid MJCF: joint {full.names[j]} mixes estimated and fixed hinges {covered}")
        self.model = pin.buildReducedModel(full, lock, pin.neutral(full))
        self.data = self.model.createData()
        kept = [h for h in names if h in UPPER_HINGES]
        if tuple(kept) != UPPER_HINGES or self.model.nq != UPPER_NQ:
            raise MocapInputError(f"humanoid MJCF: estimated hinges in the order {kept}, expected {list(UPPER_HINGES)}; keep the body order of docs/humanoid_spec.md")
        self.lower = np.asarray(self.model.lowerPositionLimit[7:], float).copy()
        self.upper = np.asarray(self.model.upperPositionLimit[7:], float).copy()
        self._frame = {}
        for f in range(self.model.nframes):
            fr = self.model.frames[f]
            if fr.type == pin.FrameType.BODY:
                self._frame[fr.name] = f
        self._abdomen_full = full.getFrameId("abdomen", pin.FrameType.BODY)
        # abdomen origin in the pelvis frame at zero lumbar angles (lumbar joint placement)
        pin.framesForwardKinematics(full, self.full_data, pin.neutral(full))
        self._abdomen_in_pelvis = self.full_data.oMf[self._abdomen_full].copy()
        self._full_hinge_index = {n: 7 + i for i, n in enumerate(names)}

    # ------------------------------------------------------------------ configurations
    @property
    def nq(self) -> int:
        return int(self.model.nq)

    @property
    def nv(self) -> int:
        return int(self.model.nv)

    def frame_id(self, body: str) -> int:
        if body not in self._frame:
            raise MocapInputError(f"humanoid MJCF: no body {body!r}")
        return self._frame[body]

    def neutral(self) -> np.ndarray:
        return np.asarray(pin.neutral(self.model), float)

    def from_full_qpos(self, qpos: np.ndarray) -> np.ndarray:
        """MuJoCo humanoid ``qpos (..., 40)`` (quaternion ``w x y z``) -> upper-body ``q (..., 18)``.

        The root takes the abdomen's world pose (lumbar rotation folded in), so every
        shirt body has exactly the same world placement in both.
        """
        qpos = np.asarray(qpos, float)
        flat = qpos.reshape(-1, qpos.shape[-1])
        if flat.shape[1] != self.full_model.nq:
            raise MocapInputError(f"qpos must have {self.full_model.nq} values (MuJoCo humanoid qpos), got {flat.shape[1]}")
        out = np.empty((len(flat), self.nq))
        for i, qm in enumerate(flat):
            qp = qm.copy()
            qp[3:7] = qm[[4, 5, 6, 3]]
            pin.framesForwardKinematics(self.full_model, self.full_data, qp)
            abd = self.full_data.oMf[self._abdomen_full]
            root = abd * self._abdomen_in_pelvis.inverse()
            out[i, :7] = pin.SE3ToXYZQUAT(root)
            out[i, 7:] = [qm[self._full_hinge_index[h]] for h in UPPER_HINGES]
        return out.reshape(*qpos.shape[:-1], self.nq)

    def to_full_qpos(self, q: np.ndarray) -> np.ndarray:
        """Upper-body ``q (..., 18)`` -> MuJoCo ``qpos (..., 40)`` with every other hinge at zero."""
        q = np.asarray(q, float)
        flat = q.reshape(-1, self.nq)
        out = np.zeros((len(flat), self.full_model.nq))
        out[:, :3] = flat[:, :3]
        out[:, 3] = flat[:, 6]
        out[:, 4:7] = flat[:, 3:6]
        for i, h in enumerate(UPPER_HINGES):
            out[:, self._full_hinge_index[h]] = flat[:, 7 + i]
        return out.reshape(*q.shape[:-1], self.full_model.nq)

    def make_q(self, rotation: np.ndarray, translation_m: np.ndarray, hinges: np.ndarray) -> np.ndarray:
        """``q (18,)`` from a root rotation ``(3, 3)``, translation ``(3,)`` m and hinges ``(11,)`` rad."""
        q = np.empty(self.nq)
        q[:7] = pin.SE3ToXYZQUAT(pin.SE3(np.asarray(rotation, float), np.asarray(translation_m, float)))
        q[7:] = hinges
        return q

    def clamp(self, q: np.ndarray) -> np.ndarray:
        """Hinges clipped to the joint limits; quaternion normalised."""
        q = np.array(q, float)
        q[7:] = np.clip(q[7:], self.lower, self.upper)
        q[3:7] /= np.linalg.norm(q[3:7])
        return q

    # ------------------------------------------------------------------ kinematics
    def placements(self, q: np.ndarray, bodies: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
        """World rotation ``(B, 3, 3)`` and origin ``(B, 3)`` m of ``bodies`` at ``q``."""
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, float))
        R = np.empty((len(bodies), 3, 3))
        p = np.empty((len(bodies), 3))
        for i, b in enumerate(bodies):
            M = self.data.oMf[self.frame_id(b)]
            R[i] = M.rotation
            p[i] = M.translation
        return R, p

    def joint_centres(self, q: np.ndarray) -> np.ndarray:
        """``(..., J, 3)`` origins of :data:`UPPER_BODY_JOINTS` (metres) for ``q (..., 18)``."""
        q = np.asarray(q, float)
        flat = q.reshape(-1, self.nq)
        out = np.full((len(flat), len(UPPER_BODY_JOINTS), 3), np.nan)
        for i, qi in enumerate(flat):
            if np.all(np.isfinite(qi)):
                out[i] = self.placements(qi, UPPER_BODY_JOINTS)[1]
        return out.reshape(*q.shape[:-1], len(UPPER_BODY_JOINTS), 3)
