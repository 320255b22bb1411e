"""What every exchange format shares: the axis conventions, units, the frame rate (atomic writes: :mod:`mocap.atomic_files`).

World: Z up, metres (``docs/humanoid_spec.md``). OpenSim's TRC axes are Y up, ``(x, z, -y)``
of the world; Pose2Sim's are Y up, ``(y, z, x)`` of the world (see :mod:`mocap.exports`).
"""

from __future__ import annotations

import numpy as np

from mocap.errors import MocapInputError

# (x, y, z)_opensim = P @ (x, y, z)_world: -90 deg about X (Z up -> Y up, Y left -> Z right).
_Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
_UNIT_TO_M = {"mm": 1e-3, "m": 1.0, "cm": 1e-2, "dm": 0.1, "in": 0.0254}


def world_to_opensim(xyz: np.ndarray) -> np.ndarray:
    """``(..., 3)`` world (Z up) -> OpenSim axes (Y up, Z right): ``(x, z, -y)``."""
    return np.asarray(xyz, dtype=np.float64) @ _Z_UP_TO_Y_UP.T


def opensim_to_world(xyz: np.ndarray) -> np.ndarray:
    """Inverse of :func:`world_to_opensim`."""
    return np.asarray(xyz, dtype=np.float64) @ _Z_UP_TO_Y_UP


# Pose2Sim's TRC files (its ``zup2yup``: "X->Y, Y->Z, Z->X") hold ``(y, z, x)`` of its Z-up
# calibration world: Y up like OpenSim's, but turned 90 deg about the vertical from
# :func:`world_to_opensim`'s ``(x, z, -y)``. Rows: world axes from the file's (world = M @ file).
_POSE2SIM_TO_WORLD = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def world_to_pose2sim(xyz: np.ndarray) -> np.ndarray:
    """``(..., 3)`` world (Z up) -> Pose2Sim's TRC axes (Y up): ``(y, z, x)``."""
    return np.asarray(xyz, dtype=np.float64) @ _POSE2SIM_TO_WORLD


def pose2sim_to_world(xyz: np.ndarray) -> np.ndarray:
    """Inverse of :func:`world_to_pose2sim`: a Pose2Sim TRC's ``(X, Y, Z)`` -> world ``(Z, X, Y)``."""
    return np.asarray(xyz, dtype=np.float64) @ _POSE2SIM_TO_WORLD.T


def _rate(traj_times: np.ndarray, rate_hz: float | None, what: str) -> float:
    if rate_hz is not None:
        rate = float(rate_hz)
    elif len(traj_times) >= 2:
        rate = float(1.0 / np.median(np.diff(traj_times)))
    else:
        rate = float("nan")
    if not (np.isfinite(rate) and rate > 0):
        raise MocapInputError(f"{what}: cannot tell the frame rate from {len(traj_times)} timestamps; pass rate_hz=")
    return rate
