"""First guess of the rig: camera poses from board views shared between cameras.

Each camera's pose relative to the board is found per view with ``cv2.solvePnP``. Two
cameras that saw the board in the same view are linked by
``T_c2_c1 = T_c2_board @ inv(T_c1_board)``; averaging over their shared views gives one
relative pose per camera pair. The cameras form a graph (edge weight = shared views);
a maximum spanning tree from the reference camera chains the relative poses, so each
camera is reached through the pairs that saw the board together most often. The result
is expressed in the reference camera's frame and refined by bundle adjustment.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from mocap.calib.errors import DisconnectedCamerasError
from mocap.calib.geometry import compose_poses, invert_pose, mean_pose


@dataclass
class BoardPoses:
    """Camera-from-board pose of every view each camera saw.

    Attributes
    ----------
    R : (C, V, 3, 3) float
    t : (C, V, 3) float
        Metres; NaN where camera ``c`` did not use view ``v``.
    """

    R: np.ndarray
    t: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """``(C, V)`` bool."""
        return np.isfinite(self.t).all(axis=2)


@dataclass
class InitialRig:
    """Cameras and boards in the reference camera's frame.

    Attributes
    ----------
    R_cw, t_cw : (C, 3, 3), (C, 3)
        World-to-camera poses (world = reference camera frame), metres.
    R_wb, t_wb : (V, 3, 3), (V, 3)
        World-from-board pose of each view; NaN for views no camera used.
    reference : int
    tree : list[tuple[int, int]]
        ``(parent, child)`` edges used to chain the cameras.
    """

    R_cw: np.ndarray
    t_cw: np.ndarray
    R_wb: np.ndarray
    t_wb: np.ndarray
    reference: int
    tree: list[tuple[int, int]]


def board_poses_pnp(corners_px: np.ndarray, object_points: np.ndarray, Ks: np.ndarray, dists: np.ndarray,
                    use: np.ndarray) -> BoardPoses:
    """``cv2.solvePnP`` of every used view of every camera.

    Parameters
    ----------
    corners_px : (C, V, N, 2) float, NaN where unseen
    object_points : (N, 3) float
    Ks, dists : (C, 3, 3), (C, 5) float
    use : (C, V) bool
        Views to solve (e.g. the views each camera's intrinsics kept).
    """
    C, V = corners_px.shape[:2]
    R = np.full((C, V, 3, 3), np.nan)
    t = np.full((C, V, 3), np.nan)
    for c in range(C):
        for v in np.flatnonzero(use[c]):
            ok = np.isfinite(corners_px[c, v]).all(axis=1)
            if ok.sum() < 4:
                continue
            good, rvec, tvec = cv2.solvePnP(object_points[ok], corners_px[c, v, ok], Ks[c], dists[c],
                                            flags=cv2.SOLVEPNP_ITERATIVE)
            if good and tvec[2, 0] > 0:
                R[c, v] = cv2.Rodrigues(rvec)[0]
                t[c, v] = tvec.ravel()
    return BoardPoses(R, t)


def connected_groups(shared: np.ndarray) -> list[list[int]]:
    """Connected components of a ``(C, C)`` count matrix (edge where > 0)."""
    C = shared.shape[0]
    seen = np.zeros(C, dtype=bool)
    groups = []
    for s in range(C):
        if seen[s]:
            continue
        stack, comp = [s], []
        seen[s] = True
        while stack:
            a = stack.pop()
            comp.append(a)
            for b in np.flatnonzero((shared[a] > 0) & ~seen):
                seen[b] = True
                stack.append(int(b))
        groups.append(sorted(comp))
    return groups


def maximum_spanning_tree(shared: np.ndarray, root: int) -> list[tuple[int, int]]:
    """Prim's algorithm on ``(C, C)`` weights from ``root``: ``(parent, child)`` edges.

    Raises ``ValueError`` listing the unreachable cameras if the graph is disconnected.
    """
    C = shared.shape[0]
    in_tree = np.zeros(C, dtype=bool)
    in_tree[root] = True
    edges = []
    while not in_tree.all():
        w = np.where(in_tree[:, None] & ~in_tree[None, :], shared, 0)
        a, b = np.unravel_index(np.argmax(w), w.shape)
        if w[a, b] <= 0:
            raise ValueError(f"cameras {np.flatnonzero(~in_tree).tolist()} are not connected to camera {root}")
        edges.append((int(a), int(b)))
        in_tree[b] = True
    return edges


def initial_rig(poses: BoardPoses, camera_names: list[str], reference: int = 0) -> InitialRig:
    """Chain pairwise relative poses into a rig (see module docstring).

    Raises
    ------
    DisconnectedCamerasError
        Some cameras share no view, directly or through other cameras, with the reference.
    """
    valid = poses.valid
    C, V = valid.shape
    shared = (valid[:, None, :] & valid[None, :, :]).sum(axis=2)
    np.fill_diagonal(shared, 0)
    groups = connected_groups(shared)
    if len(groups) > 1:
        raise DisconnectedCamerasError([[camera_names[i] for i in g] for g in groups], camera_names[reference])
    tree = maximum_spanning_tree(shared, reference)
    R_cw = np.full((C, 3, 3), np.nan)
    t_cw = np.full((C, 3), np.nan)
    R_cw[reference], t_cw[reference] = np.eye(3), np.zeros(3)
    for parent, child in tree:
        both = valid[parent] & valid[child]
        # T_child_parent = T_child_board @ inv(T_parent_board), one per shared view.
        Rpb_inv, tpb_inv = invert_pose(poses.R[parent, both], poses.t[parent, both])
        R_rel, t_rel = compose_poses(poses.R[child, both], poses.t[child, both], Rpb_inv, tpb_inv)
        R_cp, t_cp = mean_pose(R_rel, t_rel)
        R_cw[child], t_cw[child] = compose_poses(R_cp, t_cp, R_cw[parent], t_cw[parent])
    # World-from-board per view: average over the cameras that saw it.
    R_wb = np.full((V, 3, 3), np.nan)
    t_wb = np.full((V, 3), np.nan)
    R_wc, t_wc = invert_pose(R_cw, t_cw)
    for v in np.flatnonzero(valid.any(axis=0)):
        cams = np.flatnonzero(valid[:, v])
        Rw, tw = compose_poses(R_wc[cams], t_wc[cams], poses.R[cams, v], poses.t[cams, v])
        R_wb[v], t_wb[v] = mean_pose(Rw, tw)
    return InitialRig(R_cw, t_cw, R_wb, t_wb, reference, tree)
