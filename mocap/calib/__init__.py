"""Camera calibration building blocks (boards, intrinsics, extrinsics, bundle adjustment, wand).

The user-facing entry point is :func:`mocap.calibrate.calibrate_cameras`.
"""

from mocap.calib.board_detection import BoardDetection, DetectionSettings, detect_board
from mocap.calib.boards import BoardSpec, BoardTextureLayout, board_object_points, board_texture_layout, render_board_texture
from mocap.calib.bundle_adjustment import BundleAdjustmentOptions, BundleAdjustmentResult, bundle_adjust
from mocap.calib.errors import (
    BoardNotFoundError,
    BundleAdjustmentError,
    CalibrationError,
    DegenerateViewsError,
    DisconnectedCamerasError,
    ViewFailure,
    WandError,
)
from mocap.calib.intrinsics import IntrinsicsOptions, IntrinsicsResult, calibrate_intrinsics
from mocap.calib.observations import BoardObservations, WandObservations
from mocap.calib.wand import WandSpec, label_collinear_wand

__all__ = [
    "BoardDetection", "DetectionSettings", "detect_board",
    "BoardSpec", "BoardTextureLayout", "board_object_points", "board_texture_layout", "render_board_texture",
    "BundleAdjustmentOptions", "BundleAdjustmentResult", "bundle_adjust",
    "BoardNotFoundError", "BundleAdjustmentError", "CalibrationError", "DegenerateViewsError",
    "DisconnectedCamerasError", "ViewFailure", "WandError",
    "IntrinsicsOptions", "IntrinsicsResult", "calibrate_intrinsics",
    "BoardObservations", "WandObservations", "WandSpec", "label_collinear_wand",
]
