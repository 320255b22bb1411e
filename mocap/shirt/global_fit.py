"""Step 2b of the shirt tracker: the database neighbours of every camera blended into one pose, and its root
fitted in 6 DoF (:meth:`GlobalFit._blend_and_fit`).

Each camera's neighbours come with their orientation in the view of the ray through the
centre of the camera's query square (:meth:`GlobalFit._ray_rotation`); the blended pose is
rendered orthographically in each such view (:meth:`GlobalFit._canonicals`) and its patch
centroids, scaled to the query square, are the targets of a root-only IK
(:meth:`GlobalFit._global_fit`).

:class:`GlobalFit` is a part of :class:`mocap.shirt.pipeline.ShirtTracker` (a mixin: it
uses the tracker's model, cameras, settings and IK).
"""

from __future__ import annotations

import numpy as np

from mocap.shirt.classify import patch_centroids
from mocap.shirt.ik import Constraints
from mocap.shirt.pose_database import blend_poses, blend_weights, tiny_id_map
from mocap.shirt.settings import CameraObservation
from mocap.shirt.shirt_model import look_at_view

__all__ = ["GlobalFit"]

_CANONICAL_SIZE = 64  # px: orthographic render of the blended pose for the 6-DoF fit
_CANONICAL_MARGIN = 1.15


class GlobalFit:
    """Step 2b: blend and 6-DoF fit (part of ``ShirtTracker``)."""

    def _ray_rotation(self, ci: int, uv: np.ndarray) -> np.ndarray:
        """Rows: the ray frame's axes in camera coordinates, z along the ray through pixel ``uv``."""
        cam = self.cameras[ci]
        xy = cam.undistort_pixels(np.asarray(uv, float)[None])[0] if np.any(cam.dist != 0) else \
            np.linalg.solve(cam.K, np.array([uv[0], uv[1], 1.0]))[:2]
        return look_at_view(np.array([xy[0], xy[1], 1.0]))

    def _canonicals(self, hinges: np.ndarray, view_rotations: list[np.ndarray]) -> list:
        """Orthographic render of a pose in several views, and per view its tiny square (view metres), anchors and
        centroids (None where no shirt shows)."""
        # the root at the origin with identity orientation, then each view's rotation
        base = self.model.world_vertices(self.kin.make_q(np.eye(3), np.zeros(3), hinges))
        vvs = [base @ np.asarray(V, float).T for V in view_rotations]
        ext = [self.model.shirt_extent(vv) for vv in vvs]
        sides = [sd * _CANONICAL_MARGIN for _, sd in ext]
        rends = self.model.render_orthographic_views(vvs, [c for c, _ in ext], sides, _CANONICAL_SIZE)
        out = []
        for (centre, _), side, rend in zip(ext, sides, rends):
            tm = tiny_id_map(rend.colour, self.model.n_colours)
            if tm is None:
                out.append(None)
                continue
            px = side / _CANONICAL_SIZE
            box_c = centre + (tm.centre + 0.5 - _CANONICAL_SIZE / 2.0) * px
            box_s = tm.side * px
            cents, counts = patch_centroids(rend.patch, self.model.n_patches)
            cents_m = centre + (cents + 0.5 - _CANONICAL_SIZE / 2.0) * px
            out.append((box_c, box_s, self.model.patch_anchors(rend), cents_m, counts))
        return out

    def _blend_and_fit(self, obs: list[CameraObservation], seen: list[int]) -> np.ndarray | None:
        """Step 2b: the neighbours of every camera blended into one pose, its root fitted (6 DoF)."""
        hs, Rs, ws = [], [], []
        for ci in seen:
            nb = obs[ci].neighbours
            to_world = self.cameras[ci].R.T @ obs[ci].ray_rotation.T
            hs.append(nb.hinges)
            Rs.append(np.einsum("ij,njk->nik", to_world, nb.view_rotation))
            ws.append(blend_weights(nb.distance) / len(seen))
        hinges_b, R_b, _ = blend_poses(np.concatenate(hs), np.concatenate(Rs), np.concatenate(ws))
        return self._global_fit(obs, seen, hinges_b, R_b)

    def _global_fit(self, obs: list[CameraObservation], seen: list[int], hinges: np.ndarray, R_world: np.ndarray) -> np.ndarray | None:
        """Step 2's 6-DoF fit of the blended pose to the query squares of every camera."""
        p = self.params
        parts, roots = [], []
        # root -> ray view of every camera
        cans = self._canonicals(hinges, [obs[ci].ray_rotation @ self.cameras[ci].R @ R_world for ci in seen])
        for ci, can in zip(seen, cans):
            o = obs[ci]
            cam = self.cameras[ci]
            if can is None:
                continue
            box_c, box_s, anchors, cents_m, counts = can
            size_px = o.tiny.side * o.view.scale
            centre_px = o.view.to_image(o.tiny.centre)
            scale = size_px / box_s  # image px per view metre
            targets = centre_px + (cents_m - box_c) * scale
            f = cam.mean_focal_px
            depth = f / scale
            root_view = np.array([-box_c[0], -box_c[1], depth])
            roots.append(cam.R.T @ (o.ray_rotation.T @ root_view - cam.t))
            info = np.repeat((np.eye(2) / (p.global_fit_std * size_px))[None], self.model.n_patches, axis=0)
            parts.append(self._constraints(ci, targets, counts >= 2, anchors, info, size_px))
        if not roots:
            return None
        q0 = self.kin.make_q(R_world, np.mean(roots, axis=0), hinges)
        cons = Constraints.concatenate(parts)
        if len(cons) < 3:
            return q0
        return self.ik.solve(q0, cons, (), active=self._root_active, iterations=p.global_iterations, rel_tol=p.ik_rel_tol).q
