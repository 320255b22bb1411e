"""Skeleton solving: joint angles of the subject's humanoid fitted to labelled 3D markers.

Per frame, inverse kinematics by Levenberg-Marquardt on the stacked marker position
residuals ``p_model(q) - p_measured`` (only the markers with finite positions), with

* the kinematics and analytic Jacobians of Pinocchio (model built from the subject's MJCF by
  ``pinocchio.buildModelFromMJCF``; each marker an operational frame on its body);
* joint limits as box constraints (active-set projection: a hinge at a limit whose step
  points outwards is frozen for that step, the others are clamped);
* warm start from the previous frame; the first frame (and the first after a gap) starts from
  a rigid fit of the root (Kabsch, ``scipy.spatial.transform.Rotation.align_vectors``) on the
  markers of the pelvis (and of the bodies next to it if the pelvis has fewer than three),
  and gets more iterations;
* a small Tikhonov term pulling every hinge towards its value in the previous frame (zero on
  a cold start), so hinges the markers do not constrain (e.g. lumbar vs thorax split when
  only the thorax carries markers) stay put instead of drifting.

After every frame is solved, hinges the markers leave undetermined for a few frames are
interpolated across them (:mod:`mocap.skeleton_bridge`).

The Levenberg-Marquardt loop is written here rather than calling
``scipy.optimize.least_squares`` because the free-flyer root lives on SE(3) (steps go through
``pinocchio.integrate``) and because scipy's per-call overhead (about a millisecond) would
dominate a 39-marker frame; a few numpy solves of a 39 x 39 system are all one frame needs.

Conventions (``docs/humanoid_spec.md``): world Z up, metres, radians. Pinocchio's
configuration ``q`` is ``(x, y, z, qx, qy, qz, qw, hinges...)``; MuJoCo's ``qpos`` is
``(x, y, z, qw, qx, qy, qz, hinges...)`` with the same hinge order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from mocap.errors import MocapInputError, require, require_finite
from mocap.skeleton_bridge import bridge_fit
from mocap.skeleton_cold_start import cold_start, cold_start_tables
from mocap.skeleton_fit import KinematicTree, SkeletonFit, mujoco_from_pinocchio_q
from mocap.skeleton_memo import FrameMemo
from mocap.subject import SubjectModel
from mocap.types import Trajectories

__all__ = [
    "IKParams",
    "SkeletonSolver",
    "solve_skeleton",
]


@dataclass(frozen=True)
class IKParams:
    """Settings of the per-frame inverse kinematics.

    Attributes
    ----------
    max_iterations : int
        Levenberg-Marquardt iterations per frame when warm-started.
    cold_start_iterations : int
        Iterations on the first frame and after a gap (start from the rigid root fit).
    step_tolerance : float
        Stop when the step norm (rad, m mixed) falls below this.
    regularization_m_per_rad : float
        Weight of the pull of each hinge towards its previous value: one radian of change
        costs as much as this many metres of marker residual. Small enough not to bias
        hinges the markers constrain (their marker Jacobians are ~0.1-0.5 m/rad).
    initial_damping : float
        Initial Levenberg-Marquardt damping (relative to the diagonal of J^T J).
    min_markers : int
        Frames with fewer finite markers are not solved (NaN in the fit).
    restart_residual_m : float
        If a warm-started frame ends with an RMS residual above this, it is solved again
        from a cold start and the better of the two is kept.
    marker_noise_m : float
        Marker noise (standard deviation per axis) assumed for ``SkeletonFit.angle_std_rad``.
    bridge_max_frames : int
        A hinge the measured markers leave undetermined (``angle_std_rad`` above
        ``bridge_std_deg``) for at most this many frames between determined ones is
        interpolated across them (:func:`mocap.skeleton_bridge.bridge_undetermined_hinges`);
        0: never.
    bridge_std_deg : float
        Angle std above which a frame's hinge counts as undetermined.
    """

    max_iterations: int = 30
    cold_start_iterations: int = 300
    step_tolerance: float = 1e-5
    regularization_m_per_rad: float = 0.003
    initial_damping: float = 1e-3
    min_markers: int = 4
    restart_residual_m: float = 0.02
    marker_noise_m: float = 0.001
    bridge_max_frames: int = 15
    bridge_std_deg: float = 5.0

    def __post_init__(self) -> None:
        for name in ("max_iterations", "cold_start_iterations", "min_markers"):
            require(int(getattr(self, name)) >= 1, self, name, "must be >= 1")
        require(int(self.bridge_max_frames) >= 0, self, "bridge_max_frames", "must be >= 0 (0: never bridge)")
        require_finite(self, ("step_tolerance", "regularization_m_per_rad", "initial_damping", "restart_residual_m", "marker_noise_m",
                              "bridge_std_deg"), positive=False)


def _spread_m(J: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``(M,)``: root of the trace of ``J cov J^T`` per marker, ``J (M, 3, nv)``."""
    return np.sqrt(np.clip(np.einsum("mik,kl,mil->m", J, cov, J), 0.0, None))


class SkeletonSolver:
    """Pinocchio model of a subject with its markers, and the per-frame IK on it.

    Parameters
    ----------
    subject : SubjectModel
    params : IKParams, optional
    grids_from : SkeletonSolver, optional
        A solver of the same MJCF (other markers, or in another order) whose cold-start hinge
        grids this one takes instead of building them (they depend on the joints alone).
    """

    def __init__(self, subject: SubjectModel, params: IKParams | None = None,
                 grids_from: SkeletonSolver | None = None) -> None:
        self.subject = subject
        self.params = params if params is not None else IKParams()
        root = subject.bodies[0]
        source = str(subject.mjcf_path) if subject.mjcf_path is not None else "<MJCF text>"
        if sum(1 for b in subject.bodies if b.parent is None) != 1:
            raise MocapInputError(f"{source}: the humanoid must have a single root body under <worldbody>; keep only the humanoid in the subject MJCF (no floor or props bodies)")
        path, temporary = subject.mjcf_file()
        try:
            if any(t == "free" for _, t in root.joints):
                model = pin.buildModelFromMJCF(str(path))
            else:
                model = pin.buildModelFromMJCF(str(path), pin.JointModelFreeFlyer())
        except Exception as exc:  # Pinocchio raises plain RuntimeError/ValueError on bad MJCF
            raise MocapInputError(f"{source}: Pinocchio cannot build a model from this MJCF ({exc}); give the standalone humanoid MJCF of docs/humanoid_spec.md") from None
        finally:
            if temporary:
                path.unlink(missing_ok=True)
        if model.joints[1].shortname() != "JointModelFreeFlyer" or model.nq - 7 != model.nv - 6:
            raise MocapInputError(f"{source}: the root body {root.name!r} must carry the only free joint and every other joint must be a hinge")
        hinge_names = subject.hinge_names
        if len(hinge_names) != model.nv - 6:
            raise MocapInputError(f"{source}: {len(hinge_names)} hinges in the XML but Pinocchio built {model.nv - 6} 1-DoF joints; use only hinge joints below the free root")

        # Marker frames: operational frames on their bodies.
        self.marker_labels = subject.marker_names
        body_frame = {b.name: model.getFrameId(b.name, pin.FrameType.BODY) for b in subject.bodies}
        marker_joint, marker_local = [], []
        self._marker_frames = []
        for m in subject.markers:
            parent = model.frames[body_frame[m.body]]
            placement = parent.placement * pin.SE3(np.eye(3), m.offset_m)
            fid = model.addFrame(pin.Frame(f"marker:{m.name}", parent.parentJoint, body_frame[m.body], placement, pin.FrameType.OP_FRAME))
            self._marker_frames.append(fid)
            marker_joint.append(parent.parentJoint)
            marker_local.append(placement.translation.copy())
        self.model = model
        self.data = model.createData()
        self._marker_joint = np.array(marker_joint, dtype=np.intp)  # (M,)
        # The joints markers hang on, and each marker's index among them (placements fetched
        # from Pinocchio for these joints only).
        used, self._marker_joint_index = np.unique(self._marker_joint, return_inverse=True)
        self._marker_joints_used = [int(j) for j in used]
        self._marker_local = np.array(marker_local).reshape(-1, 3)  # (M, 3) in the joint frame
        self._body_frames = [body_frame[b.name] for b in subject.bodies]
        # support[m, k]: tangent DoF k moves marker m (k is on the path root -> marker's joint).
        support = np.zeros((len(marker_joint), model.nv), dtype=bool)
        for i, j in enumerate(marker_joint):
            for a in model.supports[j]:
                if a > 0:
                    jm = model.joints[a]
                    support[i, jm.idx_v : jm.idx_v + jm.nv] = True
        self._support = support
        self._hinge_lower = np.asarray(model.lowerPositionLimit[7:], dtype=np.float64).copy()
        self._hinge_upper = np.asarray(model.upperPositionLimit[7:], dtype=np.float64).copy()
        self.tree = self._kinematic_tree(hinge_names)
        same_joints = grids_from is not None and grids_from.subject.mjcf_text == subject.mjcf_text
        self._cold = cold_start_tables(self, grids_from._cold.grids if same_joints else None)
        self._memo = FrameMemo()

    # ------------------------------------------------------------------ model views
    @property
    def nq(self) -> int:
        return int(self.model.nq)

    def neutral(self) -> np.ndarray:
        """``(nq,)`` T-pose at the origin (identity root)."""
        return np.asarray(pin.neutral(self.model), dtype=np.float64)

    def _kinematic_tree(self, hinge_names: list[str]) -> KinematicTree:
        bodies = self.subject.bodies
        index = {b.name: i for i, b in enumerate(bodies)}
        parents = np.array([index[b.parent] if b.parent is not None else -1 for b in bodies], dtype=np.intp)
        offsets = np.array([b.pos_m for b in bodies])
        # Hinge axes from Pinocchio's world Jacobian at the rest pose: the angular part of each
        # hinge column, expressed in its body's frame (the hinges of a body share its origin).
        q0 = self.neutral()
        pin.computeJointJacobians(self.model, self.data, q0)
        pin.updateFramePlacements(self.model, self.data)
        J = np.asarray(self.data.J)
        hinge_bodies = np.zeros(len(hinge_names), dtype=np.intp)
        axes = np.zeros((len(hinge_names), 3))
        joint_to_bodies: dict[int, list[int]] = {}
        for bi, fid in enumerate(self._body_frames):
            joint_to_bodies.setdefault(self.model.frames[fid].parentJoint, []).append(bi)
        for jid in range(2, self.model.njoints):
            jm = self.model.joints[jid]
            # The body that owns the joint is the first body attached to it.
            bi = joint_to_bodies[jid][0]
            R = np.asarray(self.data.oMf[self._body_frames[bi]].rotation)
            for k in range(jm.nv):
                h = jm.idx_v + k - 6
                hinge_bodies[h] = bi
                axes[h] = R.T @ J[3:, jm.idx_v + k]
        return KinematicTree(
            body_names=[b.name for b in bodies],
            parents=parents,
            offsets_m=offsets,
            hinge_names=list(hinge_names),
            hinge_bodies=hinge_bodies,
            hinge_axes=axes,
            lower_rad=self._hinge_lower.copy(),
            upper_rad=self._hinge_upper.copy(),
            rest_rotation=any(b.has_rotation for b in bodies),
        )

    # ------------------------------------------------------------------ kinematics
    def _markers_and_jacobian(self, q: np.ndarray, with_jacobian: bool = True,
                              rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """Marker positions ``(M, 3)`` m and their Jacobians ``(M, 3, nv)`` m per tangent unit.

        One ``computeJointJacobians`` pass gives every joint column in the WORLD frame
        (spatial velocity at the world origin, ``[v; w]``); the linear velocity of a point ``p``
        is ``v + w x p``, restricted to the DoFs on the marker's path to the root. This equals
        ``getFrameJacobian(..., LOCAL_WORLD_ALIGNED)[:3]`` of each marker frame (tested), for
        all markers at once instead of one Python call per marker. With ``rows`` (marker
        indices), the Jacobian ``(len(rows), 3, nv)`` of those markers only (the positions are
        all the markers').
        """
        if with_jacobian:
            pin.computeJointJacobians(self.model, self.data, q)
        else:
            pin.forwardKinematics(self.model, self.data, q)
        oMi = self.data.oMi.tolist()
        T = np.array([oMi[j].homogeneous for j in self._marker_joints_used])[self._marker_joint_index]  # (M, 4, 4)
        p = np.einsum("mij,mj->mi", T[:, :3, :3], self._marker_local) + T[:, :3, 3]
        if not with_jacobian:
            return p, None
        J = np.asarray(self.data.J)  # (6, nv)
        pj, support = (p, self._support) if rows is None else (p[rows], self._support[rows])
        # v + w x p = v - [p]x w, with [p]x the cross-product matrix of each marker.
        S = np.zeros((len(pj), 3, 3))
        S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -pj[:, 2], pj[:, 1], -pj[:, 0]
        S[:, 1, 0], S[:, 2, 0], S[:, 2, 1] = pj[:, 2], -pj[:, 1], pj[:, 0]
        jac = J[:3] - (S.reshape(-1, 3) @ J[3:]).reshape(len(pj), 3, -1)  # (M, 3, nv): S @ J[3:] as one product
        jac *= support[:, None, :]
        return p, jac

    def marker_positions(self, q: np.ndarray) -> np.ndarray:
        """Model marker positions ``(F, M, 3)`` m (or ``(M, 3)``) for configurations ``q (F, nq)``."""
        q = np.asarray(q, dtype=np.float64)
        if q.ndim == 1:
            return self._markers_and_jacobian(q, with_jacobian=False)[0]
        return np.stack([self._markers_and_jacobian(qi, with_jacobian=False)[0] for qi in q])

    def joint_centres(self, q: np.ndarray) -> np.ndarray:
        """Body origins ``(J, 3)`` in world metres for one configuration ``q (nq,)``."""
        pin.framesForwardKinematics(self.model, self.data, q)
        return np.array([self.data.oMf[f].translation for f in self._body_frames])

    # ------------------------------------------------------------------ IK
    def _cold_start(self, obs: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """Initial configuration for a frame with no usable previous solution
        (:func:`mocap.skeleton_cold_start.cold_start`)."""
        return cold_start(self, obs, ok)

    def _solve_frame(self, obs: np.ndarray, ok: np.ndarray, q0: np.ndarray, prior: np.ndarray, iterations: int) -> tuple[np.ndarray, float, int, np.ndarray]:
        """Levenberg-Marquardt from ``q0``; returns ``(q, rms_m, iterations, hessian)``."""
        p = self.params
        model = self.model
        nv = model.nv
        lam = p.regularization_m_per_rad
        lam2 = lam * lam
        lo, hi = self._hinge_lower, self._hinge_upper
        q = q0.copy()
        q[7:] = np.clip(q[7:], lo, hi)

        obs_ok = obs[ok]
        all_ok = bool(ok.all())  # then no row selection (the same values without the copies)
        ok_rows = np.flatnonzero(ok)
        lo_tol, hi_tol = lo + 1e-9, hi - 1e-9

        def evaluate(qc: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
            if all_ok:
                pos, jac = self._markers_and_jacobian(qc)
                r = (pos - obs_ok).reshape(-1)
            else:  # the Jacobian of the measured markers only
                pos, jac = self._markers_and_jacobian(qc, rows=ok_rows)
                r = (pos[ok] - obs_ok).reshape(-1)
            Jr = jac.reshape(-1, nv)
            reg = qc[7:] - prior
            return float(r @ r + lam2 * (reg @ reg)), r, Jr

        def normal_matrix(J: np.ndarray) -> np.ndarray:
            H = J.T @ J
            H[hinge_diag, hinge_diag] += lam2
            return H

        hinge_diag = np.arange(6, nv)
        diag = np.arange(nv)
        cost, r, Jr = evaluate(q)
        mu = p.initial_damping
        it = 0
        for it in range(1, iterations + 1):
            g = Jr.T @ r
            g[6:] += lam2 * (q[7:] - prior)
            H = normal_matrix(Jr)
            H_diag = H[diag, diag]
            at_lo, at_hi = q[7:] <= lo_tol, q[7:] >= hi_tol
            converged = True  # stays True if no damping makes the cost decrease
            for _ in range(12):
                # H + mu * diag(diag(H) + 1e-9), adding only to the diagonal
                A = H.copy()
                A[diag, diag] = H_diag + mu * (H_diag + 1e-9)
                dq = -np.linalg.solve(A, g)
                # Active set: hinges at a limit whose step points outwards stay there.
                h = dq[6:]
                active = (at_lo & (h < 0)) | (at_hi & (h > 0))
                if active.any():
                    free = np.ones(nv, dtype=bool)
                    free[6:][active] = False
                    fi = np.flatnonzero(free)
                    dq = np.zeros(nv)
                    dq[fi] = -np.linalg.solve(A[fi[:, None], fi], g[fi])
                q_new = pin.integrate(model, q, dq)
                q_new[7:] = np.clip(q_new[7:], lo, hi)
                cost_new, r_new, J_new = evaluate(q_new)
                if cost_new < cost:
                    converged = cost - cost_new <= 1e-9 * cost or float(np.sqrt(dq.dot(dq))) < p.step_tolerance
                    q, r, Jr, cost = q_new, r_new, J_new, cost_new
                    mu = max(mu / 3.0, 1e-12)
                    break
                mu *= 4.0
            if converged:
                break
        H = normal_matrix(Jr)
        n = max(int(ok.sum()), 1)
        rms = float(np.sqrt((r @ r) / n))
        return q, rms, it, H

    def solve_frame(self, obs: np.ndarray, ok: np.ndarray, q0: np.ndarray,
                    prior: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """One frame fitted to markers ``obs (M, 3)`` where ``ok (M,)``, warm-started from ``q0``;
        hinges the markers leave free are pulled to ``prior`` (``(nq,)`` configuration, default
        ``q0``), as a tracked frame's to the previous frame's. Returns the configuration ``(nq,)``
        and its covariance ``(nv, nv)`` in the tangent space for markers measured with
        ``IKParams.marker_noise_m`` (a free hinge's is set by the prior's weight alone)."""
        prior = q0 if prior is None else prior
        q, _, _, H = self._solve_frame(obs, ok, q0, prior[7:], self.params.max_iterations)
        try:
            cov = self.params.marker_noise_m**2 * np.linalg.inv(H)
        except np.linalg.LinAlgError:
            cov = np.full(H.shape, np.inf)
        return q, cov

    def measured_spread_m(self, q: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """``(M,)`` m: :meth:`marker_spread_m` of configuration ``q`` fitted to the markers
        ``ok (M,)`` measured with ``IKParams.marker_noise_m`` (Gauss-Newton covariance, with the
        fit's pull on hinges); the markers' Jacobian is computed once for both."""
        J = self._markers_and_jacobian(q)[1]                                           # (M, 3, nv)
        Jok = J[ok].reshape(-1, self.model.nv)
        H = Jok.T @ Jok
        H[6:, 6:] += self.params.regularization_m_per_rad**2 * np.eye(self.model.nv - 6)
        try:
            cov = self.params.marker_noise_m**2 * np.linalg.inv(H)
        except np.linalg.LinAlgError:
            cov = np.full(H.shape, np.inf)
        return _spread_m(J, cov)

    def marker_spread_m(self, q: np.ndarray, cov: np.ndarray) -> np.ndarray:
        """``(M,)`` m: how far each model marker may lie from where ``q`` puts it, given the
        configuration's covariance ``cov (nv, nv)`` (root of the trace of ``J cov J^T``)."""
        return _spread_m(self._markers_and_jacobian(q)[1], cov)

    def solve(self, traj: Trajectories, bridge: bool = True) -> SkeletonFit:
        """Fit every frame of ``traj`` (markers matched by label; unknown labels ignored).

        Parameters
        ----------
        traj : Trajectories
            ``(F, M', 3)`` metres; NaN gaps are skipped per frame.
        bridge : bool
            Interpolate hinges the markers leave undetermined for at most
            ``IKParams.bridge_max_frames`` frames (:func:`mocap.skeleton_bridge.bridge_fit`).
            Off for fits that only judge which points to keep (:mod:`mocap.model_check`).

        Returns
        -------
        SkeletonFit
        """
        p = self.params
        obs_all, finite = self._measured(traj)
        F, M = finite.shape
        nq, H_n, J_n = self.model.nq, self.model.nv - 6, len(self.subject.bodies)
        q_out = np.full((F, nq), np.nan)
        centres = np.full((F, J_n, 3), np.nan)
        errors = np.full((F, M), np.nan)
        std = np.full((F, H_n), np.nan)
        rms_m = np.full(F, np.nan)
        iters = np.zeros(F, dtype=np.int64)
        valid = finite.sum(axis=1) >= p.min_markers
        out = (q_out, errors, centres, std, rms_m)
        q_prev: np.ndarray | None = None
        for f in range(F):
            if not valid[f]:
                q_prev = None  # after a gap, start cold again
                continue
            q_prev = self._forward_frame(out, iters, f, obs_all[f], finite[f], q_prev)
        self._solve_backwards(out, iters, valid, obs_all, finite)
        if bridge and p.bridge_max_frames > 0:
            bridge_fit(self, q_out, std, valid, traj.times, obs_all, finite, errors, centres)
        return self._fit(traj, q_out, centres, errors, finite, iters, std, valid)

    def _forward_frame(self, out: tuple, iters: np.ndarray, f: int, obs: np.ndarray, ok: np.ndarray,
                       q_prev: np.ndarray | None) -> np.ndarray:
        """Fit frame ``f`` warm-started from ``q_prev`` and store it (``out`` as in :meth:`_record`);
        returns its solution. A frame whose inputs are bit-identical to this frame's last fit takes
        that fit's results (:mod:`mocap.skeleton_memo`): the pipeline refits mostly unchanged frames."""
        key = (self.params, *self._memo.key(obs, ok, q_prev))  # params too: a caller may swap them
        hit = self._memo.get(f, key)
        q_out, errors, centres, std, rms_m = out
        if hit is None:
            q, rms, iters[f], H = self._fit_frame(obs, ok, q_prev)
            self._record(out, f, q, rms, H, obs, ok)
            # the memo keeps its own copy: q goes on as the next frame's warm start
            self._memo.put(f, key, (q.copy(), rms, int(iters[f]), errors[f].copy(), centres[f].copy(), std[f].copy()))
            return q
        q, rms_m[f], iters[f], errors[f], centres[f], std[f] = hit
        q_out[f] = q
        return q.copy()

    def _record(self, out: tuple, f: int, q: np.ndarray, rms: float, H: np.ndarray, obs: np.ndarray, ok: np.ndarray) -> None:
        """Store frame ``f``'s solution ``q`` in ``out = (q_out, errors, centres, std, rms_m)``."""
        q_out, errors, centres, std, rms_m = out
        q_out[f], rms_m[f] = q, rms
        errors[f] = np.nan
        errors[f, ok] = 1000.0 * np.linalg.norm(self.marker_positions(q)[ok] - obs[ok], axis=1)
        centres[f] = self.joint_centres(q)
        try:
            std[f] = np.sqrt(np.clip(np.diag(self.params.marker_noise_m**2 * np.linalg.inv(H))[6:], 0.0, None))
        except np.linalg.LinAlgError:
            std[f] = np.nan

    def _solve_backwards(self, out: tuple, iters: np.ndarray, valid: np.ndarray, obs_all: np.ndarray,
                         finite: np.ndarray) -> None:
        """Solve frames left over ``restart_residual_m`` again from the next frame's solution,
        last to first, keeping the better (``out`` as in :meth:`_record`, in place).

        A cold start can settle in a wrong minimum that the frames after it leave (their warm
        start fails and they start cold again, or their markers pull them out): on frame 0 of
        the CMU walk seen by 4 cameras, refitted without one pelvis marker, the right arm came
        out 198 deg off at 31 mm RMS while frame 1 was right at 1.4 mm. Going backwards hands
        the right solution down to it (and to any run of such frames before it)."""
        q_out, rms_m = out[0], out[4]
        p = self.params
        for f in range(len(q_out) - 2, -1, -1):
            if not (valid[f] and valid[f + 1]) or rms_m[f] <= p.restart_residual_m or rms_m[f + 1] >= rms_m[f]:
                continue
            nxt = q_out[f + 1]
            q, rms, it, H = self._solve_frame(obs_all[f], finite[f], nxt, nxt[7:], p.max_iterations)
            iters[f] += it
            if rms < rms_m[f]:
                self._record(out, f, q, rms, H, obs_all[f], finite[f])

    def _measured(self, traj: Trajectories) -> tuple[np.ndarray, np.ndarray]:
        """The trajectories' markers in the solver's marker order ``(F, M, 3)`` (NaN where
        missing or not in ``traj``) and where they are finite ``(F, M)``."""
        labels = self.marker_labels
        index = {n: i for i, n in enumerate(traj.labels)}
        common = [n for n in labels if n in index]
        if not common:
            raise MocapInputError(
                f"none of the trajectory labels {list(traj.labels)[:8]}... is a marker of subject {self.subject.name!r} "
                f"({labels[:8]}...); give the subject file whose marker names match the trajectories"
            )
        F, M = len(traj.times), len(labels)
        obs_all = np.full((F, M, 3), np.nan)
        cols = [labels.index(n) for n in common]
        obs_all[:, cols] = traj.xyz[:, [index[n] for n in common]]
        return obs_all, np.isfinite(obs_all).all(axis=2)

    def _fit_frame(self, obs: np.ndarray, ok: np.ndarray, q_prev: np.ndarray | None) -> tuple[np.ndarray, float, int, np.ndarray]:
        """One frame's ``(q, rms_m, iterations, hessian)``: warm-started from ``q_prev``, and from a
        cold start when there is none or the warm fit's residual is over ``restart_residual_m``
        (the better of the two kept)."""
        p = self.params
        H_n = self.model.nv - 6
        if q_prev is None:
            q0 = self._cold_start(obs, ok)
            return self._solve_frame(obs, ok, q0, np.zeros(H_n), p.cold_start_iterations)
        q, rms, it, H = self._solve_frame(obs, ok, q_prev, q_prev[7:], p.max_iterations)
        if rms > p.restart_residual_m:
            q0 = self._cold_start(obs, ok)
            q_c, rms_c, it_c, H_c = self._solve_frame(obs, ok, q0, np.zeros(H_n), p.cold_start_iterations)
            it += it_c
            if rms_c < rms:
                q, rms, H = q_c, rms_c, H_c
        return q, rms, it, H

    def _fit(self, traj: Trajectories, q_out: np.ndarray, centres: np.ndarray, errors: np.ndarray,
             finite: np.ndarray, iters: np.ndarray, std: np.ndarray, valid: np.ndarray) -> SkeletonFit:
        """The :class:`SkeletonFit` of the solved frames."""
        F = len(q_out)
        qpos = mujoco_from_pinocchio_q(q_out)
        measured = np.isfinite(errors)
        sq = np.where(measured, errors, 0.0) ** 2
        rms_mm = np.full(F, np.nan)
        rms_mm[valid] = np.sqrt(sq[valid].sum(axis=1) / np.maximum(measured[valid].sum(axis=1), 1))
        return SkeletonFit(
            times=np.asarray(traj.times, dtype=np.float64).copy(),
            q=q_out,
            qpos=qpos,
            hinge_names=list(self.tree.hinge_names),
            joint_angles_rad=qpos[:, 7:].copy(),
            body_names=list(self.tree.body_names),
            joint_centres_m=centres,
            marker_labels=list(self.marker_labels),
            marker_errors_mm=errors,
            marker_rms_mm=rms_mm,
            n_markers=finite.sum(axis=1).astype(np.int64),
            iterations=iters,
            angle_std_rad=std,
            valid=valid,
            tree=self.tree,
        )


def solve_skeleton(traj: Trajectories, subject: SubjectModel, params: IKParams | None = None) -> SkeletonFit:
    """Fit the subject's humanoid to labelled 3D markers, frame by frame.

    Parameters
    ----------
    traj : Trajectories
        Labelled markers, ``(F, M, 3)`` metres, NaN in gaps.
    subject : SubjectModel
        Humanoid MJCF and marker placement (labels matched by name).
    params : IKParams, optional

    Returns
    -------
    SkeletonFit
    """
    return SkeletonSolver(subject, params).solve(traj)
