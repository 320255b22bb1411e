"""A real capture (C3D or TRC) as a scenario's motion: its physical markers, frame by frame.

``[motion] c3d = "FILE"`` (or ``trc``) makes a scenario replay a real capture: the file's
physical markers (:func:`mocap.exports.read_c3d` sets model outputs, virtual points and
empty entries aside) become marker spheres, and the capture is the ground truth the run
is scored against. :func:`simbench.stage.capture.load_capture_clip` prepares it:

* **Window**: scenario time ``t`` is capture time ``start_s + speed * t``, capture time
  counted from the file's first frame. The window must lie inside the capture.
* **Resampling**: positions at any instant (frame mid-exposure, shutter sub-frames) are
  linear interpolations of the two file samples around it; if either is missing the
  marker is missing at that instant (an instant on a file sample uses that sample only).
* **Placement**: world axes, Z up, metres (the reader converts units and Y-up files). The
  capture is shifted horizontally, never vertically or rotated, so that the middle of
  its markers' horizontal extent over the window (at the frame times) is under the
  rig's ``look_at``: a walk crosses the capture volume.
* **Selection**: ``labels`` picks markers (default: every physical marker); markers with
  no sample at any frame time of the window are dropped (named in ``dropped``).
* **Seeded gaps** (``gaps``): ``round(fraction * M)`` markers, drawn with the scenario's
  seed, each lose ``runs`` runs of ``min_frames``..``max_frames`` rendered frames, inside
  the window (never its first or last frame) and never touching each other. A rendered
  frame ``k`` spans ``[k / fps, (k + 1) / fps)``: every instant of its shutter is in the gap.

Missing samples (the file's or the seeded gaps) are NaN in :meth:`CaptureClip.positions_at`;
the renderer draws no sphere there and the ground truth has the marker absent.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocap.labelling import LabelTemplate
from mocap.cluster_labelling import ClusterMarkerModel
from mocap.labelled_trial import reference_frame, template_from_trial

__all__ = ["CaptureClip", "CaptureReference"]

_ON_SAMPLE = 1e-9  # an instant within this fraction of a frame of a file sample uses that sample only


@dataclass(frozen=True, eq=False)
class CaptureClip:
    """A real capture placed in the scene and evaluable at any scenario time.

    Attributes
    ----------
    labels : tuple[str, ...], length M
        The rendered markers, in file order.
    source_xyz : (N, M, 3) float
        The file's samples, world metres (Z up, already shifted by ``shift_xy``); NaN missing.
    rate_hz : float
        The file's frame rate; sample ``i`` is at capture time ``i / rate_hz``.
    start_s, speed : float
        Scenario time ``t`` -> capture time ``start_s + speed * t``.
    fps : float
        The scenario's frame rate (frame ``k`` spans ``[k / fps, (k + 1) / fps)``).
    gap_mask : (F, M) bool
        True where a seeded gap hides the marker in rendered frame ``k``.
    shift_xy : (2,) float
        Horizontal shift applied to the file's positions (metres).
    path : Path
    set_aside : dict[str, str]
        What the reader did not take as physical markers, and why.
    dropped : tuple[str, ...]
        Physical markers with no sample in the window (not rendered).
    source_up_axis, up_axis_reason : str
        The file's up axis and how it was decided.
    label_repairs : str
        The file's own label swaps exchanged back in the window, on one line ("" if none;
        :func:`simbench.stage.capture.repair_window_swaps`).
    """

    labels: tuple[str, ...]
    source_xyz: np.ndarray
    rate_hz: float
    start_s: float
    speed: float
    fps: float
    gap_mask: np.ndarray
    shift_xy: np.ndarray
    path: Path
    set_aside: dict[str, str] = field(default_factory=dict)
    dropped: tuple[str, ...] = ()
    source_up_axis: str = "z"
    up_axis_reason: str = ""
    label_repairs: str = ""

    @property
    def n_markers(self) -> int:
        return len(self.labels)

    @property
    def capture_duration_s(self) -> float:
        return (len(self.source_xyz) - 1) / self.rate_hz

    def file_positions_at(self, times: np.ndarray) -> np.ndarray:
        """Marker positions ``(T, M, 3)`` at scenario ``times (T,)`` seconds, from the file only
        (no seeded gaps): linear interpolation, NaN where a sample used is missing."""
        t = np.asarray(times, dtype=np.float64).reshape(-1)
        u = (self.start_s + self.speed * t) * self.rate_hz  # fractional file sample index
        N = len(self.source_xyz)
        u = np.clip(u, 0.0, N - 1)
        i0 = np.floor(u + _ON_SAMPLE).astype(np.int64)
        i0 = np.minimum(i0, N - 1)
        w = u - i0
        on_sample = np.abs(w) <= _ON_SAMPLE
        i1 = np.where(on_sample, i0, np.minimum(i0 + 1, N - 1))
        w = np.where(on_sample, 0.0, w)[:, None, None]
        a, b = self.source_xyz[i0], self.source_xyz[i1]
        return (1.0 - w) * a + w * b  # NaN propagates: missing if either sample used is missing

    def outside_window(self, duration_s: float) -> np.ndarray:
        """``(N,)`` bool: the file's samples outside the capture window of a scenario ``duration_s`` long
        (before ``start_s`` or after ``start_s + speed * duration_s``)."""
        t = np.arange(len(self.source_xyz)) / self.rate_hz
        return (t < self.start_s - 1e-9) | (t > self.start_s + self.speed * duration_s + 1e-9)

    def rest_reference(self, duration_s: float) -> "CaptureReference":
        """The file's samples outside the window (:meth:`outside_window`) as a labelled trial: another trial
        of the same subject, its times the file's own (seconds from its first sample); the file's own label
        swaps there are left as they are, as a user's trial would have them."""
        out = self.outside_window(duration_s)
        return CaptureReference(self.labels, self.source_xyz[out], np.flatnonzero(out) / self.rate_hz)

    def frame_index(self, times: np.ndarray) -> np.ndarray:
        """Rendered frame ``k`` of each scenario instant (``floor(t * fps)``, clipped to the window)."""
        t = np.asarray(times, dtype=np.float64).reshape(-1)
        k = np.floor(t * self.fps + 1e-6).astype(np.int64)
        return np.clip(k, 0, len(self.gap_mask) - 1)

    def positions_at(self, times: np.ndarray) -> np.ndarray:
        """Marker positions ``(T, M, 3)`` world metres at scenario ``times``: the file's,
        NaN where it has none and in seeded gaps."""
        xyz = self.file_positions_at(times)
        hidden = self.gap_mask[self.frame_index(times)]  # (T, M)
        xyz[hidden] = np.nan
        return xyz


@dataclass(frozen=True, eq=False)
class CaptureReference:
    """What a user's subject calibration gives for a real capture: its labelled trajectories.

    Attributes
    ----------
    labels : tuple[str, ...], length M
    xyz : (F, M, 3) float
        World metres at the scenario's frame times, NaN where the file has no sample
        (seeded gaps are not applied: they stand for markers the cameras lose in the take).
    times : (F,) float
        Seconds.
    """

    labels: tuple[str, ...]
    xyz: np.ndarray
    times: np.ndarray

    def reference_frame(self) -> int:
        """The first frame with the most markers present."""
        return reference_frame(self.xyz)

    def marker_model(self) -> ClusterMarkerModel:
        """The rigid marker clusters of these trajectories (what a commercial system's subject
        calibration learns from a labelled trial), for model-based labelling without a skeleton."""
        return ClusterMarkerModel(list(self.labels), self.xyz)

    def label_template(self) -> LabelTemplate:
        """A :class:`~mocap.labelling.LabelTemplate` from the reference frame, in the subject-local frame the
        template wants (:func:`mocap.labelled_trial.template_from_trial`: what ``mocap markers
        --labelled-trial`` takes as its template when given none)."""
        return template_from_trial(self.labels, self.xyz)
