"""The subject model a user gives the pipeline: a humanoid MJCF and where the markers sit on it.

This is the pipeline's equivalent of a Vicon subject file (``.vsk``): the kinematic model
(bodies, hinges, segment lengths: the MJCF of ``docs/humanoid_spec.md``) plus the marker
placement, each marker being a point fixed in one body's frame.

Two ways to get one:

* :meth:`SubjectModel.from_mjcf` reads the MJCF itself; its ``<site>`` elements on bodies are
  the markers (optionally only those whose name starts with a prefix).
* :meth:`SubjectModel.load` reads a small TOML that names the MJCF (path relative to the TOML)
  and lists the markers, as written by :meth:`SubjectModel.save_toml`::

      [subject]
      name = "humanoid"
      mjcf = "humanoid.xml"

      [[markers]]
      name = "LASI"
      body = "pelvis"
      offset_m = [0.08, 0.12, 0.05]

Only the standard library parses the XML here (no simulator import): ``mocap`` runs on real
video and must never import MuJoCo.
"""

from __future__ import annotations

import os
import tempfile
import tomllib
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
import tomli_w

from mocap.atomic_files import atomic_write_text
from mocap.errors import InputFileError

__all__ = ["MarkerPlacement", "MjcfBody", "SubjectModel"]


@dataclass(frozen=True, eq=False)
class MarkerPlacement:
    """One marker fixed on one body.

    Attributes
    ----------
    name : str
        Marker label (as in the trajectories).
    body : str
        Name of the MJCF body carrying the marker.
    offset_m : (3,) float
        Marker position in that body's frame, metres.
    """

    name: str
    body: str
    offset_m: np.ndarray

    def __post_init__(self) -> None:
        offset = np.array(self.offset_m, dtype=np.float64).reshape(-1)
        if offset.shape != (3,) or not np.isfinite(offset).all():
            raise ValueError(f"marker {self.name!r}: offset_m must be 3 finite numbers (metres), got {self.offset_m!r}")
        offset.setflags(write=False)
        object.__setattr__(self, "offset_m", offset)


@dataclass(frozen=True, eq=False)
class MjcfBody:
    """A body of the MJCF tree, as read from the XML (no simulator involved).

    Attributes
    ----------
    name : str
    parent : str or None
        Parent body name; None for a child of ``<worldbody>``.
    pos_m : (3,) float
        Body origin in the parent frame, metres (the MJCF ``pos``).
    has_rotation : bool
        True if the body declares a rest orientation (``quat``, ``euler``, ``axisangle``,
        ``xyaxes``, ``zaxis``); the humanoid contract has none.
    joints : list of (name, type)
        The body's joints in document order (``type`` is ``"hinge"``, ``"free"``, ...).
    sites : list of (name, (3,) float)
        The body's sites and their positions in the body frame, metres.
    """

    name: str
    parent: str | None
    pos_m: np.ndarray
    has_rotation: bool
    joints: list[tuple[str, str]]
    sites: list[tuple[str, np.ndarray]]


_ROTATION_ATTRIBUTES = ("quat", "euler", "axisangle", "xyaxes", "zaxis")


def _parse_vector(text: str | None, default: Sequence[float], where: str, path: str) -> np.ndarray:
    if text is None:
        return np.asarray(default, dtype=np.float64)
    try:
        values = np.array([float(v) for v in text.split()], dtype=np.float64)
    except ValueError:
        raise InputFileError(path, f"{where}: {text!r} is not a list of numbers", "write it as three numbers, e.g. pos=\"0 0.1 0\"") from None
    if values.shape != (3,):
        raise InputFileError(path, f"{where}: expected 3 numbers, got {text!r}", "write it as three numbers, e.g. pos=\"0 0.1 0\"")
    return values


def parse_mjcf_bodies(mjcf_text: str, source: str = "<MJCF text>") -> list[MjcfBody]:
    """Bodies of an MJCF in depth-first document order (the order of MuJoCo's qpos).

    Parameters
    ----------
    mjcf_text : str
        The MJCF XML.
    source : str
        File name used in error messages.

    Returns
    -------
    list of MjcfBody
    """
    try:
        root = ET.fromstring(mjcf_text)
    except ET.ParseError as exc:
        raise InputFileError(source, f"not valid XML ({exc})", "give the humanoid MJCF file written by the bench or a valid MJCF") from None
    if root.tag != "mujoco":
        raise InputFileError(source, f"root element is <{root.tag}>, not <mujoco>", "give an MJCF file (root element <mujoco>)")
    worldbody = root.find("worldbody")
    if worldbody is None:
        raise InputFileError(source, "no <worldbody> element", "give the humanoid MJCF, which has its bodies under <worldbody>")
    bodies: list[MjcfBody] = []

    def visit(element: ET.Element, parent: str | None) -> None:
        for child in element.findall("body"):
            name = child.get("name")
            if not name:
                raise InputFileError(source, f"a <body> under {parent or 'worldbody'!r} has no name", "give every body a name attribute", field="body")
            joints = []
            for j in child:
                if j.tag == "freejoint":
                    joints.append((j.get("name", ""), "free"))
                elif j.tag == "joint":
                    joints.append((j.get("name", ""), j.get("type", "hinge")))
            sites = [
                (s.get("name", ""), _parse_vector(s.get("pos"), (0.0, 0.0, 0.0), f"site {s.get('name')!r} pos", source))
                for s in child.findall("site")
            ]
            bodies.append(
                MjcfBody(
                    name=name,
                    parent=parent,
                    pos_m=_parse_vector(child.get("pos"), (0.0, 0.0, 0.0), f"body {name!r} pos", source),
                    has_rotation=any(child.get(a) is not None for a in _ROTATION_ATTRIBUTES),
                    joints=joints,
                    sites=sites,
                )
            )
            visit(child, name)

    visit(worldbody, None)
    if not bodies:
        raise InputFileError(source, "<worldbody> has no <body>", "give the humanoid MJCF (bodies pelvis, abdomen, ...)")
    return bodies


@dataclass(eq=False)
class SubjectModel:
    """Humanoid model and marker placement of one subject.

    Attributes
    ----------
    mjcf_text : str
        The humanoid MJCF (standalone: no floor, no props; joints as in the humanoid contract).
    markers : list of MarkerPlacement
        Marker placement, in the order the subject lists them.
    mjcf_path : Path or None
        Where the MJCF was read from (None when built from text).
    name : str
        Subject name.
    """

    mjcf_text: str
    markers: list[MarkerPlacement]
    mjcf_path: Path | None = None
    name: str = "subject"
    bodies: list[MjcfBody] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        source = str(self.mjcf_path) if self.mjcf_path is not None else "<MJCF text>"
        self.bodies = parse_mjcf_bodies(self.mjcf_text, source)
        self.markers = list(self.markers)
        body_names = {b.name for b in self.bodies}
        seen: set[str] = set()
        for m in self.markers:
            if m.body not in body_names:
                raise InputFileError(
                    source, f"marker {m.name!r} is on body {m.body!r}, which the MJCF does not have",
                    f"use one of the bodies {sorted(body_names)}", field="markers.body",
                )
            if m.name in seen:
                raise InputFileError(source, f"marker name {m.name!r} appears twice", "give every marker a unique name", field="markers.name")
            seen.add(m.name)

    # ------------------------------------------------------------------ views
    @property
    def marker_names(self) -> list[str]:
        return [m.name for m in self.markers]

    @property
    def body_names(self) -> list[str]:
        """Body names in depth-first MJCF order."""
        return [b.name for b in self.bodies]

    @property
    def hinge_names(self) -> list[str]:
        """Names of the 1-DoF joints (hinges) in qpos order."""
        return [n for b in self.bodies for n, t in b.joints if t == "hinge"]

    def marker(self, name: str) -> MarkerPlacement:
        for m in self.markers:
            if m.name == name:
                return m
        raise KeyError(f"subject {self.name!r} has no marker {name!r}; it has {self.marker_names}")

    def with_markers(self, names: Iterable[str]) -> "SubjectModel":
        """The same subject restricted to (and ordered as) ``names``."""
        return SubjectModel(self.mjcf_text, [self.marker(n) for n in names], self.mjcf_path, self.name)

    # ------------------------------------------------------------------ files
    @classmethod
    def from_mjcf(cls, path: str | os.PathLike, *, site_prefix: str = "", name: str | None = None) -> "SubjectModel":
        """Subject from an MJCF whose ``<site>`` elements on bodies are the markers.

        Parameters
        ----------
        path : path-like
            The humanoid MJCF.
        site_prefix : str
            Only sites whose name starts with this prefix are markers; the prefix is removed
            from the marker name. ``""`` (default): every named site is a marker.
        name : str, optional
            Subject name (default: the file stem).
        """
        path = Path(path)
        try:
            text = path.read_text()
        except OSError as exc:
            raise InputFileError(path, f"cannot read the MJCF ({exc.strerror})", "give the path of the humanoid MJCF file") from None
        return cls.from_mjcf_text(text, site_prefix=site_prefix, name=name or path.stem, mjcf_path=path)

    @classmethod
    def from_mjcf_text(
        cls, text: str, *, site_prefix: str = "", name: str = "subject", mjcf_path: Path | None = None
    ) -> "SubjectModel":
        """Same as :meth:`from_mjcf` from the XML text."""
        source = str(mjcf_path) if mjcf_path is not None else "<MJCF text>"
        markers = [
            MarkerPlacement(site_name[len(site_prefix):], body.name, pos)
            for body in parse_mjcf_bodies(text, source)
            for site_name, pos in body.sites
            if site_name and site_name.startswith(site_prefix)
        ]
        if not markers:
            raise InputFileError(
                source, f"no <site> named {site_prefix + '*'!r} on any body, so no markers",
                "add marker sites to the bodies or give the marker placement in a subject TOML",
            )
        return cls(text, markers, mjcf_path, name)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "SubjectModel":
        """Load a subject TOML (see the module docstring), or an MJCF (``.xml``) via :meth:`from_mjcf`."""
        path = Path(path)
        if path.suffix.lower() in (".xml", ".mjcf"):
            return cls.from_mjcf(path)
        try:
            doc = tomllib.loads(path.read_bytes().decode("utf-8-sig"))  # a byte-order mark first is not TOML
        except OSError as exc:
            raise InputFileError(path, f"cannot read the subject file ({exc.strerror})", "give the path of a subject TOML or humanoid MJCF") from None
        except UnicodeDecodeError as exc:
            raise InputFileError(path, f"byte {exc.start} is not UTF-8", "save the subject file as UTF-8 text") from None
        except tomllib.TOMLDecodeError as exc:
            raise InputFileError(path, f"not valid TOML ({exc})", "fix the TOML syntax") from None
        subject = doc.get("subject")
        if not isinstance(subject, dict) or not isinstance(subject.get("mjcf"), str):
            raise InputFileError(path, "missing the MJCF path", 'add [subject] with mjcf = "humanoid.xml" (relative to this file)', field="subject.mjcf")
        mjcf_path = (path.parent / subject["mjcf"]).resolve() if not Path(subject["mjcf"]).is_absolute() else Path(subject["mjcf"])
        try:
            text = mjcf_path.read_text()
        except OSError as exc:
            raise InputFileError(path, f"cannot read the MJCF {str(mjcf_path)!r} ({exc.strerror})", "fix subject.mjcf (a path relative to the subject TOML)", field="subject.mjcf") from None
        entries = doc.get("markers")
        if not isinstance(entries, list) or not entries:
            raise InputFileError(path, "no markers", "add [[markers]] tables with name, body and offset_m = [x, y, z] (metres)", field="markers")
        markers = []
        for i, entry in enumerate(entries):
            where = f"markers[{i}]"
            if not isinstance(entry, dict):
                raise InputFileError(path, f"{where} is not a table", "write each marker as [[markers]] with name, body, offset_m", field=where)
            for key in ("name", "body", "offset_m"):
                if key not in entry:
                    raise InputFileError(path, f"{where} has no {key!r}", "give name, body and offset_m = [x, y, z] (metres) for each marker", field=f"{where}.{key}")
            try:
                markers.append(MarkerPlacement(str(entry["name"]), str(entry["body"]), entry["offset_m"]))
            except (ValueError, TypeError):
                raise InputFileError(path, f"{where}.offset_m = {entry['offset_m']!r} is not 3 numbers", "write offset_m = [x, y, z] in metres, in the body frame", field=f"{where}.offset_m") from None
        try:
            return cls(text, markers, mjcf_path, str(subject.get("name", path.stem)))
        except InputFileError as exc:
            # Re-attribute marker errors to the TOML that listed the markers.
            raise InputFileError(path, exc.problem, exc.fix, field=exc.field) from None

    def save_toml(self, path: str | os.PathLike, *, mjcf_path: str | os.PathLike | None = None) -> Path:
        """Write the subject TOML; writes the MJCF next to it if the subject has no MJCF file.

        Parameters
        ----------
        path : path-like
            Output TOML.
        mjcf_path : path-like, optional
            MJCF to reference (default: ``self.mjcf_path``, or ``<path stem>.xml`` written next to
            the TOML). Stored relative to the TOML's folder when possible.

        Returns
        -------
        Path of the TOML.
        """
        path = Path(path)
        target = Path(mjcf_path) if mjcf_path is not None else self.mjcf_path
        if target is None:
            target = path.with_suffix(".xml")
            atomic_write_text(target, self.mjcf_text)
        try:
            ref = os.path.relpath(Path(target).resolve(), path.parent.resolve())
        except ValueError:  # different drives
            ref = str(Path(target).resolve())
        doc = {
            "subject": {"name": self.name, "mjcf": ref},
            "markers": [{"name": m.name, "body": m.body, "offset_m": [float(v) for v in m.offset_m]} for m in self.markers],
        }
        atomic_write_text(path, tomli_w.dumps(doc))
        return path

    def mjcf_file(self) -> tuple[Path, bool]:
        """A file holding the MJCF: ``(path, is_temporary)``; the caller deletes temporary files."""
        if self.mjcf_path is not None and Path(self.mjcf_path).is_file():
            try:
                if Path(self.mjcf_path).read_text() == self.mjcf_text:
                    return Path(self.mjcf_path), False
            except OSError:
                pass
        fd, name = tempfile.mkstemp(suffix=".xml", prefix="subject_")
        with os.fdopen(fd, "w") as f:
            f.write(self.mjcf_text)
        return Path(name), True
