"""The stage of a capture scenario (``[motion] c3d`` / ``trc``): marker spheres only.

:func:`load_capture_clip` reads the scenario's capture file and places it for the
scenario (window, placement under the rig, selection, seeded gaps: see
:mod:`simbench.scenes.capture_motion`). :class:`CaptureStage` is a
:class:`~simbench.stage.stage.Stage` whose markers are that capture's instead of a
humanoid's marker sites:

* The MuJoCo scene keeps its humanoid (the simulation drives one, and props collide with
  it) but has no marker sites and no rendered surface, and the humanoid is parked
  :data:`PARK_HEIGHT_M` above the floor, out of reach of any prop. Props still work.
* :meth:`CaptureStage.states` returns the capture's marker positions (NaN where missing)
  and NaN for the humanoid's qpos and joint centres: there is no body to score.
* The renderer draws each marker at its position, a sphere of ``motion.marker_diameter_mm``
  (the capture system's marker size; default the bench's 14 mm), and nothing where the position is NaN,
  so a missing sample is an absent marker in the frames and in the ground truth's
  visibility (its visible fraction is 0).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocap.errors import MocapInputError
from mocap.exports import CaptureTrajectories, read_c3d, read_trc
from mocap.swap_repair import repair_source_swaps
from simbench.errors import ScenarioError
from simbench.render.camera import cameras_from_scenario
from simbench.render.frames import FrameRenderer
from simbench.render.geometry import MovingGeometry
from simbench.render.lighting import Lighting
from simbench.scenario import CaptureGapsConfig, Scenario
from simbench.scenes.capture_motion import CaptureClip, CaptureReference
from simbench.scenes.humanoid import NQ, tpose_qpos
from simbench.scenes.motions import Motion
from simbench.scenes.scene import build_scene
from simbench.scenes.simulation import SceneStates
from simbench.stage.renderer import mid_exposure_times
from simbench.stage.stage import Stage, body_params, make_props

__all__ = ["CaptureStage", "PARK_HEIGHT_M", "load_capture_clip", "seeded_gaps", "look_at_point"]

PARK_HEIGHT_M = 100.0  # the unused humanoid stands this high: no prop reaches it, no floor contact


def look_at_point(scenario: Scenario) -> np.ndarray:
    """The point the cameras aim at: the rig's ``look_at``, else the mean of the cameras'."""
    if scenario.rig is not None:
        return np.asarray(scenario.rig.look_at, dtype=np.float64)
    return np.mean([c.look_at for c in scenario.cameras], axis=0)


def seeded_gaps(cfg: CaptureGapsConfig, n_frames: int, n_markers: int, rng: np.random.Generator) -> np.ndarray:
    """Gap mask ``(n_frames, n_markers)`` bool: ``round(fraction * M)`` markers get ``runs`` runs each.

    The frames ``1 .. n_frames - 2`` are split into ``runs`` equal spans; each run lies in
    its own span, its length drawn uniformly in ``min_frames .. max_frames`` (at most the
    span minus one frame, so runs never touch), its start uniformly where it fits.
    """
    mask = np.zeros((n_frames, n_markers), dtype=bool)
    n_chosen = int(round(cfg.fraction * n_markers))
    span = (n_frames - 2) // cfg.runs
    if n_chosen == 0 or span < 2:
        return mask
    for m in np.sort(rng.choice(n_markers, size=n_chosen, replace=False)):
        for r in range(cfg.runs):
            length = min(int(rng.integers(cfg.min_frames, cfg.max_frames + 1)), span - 1)
            lo = 1 + r * span
            start = lo + int(rng.integers(0, span - length))  # last start leaves one free frame
            mask[start : start + length, m] = True
    return mask


def _read(scenario: Scenario) -> tuple[CaptureTrajectories, str, str]:
    m = scenario.motion
    key = "c3d" if m.c3d else "trc"
    given = m.c3d or m.trc
    path = scenario.resolve_path(given)
    try:
        if key == "c3d":
            traj = read_c3d(path, up_axis=m.up_axis)
        else:
            axes = {"auto": "auto", "y": "opensim", "z": "world"}.get(m.up_axis)
            if axes is None:
                raise ScenarioError(scenario.origin, "motion.up_axis", m.up_axis,
                                    "a TRC file's up axis is 'auto', 'y' or 'z'")
            traj = read_trc(path, axes=axes)
    except MocapInputError as exc:
        raise ScenarioError(scenario.origin, f"motion.{key}", given, f"cannot use it: {exc}") from None
    return traj, key, given


def load_capture_clip(scenario: Scenario) -> CaptureClip:
    """Read the scenario's capture file and place it for the scenario (see the module doc).

    Raises
    ------
    ScenarioError
        The file cannot be read, a selected label is not a physical marker of the file,
        the window does not fit in the capture, or no marker has a sample in it.
    """
    m = scenario.motion
    where = scenario.origin
    traj, key, given = _read(scenario)
    labels = list(traj.labels)
    if m.labels is not None:
        for name in m.labels:
            if name not in labels:
                why = f" (set aside: {traj.set_aside[name]})" if name in traj.set_aside else ""
                raise ScenarioError(where, "motion.labels", name,
                                    f"not a physical marker of {given}{why}; choose from {labels}")
        if len(set(m.labels)) != len(m.labels):
            raise ScenarioError(where, "motion.labels", list(m.labels), "each label once")
        idx = [labels.index(n) for n in labels if n in set(m.labels)]  # file order
    else:
        idx = list(range(len(labels)))
    rate = traj.point_rate_hz
    xyz = traj.xyz[:, idx]
    names = [labels[i] for i in idx]
    capture_s = (len(xyz) - 1) / rate
    end_s = m.start_s + m.speed * (scenario.duration_s)
    if end_s > capture_s + 1e-9:
        raise ScenarioError(where, "duration_s", scenario.duration_s,
                            f"the window motion.start_s + motion.speed * duration_s = {end_s:.3f} s runs past the end "
                            f"of {given} ({capture_s:.3f} s of capture at {rate:g} Hz); shorten it or start earlier")
    F = scenario.n_frames
    frame_times = mid_exposure_times(scenario.n_frames, scenario.fps, scenario.sensor.exposure_ms)
    provisional = CaptureClip(tuple(names), xyz, rate, m.start_s, m.speed, scenario.fps, np.zeros((F, len(names)), bool),
                              np.zeros(2), Path(given))
    at_frames = provisional.file_positions_at(frame_times)  # (F, M, 3)
    seen = np.isfinite(at_frames).all(axis=2).any(axis=0)
    if not seen.any():
        raise ScenarioError(where, "motion.start_s", m.start_s,
                            f"no marker of {given} has a sample in the window {m.start_s:g}-{end_s:g} s; move the window")
    if m.subject_trial == "rest":
        _check_rest_trial(provisional, scenario, given, end_s)
    dropped = tuple(n for n, s in zip(names, seen) if not s)
    keep = np.flatnonzero(seen)
    xyz, names, at_frames = xyz[:, keep], [names[i] for i in keep], at_frames[:, keep]
    lo = np.nanmin(at_frames[..., :2].reshape(-1, 2), axis=0)
    hi = np.nanmax(at_frames[..., :2].reshape(-1, 2), axis=0)
    shift = look_at_point(scenario)[:2] - 0.5 * (lo + hi)
    xyz = xyz.copy()
    xyz[..., :2] += shift
    # The file's own label swaps inside the window, exchanged back (see repair_window_swaps).
    xyz, repairs = repair_window_swaps(xyz, names, rate, m.start_s, end_s)
    if m.gaps is not None:
        rng = np.random.default_rng(np.random.SeedSequence([scenario.seed, 0x6A95]))
        gap_mask = seeded_gaps(m.gaps, F, len(names), rng)
    else:
        gap_mask = np.zeros((F, len(names)), dtype=bool)
    return CaptureClip(tuple(names), xyz, rate, m.start_s, m.speed, scenario.fps, gap_mask, shift, Path(given),
                       set_aside=dict(traj.set_aside), dropped=dropped, source_up_axis=traj.source_up_axis,
                       up_axis_reason=traj.up_axis_reason, label_repairs=repairs)


def _check_rest_trial(clip: CaptureClip, scenario: Scenario, given: str, end_s: float) -> None:
    """``motion.subject_trial = "rest"`` needs 2 samples or more outside the window that see 3 markers or more."""
    out = clip.outside_window(scenario.duration_s)
    usable = int((np.isfinite(clip.source_xyz[out]).all(axis=2).sum(axis=1) >= 3).sum())
    if usable < 2:
        raise ScenarioError(scenario.origin, "motion.subject_trial", "rest",
                            f"{given} has {usable} sample{'' if usable == 1 else 's'} with 3 markers or more outside the "
                            f"window {scenario.motion.start_s:g}-{end_s:g} s; use 'take', or shorten or move the window")


def repair_window_swaps(xyz: np.ndarray, names: list[str], rate_hz: float, start_s: float, end_s: float
                        ) -> tuple[np.ndarray, str]:
    """The file samples ``xyz (N, M, 3)`` with the capture's own label swaps inside the window
    ``start_s..end_s`` exchanged back (:func:`mocap.swap_repair.repair_source_swaps`: a label
    that jumps onto the path another label's run continues), and one line saying what was
    exchanged ("" if nothing). A user repairs such swaps before taking a capture as truth; the
    labeller follows physical markers, and unrepaired it is scored as swapping where the file's
    labelling does (c3d_basket_sprint: ForearmL:Marker4 carries ForearmL:Marker1's marker in the
    window's first 24 frames and its last, 73 mm from the point Marker1 carries there)."""
    i0 = max(int(np.floor(start_s * rate_hz)), 0)
    i1 = min(int(np.ceil(end_s * rate_hz)) + 1, len(xyz) - 1)
    fixed, events = repair_source_swaps(xyz[i0:i1 + 1])
    if not events:
        return xyz, ""
    out = xyz.copy()
    out[i0:i1 + 1] = fixed
    parts = [f"{names[a]} <-> {names[b]} at {(i0 + first) / rate_hz:.3f}-{(i0 + last) / rate_hz:.3f} s "
             f"({names[a]} jumped {1e3 * jump:.0f} mm onto {names[b]}'s path)" for a, b, first, last, jump in events]
    return out, "label swaps of the file repaired in the truth: " + "; ".join(parts)


class _AbsentMarkersGeometry(MovingGeometry):
    """Moving geometry that draws nothing for a marker whose position is not finite.

    Such a marker's sphere is collapsed onto one point, the centre of a drawn marker
    (or the world origin if none is drawn): its triangles have no area, so they cover no
    pixel, and the image region the moving geometry spans (the rasteriser bounds it by
    the vertices) stays that of the drawn geometry.
    """

    def __post_init__(self) -> None:
        super().__post_init__()
        self._marker_vertices = {i: np.arange(sl.start, sl.stop) for kind, i, sl in self.group_slices if kind == "marker"}

    def pose(self, body_pos, body_rot, marker_pos, prop_T):
        mp = np.asarray(marker_pos, dtype=np.float64).reshape(-1, 3)
        shown = np.isfinite(mp).all(axis=1)
        anchor = mp[np.argmax(shown)] if shown.any() else np.zeros(3)
        P, N = super().pose(body_pos, body_rot, np.where(shown[:, None], mp, anchor), prop_T)
        for m in np.flatnonzero(~shown):
            P[self._marker_vertices[int(m)]] = anchor
        return P, N


@dataclass
class CaptureStage(Stage):
    """A bench that replays a real capture's markers (see the module doc)."""

    clip: CaptureClip | None = None

    @classmethod
    def from_capture_scenario(cls, scenario: Scenario) -> "CaptureStage":
        where = scenario.origin
        if scenario.subject.shirt:
            raise ScenarioError(where, "subject.shirt", True, "a capture scenario renders the file's markers only; remove shirt")
        params = body_params(scenario)
        clip = load_capture_clip(scenario)
        scene = build_scene(params, marker_set=None, props=make_props(scenario))
        scene = dataclasses.replace(scene, surface_parts=())  # the humanoid is not rendered
        parked = tpose_qpos(params)
        parked[2] += PARK_HEIGHT_M
        motion = Motion(name=f"capture:{clip.path.name}", duration_s=scenario.duration_s + 0.1,
                        evaluate=lambda t: np.broadcast_to(parked, (len(t), NQ)).copy(),
                        description=f"real capture {clip.path.name}: {clip.n_markers} markers")
        cams = cameras_from_scenario(scenario)
        lighting = Lighting(scenario.lighting)
        return cls(scenario, params, scene, motion, cams, lighting, list(clip.labels), [p.name for p in scene.props],
                   clip=clip)

    def states(self, times: np.ndarray) -> SceneStates:
        """Props simulated as usual; markers from the capture (NaN where missing); no humanoid."""
        st = super().states(times)
        qpos = st.qpos.copy()
        qpos[:, :NQ] = np.nan
        return dataclasses.replace(st, marker_xpos=self.clip.positions_at(st.times), qpos=qpos,
                                   joint_centres=np.full_like(st.joint_centres, np.nan), marker_names=self.clip.labels)

    @property
    def marker_radius_m(self) -> float:
        """Half the scenario's ``motion.marker_diameter_mm`` (the capture system's markers), else
        the bench's 14 mm spheres."""
        d = self.scenario.motion.marker_diameter_mm
        return super().marker_radius_m if d is None else 0.5e-3 * float(d)

    def frame_renderer(self, rasterizer=None) -> FrameRenderer:
        renderer = super().frame_renderer(rasterizer)
        # Same vertex buffers (already uploaded), posed so that absent markers are not drawn.
        renderer.moving = _AbsentMarkersGeometry(renderer.moving.buffers, renderer.moving.group_slices)
        return renderer

    def capture_reference(self) -> CaptureReference:
        """The labelled trial the marker pipeline calibrates the subject from (see :class:`CaptureReference`):
        the capture's trajectories at the frame times, or with ``motion.subject_trial = "rest"`` the file's
        samples outside the window."""
        if self.scenario.motion.subject_trial == "rest":
            return self.clip.rest_reference(self.scenario.duration_s)
        times = self.frame_times()
        return CaptureReference(self.clip.labels, self.clip.file_positions_at(times), times)
