"""The skeleton solver's cold start: an initial configuration for a frame with no usable
previous solution (a rigid root fit, then each body's hinges by a grid search), and the tables
it works from. Split from :mod:`mocap.skeleton` (:class:`~mocap.skeleton.SkeletonSolver`
builds the tables once and calls :func:`cold_start`); :mod:`mocap.skeleton_labelling` searches
the same grids on unlabelled points and places bodies with :func:`place_body`.
"""

from __future__ import annotations

from dataclasses import dataclass
import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation

# Cold-start grid: values per hinge for bodies with 1, 2 and 3 hinges (25, 169 and 729 candidates).
GRID_STEPS = {1: 25, 2: 13, 3: 9}


@dataclass(frozen=True, eq=False)
class HingeGrid:
    values: np.ndarray  # (G, h) rad
    rotations: np.ndarray  # (G, 3, 3) body rotation relative to its rest frame


@dataclass(frozen=True, eq=False)
class ColdStartTables:
    marker_depth: np.ndarray  # (M,) depth of each marker's body in the tree
    parent: np.ndarray  # (B,)
    rest_R: np.ndarray  # (B, 3, 3) body rest frame in its parent's frame
    rest_t: np.ndarray  # (B, 3)
    hinge_slice: list[np.ndarray]  # per body, indices of its hinges
    grids: list[HingeGrid | None]
    own_markers: list[np.ndarray]  # per body, (M,) bool: marker on the body
    child_markers: list[np.ndarray]  # per body, (M,) bool: marker on a child of the body
    local_in_body: list[np.ndarray]  # per body, (M, 3) T-pose marker positions in its frame
    child_origin: list[np.ndarray]  # per body, (M, 3) T-pose origin of each marker's body in its frame
    child_radius: np.ndarray  # (M,) distance of each marker from its body's origin


def place_body(cs: ColdStartTables, b: int, q: np.ndarray, R_w: np.ndarray, t_w: np.ndarray, t_b: np.ndarray,
               R_rest: np.ndarray, R_c: np.ndarray | None = None, cost: np.ndarray | None = None) -> None:
    """Place body ``b`` at ``t_b``: with the grid search's candidate rotations ``R_c (G, 3, 3)``
    and their ``cost (G,)``, at the cheapest (its hinges' grid values into ``q``); without,
    at its rest rotation ``R_rest``. ``R_w``, ``t_w`` are every body's world pose."""
    if cost is not None:
        best = int(np.argmin(cost))
        q[7 + cs.hinge_slice[b]] = cs.grids[b].values[best]
        R_w[b] = R_c[best]
    else:
        R_w[b] = R_rest
    t_w[b] = t_b


def _hinge_grid(tree, idx: np.ndarray) -> HingeGrid | None:
    """The grid of the hinges ``idx`` of one body (None without hinges)."""
    if not len(idx):
        return None
    steps = GRID_STEPS[min(len(idx), 3)]
    lo = np.maximum(tree.lower_rad[idx], -np.pi)
    hi = np.minimum(tree.upper_rad[idx], np.pi)
    axes_values = [np.linspace(lo[k], hi[k], steps) for k in range(len(idx))]
    values = np.stack(np.meshgrid(*axes_values, indexing="ij"), axis=-1).reshape(-1, len(idx))
    # R = R_1 R_2 R_3 (parent-to-child order) for every row of ``values`` (the last hinge's values
    # fastest). Each product R_1..R_k is composed once for each combination of the first k values
    # and repeated for the next hinge's values, not once per row of the full grid: scipy composes
    # row by row, so the rows are the same bits, and a 3-hinge body costs 9 + 81 + 729 products
    # instead of 3 x 729 (scipy's composition is most of the cost of building a solver).
    rot = Rotation.identity(1)[[0]]
    for k, h in enumerate(idx):
        rows = steps ** (k + 1)
        prefix = rot[np.repeat(np.arange(len(rot)), steps)]
        rot = prefix * Rotation.from_rotvec(np.tile(axes_values[k], rows // steps)[:, None] * tree.hinge_axes[h])
    return HingeGrid(values, rot.as_matrix())


def cold_start_tables(solver, grids: list[HingeGrid | None] | None = None) -> ColdStartTables:
    """The tables of ``solver`` (a :class:`mocap.skeleton.SkeletonSolver`, which imports this
    module) for :func:`cold_start`: rest frames, hinge grids, markers per body. ``grids``: the
    hinge grids of another solver of the same joints, taken as they are (composing the grids'
    rotations is most of the cost of building a solver: ~0.1 s)."""
    tree = solver.tree
    n_b, M = len(tree.body_names), len(solver.marker_labels)
    q0 = solver.neutral()
    pin.framesForwardKinematics(solver.model, solver.data, q0)
    R0 = np.array([solver.data.oMf[f].rotation for f in solver._body_frames])
    t0 = np.array([solver.data.oMf[f].translation for f in solver._body_frames])
    marker_p0 = solver._markers_and_jacobian(q0, with_jacobian=False)[0]
    body_index = {n: i for i, n in enumerate(tree.body_names)}
    marker_body = np.array([body_index[m.body] for m in solver.subject.markers], dtype=np.intp)
    depth = np.zeros(n_b, dtype=np.intp)
    rest_R = np.tile(np.eye(3), (n_b, 1, 1))
    rest_t = np.zeros((n_b, 3))
    for b in range(1, n_b):
        par = tree.parents[b]
        depth[b] = depth[par] + 1
        rest_R[b] = R0[par].T @ R0[b]
        rest_t[b] = R0[par].T @ (t0[b] - t0[par])
    new_grids: list[HingeGrid | None] = []
    hinge_index, own, kids, local_in_body, child_origin = [], [], [], [], []
    marker_parent_body = tree.parents[marker_body]
    for b in range(n_b):
        idx = np.flatnonzero(tree.hinge_bodies == b)
        hinge_index.append(idx)
        if grids is None:
            new_grids.append(_hinge_grid(tree, idx))
        own.append(marker_body == b)
        kids.append(marker_parent_body == b)
        local_in_body.append((marker_p0 - t0[b]) @ R0[b])
        # Rest position of each marker's body origin in body b's frame (used for children).
        child_origin.append((t0[marker_body] - t0[b]) @ R0[b])
    child_radius = np.linalg.norm(marker_p0 - t0[marker_body], axis=1)
    return ColdStartTables(
        marker_depth=depth[marker_body],
        parent=tree.parents,
        rest_R=rest_R,
        rest_t=rest_t,
        hinge_slice=hinge_index,
        grids=new_grids if grids is None else grids,
        own_markers=own,
        child_markers=kids,
        local_in_body=local_in_body,
        child_origin=child_origin,
        child_radius=child_radius,
    )


def cold_start(solver, obs: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Initial configuration for a frame with no usable previous solution.

    1. Root pose by a rigid (Kabsch) fit of the T-pose markers nearest the root: those of
       the root body, adding the bodies one level further away until at least three are
       measured and not collinear.
    2. Then, body by body from the root outwards, the body's hinges by a grid search over
       their range. A candidate is scored on the body's own markers (squared distance to
       their measurements) and on the markers of its child bodies, which are free to
       rotate about the child's joint centre: a child's marker must lie at its fixed
       distance from that centre (squared error of the distance). The best candidate is
       kept. This lands every limb in the right basin (a T-pose start can leave a bent
       knee or an arm behind the back in a local minimum); Levenberg-Marquardt then
       refines all hinges together.
    """
    q = solver.neutral()
    model_p, _ = solver._markers_and_jacobian(q, with_jacobian=False)
    cs = solver._cold
    use = ok.copy()
    for d in range(int(cs.marker_depth.max()) + 1):
        use = ok & (cs.marker_depth <= d)
        if use.sum() >= 3:
            a = obs[use] - obs[use].mean(axis=0)
            if np.linalg.svd(a, compute_uv=False)[1] > 1e-3 * max(1.0, np.abs(a).max()):
                break
    a_c = obs[use].mean(axis=0)
    b_c = model_p[use].mean(axis=0)
    if use.sum() >= 2:
        rot, _ = Rotation.align_vectors(obs[use] - a_c, model_p[use] - b_c)
    else:
        rot = Rotation.identity()
    q[:3] = a_c - rot.apply(b_c)
    q[3:7] = rot.as_quat()  # scipy and Pinocchio both use x y z w

    # Body-by-body grid search (numpy forward kinematics of the rest-aligned tree).
    n_b = len(cs.parent)
    R_w = np.zeros((n_b, 3, 3))
    t_w = np.zeros((n_b, 3))
    R_w[0], t_w[0] = rot.as_matrix(), q[:3]
    for b in range(1, n_b):
        par = cs.parent[b]
        R_p = R_w[par] @ cs.rest_R[b]
        t_b = t_w[par] + R_w[par] @ cs.rest_t[b]
        grid = cs.grids[b]
        own = cs.own_markers[b] & ok
        kid = cs.child_markers[b] & ok
        R_c = cost = None
        if grid is not None and (own.any() or kid.any()):
            R_c = R_p[None] @ grid.rotations  # (G, 3, 3)
            cost = np.zeros(len(R_c))
            if own.any():
                pred = R_c @ cs.local_in_body[b][own].T  # (G, 3, k), relative to t_b
                cost += ((pred - (obs[own] - t_b).T) ** 2).sum(axis=(1, 2))
            if kid.any():
                centre = R_c @ cs.child_origin[b][kid].T  # (G, 3, k), relative to t_b
                dist = np.sqrt(((centre - (obs[kid] - t_b).T) ** 2).sum(axis=1))  # (G, k)
                cost += ((dist - cs.child_radius[kid]) ** 2).sum(axis=1)
        place_body(cs, b, q, R_w, t_w, t_b, R_p, R_c, cost)
    return q
