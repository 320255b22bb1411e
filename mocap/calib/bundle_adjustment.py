"""Bundle adjustment of the whole rig: all cameras, board poses and wand points at once.

Minimises the reprojection error of every board corner and wand marker in every
camera, plus (with a wand) the error of the known distances between wand markers,
with ``scipy.optimize.least_squares`` (trust-region reflective, robust ``soft_l1`` loss,
``x_scale='jac'``). Every residual depends on one camera and one board pose or wand
frame, so the Jacobian is very sparse; its structure is passed as ``jac_sparsity`` and
finite differences then need only a few dozen function evaluations per Jacobian
whatever the number of views.

Unknowns: the pose of every camera but the reference one (it defines the frame), the
intrinsics ``fx fy cx cy k1 k2 p1 p2 k3`` of every camera (optional, per-parameter
masks), the world-from-board pose of every view and the 3D position of every wand
marker in every frame. Scale is fixed by the board squares or the wand distances.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse
from scipy.optimize import least_squares

from mocap.calib.errors import BundleAdjustmentError
from mocap.calib.geometry import matrix_to_rotvec, project_camera_points, rotvec_to_matrix, transform_points
from mocap.errors import require_one_of

_WAND_PAIRS = np.array([[0, 1], [1, 2], [0, 2]])


@dataclass(frozen=True)
class BundleAdjustmentOptions:
    """Options of :func:`bundle_adjust`.

    Attributes
    ----------
    refine_intrinsics : bool
        Refine every camera's intrinsics with the rig (recommended: shared views add
        constraints single-camera calibration lacks).
    fix_aspect_ratio, fix_principal_point, zero_tangent : bool
        Same meaning as in :class:`mocap.calib.intrinsics.IntrinsicsOptions`.
    loss : str
        ``least_squares`` loss: ``"soft_l1"``, ``"huber"``, ``"cauchy"`` or ``"linear"``.
    f_scale_px : float
        Residual size (pixels) where the robust loss starts to flatten.
    max_evaluations : int
        Budget of residual evaluations (``max_nfev``).
    max_rms_px : float
        A camera whose final reprojection RMS exceeds this means the adjustment failed.
    wand_weight_px_per_mm : float
        A 1 mm error in a wand distance costs as much as this many pixels of reprojection.
    """

    refine_intrinsics: bool = True
    fix_aspect_ratio: bool = False
    fix_principal_point: bool = False
    zero_tangent: bool = False
    loss: str = "soft_l1"
    f_scale_px: float = 1.0
    max_evaluations: int = 300
    max_rms_px: float = 3.0
    wand_weight_px_per_mm: float = 1.0

    def __post_init__(self) -> None:
        require_one_of(self, "loss", ("linear", "soft_l1", "huber", "cauchy", "arctan"))


@dataclass
class BundleAdjustmentResult:
    """Refined rig (world = reference camera frame unless transformed later).

    Attributes
    ----------
    intrinsics : (C, 9) float
        ``fx fy cx cy k1 k2 p1 p2 k3``.
    R_cw, t_cw : (C, 3, 3), (C, 3)
        World-to-camera poses, metres.
    R_wb, t_wb : (V, 3, 3), (V, 3)
        World-from-board pose per view (NaN where not adjusted).
    wand_points : (F, 3, 3)
        Wand marker positions per frame, metres (NaN where not adjusted).
    rms_px : (C,) float
        Reprojection RMS per camera (board and wand observations together).
    view_rms_px : (C, V) float
        Board reprojection RMS per camera and view (NaN where unused).
    wand_distance_error_m : (F, 3) float
        Estimated minus known wand distances (pairs 0-1, 1-2, 0-2); NaN where unused.
    cost, evaluations, status, message
        From ``least_squares``.
    """

    intrinsics: np.ndarray
    R_cw: np.ndarray
    t_cw: np.ndarray
    R_wb: np.ndarray
    t_wb: np.ndarray
    wand_points: np.ndarray
    rms_px: np.ndarray
    view_rms_px: np.ndarray
    wand_distance_error_m: np.ndarray
    cost: float
    initial_cost: float
    evaluations: int
    status: int
    message: str
    n_parameters: int = 0
    n_residuals: int = 0
    extra: dict = field(default_factory=dict)


def _free_intrinsics_mask(C: int, k3_free: np.ndarray, opt: BundleAdjustmentOptions) -> np.ndarray:
    free = np.zeros((C, 9), dtype=bool)
    if not opt.refine_intrinsics:
        return free
    free[:] = True
    if opt.fix_aspect_ratio:
        free[:, 1] = False  # fy follows fx
    if opt.fix_principal_point:
        free[:, 2:4] = False
    if opt.zero_tangent:
        free[:, 6:8] = False
    free[:, 8] = np.asarray(k3_free, dtype=bool)
    return free


def bundle_adjust(intrinsics: np.ndarray, R_cw: np.ndarray, t_cw: np.ndarray, *, camera_names: list[str],
                  reference: int = 0, k3_free: np.ndarray | None = None,
                  board_corners_px: np.ndarray | None = None, object_points: np.ndarray | None = None,
                  board_use: np.ndarray | None = None, R_wb: np.ndarray | None = None, t_wb: np.ndarray | None = None,
                  wand_px: np.ndarray | None = None, wand_points: np.ndarray | None = None,
                  wand_distances_m: np.ndarray | None = None,
                  options: BundleAdjustmentOptions | None = None) -> BundleAdjustmentResult:
    """Jointly refine cameras, board poses and wand points.

    Parameters
    ----------
    intrinsics : (C, 9) float
        Initial ``fx fy cx cy k1 k2 p1 p2 k3``.
    R_cw, t_cw : (C, 3, 3), (C, 3) float
        Initial world-to-camera poses; camera ``reference`` stays fixed.
    camera_names : list[str]
    k3_free : (C,) bool, optional
        Which cameras may adjust ``k3`` (default: all).
    board_corners_px : (C, V, N, 2) float, optional
        Board corners per camera and view, NaN where unseen.
    object_points : (N, 3) float
    board_use : (C, V) bool
        Which camera views to use.
    R_wb, t_wb : (V, 3, 3), (V, 3)
        Initial world-from-board poses (NaN rows: view not adjusted).
    wand_px : (C, F, 3, 2) float, optional
        Wand markers per camera and frame, NaN where unseen.
    wand_points : (F, 3, 3) float
        Initial 3D wand markers (NaN rows: frame not adjusted).
    wand_distances_m : (3,) float
        Known distances of marker pairs 0-1, 1-2, 0-2.
    options : BundleAdjustmentOptions

    Raises
    ------
    BundleAdjustmentError
        When the solver stops with a camera's reprojection RMS above ``options.max_rms_px``.
    """
    opt = options if options is not None else BundleAdjustmentOptions()
    intr0 = np.asarray(intrinsics, dtype=np.float64).copy()
    C = intr0.shape[0]
    k3_free = np.ones(C, dtype=bool) if k3_free is None else np.asarray(k3_free, dtype=bool)
    obs = _Observations.collect(board_corners_px, object_points, board_use, t_wb, wand_px, wand_points, wand_distances_m)
    problem = _RigProblem(obs, intr0, np.asarray(R_cw), np.asarray(t_cw, dtype=np.float64), reference,
                          _free_intrinsics_mask(C, k3_free, opt), opt)
    x0 = problem.initial_parameters(R_wb, t_wb, wand_points)
    r0 = problem.residuals(x0)
    sol = least_squares(problem.residuals, x0, jac_sparsity=problem.jacobian_sparsity(), method="trf", loss=opt.loss,
                        f_scale=opt.f_scale_px, x_scale="jac", max_nfev=opt.max_evaluations, tr_solver="lsmr",
                        # Tight inner LSMR tolerances: with the defaults (1e-6) the Gauss-Newton
                        # direction is so rough on this ill-conditioned problem (focal length vs
                        # distance, principal point vs rotation) that the solver zigzags for
                        # hundreds of evaluations and stops short of the optimum.
                        tr_options={"atol": 1e-10, "btol": 1e-10},
                        ftol=1e-10, xtol=1e-10, gtol=1e-10)
    result = problem.result(sol, initial_cost=float(0.5 * np.sum(r0 ** 2)))
    _raise_if_a_camera_failed(result, sol.status, camera_names, problem.observations_per_camera(), opt)
    return result


@dataclass(frozen=True)
class _Observations:
    """The board corners and wand markers the adjustment fits, one row per observation.

    Board: camera ``bc``, view ``bv``, corner ``bn`` and pixel ``b_uv`` of each seen corner of
    a view with a pose; ``views`` the adjusted views (``view_slot``: view -> parameter slot).
    Wand: camera ``wc``, frame ``wf``, marker ``wm``, pixel ``w_uv``; ``frames`` / ``frame_slot``
    likewise; ``dist_known (3,)`` the wand's marker distances.
    """

    V: int
    views: np.ndarray
    view_slot: np.ndarray
    bc: np.ndarray
    bv: np.ndarray
    bn: np.ndarray
    b_uv: np.ndarray
    obj: np.ndarray
    F: int
    frames: np.ndarray
    frame_slot: np.ndarray
    wc: np.ndarray
    wf: np.ndarray
    wm: np.ndarray
    w_uv: np.ndarray
    dist_known: np.ndarray | None

    @property
    def n_b(self) -> int:
        return len(self.bc)

    @property
    def n_w(self) -> int:
        return len(self.wc)

    @classmethod
    def collect(cls, board_corners_px, object_points, board_use, t_wb, wand_px, wand_points, wand_distances_m) -> "_Observations":
        if board_corners_px is not None:
            corners = np.asarray(board_corners_px, dtype=np.float64)
            views = np.flatnonzero(np.isfinite(np.asarray(t_wb)).all(axis=1) & np.asarray(board_use).any(axis=0))
            V, view_slot, (bc, bv, bn), b_uv = _seen(corners, views, np.asarray(board_use)[:, :, None])
            obj = np.asarray(object_points, dtype=np.float64)
        else:
            V, views, view_slot, (bc, bv, bn), b_uv = _nothing_seen()
            obj = np.zeros((0, 3))
        dist_known = None
        if wand_px is not None:
            wpx = np.asarray(wand_px, dtype=np.float64)
            frames = np.flatnonzero(np.isfinite(np.asarray(wand_points)).all(axis=(1, 2)))
            F, frame_slot, (wc, wf, wm), w_uv = _seen(wpx, frames)
            dist_known = np.asarray(wand_distances_m, dtype=np.float64)
        else:
            F, frames, frame_slot, (wc, wf, wm), w_uv = _nothing_seen()
        if len(bc) + len(wc) == 0:
            raise ValueError("bundle_adjust: no observations (no board corners or wand markers seen)")
        return cls(V, views, view_slot, bc, bv, bn, b_uv, obj, F, frames, frame_slot, wc, wf, wm, w_uv, dist_known)


def _seen(px: np.ndarray, adjusted: np.ndarray, use: np.ndarray | bool = True):
    """The observations of ``px`` (C, N, K, 2) (cameras, views or frames, points) that the
    adjustment fits: finite pixels of the ``adjusted`` views or frames where ``use`` (C, N, 1)
    is set. Returns ``N``, the slot of each view or frame (-1: not adjusted), the camera,
    view or frame and point index of each observation, and its pixel (n, 2)."""
    n = px.shape[1]
    slot = np.full(n, -1)
    slot[adjusted] = np.arange(len(adjusted))
    seen = np.isfinite(px).all(axis=3) & use & (slot >= 0)[None, :, None]
    index = np.nonzero(seen)
    return n, slot, index, px[index]


def _nothing_seen():
    """What :func:`_seen` returns, and the adjusted indices, where there are no observations."""
    none = np.zeros(0, dtype=int)
    return 0, none, np.zeros(0, dtype=int), (none, none, none), np.zeros((0, 2))


class _RigProblem:
    """The adjustment's parameter vector, residuals and Jacobian structure.

    Parameters, in order: the 6 pose values (rotation vector, translation) of every camera
    but the reference, the free intrinsics, 6 per adjusted board view, 9 per adjusted wand
    frame. Residuals, in order: 2 per board corner, 2 per wand marker, 3 wand distances per
    adjusted frame (weighted by ``wand_weight_px_per_mm``).
    """

    def __init__(self, obs: _Observations, intr0: np.ndarray, R_cw: np.ndarray, t_cw: np.ndarray, reference: int,
                 free: np.ndarray, opt: BundleAdjustmentOptions) -> None:
        C = intr0.shape[0]
        self.obs, self.intr0, self.t_cw, self.free, self.opt = obs, intr0, t_cw, free, opt
        self.aspect = intr0[:, 1] / intr0[:, 0]
        self.moving = np.array([c != reference for c in range(C)])
        self.rv_cw0 = matrix_to_rotvec(R_cw)
        self.n_ext = 6 * int(self.moving.sum())
        self.ext_slot = np.full(C, -1)
        self.ext_slot[self.moving] = np.arange(int(self.moving.sum()))
        self.intr_idx = np.full((C, 9), -1)
        self.intr_idx[free] = self.n_ext + np.arange(int(free.sum()))
        self.off_board = self.n_ext + int(free.sum())
        self.off_wand = self.off_board + 6 * len(obs.views)
        self.n_par = self.off_wand + 9 * len(obs.frames)
        self.n_res = 2 * (obs.n_b + obs.n_w) + (3 * len(obs.frames) if obs.n_w else 0)
        self.w_dist = opt.wand_weight_px_per_mm * 1000.0

    def initial_parameters(self, R_wb, t_wb, wand_points) -> np.ndarray:
        obs = self.obs
        x0 = np.zeros(self.n_par)
        x0[:self.n_ext] = np.column_stack([self.rv_cw0, self.t_cw])[self.moving].ravel()
        x0[self.n_ext:self.off_board] = self.intr0[self.free]
        if len(obs.views):
            x0[self.off_board:self.off_wand] = np.column_stack([matrix_to_rotvec(np.asarray(R_wb)[obs.views]),
                                                                np.asarray(t_wb)[obs.views]]).ravel()
        if len(obs.frames):
            x0[self.off_wand:] = np.asarray(wand_points)[obs.frames].ravel()
        return x0

    def unpack(self, x: np.ndarray):
        """Cameras ``R (C, 3, 3)``, ``t (C, 3)``, intrinsics ``(C, 9)``, board poses ``(Vu, 6)``, wand points ``(Fu, 3, 3)``."""
        rv = self.rv_cw0.copy()
        t = self.t_cw.copy()
        e = x[:self.n_ext].reshape(-1, 6)
        rv[self.moving], t[self.moving] = e[:, :3], e[:, 3:]
        intr = self.intr0.copy()
        intr[self.free] = x[self.n_ext:self.off_board]
        if self.opt.fix_aspect_ratio:
            intr[:, 1] = intr[:, 0] * self.aspect
        b = x[self.off_board:self.off_wand].reshape(-1, 6)
        wp = x[self.off_wand:].reshape(-1, 3, 3)
        return rotvec_to_matrix(rv), t, intr, b, wp

    def residuals(self, x: np.ndarray) -> np.ndarray:
        obs = self.obs
        Rc, tc, intr, b, wp = self.unpack(x)
        parts = []
        if obs.n_b:
            Rb = rotvec_to_matrix(b[:, :3])
            slot = obs.view_slot[obs.bv]
            Xw = transform_points(Rb[slot], b[slot, 3:], obs.obj[obs.bn])
            Xc = transform_points(Rc[obs.bc], tc[obs.bc], Xw)
            parts.append((project_camera_points(Xc, intr[obs.bc]) - obs.b_uv).ravel())
        if obs.n_w:
            Xw = wp[obs.frame_slot[obs.wf], obs.wm]
            Xc = transform_points(Rc[obs.wc], tc[obs.wc], Xw)
            parts.append((project_camera_points(Xc, intr[obs.wc]) - obs.w_uv).ravel())
            d = np.linalg.norm(wp[:, _WAND_PAIRS[:, 0]] - wp[:, _WAND_PAIRS[:, 1]], axis=2)  # (Fu, 3)
            parts.append(((d - obs.dist_known) * self.w_dist).ravel())
        r = np.concatenate(parts)
        return np.where(np.isfinite(r), r, 1e6)  # a point behind a camera: large, finite residual

    def jacobian_sparsity(self) -> scipy.sparse.csr_matrix:
        """Which parameters each residual depends on: its camera's pose and intrinsics, and its view or wand frame."""
        obs = self.obs
        rows, cols = [], []

        def link(row0: np.ndarray, n_rows: int, col_blocks: list[np.ndarray]) -> None:
            """Mark rows ``row0 + 0..n_rows-1`` of each observation as depending on ``col_blocks``."""
            for blk in col_blocks:  # blk: (n_obs, k) column indices, -1 = none
                for r in range(n_rows):
                    rr = np.repeat(row0 + r, blk.shape[1])
                    cc = blk.ravel()
                    keep = cc >= 0
                    rows.append(rr[keep])
                    cols.append(cc[keep])

        if obs.n_b:
            bcols = self.off_board + obs.view_slot[obs.bv][:, None] * 6 + np.arange(6)
            link(2 * np.arange(obs.n_b), 2, self._camera_columns(obs.bc) + [bcols])
        if obs.n_w:
            wcols = self.off_wand + obs.frame_slot[obs.wf][:, None] * 9 + obs.wm[:, None] * 3 + np.arange(3)
            link(2 * obs.n_b + 2 * np.arange(obs.n_w), 2, self._camera_columns(obs.wc) + [wcols])
            n_f = len(obs.frames)
            drow = 2 * (obs.n_b + obs.n_w) + np.arange(3 * n_f)
            fi = np.repeat(np.arange(n_f), 3)
            pr = np.tile(_WAND_PAIRS, (n_f, 1))
            dcols = np.concatenate([self.off_wand + fi[:, None] * 9 + pr[:, :1] * 3 + np.arange(3),
                                    self.off_wand + fi[:, None] * 9 + pr[:, 1:] * 3 + np.arange(3)], axis=1)
            link(drow, 1, [dcols])
        r_idx = np.concatenate(rows)
        c_idx = np.concatenate(cols)
        sparsity = scipy.sparse.coo_matrix((np.ones(len(r_idx), dtype=np.int8), (r_idx, c_idx)),
                                           shape=(self.n_res, self.n_par)).tocsr()
        sparsity.data[:] = 1
        return sparsity

    def _camera_columns(self, cidx: np.ndarray) -> list[np.ndarray]:
        ext = np.where(self.ext_slot[cidx, None] >= 0, self.ext_slot[cidx, None] * 6 + np.arange(6), -1)
        return [ext, self.intr_idx[cidx]]

    def observations_per_camera(self) -> np.ndarray:
        """``(C,)`` board corners and wand markers each camera contributes."""
        cnt = np.zeros(len(self.intr0))
        np.add.at(cnt, self.obs.bc, 1)
        np.add.at(cnt, self.obs.wc, 1)
        return cnt

    def result(self, sol, initial_cost: float) -> BundleAdjustmentResult:
        """The refined rig with reprojection RMS per camera and per view and the wand distance errors."""
        obs = self.obs
        C, V, F = len(self.intr0), obs.V, obs.F
        Rc, tc, intr, b, wp = self.unpack(sol.x)
        res = sol.fun
        n_b, n_w = obs.n_b, obs.n_w
        sq = np.zeros(C)
        cnt = np.zeros(C)
        view_rms = np.full((C, V), np.nan)
        if n_b:
            e2 = np.sum(res[: 2 * n_b].reshape(-1, 2) ** 2, axis=1)
            np.add.at(sq, obs.bc, e2)
            np.add.at(cnt, obs.bc, 1)
            vs = np.zeros((C, V))
            vc = np.zeros((C, V))
            np.add.at(vs, (obs.bc, obs.bv), e2)
            np.add.at(vc, (obs.bc, obs.bv), 1)
            with np.errstate(invalid="ignore", divide="ignore"):
                view_rms = np.sqrt(vs / vc)
        wand_err = np.full((F, 3), np.nan)
        if n_w:
            e2 = np.sum(res[2 * n_b: 2 * (n_b + n_w)].reshape(-1, 2) ** 2, axis=1)
            np.add.at(sq, obs.wc, e2)
            np.add.at(cnt, obs.wc, 1)
            wand_err[obs.frames] = res[2 * (n_b + n_w):].reshape(-1, 3) / self.w_dist
        with np.errstate(invalid="ignore", divide="ignore"):
            rms = np.sqrt(sq / cnt)
        R_wb_out = np.full((V, 3, 3), np.nan)
        t_wb_out = np.full((V, 3), np.nan)
        if len(obs.views):
            R_wb_out[obs.views] = rotvec_to_matrix(b[:, :3])
            t_wb_out[obs.views] = b[:, 3:]
        wand_out = np.full((F, 3, 3), np.nan)
        if len(obs.frames):
            wand_out[obs.frames] = wp
        return BundleAdjustmentResult(
            intrinsics=intr, R_cw=Rc, t_cw=tc, R_wb=R_wb_out, t_wb=t_wb_out, wand_points=wand_out,
            rms_px=rms, view_rms_px=view_rms, wand_distance_error_m=wand_err,
            cost=float(sol.cost), initial_cost=initial_cost, evaluations=int(sol.nfev),
            status=int(sol.status), message=str(sol.message), n_parameters=self.n_par, n_residuals=self.n_res,
        )


def _raise_if_a_camera_failed(result: BundleAdjustmentResult, status: int, camera_names: list[str], observations: np.ndarray,
                              opt: BundleAdjustmentOptions) -> None:
    """:class:`BundleAdjustmentError` when a camera that has observations ends above ``max_rms_px``."""
    rms = result.rms_px
    bad = (~np.isfinite(rms) | (rms > opt.max_rms_px)) & (observations > 0)
    if not bad.any():
        return
    checks = ("check that view i of every camera shows the same moment (synchronise the videos, keep the "
              "image lists in the same order), that --board-size and --square-mm match the printed board, and "
              "drop motion-blurred views; the camera with the largest error is usually the one at fault")
    if status == 0:
        fix = (f"raise the evaluation budget (now {opt.max_evaluations}, e.g. --ba-max-evaluations "
               f"{4 * opt.max_evaluations}); if the error stays large, {checks}")
    else:
        fix = checks
    raise BundleAdjustmentError(result.cost, result.evaluations, {n: float(v) for n, v in zip(camera_names, rms)},
                                opt.max_rms_px, result.message, fix)
