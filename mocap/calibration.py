"""Camera calibration: the one type every stage of the pipeline agrees on.

A :class:`Camera` is a pinhole with OpenCV's Brown-Conrady distortion
(``k1 k2 p1 p2 k3``) and a world-to-camera rigid transform ``x_cam = R @ x_world + t``
(metres). A :class:`Calibration` is an ordered group of cameras, in the spirit of
aniposelib's ``CameraGroup``: arrays are ``p3ds`` of shape ``(N, 3)`` in metres and
``p2ds`` of shape ``(C, N, 2)`` in pixels.

The bench turns its exact virtual cameras into this same type, so the pipeline cannot
tell a virtual rig from a real one.

File formats
------------
* OpenCV YAML (``cv2.FileStorage``): ``camera_count`` then, per camera ``i``,
  ``camera_i_name``, ``camera_i_image_size`` (width, height), ``camera_i_K``,
  ``camera_i_dist``, ``camera_i_R``, ``camera_i_t``.  A single-camera file written by
  OpenCV's ``calibration.cpp`` sample (``camera_matrix``, ``distortion_coefficients``,
  ``image_width``, ``image_height``) also loads, with identity extrinsics.
* anipose-style TOML: one table per camera with ``name``, ``size``, ``matrix``,
  ``distortions``, ``rotation`` (Rodrigues vector) and ``translation``.
"""

from __future__ import annotations

import os
import tomllib
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Sequence

import cv2
import numpy as np
import tomli_w

from mocap.atomic_files import atomic_target, atomic_write_text
from mocap.errors import CalibrationFileError


@contextmanager
def opencv_yaml_writer(path: Path) -> Iterator[cv2.FileStorage]:
    """An OpenCV ``FileStorage`` writing YAML to ``path`` once the block has written everything
    (an error leaves ``path`` as it was; :func:`mocap.atomic_files.atomic_target`)."""
    with atomic_target(path, ".yml") as tmp:
        fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
        try:
            yield fs
        finally:
            fs.release()


def _as_matrix(value, shape: tuple[int, ...], what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.size != int(np.prod(shape)):
        raise ValueError(f"{what} must have {int(np.prod(shape))} values, got shape {arr.shape}")
    return arr.reshape(shape)


def _refuse_unusable(path: Path, cam: "Camera", fields: dict[str, str]) -> "Camera":
    """``cam`` as read from ``path`` if every stage can use it, else a :class:`CalibrationFileError`
    naming the file's field (``fields`` maps ``K``, ``dist``, ``R``, ``t`` to the file's keys):
    finite numbers, positive focal lengths and image size, K's last row [0, 0, 1], R a rotation.
    A NaN or a singular matrix would otherwise fail deep inside triangulation, and a non-rotation
    would reconstruct nothing without saying why."""
    for what in ("K", "dist", "R", "t"):
        arr = getattr(cam, what)
        if not np.isfinite(arr).all():
            raise CalibrationFileError(path, fields[what], f"value {arr.ravel().tolist()} is not all finite numbers",
                                       "write it with finite numbers (recalibrate: `mocap calibrate`)")
    if not (cam.K[0, 0] > 0 and cam.K[1, 1] > 0) or not np.allclose(cam.K[2], [0.0, 0.0, 1.0]):
        raise CalibrationFileError(path, fields["K"], f"value {cam.K.ravel().tolist()}",
                                   "K must be [fx, s, cx, 0, fy, cy, 0, 0, 1] with positive focal lengths fx, fy (pixels)")
    if not (np.allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-4) and np.linalg.det(cam.R) > 0):
        raise CalibrationFileError(path, fields["R"], f"value {cam.R.ravel().tolist()} is not a rotation matrix",
                                   "R must be orthonormal with determinant +1 (world to camera)")
    if not (cam.size[0] > 0 and cam.size[1] > 0):
        raise CalibrationFileError(path, fields["size"], f"value {list(cam.size)}", "the image size must be positive pixels")
    return cam


def _camera_from_table(path: Path, key: str, tab: dict) -> "Camera":
    """One camera table of an anipose or Pose2Sim TOML file (:meth:`Calibration.load_toml`)."""
    for field_name in ("size", "matrix", "distortions", "rotation", "translation"):
        if field_name not in tab:
            raise CalibrationFileError(path, f"{key}.{field_name}", "missing",
                                       "camera tables need size, matrix, distortions, rotation, translation")
    if tab.get("fisheye", False):  # OpenCV's equidistant model: read as a pinhole it would be silently wrong
        raise CalibrationFileError(path, f"{key}.fisheye", f"value {tab['fisheye']!r}",
                                   "fisheye (OpenCV's equidistant model) cannot be read as the pinhole + k1 k2 p1 p2 k3 model "
                                   "the bench and mocap use; recalibrate with fisheye = false")
    try:
        dist = np.asarray(tab["distortions"], dtype=np.float64).ravel()
        if dist.size not in (4, 5):
            raise ValueError(f"{dist.size} distortion terms (the pinhole model has 4 or 5: k1 k2 p1 p2 [k3])")
        rvec = np.asarray(tab["rotation"], dtype=np.float64)
        if rvec.size != 3:
            raise ValueError(f"rotation has {rvec.size} values (a Rodrigues vector has 3)")
        R = cv2.Rodrigues(rvec.reshape(3, 1))[0]
        size = tab["size"]
        if len(size) != 2:
            raise ValueError(f"size has {len(size)} values; it is [width, height]")
        cam = Camera(str(tab.get("name", key)), (int(size[0]), int(size[1])), tab["matrix"], dist, R, tab["translation"])
    except (ValueError, TypeError, cv2.error) as exc:
        raise CalibrationFileError(path, key, str(exc).splitlines()[0],
                                   "check the array sizes (matrix 3x3, distortions 4 or 5, rotation 3, translation 3)") from None
    fields = {"K": f"{key}.matrix", "dist": f"{key}.distortions", "R": f"{key}.rotation", "t": f"{key}.translation",
              "size": f"{key}.size"}
    return _refuse_unusable(path, cam, fields)


@dataclass(frozen=True, eq=False)
class Camera:
    """One calibrated camera.

    Attributes
    ----------
    name : str
    size : (int, int)
        Image ``(width, height)`` in pixels.
    K : (3, 3) float
        Intrinsic matrix in pixels.
    dist : (5,) float
        OpenCV distortion ``k1, k2, p1, p2, k3``.
    R : (3, 3) float
        World-to-camera rotation.
    t : (3,) float
        World-to-camera translation in metres.
    """

    name: str
    size: tuple[int, int]
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        object.__setattr__(self, "K", _as_matrix(self.K, (3, 3), f"camera {self.name!r} K"))
        d = np.zeros(5)
        src = np.asarray(self.dist, dtype=np.float64).ravel()
        if src.size > 5:
            raise ValueError(f"camera {self.name!r}: only the 5-term OpenCV model (k1 k2 p1 p2 k3) is supported, got {src.size} terms")
        d[: src.size] = src
        object.__setattr__(self, "dist", d)
        object.__setattr__(self, "R", _as_matrix(self.R, (3, 3), f"camera {self.name!r} R"))
        object.__setattr__(self, "t", _as_matrix(self.t, (3,), f"camera {self.name!r} t"))
        object.__setattr__(self, "size", (int(self.size[0]), int(self.size[1])))

    # ------------------------------------------------------------------ geometry
    @property
    def rvec(self) -> np.ndarray:
        """Rodrigues vector of ``R``, shape (3,)."""
        return cv2.Rodrigues(self.R)[0].ravel()

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, metres, shape (3,)."""
        return -self.R.T @ self.t

    @property
    def mean_focal_px(self) -> float:
        """Mean of the two focal lengths ``(fx + fy) / 2``, pixels: the scale from
        normalised image coordinates (or metres over depth) to pixels."""
        return 0.5 * (self.K[0, 0] + self.K[1, 1])

    @property
    def projection_matrix(self) -> np.ndarray:
        """``K [R | t]``, shape (3, 4), for undistorted pixel coordinates."""
        return self.K @ np.hstack([self.R, self.t[:, None]])

    def to_camera(self, p3ds: np.ndarray) -> np.ndarray:
        """World points ``(N, 3)`` to camera coordinates ``(N, 3)``."""
        return np.asarray(p3ds, dtype=np.float64) @ self.R.T + self.t

    def project(self, p3ds: np.ndarray) -> np.ndarray:
        """Project world points ``(N, 3)`` metres to distorted pixels ``(N, 2)``.

        Exactly ``cv2.projectPoints``. Points behind the camera come back as NaN.
        NaN inputs give NaN outputs.
        """
        p = np.asarray(p3ds, dtype=np.float64).reshape(-1, 3)
        out = np.full((p.shape[0], 2), np.nan)
        ok = np.isfinite(p).all(axis=1)
        if ok.any():
            z = self.to_camera(p[ok])[:, 2]
            uv, _ = cv2.projectPoints(p[ok], self.rvec, self.t, self.K, self.dist)
            uv = uv.reshape(-1, 2)
            uv[z <= 0] = np.nan
            out[ok] = uv
        return out

    def undistort_pixels(self, p2ds: np.ndarray) -> np.ndarray:
        """Distorted pixels ``(N, 2)`` to undistorted pixels ``(N, 2)`` (same K)."""
        p = np.asarray(p2ds, dtype=np.float64).reshape(-1, 2)
        out = np.full_like(p, np.nan)
        ok = np.isfinite(p).all(axis=1)
        if ok.any():
            # Iterative inversion with a tight criterion: the default (5 iterations)
            # leaves ~0.1 px error at the image corners for strong distortion.
            und = cv2.undistortPoints(
                p[ok].reshape(-1, 1, 2), self.K, self.dist, None, None, self.K,
                (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-12),
            )
            out[ok] = und.reshape(-1, 2)
        return out

    def normalized_rays(self, p2ds: np.ndarray) -> np.ndarray:
        """Distorted pixels ``(N, 2)`` to unit viewing rays in world coordinates ``(N, 3)``."""
        und = self.undistort_pixels(p2ds)
        xy1 = np.column_stack([und, np.ones(len(und))]) @ np.linalg.inv(self.K).T
        rays = xy1 @ self.R  # R.T applied to each row
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)

    def in_image(self, p2ds: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """Boolean ``(N,)``: pixel inside the image with ``margin_px`` to spare."""
        p = np.asarray(p2ds, dtype=np.float64).reshape(-1, 2)
        w, h = self.size
        with np.errstate(invalid="ignore"):
            return (
                (p[:, 0] >= -0.5 + margin_px) & (p[:, 0] <= w - 0.5 - margin_px)
                & (p[:, 1] >= -0.5 + margin_px) & (p[:, 1] <= h - 0.5 - margin_px)
            )

    def replace(self, **changes) -> "Camera":
        kw = dict(name=self.name, size=self.size, K=self.K, dist=self.dist, R=self.R, t=self.t)
        kw.update(changes)
        return Camera(**kw)


@dataclass(frozen=True, eq=False)
class Calibration:
    """An ordered group of :class:`Camera` (the rig)."""

    cameras: tuple[Camera, ...]

    def __post_init__(self) -> None:
        cams = tuple(self.cameras)
        if not cams:
            raise ValueError("a Calibration needs at least one camera")
        names = [c.name for c in cams]
        if len(set(names)) != len(names):
            raise ValueError(f"camera names must be unique, got {names}")
        object.__setattr__(self, "cameras", cams)

    def __len__(self) -> int:
        return len(self.cameras)

    def __iter__(self) -> Iterator[Camera]:
        return iter(self.cameras)

    def __getitem__(self, key: int | str) -> Camera:
        if isinstance(key, str):
            for c in self.cameras:
                if c.name == key:
                    return c
            raise KeyError(f"no camera named {key!r}; cameras are {self.names}")
        return self.cameras[key]

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.cameras]

    @property
    def mean_focal_px(self) -> np.ndarray:
        """``(C,)`` :attr:`Camera.mean_focal_px` of every camera, pixels."""
        return np.array([c.mean_focal_px for c in self.cameras])

    def project(self, p3ds: np.ndarray) -> np.ndarray:
        """World points ``(N, 3)`` to pixels in every camera, ``(C, N, 2)``."""
        return np.stack([c.project(p3ds) for c in self.cameras])

    # ------------------------------------------------------------------ OpenCV YAML
    def save_opencv_yaml(self, path: str | os.PathLike) -> None:
        """Write OpenCV ``FileStorage`` YAML (atomically: temp file then rename)."""
        path = Path(path)
        with opencv_yaml_writer(path) as fs:
            fs.write("camera_count", len(self.cameras))
            for i, c in enumerate(self.cameras):
                fs.write(f"camera_{i}_name", c.name)
                fs.write(f"camera_{i}_image_size", np.array(c.size, dtype=np.int32).reshape(1, 2))
                fs.write(f"camera_{i}_K", c.K)
                fs.write(f"camera_{i}_dist", c.dist.reshape(1, 5))
                fs.write(f"camera_{i}_R", c.R)
                fs.write(f"camera_{i}_t", c.t.reshape(3, 1))

    @classmethod
    def load_opencv_yaml(cls, path: str | os.PathLike) -> "Calibration":
        path = Path(path)
        if not path.is_file():
            raise CalibrationFileError(path, "", "file not found", "pass the path of a calibration .yml/.yaml written by `mocap calibrate` or OpenCV")
        if path.stat().st_size == 0:
            raise CalibrationFileError(path, "", "the file is empty", "pass a calibration written by `mocap calibrate` or OpenCV")
        try:
            raw = path.read_bytes()
            if raw.startswith(b"\xef\xbb\xbf"):  # a UTF-8 byte-order mark (Windows editors): FileStorage refuses it
                fs = cv2.FileStorage(raw[3:].decode("utf-8", "replace"), cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
            else:
                fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        except (cv2.error, SystemError) as exc:  # malformed YAML (OpenCV 5 may wrap its error in a SystemError)
            first = str(getattr(exc, "err", "") or "").strip().splitlines()[:1]
            why = f" ({first[0]})" if first else ""
            raise CalibrationFileError(path, "", f"not readable as OpenCV YAML{why}", "check the file is an OpenCV FileStorage YAML") from None
        try:
            def node(key: str, required: bool = True):
                n = fs.getNode(key)
                if n.empty():
                    if required:
                        raise CalibrationFileError(path, key, "missing", "write it with Calibration.save_opencv_yaml or `mocap calibrate`")
                    return None
                return n

            count_node = node("camera_count", required=False)
            if count_node is None:
                # Single camera in the layout of OpenCV's calibration sample.
                K = node("camera_matrix").mat()
                dist = node("distortion_coefficients").mat()
                w = int(node("image_width").real())
                h = int(node("image_height").real())
                fields = {"K": "camera_matrix", "dist": "distortion_coefficients", "R": "camera_matrix", "t": "camera_matrix",
                          "size": "image_width"}
                return cls((_refuse_unusable(path, Camera(path.stem, (w, h), K, dist), fields),))
            n = int(count_node.real())
            if n < 1:
                raise CalibrationFileError(path, "camera_count", f"value {n}", "must be >= 1")
            cams = []
            for i in range(n):
                name = node(f"camera_{i}_name").string()
                size = node(f"camera_{i}_image_size").mat().ravel()
                K = node(f"camera_{i}_K").mat()
                dist = node(f"camera_{i}_dist").mat()
                R = node(f"camera_{i}_R").mat()
                t = node(f"camera_{i}_t").mat()
                for key, arr, shape in ((f"camera_{i}_K", K, 9), (f"camera_{i}_R", R, 9), (f"camera_{i}_t", t, 3)):
                    if arr is None or np.asarray(arr).size != shape:
                        raise CalibrationFileError(path, key, f"value {None if arr is None else np.asarray(arr).shape}", f"needs {shape} numbers")
                fields = {k: f"camera_{i}_{k}" for k in ("K", "dist", "R", "t")} | {"size": f"camera_{i}_image_size"}
                cams.append(_refuse_unusable(path, Camera(name, (int(size[0]), int(size[1])), K, dist, R, t), fields))
            return cls(tuple(cams))
        finally:
            fs.release()

    # ------------------------------------------------------------------ anipose TOML
    def save_toml(self, path: str | os.PathLike) -> None:
        """Write an anipose-style calibration TOML (atomically)."""
        doc: dict = {}
        for i, c in enumerate(self.cameras):
            doc[f"cam_{i}"] = {
                "name": c.name,
                "size": [int(c.size[0]), int(c.size[1])],
                "matrix": c.K.tolist(),
                "distortions": c.dist.tolist(),
                "rotation": c.rvec.tolist(),
                "translation": c.t.tolist(),
            }
        doc["metadata"] = {"units": "metres", "convention": "x_cam = R(rotation) @ x_world + translation"}
        atomic_write_text(path, tomli_w.dumps(doc))

    @classmethod
    def load_toml(cls, path: str | os.PathLike) -> "Calibration":
        """An anipose ``calibration.toml`` or a Pose2Sim ``Calib.toml``: every table but
        ``[metadata]`` is a camera, in file order (Pose2Sim's), which for anipose's keys
        (``cam_0`` ...) is their numeric order. A fisheye camera, 6+ distortion terms, a bad
        size, non-finite numbers, a bad K or a non-rotation are refused naming the table."""
        path = Path(path)
        if not path.is_file():
            raise CalibrationFileError(path, "", "file not found", "pass the path of a calibration .toml")
        try:
            doc = tomllib.loads(path.read_bytes().decode("utf-8-sig"))  # a byte-order mark first is not TOML
        except UnicodeDecodeError as exc:
            raise CalibrationFileError(path, "", f"byte {exc.start} is not UTF-8", "save the file as UTF-8 text") from None
        except tomllib.TOMLDecodeError as exc:
            raise CalibrationFileError(path, "", f"invalid TOML: {exc}", "fix the syntax at the position given") from None
        keys = [k for k, v in doc.items() if k != "metadata" and isinstance(v, dict)]
        if all(k.startswith("cam_") and k[4:].isdigit() for k in keys):
            keys.sort(key=lambda k: int(k[4:]))  # anipose: cam_0, cam_1, ..., cam_10 (not string order)
        cams = [_camera_from_table(path, k, doc[k]) for k in keys]
        if not cams:
            raise CalibrationFileError(path, "cam_0", "missing", "the file has no camera tables ([cam_0] or [<camera name>])")
        try:
            return cls(tuple(cams))
        except ValueError as exc:
            raise CalibrationFileError(path, "name", str(exc), "give every camera its own name") from None

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Calibration":
        """Load by extension: ``.toml`` or ``.yml``/``.yaml``."""
        suffix = Path(path).suffix.lower()
        if suffix == ".toml":
            return cls.load_toml(path)
        if suffix in (".yml", ".yaml", ".xml", ".json"):
            return cls.load_opencv_yaml(path)
        raise CalibrationFileError(Path(path), "", f"unknown extension {suffix!r}", "use .toml (anipose) or .yml/.yaml (OpenCV)")

    def save(self, path: str | os.PathLike) -> None:
        if Path(path).suffix.lower() == ".toml":
            self.save_toml(path)
        else:
            self.save_opencv_yaml(path)


def calibration_from_arrays(names: Sequence[str], size: tuple[int, int], Ks, dists, Rs, ts) -> Calibration:
    """Build a :class:`Calibration` from stacked arrays ``(C, 3, 3)``, ``(C, 5)``, ``(C, 3, 3)``, ``(C, 3)``."""
    return Calibration(tuple(Camera(n, size, K, d, R, t) for n, K, d, R, t in zip(names, Ks, dists, Rs, ts)))
