"""Calibration files of other capture systems, written and read in their own conventions.

Every format holds the same :class:`~mocap.calibration.Calibration`: pinhole + OpenCV's
``k1 k2 p1 p2 k3`` distortion, world-to-camera ``x_cam = R @ x_world + t`` in metres,
pixel centres at integers (OpenCV). What differs is the file:

``opencv``
    ``calibration.yml``, OpenCV ``FileStorage`` (:meth:`Calibration.save_opencv_yaml`).
``anipose``
    ``calibration.toml`` as aniposelib's ``CameraGroup.dump`` writes it: tables
    ``[cam_0]`` ... (``name``, ``size`` = [width, height], ``matrix``, ``distortions``
    (5), ``rotation`` (Rodrigues), ``translation``) and ``[metadata]``. aniposelib takes
    the tables in *sorted key order*, so the keys are zero-padded (``cam_00`` ... when
    there are ten or more cameras). Units are whatever the board was measured in; the
    bench writes metres and says so in ``[metadata]``.
``pose2sim``
    ``Calib.toml`` as Pose2Sim writes it: one table per camera named after it (``name``,
    ``size``, ``matrix``, ``distortions`` (4 terms ``k1 k2 p1 p2``, 5 when ``k3`` is not 0),
    ``rotation``, ``translation`` in metres, ``fisheye = false``) and ``[metadata]``.
    Pose2Sim takes the cameras in file order and pairs them with its sorted pose folders.
``easymocap``
    ``intri.yml`` (``names``, ``K_<name>``, ``dist_<name>`` (1x5), ``H_<name>``,
    ``W_<name>``) and ``extri.yml`` (``names``, ``R_<name>`` (Rodrigues, 3x1),
    ``Rot_<name>`` (3x3), ``T_<name>`` (3x1, metres)) in one folder.

A loader refuses what it would misread: a ``fisheye = true`` camera (OpenCV's fisheye
model is not the pinhole + Brown-Conrady model every stage assumes), distortion with more
than 5 terms, a rotation that is not a rotation, a missing image size.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import tomli_w

from mocap.atomic_files import atomic_write_text
from mocap.calibration import Calibration, Camera, opencv_yaml_writer
from mocap.errors import CalibrationFileError

CalibrationFormat = Literal["opencv", "anipose", "pose2sim", "easymocap"]
CALIBRATION_FORMATS: tuple[str, ...] = ("opencv", "anipose", "pose2sim", "easymocap")

#: The file (or, for EasyMocap, the pair of files) each format writes in an export folder.
CALIBRATION_FILE_NAMES = {"opencv": "calibration.yml", "anipose": "calibration.toml", "pose2sim": "Calib.toml",
                          "easymocap": "intri.yml"}


def _camera_table(c: Camera, n_dist: int) -> dict:
    return {
        "name": c.name,
        "size": [int(c.size[0]), int(c.size[1])],
        "matrix": c.K.tolist(),
        "distortions": c.dist[:n_dist].tolist(),
        "rotation": c.rvec.tolist(),
        "translation": c.t.tolist(),
    }


def save_calibration(calibration: Calibration, folder: str | os.PathLike, fmt: CalibrationFormat) -> list[Path]:
    """Write ``calibration`` into ``folder`` in format ``fmt``; returns the files written
    (names: :data:`CALIBRATION_FILE_NAMES`, plus ``extri.yml`` for EasyMocap)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if fmt not in CALIBRATION_FORMATS:
        raise CalibrationFileError(folder, "format", f"unknown calibration format {fmt!r}", f"use one of {', '.join(CALIBRATION_FORMATS)}")
    path = folder / CALIBRATION_FILE_NAMES[fmt]
    if fmt == "opencv":
        calibration.save_opencv_yaml(path)
        return [path]
    if fmt == "anipose":
        width = len(str(len(calibration) - 1))
        doc = {f"cam_{i:0{width}d}": _camera_table(c, 5) for i, c in enumerate(calibration)}
        doc["metadata"] = {"adjusted": False, "error": 0.0, "units": "metres",
                           "convention": "x_cam = R(rotation) @ x_world + translation; pixel centres at integers"}
        atomic_write_text(path, tomli_w.dumps(doc))
        return [path]
    if fmt == "pose2sim":
        doc = {}
        for c in calibration:
            table = _camera_table(c, 4 if c.dist[4] == 0.0 else 5)
            table["fisheye"] = False
            doc[c.name] = table
        doc["metadata"] = {"adjusted": False, "error": 0.0}
        atomic_write_text(path, tomli_w.dumps(doc))
        return [path]
    return _save_easymocap(calibration, folder)


def _write_names(fs: cv2.FileStorage, names: list[str]) -> None:
    fs.startWriteStruct("names", cv2.FileNode_SEQ)
    for n in names:
        fs.write("", n)
    fs.endWriteStruct()


def _save_easymocap(calibration: Calibration, folder: Path) -> list[Path]:
    paths = []
    for kind in ("intri", "extri"):
        path = folder / f"{kind}.yml"
        with opencv_yaml_writer(path) as fs:
            _write_names(fs, calibration.names)
            for c in calibration:
                if kind == "intri":
                    fs.write(f"K_{c.name}", c.K)
                    fs.write(f"dist_{c.name}", c.dist.reshape(1, 5))
                    fs.write(f"H_{c.name}", int(c.size[1]))
                    fs.write(f"W_{c.name}", int(c.size[0]))
                else:
                    fs.write(f"R_{c.name}", c.rvec.reshape(3, 1))
                    fs.write(f"Rot_{c.name}", c.R)
                    fs.write(f"T_{c.name}", c.t.reshape(3, 1))
        paths.append(path)
    return paths


# -------------------------------------------------------------------------------- reading
def load_calibration(path: str | os.PathLike) -> Calibration:
    """Read a calibration in any of :data:`CALIBRATION_FORMATS`, told apart by the file:
    a folder or an ``intri.yml``/``extri.yml`` is EasyMocap's pair, another ``.yml``/``.yaml``
    OpenCV's, a ``.toml`` anipose's or Pose2Sim's (same fields, different table names).
    Raises :class:`~mocap.errors.CalibrationFileError` naming the file and field."""
    path = Path(path)
    if path.is_dir() or path.name in ("intri.yml", "extri.yml"):
        return _load_easymocap(path if path.is_dir() else path.parent)
    suffix = path.suffix.lower()
    if suffix == ".toml":
        return Calibration.load_toml(path)
    if suffix in (".yml", ".yaml", ".xml", ".json"):
        return Calibration.load_opencv_yaml(path)
    raise CalibrationFileError(path, "", f"unknown calibration file type {suffix or '(no extension)'!r}",
                               "give an OpenCV .yml, an anipose calibration.toml, a Pose2Sim Calib.toml or an EasyMocap folder (intri.yml + extri.yml)")


def _read_names(fs: cv2.FileStorage, path: Path) -> list[str]:
    node = fs.getNode("names")
    if node.empty() or not node.isSeq():
        raise CalibrationFileError(path, "names", "missing", "EasyMocap files list their cameras under 'names'")
    return [node.at(i).string() for i in range(node.size())]


def _load_easymocap(folder: Path) -> Calibration:
    intri, extri = folder / "intri.yml", folder / "extri.yml"
    for p in (intri, extri):
        if not p.is_file():
            raise CalibrationFileError(p, "", "file not found", "an EasyMocap calibration is intri.yml and extri.yml in one folder")
    fi = cv2.FileStorage(str(intri), cv2.FILE_STORAGE_READ)
    fe = cv2.FileStorage(str(extri), cv2.FILE_STORAGE_READ)
    try:
        names = _read_names(fi, intri)
        cams = []
        for n in names:
            def mat(fs, path, key, size):
                node = fs.getNode(key)
                arr = None if node.empty() else node.mat()
                if arr is None or arr.size != size:
                    raise CalibrationFileError(path, key, "missing" if arr is None else f"{arr.size} values",
                                               f"needs {size} numbers for camera {n!r}")
                return arr

            def integer(key):
                node = fi.getNode(key)
                if node.empty():
                    raise CalibrationFileError(intri, key, "missing", "write the image size as H_<name> and W_<name> (pixels)")
                return int(node.real())

            K = mat(fi, intri, f"K_{n}", 9)
            dist = mat(fi, intri, f"dist_{n}", 5)
            rot = fe.getNode(f"Rot_{n}")
            R = rot.mat() if not rot.empty() else cv2.Rodrigues(mat(fe, extri, f"R_{n}", 3).reshape(3, 1))[0]
            if np.asarray(R).shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
                raise CalibrationFileError(extri, f"Rot_{n}", "not a rotation matrix", "write a proper 3x3 rotation (R R^T = I, det = +1)")
            t = mat(fe, extri, f"T_{n}", 3)
            cams.append(Camera(n, (integer(f"W_{n}"), integer(f"H_{n}")), K, dist, R, t))
        return Calibration(tuple(cams))
    finally:
        fi.release()
        fe.release()
