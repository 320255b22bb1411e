"""Standard motion-capture files: C3D, TRC (OpenSim), CSV for markers; BVH for the solved skeleton.

Every writer writes a temporary file next to the target and renames it into place, so an
error never leaves a half-written file behind (and an existing file stays intact).

Axes and units
--------------
Inside the pipeline: world Z up, metres, seconds (``docs/humanoid_spec.md``). Files:

* **C3D** (ezc3d): world axes (Z up), millimetres (``POINT:UNITS = "mm"``), ``POINT:RATE``,
  ``POINT:LABELS``. The 4th word of each point holds the residual as C3D defines it: ``-1``
  for a gap, ``0`` for a point filled by interpolation, ``> 0`` for a measured point. The
  pipeline's residual is the mean *reprojection* residual in pixels, so that is what is
  stored (in steps of 0.01 px, truncated, saturating at 2.55 px, ``POINT:SCALE = -0.01``), and a
  ``SIMBENCH`` parameter group says so (``RESIDUAL_UNITS = "px"``) and keeps the exact time
  of the first frame (``FIRST_TIME_S``). Other programs ignore that group.
* **TRC** (OpenSim): millimetres, OpenSim's axes by default: ``X`` forward, ``Y`` up, ``Z``
  to the subject's right, i.e. ``(x, y, z)_trc = (x, z, -y)_world`` (a rotation of -90 deg
  about X; our humanoid faces +X, as OpenSim models do). ``axes="world"`` keeps Z up.
  Gaps are written ``NaN``, which OpenSim reads as missing.
* **CSV**: world axes, millimetres: ``frame, time_s``, then ``<label>_x_mm, <label>_y_mm,
  <label>_z_mm`` per marker, then ``<label>_filled`` (0/1) per marker; gaps are empty fields.
* **BVH**: Y up by default (the usual BVH convention; ``up_axis="z"`` keeps the world axes),
  centimetres, angles in degrees; see :func:`write_bvh`.

Reading other systems' files
----------------------------
:func:`read_c3d` and :func:`read_trc` return a :class:`CaptureTrajectories`: world axes
(Z up), metres, seconds, and by default only the **physical markers**. Model outputs
(Plug-in Gait angles, forces, moments, powers, segment axes, joint centres), virtual and
unlabelled points, entries empty for the whole trial and repeated labels are set aside,
each with the reason, in ``CaptureTrajectories.set_aside``; the file's units and up axis
and how the up axis was decided are kept too. See :func:`read_c3d` for the rules.

The formats live one per module: :mod:`mocap.exports.c3d`, :mod:`mocap.exports.trc`,
:mod:`mocap.exports.csv_table`, :mod:`mocap.exports.bvh`; what the readers share in
:mod:`mocap.exports.capture_files`, the axes and atomic writes in ``_common``. Import the
public names from here.
"""

from mocap.exports._common import opensim_to_world, pose2sim_to_world, world_to_opensim, world_to_pose2sim
from mocap.exports.any_capture import CAPTURE_SUFFIXES, read_capture
from mocap.exports.bvh import write_bvh
from mocap.exports.c3d import read_c3d, write_c3d
from mocap.exports.capture_files import CaptureTrajectories
from mocap.exports.csv_table import read_csv, write_csv
from mocap.exports.trc import read_trc, write_trc

__all__ = [
    "CAPTURE_SUFFIXES",
    "read_capture",
    "CaptureTrajectories",
    "write_c3d",
    "read_c3d",
    "write_trc",
    "read_trc",
    "write_csv",
    "read_csv",
    "write_bvh",
    "world_to_opensim",
    "opensim_to_world",
    "world_to_pose2sim",
    "pose2sim_to_world",
]
