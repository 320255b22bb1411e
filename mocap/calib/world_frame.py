"""Choose the world frame of a calibrated rig.

Calibration produces the rig in the reference camera's frame. Users want a world with
the floor at ``z = 0`` and ``z`` up: put a board flat on the floor, take one synchronised
view of it, and that view's board pose defines the world:

* origin: the board origin (the first inner corner of a checkerboard, the outer
  top-left corner of a ChArUco board; see :mod:`mocap.calib.boards`),
* ``+x``: along the board's first row of corners (board ``+x``),
* ``+z``: up, out of the printed face (board ``-z``),
* ``+y = z cross x`` (board ``-y``).

All transforms map *old* world coordinates to *new* ones: ``x_new = R @ x_old + t``.
"""

from __future__ import annotations

import numpy as np

from mocap.calib.geometry import invert_pose

#: New-world-from-board rotation for a board lying printed face up.
FLOOR_FROM_BOARD = np.diag([1.0, -1.0, -1.0])


def floor_transform(R_wb: np.ndarray, t_wb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """New-from-old world transform making a floor board's pose the world frame.

    Parameters
    ----------
    R_wb, t_wb : (3, 3), (3,)
        The floor board's pose in the current world (world-from-board), metres.
    """
    R_bw, t_bw = invert_pose(np.asarray(R_wb, dtype=np.float64), np.asarray(t_wb, dtype=np.float64))
    return FLOOR_FROM_BOARD @ R_bw, FLOOR_FROM_BOARD @ t_bw


def camera_transform(R_cw: np.ndarray, t_cw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """New-from-old world transform making a camera's frame the world (x right, y down, z forward)."""
    return np.asarray(R_cw, dtype=np.float64), np.asarray(t_cw, dtype=np.float64)


def transform_cameras(R_cw: np.ndarray, t_cw: np.ndarray, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera poses ``(C, 3, 3), (C, 3)`` re-expressed after ``x_new = R x_old + t``."""
    R_new = R_cw @ R.T
    return R_new, t_cw - np.einsum("cij,j->ci", R_new, t)


def transform_poses(R_wx: np.ndarray, t_wx: np.ndarray, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-from-object poses ``(n, 3, 3), (n, 3)`` re-expressed in the new world."""
    return R @ R_wx, t_wx @ R.T + t


def transform_points(p: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Points ``(..., 3)`` to the new world."""
    return np.asarray(p) @ R.T + t
