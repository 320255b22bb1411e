"""What a skeleton fit returns: every frame's solution (:class:`SkeletonFit`), the humanoid's
tree as BVH export and reports need it (:class:`KinematicTree`), and the two orders of a
configuration (Pinocchio's quaternion ``x y z w``, MuJoCo's ``w x y z``).

Split from :mod:`mocap.skeleton`, whose :class:`~mocap.skeleton.SkeletonSolver` builds them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "KinematicTree",
    "SkeletonFit",
    "mujoco_from_pinocchio_q",
    "pinocchio_from_mujoco_q",
]


@dataclass(frozen=True, eq=False)
class KinematicTree:
    """The humanoid's tree as BVH and reports need it.

    Attributes
    ----------
    body_names : list[str], length J
        Bodies in depth-first MJCF order.
    parents : (J,) int
        Index of each body's parent body, -1 for the root.
    offsets_m : (J, 3) float
        Body origin (= joint centre) in the parent body's frame, metres.
    hinge_names : list[str], length H
        Hinges in qpos order.
    hinge_bodies : (H,) int
        Body index each hinge moves.
    hinge_axes : (H, 3) float
        Unit hinge axis in its body frame (at the rest pose).
    lower_rad, upper_rad : (H,) float
        Joint limits.
    rest_rotation : bool
        True if some body declares a rest orientation (not allowed by the humanoid contract;
        BVH export refuses such models).
    """

    body_names: list[str]
    parents: np.ndarray
    offsets_m: np.ndarray
    hinge_names: list[str]
    hinge_bodies: np.ndarray
    hinge_axes: np.ndarray
    lower_rad: np.ndarray
    upper_rad: np.ndarray
    rest_rotation: bool


@dataclass(eq=False)
class SkeletonFit:
    """Solved skeleton of every frame.

    Attributes
    ----------
    times : (F,) float
        Seconds (from the trajectories).
    q : (F, nq) float
        Pinocchio configuration: root position (m), root quaternion ``x y z w``, hinges (rad).
        NaN for frames not solved.
    qpos : (F, nq) float
        The same in MuJoCo's order: root position, quaternion ``w x y z``, hinges.
    hinge_names : list[str], length H
    joint_angles_rad : (F, H) float
        Hinge angles in qpos order (``qpos[:, 7:]``).
    body_names : list[str], length J
    joint_centres_m : (F, J, 3) float
        World position of every body origin (= the joint centre linking it to its parent).
    marker_labels : list[str], length M
        Markers of the subject, in the subject's order.
    marker_errors_mm : (F, M) float
        Distance between each fitted model marker and its measurement, mm; NaN where the
        marker had no measurement.
    marker_rms_mm : (F,) float
        RMS over the measured markers of ``marker_errors_mm`` (the per-frame residual).
    n_markers : (F,) int
        Markers used per frame.
    iterations : (F,) int
        Levenberg-Marquardt iterations spent per frame.
    angle_std_rad : (F, H) float
        Predicted standard deviation of each hinge angle for ``IKParams.marker_noise_m`` (:class:`mocap.skeleton.IKParams`) of
        marker noise (Gauss-Newton covariance at the solution): large values flag hinges the
        markers do not constrain.
    valid : (F,) bool
        Frames that were solved.
    tree : KinematicTree
    """

    times: np.ndarray
    q: np.ndarray
    qpos: np.ndarray
    hinge_names: list[str]
    joint_angles_rad: np.ndarray
    body_names: list[str]
    joint_centres_m: np.ndarray
    marker_labels: list[str]
    marker_errors_mm: np.ndarray
    marker_rms_mm: np.ndarray
    n_markers: np.ndarray
    iterations: np.ndarray
    angle_std_rad: np.ndarray
    valid: np.ndarray
    tree: KinematicTree = field(repr=False)

    def well_constrained(self, max_std_deg: float = 1.0) -> np.ndarray:
        """``(H,)`` bool: hinges whose median predicted angle std (solved frames) is below ``max_std_deg``.

        With the default 1 mm marker noise and 1 deg, these are the hinges the marker set
        determines; the others (e.g. how the trunk's axial twist splits between lumbar and
        thorax when the abdomen carries no marker) are set by the regularisation.
        """
        if not self.valid.any():
            return np.zeros(len(self.hinge_names), dtype=bool)
        return np.degrees(np.median(self.angle_std_rad[self.valid], axis=0)) < max_std_deg

    def angles_by_name(self) -> dict[str, np.ndarray]:
        """``{hinge name: (F,) angle in rad}``."""
        return {n: self.joint_angles_rad[:, i] for i, n in enumerate(self.hinge_names)}

    @property
    def rate_hz(self) -> float:
        if len(self.times) < 2:
            return float("nan")
        return float(1.0 / np.median(np.diff(self.times)))


def mujoco_from_pinocchio_q(q: np.ndarray) -> np.ndarray:
    """``(..., nq)`` Pinocchio configuration (quaternion x y z w) -> MuJoCo qpos (w x y z)."""
    q = np.asarray(q, dtype=np.float64)
    out = q.copy()
    out[..., 3] = q[..., 6]
    out[..., 4:7] = q[..., 3:6]
    return out


def pinocchio_from_mujoco_q(qpos: np.ndarray) -> np.ndarray:
    """``(..., nq)`` MuJoCo qpos (quaternion w x y z) -> Pinocchio configuration (x y z w)."""
    qpos = np.asarray(qpos, dtype=np.float64)
    out = qpos.copy()
    out[..., 3:6] = qpos[..., 4:7]
    out[..., 6] = qpos[..., 3]
    return out
