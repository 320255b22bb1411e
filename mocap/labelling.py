"""Label initialisation without ground truth: match a labelled template to the first frame.

A :class:`LabelTemplate` is what a user provides once per marker set: every marker's name
and its 3D position in a T-pose, in the subject-local frame (facing +X, left towards +Y,
Z up, origin between the feet on the floor, metres), stored as CSV ``name,x,y,z``
(:mod:`mocap.label_template`, re-exported here).

:func:`initial_labels` finds where the subject stands in the capture volume and which
detection of each camera is which marker:

1. **Seed**: the viewing rays through the centroid of each camera's detections are
   intersected (least squares): the subject is near that point.
2. **Coarse search** over heading (all directions), floor position around the seed and
   a small uniform scale (body size): each hypothesis places the template, projects it
   into every camera and scores the capped distance of each projected marker to its
   nearest detection (robust: missing markers and extra detections cost at most the
   cap). All hypotheses are scored at once, by lookups in a per-camera distance map.
3. **Refinement** of the best hypotheses (``scipy.optimize.least_squares``, soft-L1
   loss) alternating with Hungarian assignment (``linear_sum_assignment``) per camera.
4. **Per-marker slack**: the first frame is close to, not exactly, the T-pose. Each
   marker is triangulated from its assigned detections (robust, worst camera dropped),
   re-projected, and assigned again with a tighter gate; views inconsistent with the
   marker's 3D position lose their label.

Everything is in undistorted pixels, so the pinhole projection of the search is exact.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.optimize import least_squares, linear_sum_assignment

from mocap.calibration import Calibration
from mocap.distance_transform import exact_distance_transform
from mocap.errors import require
from mocap.label_template import LabelTemplate, load_template, save_template
from mocap.triangulation import triangulate
from mocap.types import Detections

__all__ = [
    "LabelTemplate",
    "load_template",
    "save_template",
    "Placement",
    "LabelInitParams",
    "LabelInit",
    "initial_labels",
]


# --------------------------------------------------------------------------- placement
@dataclass(frozen=True)
class Placement:
    """Where the subject stands: template -> world is ``x_w = s Rz(heading) x_t + (x, y, 0)``.

    Attributes
    ----------
    x, y : float
        Floor position of the template origin, metres.
    heading : float
        Rotation about +Z, radians (0: facing +X).
    scale : float
        Uniform body-size factor.
    """

    x: float
    y: float
    heading: float
    scale: float = 1.0

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Template points ``(M, 3)`` to world ``(M, 3)``, metres."""
        c, s = np.cos(self.heading), np.sin(self.heading)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return self.scale * np.asarray(points, dtype=np.float64) @ R.T + np.array([self.x, self.y, 0.0])


def _place(template: np.ndarray, x: np.ndarray, y: np.ndarray, heading: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Template ``(M, 3)`` under H hypotheses (each ``(H,)``) -> ``(H, M, 3)``."""
    c, s = np.cos(heading)[:, None], np.sin(heading)[:, None]
    tx, ty, tz = template[None, :, 0], template[None, :, 1], template[None, :, 2]
    k = scale[:, None]
    return np.stack([k * (c * tx - s * ty) + x[:, None], k * (s * tx + c * ty) + y[:, None], k * tz + 0.0 * x[:, None]], axis=2)


# --------------------------------------------------------------------------- params/result
@dataclass(frozen=True)
class LabelInitParams:
    """Settings of :func:`initial_labels`.

    Attributes
    ----------
    heading_step_deg : float
        Coarse search step over heading (the whole circle is searched).
    search_radius_m : float
        Half-width of the coarse floor-position grid around the seed, metres.
    position_step_m : float
        Coarse floor-position grid step, metres.
    scales : tuple[float, ...]
        Body-size factors tried in the coarse search; the refinement keeps the scale
        within ``[min(scales) - 0.05, max(scales) + 0.05]``. ``(1.0,)`` fixes it.
    slack_m : float
        Per-marker deviation of the first frame from the T-pose that is still matched,
        metres; turned into a pixel gate per camera from its focal length and distance.
    min_gate_px : float
        Lowest pixel gate (noise floor).
    refine_top : int
        Number of best coarse hypotheses refined.
    max_residual_px : float
        Reprojection threshold for the per-marker triangulation check.
    ambiguity_margin_px : float
        A view's detection stays unlabelled when another label's prediction is less
        than this much farther from it than its own label's (overlapping markers).
    pair_ambiguity : float
        Two markers closer than ``4 * slack_m`` in the template are both left unlabelled
        when their triangulated offset projected on the template offset is less than
        this fraction of it (their first-frame arrangement fits swapped labels about as
        well). 0 disables the check.
    """

    heading_step_deg: float = 10.0
    search_radius_m: float = 0.5
    position_step_m: float = 0.1
    scales: tuple[float, ...] = (0.9, 1.0, 1.1)
    slack_m: float = 0.15
    min_gate_px: float = 4.0
    refine_top: int = 4
    max_residual_px: float = 3.0
    ambiguity_margin_px: float = 2.0
    pair_ambiguity: float = 0.25

    def __post_init__(self) -> None:
        require(0 < self.heading_step_deg <= 90, self, "heading_step_deg", "must be in (0, 90] degrees")
        require(self.search_radius_m >= 0, self, "search_radius_m", "must be >= 0 m")
        require(self.position_step_m > 0, self, "position_step_m", "must be > 0 m")
        require(len(self.scales) >= 1 and all(0.5 <= s <= 2.0 for s in self.scales), self, "scales", "give factors in [0.5, 2]")
        require(self.slack_m > 0, self, "slack_m", "must be > 0 m")
        require(self.min_gate_px > 0, self, "min_gate_px", "must be > 0 px")
        require(self.refine_top >= 1, self, "refine_top", "must be >= 1")
        require(self.max_residual_px > 0, self, "max_residual_px", "must be > 0 px")
        require(self.ambiguity_margin_px >= 0, self, "ambiguity_margin_px", "must be >= 0 px")
        require(0 <= self.pair_ambiguity < 1, self, "pair_ambiguity", "must be in [0, 1)")


@dataclass
class LabelInit:
    """Result of :func:`initial_labels`.

    Attributes
    ----------
    labels : list[str], length M
    detection_index : (C, M) int
        Per camera, the index of each label's detection in that camera's detections,
        -1 where the label was not found.
    xy : (C, M, 2) float
        The assigned detections (distorted pixels), NaN where none: the ``initial_xy``
        of a 2D tracker.
    placement : Placement
        Fitted template placement.
    points : (M, 3) float
        Each marker's 3D position: triangulated from its assigned detections where
        possible, else the placed template position; metres.
    cost : float
        Mean capped squared distance (px^2) of the fitted placement (lower is better).
    """

    labels: list[str]
    detection_index: np.ndarray
    xy: np.ndarray
    placement: Placement
    points: np.ndarray
    cost: float


# --------------------------------------------------------------------------- internals
def _undistorted(detections: Sequence[Detections], calibration: Calibration) -> list[np.ndarray]:
    return [cam.undistort_pixels(d.xy) if len(d) else np.zeros((0, 2)) for d, cam in zip(detections, calibration)]


def _project_pinhole(cam, pts: np.ndarray) -> np.ndarray:
    """World ``(..., 3)`` to undistorted pixels ``(..., 2)``; NaN behind the camera.

    Written out per coordinate: for the ~10^6 points of the coarse search this is ~3x
    faster than a stacked ``pts @ R.T``.
    """
    R, t, K = cam.R, cam.t, cam.K
    X, Y, Z = pts[..., 0], pts[..., 1], pts[..., 2]
    z = R[2, 0] * X + R[2, 1] * Y + R[2, 2] * Z + t[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        iz = np.where(z > 1e-6, 1.0 / z, np.nan)
    x = (R[0, 0] * X + R[0, 1] * Y + R[0, 2] * Z + t[0]) * iz
    y = (R[1, 0] * X + R[1, 1] * Y + R[1, 2] * Z + t[1]) * iz
    return np.stack([K[0, 0] * x + K[0, 1] * y + K[0, 2], K[1, 1] * y + K[1, 2]], axis=-1)


def _seed_point(und: list[np.ndarray], calibration: Calibration) -> np.ndarray | None:
    """Least-squares intersection of the rays through each camera's detection centroid."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    n = 0
    for pts, cam in zip(und, calibration):
        if len(pts) == 0:
            continue
        c = pts.mean(axis=0)
        ray = cam.R.T @ (np.linalg.inv(cam.K) @ np.array([c[0], c[1], 1.0]))
        ray /= np.linalg.norm(ray)
        P = np.eye(3) - np.outer(ray, ray)
        A += P
        b += P @ cam.center
        n += 1
    if n < 2:
        return None
    return np.linalg.lstsq(A, b, rcond=None)[0]


def _gates(calibration: Calibration, centre: np.ndarray, params: LabelInitParams) -> np.ndarray:
    """Per-camera pixel gate = slack seen at the subject's distance (>= min_gate_px)."""
    out = []
    for cam in calibration:
        depth = max(float((cam.R @ centre + cam.t)[2]), 0.1)
        out.append(max(params.min_gate_px, cam.mean_focal_px * params.slack_m / depth))
    return np.array(out)


def _cost_maps(und: list[np.ndarray], calibration: Calibration, gates: np.ndarray) -> list[np.ndarray]:
    """Per camera, an image of the capped squared distance to the nearest detection,
    ``min(d / gate, 1)^2`` (:func:`exact_distance_transform`): scoring a hypothesis is then one
    lookup per projected marker instead of a nearest-neighbour query (~10x faster for
    the ~10^6 lookups of the coarse search; +-0.5 px is plenty at that stage)."""
    maps = []
    for pts, cam, gate in zip(und, calibration, gates):
        w, h = cam.size
        img = np.full((h, w), 255, np.uint8)
        if len(pts):
            q = np.round(pts).astype(int)
            ok = (q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)
            img[q[ok, 1], q[ok, 0]] = 0
        dist = exact_distance_transform(img)
        maps.append((np.minimum(dist / gate, 1.0) ** 2).astype(np.float32))
    return maps


def _coarse_costs(pts: np.ndarray, maps: list[np.ndarray], calibration: Calibration) -> np.ndarray:
    """Sum over cameras and markers of the capped squared nearest-detection distance.

    ``pts`` (H, M, 3) world -> (H,) cost; a marker out of view or behind the camera
    costs the cap (1).
    """
    H, M, _ = pts.shape
    cost = np.zeros(H)
    for cam, cmap in zip(calibration, maps):
        uv = _project_pinhole(cam, pts)
        h, w = cmap.shape
        with np.errstate(invalid="ignore"):
            u = np.round(uv[..., 0])
            v = np.round(uv[..., 1])
            inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        ui = np.where(inside, u, 0).astype(np.intp)
        vi = np.where(inside, v, 0).astype(np.intp)
        cost += np.where(inside, cmap[vi, ui], 1.0).sum(axis=1)
    return cost


def _assign(pred: np.ndarray, det: np.ndarray, gate: float | np.ndarray) -> np.ndarray:
    """Hungarian assignment of predicted ``(M, 2)`` to detections ``(n, 2)`` within gates.

    ``gate`` is one radius (px) or one per label ``(M,)``. Returns ``(M,)`` detection
    index or -1. Leaving a label unassigned costs its ``gate^2`` (dummy columns), so a
    label takes a detection only when that beats leaving it unmatched.
    """
    M = len(pred)
    idx = np.full(M, -1)
    ok = np.isfinite(pred).all(axis=1)
    if len(det) == 0 or not ok.any():
        return idx
    g2 = (np.broadcast_to(np.asarray(gate, dtype=np.float64), (M,))[ok]) ** 2
    d2 = ((pred[ok, None, :] - det[None, :, :]) ** 2).sum(axis=2)
    big = 1e6 * g2.max()
    d2 = np.where(d2 < g2[:, None], d2, big)
    m = int(ok.sum())
    dummy = np.full((m, m), big)
    np.fill_diagonal(dummy, g2)
    rows, cols = linear_sum_assignment(np.hstack([d2, dummy]))
    real = cols < len(det)
    sub = np.full(m, -1)
    sub[rows[real]] = cols[real]
    idx[ok] = sub
    return idx


def _refine(
    hyp: np.ndarray, template: np.ndarray, und: list[np.ndarray], calibration: Calibration,
    gates: np.ndarray, maps: list[np.ndarray], scale_bounds: tuple[float, float], rounds: int = 4,
) -> tuple[np.ndarray, float]:
    """Alternate Hungarian assignment and robust least squares on (x, y, heading[, scale]).

    Returns the refined ``(x, y, heading, scale)`` and its coarse-search cost.
    """
    h = hyp.astype(np.float64).copy()
    n = 3 if scale_bounds[1] - scale_bounds[0] < 1e-9 else 4   # scale fixed or free
    for _ in range(rounds):
        pts = _place(template, h[0:1], h[1:2], h[2:3], h[3:4])[0]
        assign = [_assign(_project_pinhole(cam, pts), d, 1.5 * g) for cam, d, g in zip(calibration, und, gates)]
        pairs = [(c, np.flatnonzero(a >= 0), a[a >= 0]) for c, a in enumerate(assign)]
        if sum(len(p[1]) for p in pairs) < 4:
            break

        def residuals(v: np.ndarray) -> np.ndarray:
            scale = np.array([v[3] if n == 4 else h[3]])
            P = _place(template, v[0:1], v[1:2], v[2:3], scale)[0]
            out = [((_project_pinhole(calibration[c], P[mi]) - und[c][di]) / gates[c]).ravel() for c, mi, di in pairs if len(mi)]
            return np.nan_to_num(np.concatenate(out), nan=10.0)

        lo = [-np.inf, -np.inf, -np.inf, scale_bounds[0]][:n]
        hi = [np.inf, np.inf, np.inf, scale_bounds[1]][:n]
        x0 = np.clip(h[:n], lo, hi)
        sol = least_squares(residuals, x0, bounds=(lo, hi), loss="soft_l1", f_scale=0.3, x_scale=[0.05, 0.05, 0.05, 0.02][:n])
        h[:n] = sol.x
    cost = float(_coarse_costs(_place(template, h[0:1], h[1:2], h[2:3], h[3:4]), maps, calibration)[0])
    return h, cost


# --------------------------------------------------------------------------- main entry
def initial_labels(
    detections_per_camera: Sequence[Detections],
    calibration: Calibration,
    template: LabelTemplate,
    params: LabelInitParams | None = None,
) -> LabelInit:
    """Label the first frame's detections of every camera by fitting the T-pose template.

    Parameters
    ----------
    detections_per_camera : sequence of Detections, length C
        First-frame detections of each camera, in calibration order.
    calibration : Calibration
    template : LabelTemplate
    params : LabelInitParams, optional

    Returns
    -------
    LabelInit
        Per-camera detection index of every label (-1 if not found), the assigned
        pixels, the fitted placement and per-marker 3D points.

    Raises
    ------
    ValueError
        If the number of detection sets differs from the number of cameras, or fewer
        than two cameras have detections.
    """
    params = LabelInitParams() if params is None else params
    dets = list(detections_per_camera)
    if len(dets) != len(calibration):
        raise ValueError(f"got detections of {len(dets)} cameras but the calibration has {len(calibration)} ({calibration.names})")
    C, M = len(calibration), len(template)
    und = _undistorted(dets, calibration)
    seed = _seed_point(und, calibration)
    if seed is None:
        raise ValueError("label initialisation needs detections in at least two cameras in the first frame")
    T = template.positions
    gates = _gates(calibration, seed, params)
    maps = _cost_maps(und, calibration, gates)
    hypotheses, costs = _coarse_search(T, seed, maps, calibration, params)
    chosen = _distinct_best(hypotheses, costs, params)
    scales = np.asarray(params.scales, dtype=np.float64)
    bounds = (max(0.5, scales.min() - 0.05), min(2.0, scales.max() + 0.05)) if len(scales) > 1 else (float(scales[0]),) * 2
    h, cost = min((_refine(cand, T, und, calibration, gates, maps, bounds) for cand in chosen), key=lambda r: r[1])
    placement = Placement(float(h[0]), float(h[1]), float((h[2] + np.pi) % (2 * np.pi) - np.pi), float(h[3]))
    placed = placement.apply(T)
    index, pred = _assign_with_slack(dets, und, calibration, placed, gates, params)
    _unlabel_ambiguous_views(index, und, pred, params)
    xy = _assigned_pixels(dets, index)
    # Final labels: drop views that disagree with the marker's 3D point.
    tri = triangulate(xy, calibration, max_residual_px=params.max_residual_px)
    good = np.isfinite(tri.points).all(axis=1)
    inconsistent = good[None, :] & (index >= 0) & ~tri.used
    index[inconsistent] = -1
    xy[inconsistent] = np.nan
    unsure = _swappable_markers(tri.points, good, placed, params)
    index[:, unsure] = -1
    xy[:, unsure] = np.nan
    good &= ~unsure
    points = np.where(good[:, None], tri.points, placed)
    return LabelInit(list(template.names), index, xy, placement, points, cost / max(C * M, 1))


def _coarse_search(T: np.ndarray, seed: np.ndarray, maps, calibration: Calibration,
                   params: LabelInitParams) -> tuple[np.ndarray, np.ndarray]:
    """Every heading, a floor grid around ``seed``, a few scales: hypotheses ``(H, 4)`` (x, y,
    heading, scale) and their coarse costs ``(H,)``. The template's centroid (not its origin)
    goes to the grid point, whatever the heading."""
    M = len(T)
    centroid_xy = T[:, :2].mean(axis=0)
    headings = np.deg2rad(np.arange(0.0, 360.0, params.heading_step_deg))
    n_side = int(np.floor(params.search_radius_m / params.position_step_m + 1e-9))
    offs = np.arange(-n_side, n_side + 1) * params.position_step_m
    gx, gy = np.meshgrid(offs, offs)
    scales = np.asarray(params.scales, dtype=np.float64)
    Hh, Gp, Ss = np.meshgrid(headings, np.arange(gx.size), scales, indexing="ij")
    Hh, Gp, Ss = Hh.ravel(), Gp.ravel(), Ss.ravel()
    c, s = np.cos(Hh), np.sin(Hh)
    cx = Ss * (c * centroid_xy[0] - s * centroid_xy[1])
    cy = Ss * (s * centroid_xy[0] + c * centroid_xy[1])
    X = seed[0] + gx.ravel()[Gp] - cx
    Y = seed[1] + gy.ravel()[Gp] - cy
    costs = np.empty(Hh.size)
    chunk = max(1, 200_000 // max(M, 1))  # bound memory: (chunk, M, 3) per step
    for i in range(0, Hh.size, chunk):
        sl = slice(i, i + chunk)
        costs[sl] = _coarse_costs(_place(T, X[sl], Y[sl], Hh[sl], Ss[sl]), maps, calibration)
    return np.column_stack([X, Y, Hh, Ss]), costs


def _distinct_best(hypotheses: np.ndarray, costs: np.ndarray, params: LabelInitParams) -> list[np.ndarray]:
    """The ``refine_top`` best hypotheses that are distinct (more than 1.5 grid steps or heading steps apart)."""
    chosen: list[np.ndarray] = []
    for k in np.argsort(costs):
        cand = np.array(hypotheses[k])
        if all(
            np.hypot(*(cand[:2] - o[:2])) > 1.5 * params.position_step_m
            or abs((cand[2] - o[2] + np.pi) % (2 * np.pi) - np.pi) > 1.5 * np.deg2rad(params.heading_step_deg)
            for o in chosen
        ):
            chosen.append(cand)
        if len(chosen) >= params.refine_top:
            break
    return chosen


def _assign_with_slack(dets: Sequence[Detections], und: list[np.ndarray], calibration: Calibration, placed: np.ndarray,
                       gates: np.ndarray, params: LabelInitParams) -> tuple[np.ndarray, np.ndarray]:
    """Detection index ``(C, M)`` of every label and its predicted pixel ``(C, M, 2)``.

    Per-marker slack: each camera's labels are re-assigned against the markers triangulated
    from the *other* cameras (independent of its own possible mistakes), with a tight gate
    where such a point exists and the slack gate otherwise.
    """
    C, M = len(calibration), len(placed)
    pred = np.stack([_project_pinhole(cam, placed) for cam in calibration])   # (C, M, 2)
    gate = np.repeat(1.5 * gates[:, None], M, axis=1)                          # (C, M)
    tight = max(params.min_gate_px, 2.0 * params.max_residual_px)
    index = np.full((C, M), -1)
    for _ in range(3):
        for cam_i in range(C):
            index[cam_i] = _assign(pred[cam_i], und[cam_i], gate[cam_i])
        xy = _assigned_pixels(dets, index)
        for cam_i, cam in enumerate(calibration):
            others = xy.copy()
            others[cam_i] = np.nan
            tri = triangulate(others, calibration, max_residual_px=params.max_residual_px)
            ok = np.isfinite(tri.points).all(axis=1)
            ok &= np.linalg.norm(tri.points - placed, axis=1) < 2.0 * params.slack_m
            pred[cam_i] = _project_pinhole(cam, np.where(ok[:, None], tri.points, placed))
            gate[cam_i] = np.where(ok, tight, gates[cam_i])
    return index, pred


def _unlabel_ambiguous_views(index: np.ndarray, und: list[np.ndarray], pred: np.ndarray, params: LabelInitParams) -> None:
    """A detection about as close to another label's prediction as to its own is ambiguous (two
    markers nearly overlapping in that view): leave it unlabelled (``index`` -1) rather than
    risk a swap; the other views still give the marker."""
    for cam_i in range(len(index)):
        has = np.flatnonzero(index[cam_i] >= 0)
        if has.size == 0:
            continue
        det = und[cam_i][index[cam_i, has]]                                       # (k, 2)
        d = np.linalg.norm(pred[cam_i][:, None, :] - det[None, :, :], axis=2)     # (M, k)
        d = np.where(np.isfinite(d), d, np.inf)
        own = d[has, np.arange(has.size)]
        d[has, np.arange(has.size)] = np.inf
        ambiguous = d.min(axis=0) - own < params.ambiguity_margin_px
        index[cam_i, has[ambiguous]] = -1


def _swappable_markers(points: np.ndarray, good: np.ndarray, placed: np.ndarray, params: LabelInitParams) -> np.ndarray:
    """``(M,)`` markers whose first-frame arrangement fits swapped labels about as well as the true ones.

    The template cannot tell them apart: they are unlabelled rather than risk a swap. With
    triangulated points P (``points``, ``good`` where triangulated) and placed template points
    T, the gain of the labels over the swap, relative to |Ta - Tb|^2, is (Pa - Pb).(Ta - Tb)
    when both are triangulated, and 1 + 2 (Pa - Ta).(Ta - Tb) / |Ta - Tb|^2 (a against an
    unobserved b, i.e. P_b = T_b) otherwise; 1 for a perfect T-pose.
    """
    P = np.where(good[:, None], points, placed)
    dT = placed[:, None, :] - placed[None, :, :]
    ref = np.einsum("abk,abk->ab", dT, dT)
    with np.errstate(invalid="ignore", divide="ignore"):
        gain = np.einsum("abk,abk->ab", P[:, None, :] - P[None, :, :], dT) / ref
        one_sided = 1.0 + 2.0 * np.einsum("ak,abk->ab", P - placed, dT) / ref
    gain = np.where(good[None, :], gain, one_sided)
    near = np.sqrt(ref) < 4.0 * params.slack_m
    ambiguous = near & good[:, None] & (gain < params.pair_ambiguity)
    np.fill_diagonal(ambiguous, False)
    return ambiguous.any(axis=1) | (ambiguous.any(axis=0) & good)


def _assigned_pixels(dets: Sequence[Detections], index: np.ndarray) -> np.ndarray:
    """Distorted pixels ``(C, M, 2)`` of the assigned detections, NaN where none."""
    C, M = index.shape
    xy = np.full((C, M, 2), np.nan)
    for c in range(C):
        ok = index[c] >= 0
        xy[c, ok] = dets[c].xy[index[c, ok]]
    return xy
