"""Pose from patch centroids: step 4 of seed 001 (and the 6-DoF global fit of step 2), with Pinocchio.

Energy (section 5.2, step 4)::

    E(q) = sum_{i,k} |c*_ik(q) - c_ik|^2_{Sigma_c} + |q - q_b|^2_{Sigma_b} + |q - q_h|^2_{Sigma_p}

``c_ik`` is the centroid of patch ``k`` in the classified id map of camera ``i``;
``c*_ik(q)`` the centroid of the same patch in the id map of pose ``q``, modelled as the
pixel-weighted mean of the projections of one anchor point per (patch, body) — the
mean body-frame position of the faces the rendered pose shows in that patch
(:meth:`mocap.shirt.shirt_model.ShirtModel.patch_anchors`).  ``q - q_b`` is
``pinocchio.difference`` (17 tangent components: root twist in the root frame, then
hinges).  Centroid residuals are measured in units of the shirt's size in the image
(the side of its tiny-map square), so that one trained ``Sigma_c`` serves any distance.

The covariances are trained as in the paper (after Wang & Popovic 2009): on a
ground-truth sequence, replace ``q`` by the true pose (and ``q_h`` by the true previous
pose) and take the covariance of each term (:func:`train_priors`).

Solver: Levenberg-Marquardt on the whitened residuals with a Huber weight on each
centroid (a misclassified patch must not drag the pose), steps through
``pinocchio.integrate``, hinges clipped to the joint limits.  Jacobians are Pinocchio's
frame Jacobians (``LOCAL_WORLD_ALIGNED``) moved to the anchor points, times the
pinhole projection's derivative.  The loop is hand-written rather than
``scipy.optimize.least_squares`` because the root lives on SE(3) and because a frame
needs a handful of 17 x 17 solves, far below scipy's per-call overhead.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numba
import numpy as np
import pinocchio as pin

from mocap.calibration import Camera
from mocap.errors import MocapInputError
from mocap.npz_files import read_npz
from mocap.shirt.ik_kernels import (anchor_jacobians, huber_rows, place_anchors, project_anchors, projection_jacobians, silhouette_field,
                                     whitened_errors)
from mocap.shirt.kinematics import ShirtKinematics, UPPER_NV

__all__ = ["Constraints", "Silhouette", "IKPriors", "ShirtIK", "IKResult", "train_priors"]


@dataclass
class Constraints:
    """2D patch-centroid constraints of one frame, in every camera.

    Attributes
    ----------
    camera : (n,) int
        Camera index of each constraint.
    patch : (n,) int
    target_px : (n, 2) float
        Measured centroid, image pixels.
    sqrt_info : (n, 2, 2) float
        Whitening of the residual in pixels (``L^-1`` of its covariance).
    size_px : (n,) float
        The shirt's size in that camera's image (side of its tiny-map square), pixels.
    absent : (n,) bool
        *Absence* constraints: the patch is not seen in this camera although the model
        shows it there, so it must be hidden, i.e. project inside the seen shirt; the
        residual is the distance from its model centroid to the nearest classified shirt
        pixel (:class:`Silhouette`), and ``target_px`` is unused.
    anchor_of : (A,) int
        Constraint index of each anchor.
    anchor_body : (A,) int
        Index into the model's geometry bodies.
    anchor_point_m : (A, 3) float
        Anchor in its body's frame.
    anchor_weight : (A,) float
        Sums to 1 over the anchors of a constraint.
    """

    camera: np.ndarray
    patch: np.ndarray
    target_px: np.ndarray
    sqrt_info: np.ndarray
    size_px: np.ndarray
    absent: np.ndarray
    anchor_of: np.ndarray
    anchor_body: np.ndarray
    anchor_point_m: np.ndarray
    anchor_weight: np.ndarray

    def __len__(self) -> int:
        return len(self.camera)

    @classmethod
    def empty(cls) -> "Constraints":
        z = np.zeros(0, int)
        return cls(z, z, np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros(0), np.zeros(0, bool), z, z, np.zeros((0, 3)), np.zeros(0))

    @classmethod
    def concatenate(cls, parts: list["Constraints"]) -> "Constraints":
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls.empty()
        offs = np.cumsum([0] + [len(p) for p in parts])[:-1]
        return cls(
            np.concatenate([p.camera for p in parts]), np.concatenate([p.patch for p in parts]),
            np.concatenate([p.target_px for p in parts]), np.concatenate([p.sqrt_info for p in parts]),
            np.concatenate([p.size_px for p in parts]), np.concatenate([p.absent for p in parts]),
            np.concatenate([p.anchor_of + o for p, o in zip(parts, offs)]), np.concatenate([p.anchor_body for p in parts]),
            np.concatenate([p.anchor_point_m for p in parts]), np.concatenate([p.anchor_weight for p in parts]),
        )

    def subset(self, keep: np.ndarray) -> "Constraints":
        keep = np.asarray(keep, bool)
        new = -np.ones(len(keep), int)
        new[keep] = np.arange(int(keep.sum()))
        a = keep[self.anchor_of]
        return Constraints(self.camera[keep], self.patch[keep], self.target_px[keep], self.sqrt_info[keep], self.size_px[keep],
                           self.absent[keep], new[self.anchor_of[a]], self.anchor_body[a], self.anchor_point_m[a], self.anchor_weight[a])


@dataclass(frozen=True, eq=False)
class Silhouette:
    """Distance (image pixels) to the nearest classified shirt pixel over one camera's crop.

    Attributes
    ----------
    distance_px : (h, w) float32
        At the crop's working pixels.
    x0, y0, scale : float
        Image position of working pixel (0, 0) and image pixels per working pixel.
    """

    distance_px: np.ndarray
    x0: float
    y0: float
    scale: float

    def __post_init__(self) -> None:
        D = np.asarray(self.distance_px)
        # distance and gradient interleaved per pixel: one bilinear look-up serves all three
        if D.ndim == 2 and min(D.shape) >= 2 and D.dtype in (np.float32, np.float64):
            field = silhouette_field(D, float(self.scale))
        else:  # (np.gradient's own checks and errors)
            gy, gx = np.gradient(np.asarray(D, np.float64))
            field = np.stack([D.astype(np.float64), gx / self.scale, gy / self.scale], axis=2).reshape(-1, 3)
        object.__setattr__(self, "_field", field)

    def sample(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance ``(n,)`` px at image points ``(n, 2)`` (bilinear, clamped) and its gradient ``(n, 2)`` per image px."""
        h, w = self.distance_px.shape
        v = _bilinear(np.ascontiguousarray(uv, np.float64), float(self.x0), float(self.y0), float(self.scale), h, w, self._field)
        return v[:, 0], v[:, 1:]


@numba.njit(cache=True, nogil=True)
def _bilinear(uv, x0, y0, scale, h, w, M):  # pragma: no cover
    """:meth:`Silhouette.sample`'s look-up, compiled: the operations of its former numpy form in the same order,
    ``clip((u - x0) / scale, 0, w - 1.001)``, the cell's floor and the four weighted corners summed left to right."""
    n = uv.shape[0]
    out = np.empty((n, 3))
    for a in range(n):
        x = min(max((uv[a, 0] - x0) / scale, 0.0), w - 1.001)
        y = min(max((uv[a, 1] - y0) / scale, 0.0), h - 1.001)
        i = np.int64(np.floor(y))
        j = np.int64(np.floor(x))
        fy = y - i
        fx = x - j
        k = i * w + j
        for c in range(3):
            out[a, c] = (M[k, c] * (1 - fx) * (1 - fy) + M[k + 1, c] * fx * (1 - fy) + M[k + w, c] * (1 - fx) * fy
                         + M[k + w + 1, c] * fx * fy)
    return out


@dataclass(frozen=True, eq=False)
class IKPriors:
    """Trained covariances of the three energy terms.

    Attributes
    ----------
    centroid_cov : (P, 2, 2) float
        Covariance of each patch's centroid residual, in units of the shirt's image size.
    blend_std : (17,) float
        Standard deviation of ``difference(q_b, q_true)`` per tangent component.
    motion_std : (17,) float
        Standard deviation of ``difference(q_true_prev, q_true)`` (one frame).
    n_frames : int
        Training frames behind the numbers.
    """

    centroid_cov: np.ndarray
    blend_std: np.ndarray
    motion_std: np.ndarray
    n_frames: int = 0

    def __post_init__(self) -> None:
        if np.asarray(self.blend_std).shape != (UPPER_NV,) or np.asarray(self.motion_std).shape != (UPPER_NV,):
            raise MocapInputError(f"IKPriors: blend_std and motion_std must have {UPPER_NV} values")
        if np.any(~np.isfinite(self.blend_std)) or np.any(np.asarray(self.blend_std) <= 0) or np.any(np.asarray(self.motion_std) <= 0):
            raise MocapInputError("IKPriors: standard deviations must be finite and positive")

    def centroid_sqrt_info(self, patch: np.ndarray, shirt_size_px: float) -> np.ndarray:
        """``(n, 2, 2)`` whitening of pixel residuals of the given patches for a shirt of this image size."""
        if getattr(self, "_inv_chol", None) is None:  # once per priors object (several calls per frame)
            object.__setattr__(self, "_inv_chol", np.linalg.inv(np.linalg.cholesky(np.asarray(self.centroid_cov, float))))
        return self._inv_chol[np.asarray(patch)] / float(shirt_size_px)

    def save(self, path: str | Path) -> None:
        np.savez(path, centroid_cov=self.centroid_cov, blend_std=self.blend_std, motion_std=self.motion_std,
                 n_frames=np.array(self.n_frames))

    @classmethod
    def load(cls, path: str | Path) -> "IKPriors":
        z = read_npz(path, ("centroid_cov", "blend_std", "motion_std", "n_frames"), "IK priors file",
                     "give the IK priors a run wrote (shirt/ik_priors.npz; IKPriors.save)")
        return cls(z["centroid_cov"], z["blend_std"], z["motion_std"], int(z["n_frames"]))


def train_priors(patch: np.ndarray, residual: np.ndarray, blend_error: np.ndarray, motion: np.ndarray, n_patches: int,
                 n_frames: int, floor_std: float | np.ndarray = 1e-3, floor_centroid: float = 0.005) -> IKPriors:
    """Covariances of the energy terms from ground truth (Wang & Popovic's training).

    Parameters
    ----------
    patch : (m,) int
        Patch of each centroid residual.
    residual : (m, 2) float
        ``c*(q_true) - c`` in units of the shirt's image size.
    blend_error : (f, 17) float
        ``difference(q_b, q_true)`` per frame.
    motion : (g, 17) float
        ``difference(q_true_prev, q_true)`` per pair of consecutive frames.
    floor_std : float or (17,) float
        Lower bound of the standard deviations (m or rad per tangent component): a
        training take that never moves a joint must not freeze it.
    floor_centroid : float
        Lower bound of the centroid standard deviation (shirt sizes).
    """
    patch = np.asarray(patch, int)
    res = np.asarray(residual, float)
    ok = np.all(np.isfinite(res), axis=1)
    patch, res = patch[ok], res[ok]
    pooled = _trimmed_cov(res) if len(res) > 10 else np.eye(2) * floor_centroid**2
    pooled = pooled + np.eye(2) * floor_centroid**2
    cov = np.repeat(pooled[None], n_patches, axis=0)
    for p in range(n_patches):
        r = res[patch == p]
        if len(r) >= 20:
            # shrink towards the pooled covariance (few samples per patch)
            a = len(r) / (len(r) + 20.0)
            cov[p] = a * (_trimmed_cov(r) + np.eye(2) * floor_centroid**2) + (1 - a) * pooled
    be = np.asarray(blend_error, float)
    be = be[np.all(np.isfinite(be), axis=1)]
    mo = np.asarray(motion, float)
    mo = mo[np.all(np.isfinite(mo), axis=1)]
    bstd = np.sqrt(np.mean(be**2, axis=0)) if len(be) else np.full(UPPER_NV, 1.0)
    mstd = np.sqrt(np.mean(mo**2, axis=0)) if len(mo) else np.full(UPPER_NV, 1.0)
    floor = np.broadcast_to(np.asarray(floor_std, float), (UPPER_NV,))
    return IKPriors(cov, np.maximum(bstd, floor), np.maximum(mstd, floor), int(n_frames))


def _trimmed_cov(r: np.ndarray, k: float = 3.0) -> np.ndarray:
    """Covariance ``(2, 2)`` of the residuals within ``k`` robust standard deviations (1.4826 MAD) of the median.

    Centroid residuals have heavy tails (a patch assigned to the wrong one of its colour);
    the IK down-weights those with its Huber loss, so the covariance describes the rest.
    """
    med = np.median(r, axis=0)
    mad = 1.4826 * np.median(np.abs(r - med), axis=0)
    keep = np.all(np.abs(r - med) <= k * np.maximum(mad, 1e-9), axis=1)
    return np.cov(r[keep].T) if keep.sum() > 5 else np.cov(r.T)


@dataclass
class IKResult:
    q: np.ndarray
    cost: float
    iterations: int
    centroid_rms_px: float


@dataclass
class _Layout:
    """Per-solve constants of :meth:`ShirtIK.centroids` (A anchors, n constraints)."""

    frames: list  # Pinocchio frame of each body used
    inv: np.ndarray  # (A,) index into ``frames``
    points: np.ndarray  # (A, 3) anchor in its body's frame, m
    Rc: np.ndarray  # (A, 3, 3) world -> camera of the anchor's camera
    tc: np.ndarray  # (A, 3)
    fx: np.ndarray  # (A,) px
    fy: np.ndarray
    skew: np.ndarray
    c: np.ndarray  # (A, 2) principal point, px
    S: np.ndarray  # (n, A) anchor weights of each constraint
    distorted: list  # (camera, anchor indices) of cameras with lens distortion


@dataclass
class _Prior:
    q_ref: np.ndarray
    inv_std: np.ndarray  # (nv,)


class ShirtIK:
    """Levenberg-Marquardt on patch-centroid constraints and pose priors.

    Parameters
    ----------
    kin : ShirtKinematics
    body_names : tuple[str, ...]
        Bodies indexed by ``Constraints.anchor_body`` (the geometry's bodies).
    cameras : list[Camera]
    huber : float
        Whitened residual beyond which a centroid's weight falls off (Huber).
    """

    def __init__(self, kin: ShirtKinematics, body_names: tuple[str, ...], cameras: list[Camera], huber: float = 2.5) -> None:
        self.kin = kin
        self.model = kin.model
        self.data = kin.data
        self.frames = [kin.frame_id(b) for b in body_names]
        self.cameras = list(cameras)
        self.huber = float(huber)
        self._pinhole = [bool(np.all(c.dist == 0)) for c in self.cameras]
        if self.cameras:  # every camera's rotation, translation and intrinsics, stacked once
            self._R = np.stack([c.R for c in self.cameras])
            self._t = np.stack([np.asarray(c.t, float) for c in self.cameras])
            self._K = np.stack([c.K for c in self.cameras])

    # ------------------------------------------------------------------ model
    def _layout(self, cons: Constraints) -> "_Layout":
        """What a solve evaluates again and again for the same constraints, prepared once."""
        used, inv = np.unique(cons.anchor_body, return_inverse=True)
        cam = cons.camera[cons.anchor_of]
        A, n = len(cam), len(cons)
        Rc = self._R[cam] if A else np.zeros((0, 3, 3))
        tc = self._t[cam] if A else np.zeros((0, 3))
        K = self._K[cam] if A else np.zeros((0, 3, 3))
        # anchor -> constraint weights: one matrix product replaces np.add.at
        S = np.zeros((n, A))
        S[cons.anchor_of, np.arange(A)] = cons.anchor_weight
        distorted = [(ci, np.flatnonzero(cam == ci)) for ci in range(len(self.cameras)) if not self._pinhole[ci]]
        distorted = [(ci, sel) for ci, sel in distorted if sel.size]
        return _Layout([self.frames[b] for b in used], inv, np.asarray(cons.anchor_point_m, float), Rc, tc, K[:, 0, 0], K[:, 1, 1],
                       K[:, 0, 1], K[:, :2, 2], S, distorted)

    def _anchors_world(self, q: np.ndarray, lay: "_Layout", jacobians: bool):
        """World anchors ``(A, 3)`` and their Jacobians ``(A, 3, nv)`` (point velocity, LOCAL_WORLD_ALIGNED)."""
        r, X = self._place_anchors(q, lay, jacobians)
        return X, (self._anchor_jacobians(lay, r) if jacobians else None)

    def _place_anchors(self, q: np.ndarray, lay: "_Layout", jacobians: bool) -> tuple[np.ndarray, np.ndarray]:
        """The forward kinematics at ``q`` (with the joint Jacobians if ``jacobians``), then
        :meth:`_anchor_positions`: each anchor's lever ``(A, 3)`` and world position ``(A, 3)``."""
        if jacobians:
            pin.computeJointJacobians(self.model, self.data, q)  # also runs the forward kinematics
        else:
            pin.forwardKinematics(self.model, self.data, q)
        pin.updateFramePlacements(self.model, self.data)
        return self._anchor_positions(lay)

    def _anchor_positions(self, lay: "_Layout") -> tuple[np.ndarray, np.ndarray]:
        """After the forward kinematics: each anchor's offset from its body's origin ``(A, 3)`` (world axes) and its world position."""
        # (references to all the placements in one call: indexing data.oMf per frame cost more, ~50 times a frame)
        oMf = self.data.oMf.tolist()
        H = np.array([oMf[f].homogeneous for f in lay.frames]).reshape(len(lay.frames), 4, 4)
        return place_anchors(H, lay.inv, lay.points)

    def _anchor_jacobians(self, lay: "_Layout", r: np.ndarray) -> np.ndarray:
        """After :func:`pinocchio.computeJointJacobians`: the anchors' Jacobians ``(A, 3, nv)`` (offsets ``r`` from
        :meth:`_anchor_positions`)."""
        Jb = np.empty((len(lay.frames), 6, self.model.nv))
        for i, f in enumerate(lay.frames):
            Jb[i] = pin.getFrameJacobian(self.model, self.data, f, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        # v_point = v_origin + w x r = Jl - [r]x Ja
        return anchor_jacobians(Jb, lay.inv, r)

    def _project_anchors(self, X: np.ndarray, lay: "_Layout"):
        """Model centroids ``(n, 2)`` px from world anchors ``X (A, 3)``, and the anchors' depths and normalised coordinates."""
        uv, z, x, y = project_anchors(X, lay.Rc, lay.tc, lay.fx, lay.fy, lay.skew, lay.c)
        for ci, sel in lay.distorted:
            cam = self.cameras[ci]
            uv[sel] = cv2.projectPoints(X[sel], cam.rvec, cam.t, cam.K, cam.dist)[0].reshape(-1, 2)
        return lay.S @ uv, z, x, y

    def _centroid_jacobians(self, JX: np.ndarray, z: np.ndarray, x: np.ndarray, y: np.ndarray, lay: "_Layout") -> np.ndarray:
        """``(n, 2, nv)``: the centroids' Jacobians from the anchors' (:meth:`_anchor_jacobians`) and their projection."""
        Jp = projection_jacobians(z, x, y, lay.fx, lay.fy)
        Ja = np.matmul(np.matmul(Jp, lay.Rc), JX)  # (A, 2, nv)
        return (lay.S @ Ja.reshape(len(z), -1)).reshape(lay.S.shape[0], 2, self.model.nv)

    def centroids(self, q: np.ndarray, cons: Constraints, jacobians: bool = False, layout: "_Layout | None" = None):
        """Model centroids ``(n, 2)`` px of the constraints at ``q`` (and their Jacobians ``(n, 2, nv)``)."""
        lay = self._layout(cons) if layout is None else layout
        n, nv = len(cons), self.model.nv
        if not len(lay.inv):
            return np.zeros((n, 2)), (np.zeros((n, 2, nv)) if jacobians else None)
        X, JX = self._anchors_world(q, lay, jacobians)
        out, z, x, y = self._project_anchors(X, lay)
        if not jacobians:
            return out, None
        return out, self._centroid_jacobians(JX, z, x, y, lay)

    # ------------------------------------------------------------------ solve
    def solve(self, q0: np.ndarray, cons: Constraints, priors: list[tuple[np.ndarray, np.ndarray]] = (),
              active: np.ndarray | None = None, iterations: int = 10, damping: float = 1e-3,
              silhouettes: dict[int, Silhouette] | None = None, rel_tol: float = 1e-5) -> IKResult:
        """Minimise the energy from ``q0``.

        Parameters
        ----------
        q0 : (18,) float
        cons : Constraints
        priors : list of (q_ref (18,), std (17,))
            Terms ``|difference(q_ref, q) / std|^2``.
        active : (17,) bool, optional
            Tangent components that may move (default all; the 6-DoF fit uses the root's).
        silhouettes : dict camera index -> Silhouette, optional
            Needed by absence constraints (``cons.absent``); without them those are ignored.
        rel_tol : float
            Stop when an iteration lowers the energy by less than this fraction.
        """
        nv = self.model.nv
        act = np.ones(nv, bool) if active is None else np.asarray(active, bool)
        energy = _Energy(self, cons, priors, silhouettes)
        q = self.kin.clamp(np.asarray(q0, float))
        r, J, cost, e = energy(q, True)
        lam = damping
        it = 0
        for it in range(1, iterations + 1):
            q, cost, lam, improved, step_norm, gain, e_new = self._damped_step(energy, q, r, J[:, act], cost, act, lam)
            if not improved or step_norm < 1e-6 or gain < rel_tol:
                break
            if it == iterations:  # no step follows: the accepted one's errors, without its Jacobian
                e = e_new
                break
            r, J, cost, e = energy(q, True)
        e = e[energy.present]
        rms = float(np.sqrt(np.mean(np.sum(e**2, axis=1)))) if len(e) else float("nan")
        return IKResult(q, cost, it, rms)

    def _damped_step(self, energy: "_Energy", q: np.ndarray, r: np.ndarray, Ja: np.ndarray, cost: float,
                     act: np.ndarray, lam: float) -> tuple[np.ndarray, float, float, bool, float, float, np.ndarray | None]:
        """One Levenberg-Marquardt iteration: up to 6 dampings until the energy falls.

        Parameters
        ----------
        q : (18,) float
            Current configuration; ``r (m,)`` its residuals, ``Ja (m, k)`` their Jacobian in the
            ``k`` active tangent components ``act (17,) bool``, ``cost`` their squared norm.
        lam : float
            Damping (relative to the Gauss-Newton diagonal).

        Returns
        -------
        q, cost : the new configuration and energy (unchanged if nothing improved)
        lam : float
            The damping for the next iteration.
        improved : bool
        step_norm : float
            Norm of the accepted step (NaN if none).
        gain : float
            Relative fall of the energy (NaN if none).
        e : (n, 2) float or None
            The pixel errors at the new configuration (None if nothing improved).
        """
        H = Ja.T @ Ja
        g = Ja.T @ r
        # diag(H) + 1e-9 on the diagonal, +0 elsewhere: the values of np.diag(np.diag(H)) + 1e-9 * np.eye(k), built once
        D = np.diag(np.diag(H) + 1e-9)
        for _ in range(6):
            A = H + lam * D
            try:
                step = -np.linalg.solve(A, g)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            dq = np.zeros(self.model.nv)
            dq[act] = step
            q_new = self.kin.clamp(pin.integrate(self.model, q, dq))
            _, _, cost_new, e_new = energy(q_new, False)
            if cost_new < cost:
                gain = (cost - cost_new) / max(cost, 1e-12)
                return q_new, cost_new, max(lam / 3, 1e-7), True, float(np.linalg.norm(step)), gain, e_new
            lam *= 8
        return q, cost, lam, False, float("nan"), float("nan"), None


class _Energy:
    """The energy :meth:`ShirtIK.solve` minimises, for one set of constraints and priors.

    Present centroids: whitened pixel error ``sqrt_info @ (centroid - target)``; absent ones
    (with a silhouette of their camera): the silhouette's distance at the centroid; both
    under a Huber weight beyond ``ShirtIK.huber``; then each prior's
    ``difference(q_ref, q) / std``. Calling it with ``q (18,)`` gives the stacked residuals
    ``(m,)``, their Jacobian ``(m, 17)`` (or None), the energy (their squared norm) and the
    pixel errors ``(n, 2)`` of the present centroids (0 for the others).
    """

    def __init__(self, ik: ShirtIK, cons: Constraints, priors, silhouettes: dict[int, Silhouette] | None) -> None:
        self.ik, self.cons = ik, cons
        # (np.isin written out: a few cameras, and its generic path cost 0.3 ms a solve)
        with_sil = np.zeros(len(cons.camera), bool)
        for ci in (silhouettes or {}):
            with_sil |= cons.camera == ci
        self.absent = np.asarray(cons.absent, bool) & with_sil
        self.present = ~self.absent & ~np.asarray(cons.absent, bool)
        self.priors = [_Prior(np.asarray(qr, float), 1.0 / np.asarray(sd, float)) for qr, sd in priors]
        self.layout = ik._layout(cons)
        # constant over the solve: the whitening of present centroids (zero for the others)
        # and the absent ones grouped by camera
        self.info = np.where(self.present[:, None, None], np.asarray(cons.sqrt_info, float), 0.0)
        self.target = np.where(self.present[:, None], cons.target_px, 0.0)
        groups = [(silhouettes[int(ci)], np.flatnonzero(self.absent & (cons.camera == ci)))
                  for ci in np.unique(cons.camera[self.absent])]
        self.groups = [(sil, sel, cons.sqrt_info[sel, 0, 0]) for sil, sel in groups]
        self._last = None  # the last evaluation without the Jacobian (see __call__)

    def __call__(self, qc: np.ndarray, jac: bool):
        ik, lay = self.ik, self.layout
        last, self._last = self._last, None
        if jac and last is not None and np.array_equal(last[0], qc):
            # the solver asks for the Jacobians where it has just evaluated the energy (an accepted
            # step): the residuals stand (the Jacobians' forward kinematics places the bodies bit
            # for bit as the plain one does), only the Jacobians are computed
            return self._with_jacobians(qc, last, False)
        if len(lay.inv):
            lever, X = ik._place_anchors(qc, lay, jac)
            c, z, x, y = ik._project_anchors(X, lay)
            proj = (lever, z, x, y)
        else:
            c, proj = np.zeros((len(self.cons), 2)), None
        e, r = whitened_errors(c, self.target, self.present, self.info)  # (n, 2) pixel errors, whitened
        grads = []
        for sil, sel, inv in self.groups:
            d, g = sil.sample(c[sel])
            r[sel, 0], r[sel, 1] = d * inv, 0.0
            grads.append(g)
        n2, nv = 2 * len(r), ik.model.nv
        rr = np.empty(n2 + nv * len(self.priors))
        w = huber_rows(r, ik.huber, rr)
        for i, p in enumerate(self.priors):
            np.multiply(pin.difference(ik.model, p.q_ref, qc), p.inv_std, out=rr[n2 + i * nv: n2 + (i + 1) * nv])
        cost = float(rr @ rr)
        state = (np.array(qc, float), proj, grads, w, rr, cost, e)
        if not jac:
            self._last = state
            return rr, None, cost, e
        return self._with_jacobians(qc, state, True)

    def _with_jacobians(self, qc: np.ndarray, state: tuple, kinematics_done: bool):
        """The call's results with the Jacobian ``(m, 17)``, from ``state`` (its residuals and the
        anchors' lever arms and projections); ``kinematics_done``: the Jacobians' forward pass has run at ``qc``."""
        ik, nv, lay = self.ik, self.ik.model.nv, self.layout
        _, proj, grads, w, rr, cost, e = state
        if proj is None:
            Jc = np.zeros((len(self.cons), 2, nv))
        else:
            if not kinematics_done:
                pin.computeJointJacobians(ik.model, ik.data, qc)
                pin.updateFramePlacements(ik.model, ik.data)
            lever, z, x, y = proj
            Jc = ik._centroid_jacobians(ik._anchor_jacobians(lay, lever), z, x, y, lay)
        Jr = np.matmul(self.info, Jc)
        for (sil, sel, inv), g in zip(self.groups, grads):
            Jr[sel, 0] = np.einsum("ni,nik->nk", g, Jc[sel]) * inv[:, None]
            Jr[sel, 1] = 0.0
        Js = [(Jr * w[:, None, None]).reshape(-1, nv)]
        for p in self.priors:
            Jd = pin.dDifference(ik.model, p.q_ref, qc, pin.ArgumentPosition.ARG1)
            Js.append(Jd * p.inv_std[:, None])
        return rr, np.vstack(Js), cost, e
