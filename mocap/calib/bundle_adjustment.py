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
        if self.loss not in ("linear", "soft_l1", "huber", "cauchy", "arctan"):
            raise ValueError(f"BundleAdjustmentOptions.loss must be one of linear, soft_l1, huber, cauchy, arctan; got {self.loss!r}")


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
    aspect = intr0[:, 1] / intr0[:, 0]
    free = _free_intrinsics_mask(C, k3_free, opt)
    moving = np.array([c != reference for c in range(C)])

    # ---------------------------------------------------------------- observations
    obs_c, obs_uv = [], []
    kind_board = board_corners_px is not None
    if kind_board:
        corners = np.asarray(board_corners_px, dtype=np.float64)
        V = corners.shape[1]
        views = np.flatnonzero(np.isfinite(np.asarray(t_wb)).all(axis=1) & np.asarray(board_use).any(axis=0))
        view_slot = np.full(V, -1)
        view_slot[views] = np.arange(len(views))
        seen = np.isfinite(corners).all(axis=3) & np.asarray(board_use)[:, :, None] & (view_slot >= 0)[None, :, None]
        bc, bv, bn = np.nonzero(seen)
        b_uv = corners[bc, bv, bn]
        obj = np.asarray(object_points, dtype=np.float64)
    else:
        V, views = 0, np.zeros(0, dtype=int)
        bc = bv = bn = np.zeros(0, dtype=int)
        b_uv = np.zeros((0, 2))
        view_slot = np.zeros(0, dtype=int)
        obj = np.zeros((0, 3))
    kind_wand = wand_px is not None
    if kind_wand:
        wpx = np.asarray(wand_px, dtype=np.float64)
        F = wpx.shape[1]
        frames = np.flatnonzero(np.isfinite(np.asarray(wand_points)).all(axis=(1, 2)))
        frame_slot = np.full(F, -1)
        frame_slot[frames] = np.arange(len(frames))
        wseen = np.isfinite(wpx).all(axis=3) & (frame_slot >= 0)[None, :, None]
        wc, wf, wm = np.nonzero(wseen)
        w_uv = wpx[wc, wf, wm]
        dist_known = np.asarray(wand_distances_m, dtype=np.float64)
    else:
        F, frames = 0, np.zeros(0, dtype=int)
        wc = wf = wm = np.zeros(0, dtype=int)
        w_uv = np.zeros((0, 2))
        frame_slot = np.zeros(0, dtype=int)
    n_b, n_w = len(bc), len(wc)
    if n_b + n_w == 0:
        raise ValueError("bundle_adjust: no observations (no board corners or wand markers seen)")

    # ---------------------------------------------------------------- parameter layout
    n_ext = 6 * int(moving.sum())
    ext_slot = np.full(C, -1)
    ext_slot[moving] = np.arange(int(moving.sum()))
    intr_idx = np.full((C, 9), -1)
    intr_idx[free] = n_ext + np.arange(int(free.sum()))
    n_intr = int(free.sum())
    off_board = n_ext + n_intr
    n_board = 6 * len(views)
    off_wand = off_board + n_board
    n_wand = 9 * len(frames)
    n_par = off_wand + n_wand

    rv_cw0 = matrix_to_rotvec(np.asarray(R_cw))
    x0 = np.zeros(n_par)
    x0[:n_ext] = np.column_stack([rv_cw0, np.asarray(t_cw)])[moving].ravel()
    x0[n_ext:off_board] = intr0[free]
    if len(views):
        x0[off_board:off_wand] = np.column_stack([matrix_to_rotvec(np.asarray(R_wb)[views]), np.asarray(t_wb)[views]]).ravel()
    if len(frames):
        x0[off_wand:] = np.asarray(wand_points)[frames].ravel()
    w_dist = opt.wand_weight_px_per_mm * 1000.0

    def unpack(x):
        rv = rv_cw0.copy()
        t = np.asarray(t_cw, dtype=np.float64).copy()
        e = x[:n_ext].reshape(-1, 6)
        rv[moving], t[moving] = e[:, :3], e[:, 3:]
        intr = intr0.copy()
        intr[free] = x[n_ext:off_board]
        if opt.fix_aspect_ratio:
            intr[:, 1] = intr[:, 0] * aspect
        b = x[off_board:off_wand].reshape(-1, 6)
        wp = x[off_wand:].reshape(-1, 3, 3)
        return rotvec_to_matrix(rv), t, intr, b, wp

    def residuals(x, with_parts=False):
        Rc, tc, intr, b, wp = unpack(x)
        parts = []
        if n_b:
            Rb = rotvec_to_matrix(b[:, :3])
            slot = view_slot[bv]
            Xw = transform_points(Rb[slot], b[slot, 3:], obj[bn])
            Xc = transform_points(Rc[bc], tc[bc], Xw)
            parts.append((project_camera_points(Xc, intr[bc]) - b_uv).ravel())
        if n_w:
            Xw = wp[frame_slot[wf], wm]
            Xc = transform_points(Rc[wc], tc[wc], Xw)
            parts.append((project_camera_points(Xc, intr[wc]) - w_uv).ravel())
            d = np.linalg.norm(wp[:, _WAND_PAIRS[:, 0]] - wp[:, _WAND_PAIRS[:, 1]], axis=2)  # (Fu, 3)
            parts.append(((d - dist_known) * w_dist).ravel())
        r = np.concatenate(parts)
        r = np.where(np.isfinite(r), r, 1e6)  # a point behind a camera: large, finite residual
        return r

    # ---------------------------------------------------------------- Jacobian structure
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

    def cam_cols(cidx: np.ndarray) -> list[np.ndarray]:
        ext = np.where(ext_slot[cidx, None] >= 0, ext_slot[cidx, None] * 6 + np.arange(6), -1)
        return [ext, intr_idx[cidx]]

    if n_b:
        row0 = 2 * np.arange(n_b)
        bcols = off_board + view_slot[bv][:, None] * 6 + np.arange(6)
        link(row0, 2, cam_cols(bc) + [bcols])
    if n_w:
        row0 = 2 * n_b + 2 * np.arange(n_w)
        wcols = off_wand + frame_slot[wf][:, None] * 9 + wm[:, None] * 3 + np.arange(3)
        link(row0, 2, cam_cols(wc) + [wcols])
        n_f = len(frames)
        drow = 2 * (n_b + n_w) + np.arange(3 * n_f)
        fi = np.repeat(np.arange(n_f), 3)
        pr = np.tile(_WAND_PAIRS, (n_f, 1))
        dcols = np.concatenate([off_wand + fi[:, None] * 9 + pr[:, :1] * 3 + np.arange(3),
                                off_wand + fi[:, None] * 9 + pr[:, 1:] * 3 + np.arange(3)], axis=1)
        link(drow, 1, [dcols])
    n_res = 2 * (n_b + n_w) + (3 * len(frames) if n_w else 0)
    r_idx = np.concatenate(rows)
    c_idx = np.concatenate(cols)
    sparsity = scipy.sparse.coo_matrix((np.ones(len(r_idx), dtype=np.int8), (r_idx, c_idx)), shape=(n_res, n_par)).tocsr()
    sparsity.data[:] = 1

    r0 = residuals(x0)
    sol = least_squares(residuals, x0, jac_sparsity=sparsity, method="trf", loss=opt.loss, f_scale=opt.f_scale_px,
                        x_scale="jac", max_nfev=opt.max_evaluations, tr_solver="lsmr",
                        # Tight inner LSMR tolerances: with the defaults (1e-6) the Gauss-Newton
                        # direction is so rough on this ill-conditioned problem (focal length vs
                        # distance, principal point vs rotation) that the solver zigzags for
                        # hundreds of evaluations and stops short of the optimum.
                        tr_options={"atol": 1e-10, "btol": 1e-10},
                        ftol=1e-10, xtol=1e-10, gtol=1e-10)
    Rc, tc, intr, b, wp = unpack(sol.x)
    res = sol.fun
    # ---------------------------------------------------------------- statistics
    sq = np.zeros(C)
    cnt = np.zeros(C)
    view_rms = np.full((C, V), np.nan)
    if n_b:
        e2 = np.sum(res[: 2 * n_b].reshape(-1, 2) ** 2, axis=1)
        np.add.at(sq, bc, e2)
        np.add.at(cnt, bc, 1)
        vs = np.zeros((C, V))
        vc = np.zeros((C, V))
        np.add.at(vs, (bc, bv), e2)
        np.add.at(vc, (bc, bv), 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            view_rms = np.sqrt(vs / vc)
    wand_err = np.full((F, 3), np.nan)
    if n_w:
        e2 = np.sum(res[2 * n_b: 2 * (n_b + n_w)].reshape(-1, 2) ** 2, axis=1)
        np.add.at(sq, wc, e2)
        np.add.at(cnt, wc, 1)
        wand_err[frames] = res[2 * (n_b + n_w):].reshape(-1, 3) / w_dist
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(sq / cnt)
    R_wb_out = np.full((V, 3, 3), np.nan)
    t_wb_out = np.full((V, 3), np.nan)
    if len(views):
        R_wb_out[views] = rotvec_to_matrix(b[:, :3])
        t_wb_out[views] = b[:, 3:]
    wand_out = np.full((F, 3, 3), np.nan)
    if len(frames):
        wand_out[frames] = wp
    result = BundleAdjustmentResult(
        intrinsics=intr, R_cw=Rc, t_cw=tc, R_wb=R_wb_out, t_wb=t_wb_out, wand_points=wand_out,
        rms_px=rms, view_rms_px=view_rms, wand_distance_error_m=wand_err,
        cost=float(sol.cost), initial_cost=float(0.5 * np.sum(r0 ** 2)), evaluations=int(sol.nfev),
        status=int(sol.status), message=str(sol.message), n_parameters=n_par, n_residuals=n_res,
    )
    bad = ~np.isfinite(rms) | (rms > opt.max_rms_px)
    bad &= cnt > 0
    if bad.any():
        checks = ("check that view i of every camera shows the same moment (synchronise the videos, keep the "
                  "image lists in the same order), that --board-size and --square-mm match the printed board, and "
                  "drop motion-blurred views; the camera with the largest error is usually the one at fault")
        if sol.status == 0:
            fix = (f"raise the evaluation budget (now {opt.max_evaluations}, e.g. --ba-max-evaluations "
                   f"{4 * opt.max_evaluations}); if the error stays large, {checks}")
        else:
            fix = checks
        raise BundleAdjustmentError(result.cost, result.evaluations,
                                    {n: float(v) for n, v in zip(camera_names, rms)},
                                    opt.max_rms_px, result.message, fix)
    return result
