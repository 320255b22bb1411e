"""Scene to triangles: the set (static) and the body, markers and props (moving).

The moving geometry is one indexed vertex array whose vertices are grouped by the
rigid frame that carries them (a humanoid body, a marker, a prop). Posing a frame
is then one small matrix product per group (about 60 groups, ~10k vertices), done on
the CPU and uploaded in one call.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import trimesh

from simbench.render import ids
from simbench.render.rasterizer import GeometryBuffers

MARKER_ALBEDO = np.array([0.85, 0.85, 0.85])
MARKER_RETRO = 6.0     # retro-reflective gain (see the rasteriser's ring-light term)


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _pose_groups(lp, ln, bounds, R, p, P, N):
    """``P[v] = R[g] lp[v] + p[g]`` and ``N[v] = R[g] ln[v]`` for the vertices
    ``bounds[g, 0] <= v < bounds[g, 1]`` of each group ``g``; all float32."""
    for g in range(bounds.shape[0]):
        r = R[g]
        for v in range(bounds[g, 0], bounds[g, 1]):
            x, y, z = lp[v, 0], lp[v, 1], lp[v, 2]
            P[v, 0] = r[0, 0] * x + r[0, 1] * y + r[0, 2] * z + p[g, 0]
            P[v, 1] = r[1, 0] * x + r[1, 1] * y + r[1, 2] * z + p[g, 1]
            P[v, 2] = r[2, 0] * x + r[2, 1] * y + r[2, 2] * z + p[g, 2]
            x, y, z = ln[v, 0], ln[v, 1], ln[v, 2]
            N[v, 0] = r[0, 0] * x + r[0, 1] * y + r[0, 2] * z
            N[v, 1] = r[1, 0] * x + r[1, 1] * y + r[1, 2] * z
            N[v, 2] = r[2, 0] * x + r[2, 1] * y + r[2, 2] * z


def mesh_buffers(mesh: trimesh.Trimesh, face_albedo: np.ndarray, face_ids: np.ndarray, retro: float = 0.0) -> GeometryBuffers:
    """Indexed buffers of a mesh whose faces carry albedo and id.

    Vertex normals are the smooth normals of the whole mesh; vertices are duplicated
    only where faces of different (albedo, id) meet, so patch borders stay sharp.
    """
    faces = np.asarray(mesh.faces)
    vn = np.asarray(mesh.vertex_normals, dtype=np.float64)
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    face_albedo = np.broadcast_to(np.asarray(face_albedo, float), (len(faces), 3))
    face_ids = np.broadcast_to(np.asarray(face_ids, np.int64), (len(faces),))
    key = np.column_stack([face_ids.astype(np.float64), face_albedo])
    _, group = np.unique(key, axis=0, return_inverse=True)
    group = group.ravel()
    # One vertex per (original vertex, group) pair.
    vg = np.stack([faces.ravel(), np.repeat(group, 3)], axis=1)
    uniq, inv = np.unique(vg, axis=0, return_inverse=True)
    new_faces = inv.reshape(-1, 3).astype(np.uint32)
    src = uniq[:, 0]
    # Attributes of each new vertex from any face of its group.
    first_face = np.zeros(len(uniq), dtype=np.int64)
    first_face[inv.ravel()] = np.repeat(np.arange(len(faces)), 3)
    return GeometryBuffers(
        positions=verts[src].astype(np.float32),
        normals=vn[src].astype(np.float32),
        albedo=face_albedo[first_face].astype(np.float32),
        ids=face_ids[first_face].astype(np.int32),
        retro=np.full(len(src), retro, np.float32),
        faces=new_faces,
    )


def concat_buffers(parts: list[GeometryBuffers]) -> GeometryBuffers:
    if not parts:
        z3 = np.zeros((0, 3), np.float32)
        return GeometryBuffers(z3, z3, z3, np.zeros(0, np.int32), np.zeros(0, np.float32), np.zeros((0, 3), np.uint32))
    offsets = np.cumsum([0] + [len(p.positions) for p in parts])[:-1]
    return GeometryBuffers(
        positions=np.concatenate([p.positions for p in parts]),
        normals=np.concatenate([p.normals for p in parts]),
        albedo=np.concatenate([p.albedo for p in parts]),
        ids=np.concatenate([p.ids for p in parts]),
        retro=np.concatenate([p.retro for p in parts]),
        faces=np.concatenate([p.faces + np.uint32(o) for p, o in zip(parts, offsets)]),
        uv=None if all(p.uv is None for p in parts) else np.concatenate(
            [p.uv if p.uv is not None else np.full((len(p.positions), 2), -1.0, np.float32) for p in parts]),
    )


def _grid_plane(size_x: float, size_y: float, nx: int, ny: int) -> trimesh.Trimesh:
    """A plane z = 0 centred at the origin, tessellated (Gouraud lighting needs vertices)."""
    xs = np.linspace(-size_x / 2, size_x / 2, nx + 1)
    ys = np.linspace(-size_y / 2, size_y / 2, ny + 1)
    X, Y = np.meshgrid(xs, ys)
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    i = np.arange(ny)[:, None] * (nx + 1) + np.arange(nx)[None, :]
    i = i.ravel()
    F = np.concatenate([np.column_stack([i, i + 1, i + nx + 2]), np.column_stack([i, i + nx + 2, i + nx + 1])])
    return trimesh.Trimesh(V, F, process=False)


def set_geometry(set_cfg, rng: np.random.Generator) -> GeometryBuffers:
    """Floor, walls and coloured clutter boxes (static)."""
    parts = []
    L = set_cfg.room_size_m
    if set_cfg.floor:
        floor = _grid_plane(L, L, 48, 48)
        parts.append(mesh_buffers(floor, set_cfg.floor_rgb, ids.SET))
    if set_cfg.walls:
        h = 3.0
        for k in range(4):
            wall = _grid_plane(L, h, 32, 12)
            T = trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0])  # plane into x-z
            T = trimesh.transformations.rotation_matrix(k * np.pi / 2, [0, 0, 1]) @ trimesh.transformations.translation_matrix([0, L / 2, h / 2]) @ T
            wall.apply_transform(T)
            parts.append(mesh_buffers(wall, set_cfg.wall_rgb, ids.SET))
    palette = np.array([[0.7, 0.1, 0.1], [0.1, 0.5, 0.15], [0.1, 0.2, 0.7], [0.75, 0.65, 0.1],
                        [0.6, 0.1, 0.55], [0.1, 0.55, 0.6], [0.8, 0.4, 0.1]])
    for _ in range(set_cfg.clutter):
        size = rng.uniform(0.2, 0.7, 3)
        ang = rng.uniform(0, 2 * np.pi)
        r = rng.uniform(0.4, 0.48) * L
        box = trimesh.creation.box(size)
        box = box.subdivide()
        box.apply_transform(trimesh.transformations.rotation_matrix(rng.uniform(0, np.pi), [0, 0, 1]))
        box.apply_translation([r * np.cos(ang), r * np.sin(ang), size[2] / 2])
        parts.append(mesh_buffers(box, palette[rng.integers(len(palette))], ids.CLUTTER))
    return concat_buffers(parts)


@dataclass
class MovingGeometry:
    """The body, markers and props as one vertex array grouped by rigid frame.

    buffers : local-frame positions/normals and the static attributes
    group_slices : list of (kind, index, slice) where kind is "body" (index into the
        states' body arrays), "marker" (index into marker positions) or "prop"
        (index into prop poses)
    """

    buffers: GeometryBuffers
    group_slices: list[tuple[str, int, slice]]

    def __post_init__(self) -> None:
        kinds = [k for k, _, _ in self.group_slices]
        self._bounds = np.array([[sl.start, sl.stop] for _, _, sl in self.group_slices], np.int64).reshape(-1, 2)
        self._of_kind = {kind: (np.array([g for g, k in enumerate(kinds) if k == kind], np.int64),
                                np.array([i for k, i, _ in self.group_slices if k == kind], np.int64))
                         for kind in ("body", "marker", "prop")}
        self._local = (np.ascontiguousarray(self.buffers.positions, np.float32),
                       np.ascontiguousarray(self.buffers.normals, np.float32))

    def pose(self, body_pos: np.ndarray, body_rot: np.ndarray, marker_pos: np.ndarray,
             prop_T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World positions and normals ``(V, 3)`` float32 for one instant.

        body_pos (B, 3), body_rot (B, 3, 3), marker_pos (M, 3), prop_T (P, 4, 4).

        Each group's rotation and translation are gathered in a few array operations and
        applied in one compiled loop (a matrix product per group cost ~0.6 ms a frame
        for ~60 groups, mostly call overhead); markers are translated only.
        """
        G = len(self._bounds)
        R = np.empty((G, 3, 3), np.float32)
        p = np.empty((G, 3), np.float32)
        g, i = self._of_kind["body"]
        if len(g):
            R[g] = np.asarray(body_rot)[i]
            p[g] = np.asarray(body_pos)[i]
        g, i = self._of_kind["marker"]
        if len(g):
            R[g] = np.eye(3, dtype=np.float32)
            p[g] = np.asarray(marker_pos)[i]
        g, i = self._of_kind["prop"]
        if len(g):
            T = np.asarray(prop_T)[i]
            R[g] = T[:, :3, :3]
            p[g] = T[:, :3, 3]
        lp, ln = self._local
        P = np.empty_like(lp)
        N = np.empty_like(ln)
        _pose_groups(lp, ln, self._bounds, R, p, P, N)
        return P, N


def moving_geometry(surface_parts, body_index: dict[str, int], n_markers: int,
                    prop_meshes: list[tuple[trimesh.Trimesh, np.ndarray, int]],
                    marker_radius: float, marker_subdivisions: int = 1) -> MovingGeometry:
    """Build the moving geometry.

    surface_parts : objects with ``body``, ``mesh`` (body frame), ``face_patch`` (-1 or
        0..19) and ``albedo`` (n_faces, 3)
    body_index : body name -> index into the states' body arrays
    prop_meshes : (mesh in the prop frame, rgb, id) per prop, in prop-pose order
    """
    bufs: list[GeometryBuffers] = []
    groups: list[tuple[str, int, slice]] = []
    start = 0

    def add(buf: GeometryBuffers, kind: str, idx: int) -> None:
        nonlocal start
        bufs.append(buf)
        groups.append((kind, idx, slice(start, start + len(buf.positions))))
        start += len(buf.positions)

    for part in surface_parts:
        patch = np.asarray(part.face_patch)
        face_ids = np.where(patch >= 0, ids.SHIRT_PATCH_BASE + patch, ids.BODY)
        add(mesh_buffers(part.mesh, np.asarray(part.albedo), face_ids), "body", body_index[part.body])
    sphere = trimesh.creation.icosphere(subdivisions=marker_subdivisions, radius=marker_radius)
    for m in range(n_markers):
        add(mesh_buffers(sphere, MARKER_ALBEDO, ids.MARKER_BASE + m, retro=MARKER_RETRO), "marker", m)
    for k, (mesh, rgb, pid) in enumerate(prop_meshes):
        add(mesh_buffers(mesh, rgb, pid), "prop", k)
    # Offsets of each group's faces are handled by concat_buffers.
    return MovingGeometry(concat_buffers(bufs), groups)


# ---------------------------------------------------------------------- calibration props
BOARD_BACK_RGB = np.array([0.55, 0.55, 0.52])   # foam-board backing and edges
WAND_STICK_RGB = np.array([0.05, 0.05, 0.05])   # matt black carbon stick


def board_buffers(size_m: tuple[float, float], origin_m: tuple[float, float], thickness_m: float,
                  board_id: int = ids.BOARD, cells: tuple[int, int] = (24, 18),
                  back_rgb: np.ndarray = BOARD_BACK_RGB) -> GeometryBuffers:
    """A printed calibration board in its own frame (see :mod:`mocap.calib.boards`).

    Board frame: ``+x`` right and ``+y`` down on the printed face, ``+z`` into the board
    (away from a viewer of the print); metres. The printed face is the plane ``z = 0``,
    covering ``x in [-origin_m[0], size_m[0] - origin_m[0]]`` and ``y`` likewise, i.e.
    the whole texture of :func:`mocap.calib.boards.render_board_texture` (board plus
    white margin) whose layout gives ``size_m`` and ``origin_m``. It is a grid of
    ``cells`` quads (lighting is per vertex) with ``uv`` in 0..1: ``u`` along ``+x``, ``v``
    along ``+y`` (texture row 0 at the top edge). A box of ``thickness_m`` behind the
    face (``z`` in ``[thickness_m / 10, thickness_m]``, untextured ``back_rgb``) hides the
    print from cameras behind the board: the rasteriser shades surfaces two-sided, so
    without it they would see the print mirrored.

    Returns
    -------
    GeometryBuffers
        Face and backing together, ids ``board_id``.
    """
    w, h = float(size_m[0]), float(size_m[1])
    ox, oy = float(origin_m[0]), float(origin_m[1])
    nx, ny = int(cells[0]), int(cells[1])
    face = _grid_plane(w, h, nx, ny)
    verts = np.asarray(face.vertices) + np.array([w / 2 - ox, h / 2 - oy, 0.0])
    uv = np.column_stack([(verts[:, 0] + ox) / w, (verts[:, 1] + oy) / h])
    n = len(verts)
    front = GeometryBuffers(
        positions=verts.astype(np.float32),
        normals=np.tile(np.array([0.0, 0.0, -1.0], np.float32), (n, 1)),
        albedo=np.ones((n, 3), np.float32),
        ids=np.full(n, board_id, np.int32),
        retro=np.zeros(n, np.float32),
        faces=np.asarray(face.faces, np.uint32),
        uv=uv.astype(np.float32),
    )
    depth = float(thickness_m) * 0.9
    box = trimesh.creation.box((w, h, depth))
    box.apply_translation([w / 2 - ox, h / 2 - oy, float(thickness_m) - depth / 2])
    back = mesh_buffers(box, np.asarray(back_rgb, float), board_id)
    return concat_buffers([front, back])


def wand_geometry(marker_offsets_m: np.ndarray, marker_radius_m: float, stick_radius_m: float,
                  marker_id_base: int = ids.MARKER_BASE, stick_id: int = ids.PROP_BASE,
                  stick_rgb: np.ndarray = WAND_STICK_RGB, sphere_subdivisions: int = 2) -> MovingGeometry:
    """A calibration wand: retro-reflective spheres on a thin stick.

    Parameters
    ----------
    marker_offsets_m : (M,) float
        Positions of the marker centres along the stick, metres from the stick frame's
        origin (the stick runs along its frame's ``+z``, from the first to the last marker).
    marker_radius_m, stick_radius_m : float
    marker_id_base, stick_id : int
        Id-map values of marker ``m`` (``marker_id_base + m``) and of the stick.

    Returns
    -------
    MovingGeometry
        Groups ``("marker", m, ...)`` posed by marker centre positions and
        ``("prop", 0, ...)``, the stick, posed by its world-from-stick transform.
    """
    offs = np.asarray(marker_offsets_m, dtype=np.float64).ravel()
    sphere = trimesh.creation.icosphere(subdivisions=sphere_subdivisions, radius=marker_radius_m)
    parts, groups, start = [], [], 0
    for m in range(len(offs)):
        buf = mesh_buffers(sphere, MARKER_ALBEDO, marker_id_base + m, retro=MARKER_RETRO)
        parts.append(buf)
        groups.append(("marker", m, slice(start, start + len(buf.positions))))
        start += len(buf.positions)
    length = float(offs.max() - offs.min())
    stick = trimesh.creation.cylinder(radius=stick_radius_m, height=length, sections=12)
    stick.apply_translation([0.0, 0.0, float(offs.min()) + length / 2])
    buf = mesh_buffers(stick, np.asarray(stick_rgb, float), stick_id)
    parts.append(buf)
    groups.append(("prop", 0, slice(start, start + len(buf.positions))))
    return MovingGeometry(concat_buffers(parts), groups)
