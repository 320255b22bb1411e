"""What a user gives the colour-shirt pipeline at the start of a take, made from the bench:
scribbles on the first frame (from the id map), the white balance and not-shirt colours
they give, and frames of the empty scene (the subject moved out of view)."""

from __future__ import annotations

import cv2
import numpy as np

from mocap.shirt.colour_model import NOT_SHIRT, ColourModel, train_other_colours
from mocap.shirt.pipeline import initial_white_balance
from simbench.render import ids as idc
from simbench.render.frames import Pose, frame_rng
from simbench.stage.ground_truth import GroundTruth
from simbench.stage.stage import Stage

__all__ = ["colour_labels", "scribble_labels", "render_empty_frames", "session_inputs", "first_frame_inputs"]


def colour_labels(id_map: np.ndarray, patch_colour: np.ndarray) -> np.ndarray:
    """Colour id per pixel ``(H, W)`` int16 from a bench id map (shirt patch ids), -1 elsewhere."""
    ids = np.asarray(id_map)
    patch = idc.shirt_patch(ids)
    pc = np.asarray(patch_colour)
    return np.where(patch >= 0, pc[np.clip(patch, 0, len(pc) - 1)], -1).astype(np.int16)


def scribble_labels(id_map: np.ndarray, patch_colour: np.ndarray, margin_px: int = 15) -> np.ndarray:
    """A user's labelling of the first frame, from the bench's id map.

    Shirt pixels get their colour id; the subject's other pixels (trousers, skin) and
    the set within ``margin_px`` of the subject get :data:`mocap.shirt.colour_model.NOT_SHIRT`;
    the rest stays unlabelled (-1).
    """
    ids = np.asarray(id_map)
    out = colour_labels(ids, patch_colour)
    subject = (ids == idc.BODY) | (out >= 0)
    near = cv2.dilate(subject.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1,) * 2)) > 0
    out[(out < 0) & near] = NOT_SHIRT
    return out


def render_empty_frames(bench: Stage, n: int = 3) -> list[list[np.ndarray]]:
    """``n`` frames per camera of the empty scene (the subject moved far below the floor), lights as at the start."""
    times = bench.frame_times()[:n]
    out: list[list[np.ndarray]] = [[] for _ in bench.cameras]
    with bench.frame_renderer() as fr:
        for k, (t, pose) in enumerate(zip(times, bench.pose_at(times))):
            gone = Pose(pose.body_pos + np.array([0.0, 0.0, -100.0]), pose.body_rot, pose.marker_pos - np.array([0.0, 0.0, 100.0]),
                        pose.prop_T, pose.probe_points)
            fo = fr.render_frame(k, float(t), [gone], gone, frame_rng(bench.scenario.seed + 7919, k))
            for ci in range(len(bench.cameras)):
                out[ci].append(fo.images[ci])
    return out


def session_inputs(bench: Stage, frames: np.ndarray, gt: GroundTruth, colours: ColourModel, patch_colour: np.ndarray):
    """What the user provides at the start of a session: ``W`` per camera and the not-shirt colours
    (from frame 0's labels, :func:`first_frame_inputs`), and frames of the empty scene."""
    ids0 = np.stack([gt.id_maps[n][0] for n in gt.camera_names])
    W0, other = first_frame_inputs(bench.scenario.seed, frames[0], ids0, colours, patch_colour)
    return W0, other, render_empty_frames(bench)


def first_frame_inputs(seed: int, images: np.ndarray, ids: np.ndarray, colours: ColourModel, patch_colour: np.ndarray):
    """The session inputs frame 0 gives: ``W`` per camera and the not-shirt colours, from the
    first frame's images ``(C, H, W, 3)`` uint8 and id maps ``(C, H, W)`` (the user's scribbles);
    ``seed``: the scenario's (the not-shirt colours' samples)."""
    labels = [scribble_labels(ids[ci], patch_colour) for ci in range(len(ids))]
    W0 = [initial_white_balance(images[ci], labels[ci], colours) for ci in range(len(labels))]
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x07E]))
    other = train_other_colours([images[ci] for ci in range(len(labels))], labels, W0, rng)
    return W0, other
