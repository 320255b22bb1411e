"""Exact ground truth of a rendered sequence, and its on-disk format.

On disk (directory ``ground_truth/`` of a render):

``ground_truth.npz`` (numpy, uncompressed arrays; shapes with F frames, C cameras,
M markers, J joints, P props, L lights):

=====================  ==================  ==========================================
key                    shape / dtype        meaning (units)
=====================  ==================  ==========================================
times                  (F,) float64         mid-exposure timestamp of each frame (s)
K                      (C, 3, 3)            intrinsics (px)
dist                   (C, 5)               OpenCV distortion k1 k2 p1 p2 k3
R                      (C, 3, 3)            world-to-camera rotation
t                      (C, 3)               world-to-camera translation (m)
image_size             (2,) int             width, height (px)
markers_3d             (F, M, 3)            marker centres, world frame (m)
markers_2d             (F, C, M, 2)         cv2.projectPoints of markers_3d (px)
marker_visible         (F, C, M) bool       in the image and at least 75 % of its
                                            area unoccluded in the id render
marker_visible_frac    (F, C, M) float      visible area / expected area
qpos                   (F, 40)              humanoid MuJoCo qpos (root xyz, quat wxyz,
                                            33 hinges, rad)
joint_centres          (F, J, 3)            body origins = joint centres (m)
prop_poses             (F, P, 4, 4)         prop body poses (world, m)
light_intensity        (F, L)               intensity of each light at the frame time
n_subframes            (F,) int             shutter sub-frames rendered per frame
camera_times           (F, C)               only with unsynchronised ``[sensor.clock]``:
                                            each camera's frames' true mid-exposure
                                            instants (``times`` = camera 0's) (s)
camera_timestamps      (F, C)               ... and each camera's own timestamps (s)
clock_offset_s         (C,)                 ... true time at each clock's zero (s)
clock_rate             (C,)                 ... true seconds per clock second
readout_s              ()                   only with a rolling shutter (``sensor.readout_ms``
                                            > 0): row ``y`` of a frame (``H`` rows) is
                                            exposed at its time + ``y / H * readout_s``
markers_2d_rolling     (F, C, M, 2)         ... where that row-time model puts each marker:
                                            ``uv = project(X(t + v / H * readout_s))``
                                            (``markers_2d`` stays at the frame's time)
=====================  ==================  ==========================================

``ids.npz`` (compressed): ``cam_<name>`` (F, H, W) int16 id maps at mid-exposure
(:mod:`simbench.render.ids`: 0 background, 1 body, 2 set, 100+k shirt patch k,
1000+m marker m).

``meta.json``: camera, marker, joint, hinge, prop and light names, fps, scenario
name and hash, and this table's units.

:func:`load_ground_truth` reads it back into a :class:`GroundTruth`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocap.calibration import Calibration, Camera
from simbench.errors import SimbenchInputError

FORMAT_VERSION = 1


@dataclass
class GroundTruth:
    times: np.ndarray
    camera_names: list[str]
    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    image_size: tuple[int, int]
    marker_names: list[str]
    markers_3d: np.ndarray
    markers_2d: np.ndarray
    marker_visible: np.ndarray
    marker_visible_frac: np.ndarray
    joint_names: list[str]
    hinge_names: list[str]
    qpos: np.ndarray
    joint_centres: np.ndarray
    prop_names: list[str]
    prop_poses: np.ndarray
    light_names: list[str]
    light_intensity: np.ndarray
    n_subframes: np.ndarray
    fps: float
    scenario_name: str = ""
    scenario_hash: str = ""
    id_maps: dict[str, np.ndarray] = field(default_factory=dict)
    # Only with a [sensor.clock] whose cameras are not synchronised (simbench.stage.clocks);
    # ``times`` and the 3D truth are then camera 0's frames' instants.
    camera_times: np.ndarray | None = None       # (F, C) true mid-exposure instant of each camera's frame (s)
    camera_timestamps: np.ndarray | None = None  # (F, C) each camera's own timestamp of its frame (s)
    clock_offset_s: np.ndarray | None = None     # (C,) true time at each camera clock's zero (s)
    clock_rate: np.ndarray | None = None         # (C,) true seconds per clock second
    # Only with a rolling shutter (sensor.readout_ms > 0): the row-time model and where it puts the markers.
    readout_s: float = 0.0
    markers_2d_rolling: np.ndarray | None = None  # (F, C, M, 2) px

    @property
    def n_frames(self) -> int:
        return len(self.times)

    def calibration(self) -> Calibration:
        """The exact cameras as the pipeline's :class:`~mocap.calibration.Calibration`."""
        return Calibration(tuple(
            Camera(n, self.image_size, K, d, R, t)
            for n, K, d, R, t in zip(self.camera_names, self.K, self.dist, self.R, self.t)
        ))

    # ------------------------------------------------------------------ I/O
    _ARRAYS = ("times", "K", "dist", "R", "t", "markers_3d", "markers_2d", "marker_visible", "marker_visible_frac",
               "qpos", "joint_centres", "prop_poses", "light_intensity", "n_subframes")
    _CLOCK_ARRAYS = ("camera_times", "camera_timestamps", "clock_offset_s", "clock_rate")

    def save(self, directory: str | Path) -> None:
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        arrays = {k: getattr(self, k) for k in self._ARRAYS}
        arrays.update({k: getattr(self, k) for k in self._CLOCK_ARRAYS if getattr(self, k) is not None})
        if self.readout_s > 0:
            arrays["readout_s"] = np.float64(self.readout_s)
            arrays["markers_2d_rolling"] = self.markers_2d_rolling
        arrays["image_size"] = np.asarray(self.image_size)
        np.savez(d / "ground_truth.npz", **arrays)
        if self.id_maps:
            np.savez_compressed(d / "ids.npz", **{f"cam_{k}": v for k, v in self.id_maps.items()})
        meta = {
            "format_version": FORMAT_VERSION,
            "scenario_name": self.scenario_name,
            "scenario_hash": self.scenario_hash,
            "fps": self.fps,
            "camera_names": self.camera_names,
            "marker_names": self.marker_names,
            "joint_names": self.joint_names,
            "hinge_names": self.hinge_names,
            "prop_names": self.prop_names,
            "light_names": self.light_names,
            "units": {"length": "m", "angle": "rad", "time": "s", "pixels": "px, OpenCV convention (pixel centres at integers)"},
        }
        (d / "meta.json").write_text(json.dumps(meta, indent=2))


def load_ground_truth(directory: str | Path, load_id_maps: bool = False) -> GroundTruth:
    """Read a ``ground_truth/`` directory written by ``simbench render`` or ``simbench run``."""
    d = Path(directory)
    if (d / "ground_truth").is_dir():
        d = d / "ground_truth"
    npz, meta_path = d / "ground_truth.npz", d / "meta.json"
    for p in (npz, meta_path):
        if not p.is_file():
            raise SimbenchInputError(f"{p}: missing; pass the output directory of `simbench render` (it holds ground_truth/)")
    meta = json.loads(meta_path.read_text())
    if meta.get("format_version") != FORMAT_VERSION:
        raise SimbenchInputError(f"{meta_path}: format_version {meta.get('format_version')!r}, this simbench reads {FORMAT_VERSION}; re-render")
    with np.load(npz) as z:
        arrays = {k: z[k] for k in z.files}
    id_maps = {}
    if load_id_maps and (d / "ids.npz").is_file():
        with np.load(d / "ids.npz") as z:
            id_maps = {k[4:]: z[k] for k in z.files}
    size = arrays.pop("image_size")
    if "readout_s" in arrays:
        arrays["readout_s"] = float(arrays["readout_s"])
    return GroundTruth(
        camera_names=meta["camera_names"], marker_names=meta["marker_names"], joint_names=meta["joint_names"],
        hinge_names=meta["hinge_names"], prop_names=meta["prop_names"], light_names=meta["light_names"],
        image_size=(int(size[0]), int(size[1])), fps=float(meta["fps"]), scenario_name=meta["scenario_name"],
        scenario_hash=meta["scenario_hash"], id_maps=id_maps, **arrays,
    )
