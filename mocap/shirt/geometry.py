"""The shirt's geometry as the pipeline sees it: body-frame triangle meshes with patch ids
(:class:`ShirtGeometry`), arrays the bench exports into the pose database file, or that a
user makes from their own body model."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.errors import MocapInputError

__all__ = ["SHIRT_BODIES", "ShirtGeometry"]

SHIRT_BODIES: tuple[str, ...] = ("abdomen", "thorax", "upperarm_l", "forearm_l", "upperarm_r", "forearm_r")
"""Bodies that carry shirt patches."""


@dataclass(frozen=True, eq=False)
class ShirtGeometry:
    """Triangle meshes of the shirt's bodies (and the few bodies that can hide it), in body frames.

    Attributes
    ----------
    body_names : tuple[str, ...]
        Bodies carrying geometry (names of the humanoid MJCF).
    vertices_m : (V, 3) float32
        Vertex positions in their body's frame, metres; the vertices of one body are
        contiguous, bodies in ``body_names`` order.
    vertex_body : (V,) int16
        Index into ``body_names`` of each vertex.
    faces : (T, 3) int32
        Vertex indices, counter-clockwise seen from outside (outward normals).
    face_patch : (T,) int16
        Shirt patch ``0..P-1`` of every face, ``-1`` for faces that only occlude (head, hands).
    patch_colour : (P,) int16
        Colour index ``0..K-1`` of every patch (two patches share each colour).
    colour_names : tuple[str, ...]
        Names of the K colours.
    """

    body_names: tuple[str, ...]
    vertices_m: np.ndarray
    vertex_body: np.ndarray
    faces: np.ndarray
    face_patch: np.ndarray
    patch_colour: np.ndarray
    colour_names: tuple[str, ...]

    def __post_init__(self) -> None:
        V = len(self.vertices_m)
        if np.asarray(self.vertices_m).shape != (V, 3) or np.asarray(self.vertex_body).shape != (V,):
            raise MocapInputError(f"ShirtGeometry: vertices_m must be (V, 3) and vertex_body (V,), got {np.shape(self.vertices_m)} and {np.shape(self.vertex_body)}")
        faces = np.asarray(self.faces)
        if faces.ndim != 2 or faces.shape[1] != 3 or (faces.size and (faces.min() < 0 or faces.max() >= V)):
            raise MocapInputError(f"ShirtGeometry: faces must be (T, 3) indices into {V} vertices")
        if np.asarray(self.face_patch).shape != (len(faces),):
            raise MocapInputError(f"ShirtGeometry: face_patch must have one entry per face ({len(faces)}), got {np.shape(self.face_patch)}")
        if np.any(np.asarray(self.face_patch) >= len(self.patch_colour)):
            raise MocapInputError("ShirtGeometry: a face_patch value has no entry in patch_colour")
        if np.any(np.asarray(self.patch_colour) >= len(self.colour_names)):
            raise MocapInputError("ShirtGeometry: a patch_colour value has no entry in colour_names")
        vb = np.asarray(self.vertex_body)
        if np.any(vb[faces[:, 0]] != vb[faces[:, 1]]) or np.any(vb[faces[:, 0]] != vb[faces[:, 2]]):
            raise MocapInputError("ShirtGeometry: every face must lie on one body")

    @property
    def n_patches(self) -> int:
        return len(self.patch_colour)

    @property
    def n_colours(self) -> int:
        return len(self.colour_names)

    @property
    def face_body(self) -> np.ndarray:
        """``(T,)`` body index of every face."""
        return np.asarray(self.vertex_body)[np.asarray(self.faces)[:, 0]]

    #: the arrays :meth:`to_arrays` writes, without their prefix
    ARRAY_NAMES = ("body_names", "vertices_m", "vertex_body", "faces", "face_patch", "patch_colour", "colour_names")

    def to_arrays(self, prefix: str = "geometry_") -> dict[str, np.ndarray]:
        """Arrays for ``numpy.savez`` (strings as unicode arrays)."""
        return {
            f"{prefix}body_names": np.array(self.body_names),
            f"{prefix}vertices_m": np.asarray(self.vertices_m, np.float32),
            f"{prefix}vertex_body": np.asarray(self.vertex_body, np.int16),
            f"{prefix}faces": np.asarray(self.faces, np.int32),
            f"{prefix}face_patch": np.asarray(self.face_patch, np.int16),
            f"{prefix}patch_colour": np.asarray(self.patch_colour, np.int16),
            f"{prefix}colour_names": np.array(self.colour_names),
        }

    @classmethod
    def from_arrays(cls, arrays, prefix: str = "geometry_", source: str = "<arrays>") -> "ShirtGeometry":
        try:
            return cls(
                body_names=tuple(str(s) for s in arrays[f"{prefix}body_names"]),
                vertices_m=np.asarray(arrays[f"{prefix}vertices_m"], np.float32),
                vertex_body=np.asarray(arrays[f"{prefix}vertex_body"], np.int16),
                faces=np.asarray(arrays[f"{prefix}faces"], np.int32),
                face_patch=np.asarray(arrays[f"{prefix}face_patch"], np.int16),
                patch_colour=np.asarray(arrays[f"{prefix}patch_colour"], np.int16),
                colour_names=tuple(str(s) for s in arrays[f"{prefix}colour_names"]),
            )
        except KeyError as exc:
            raise MocapInputError(f"{source}: missing array {exc.args[0]!r}; rebuild the database with `simbench shirt build-db`") from None
