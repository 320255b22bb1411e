"""Calibration errors a user can fix: each names the camera or file, the cause and the fix.

All subclass :class:`mocap.errors.MocapInputError`, so the CLI prints them as one
paragraph and exits with code 2.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

from mocap.errors import MocapInputError


@dataclass(frozen=True)
class ViewFailure:
    """Why one image or video frame could not be used.

    Attributes
    ----------
    label : str
        File name or ``video.mp4#frame 120``.
    problem : str
        Short cause (``"blurred"``, ``"cut off"``, ``"too small"``, ``"not found"``...).
    detail : str
        What was measured.
    fix : str
    """

    label: str
    problem: str
    detail: str
    fix: str = ""


class CalibrationError(MocapInputError):
    """Base class of calibration input errors."""


class BoardNotFoundError(CalibrationError):
    """A camera saw the board in too few images."""

    def __init__(self, camera: str, n_found: int, n_total: int, n_needed: int,
                 failures: Sequence[ViewFailure], board: str = "board", max_listed: int = 12) -> None:
        self.camera, self.n_found, self.n_total, self.n_needed = camera, n_found, n_total, n_needed
        self.failures = list(failures)
        counts: dict[str, int] = {}
        for f in self.failures:
            counts[f.problem] = counts.get(f.problem, 0) + 1
        causes = ", ".join(f"{n} {p}" for p, n in sorted(counts.items(), key=lambda kv: -kv[1]))
        lines = [f"camera {camera!r}: the {board} was found in only {n_found} of {n_total} images "
                 f"(need at least {n_needed}); failed: {causes or 'none'}."]
        for f in self.failures[:max_listed]:
            lines.append(f"  {f.label}: {f.detail}" + (f" -> {f.fix}" if f.fix else ""))
        if len(self.failures) > max_listed:
            lines.append(f"  ... and {len(self.failures) - max_listed} more")
        fixes = []
        for f in self.failures:
            if f.fix and f.fix not in fixes:
                fixes.append(f.fix)
        lines.append("Fix: " + ("; ".join(fixes[:3]) if fixes else f"take more pictures showing the whole {board}") +
                     f"; then take at least {n_needed} good views per camera.")
        super().__init__("\n".join(lines))


class DegenerateViewsError(CalibrationError):
    """All views show the board at (nearly) the same orientation: focal length is unobservable."""

    def __init__(self, camera: str, n_views: int, spread_deg: float, tilt_min_deg: float, tilt_max_deg: float,
                 min_spread_deg: float) -> None:
        self.camera, self.n_views, self.spread_deg = camera, n_views, spread_deg
        what = ("fronto-parallel (facing the camera squarely)" if tilt_max_deg < min_spread_deg
                else "parallel to each other (the board was only moved, not turned)")
        super().__init__(
            f"camera {camera!r}: degenerate views: the board is {what} in all {n_views} views "
            f"(board normals within {spread_deg:.1f} deg of each other, tilt from the camera axis "
            f"{tilt_min_deg:.1f}-{tilt_max_deg:.1f} deg; need a spread of at least {min_spread_deg:g} deg). "
            f"Zhang's method cannot separate focal length from distance with such views. "
            f"Fix: tilt the board by 20-45 deg in some views, to the left/right and up/down."
        )


class DisconnectedCamerasError(CalibrationError):
    """Some cameras share no synchronised board view with the reference camera's group."""

    def __init__(self, groups: Sequence[Sequence[str]], reference: str) -> None:
        self.groups = [list(g) for g in groups]
        self.reference = reference
        main = next(g for g in self.groups if reference in g)
        others = [g for g in self.groups if reference not in g]
        lost = [n for g in others for n in g]
        desc = "; ".join("{" + ", ".join(g) + "}" for g in self.groups)
        a, b = main[-1], others[0][0]
        super().__init__(
            f"cameras {', '.join(repr(n) for n in lost)} share no board view with camera {reference!r}'s group "
            f"({', '.join(repr(n) for n in main)}); connected groups: {desc}. Extrinsics need the board seen by two "
            f"cameras in the same frame. Fix: show the board to cameras {a} and {b} at the same time "
            f"(hold it where both see it, in several poses), check the image lists / videos are synchronised, "
            f"or wave a wand through the shared volume."
        )


class BundleAdjustmentError(CalibrationError):
    """Bundle adjustment did not converge to a plausible solution."""

    def __init__(self, cost: float, iterations: int, rms_px: dict[str, float], max_rms_px: float,
                 status_message: str, fix: str) -> None:
        self.cost, self.iterations, self.rms_px = cost, iterations, dict(rms_px)
        worst = max(self.rms_px, key=lambda k: self.rms_px[k]) if self.rms_px else "?"
        per_cam = ", ".join(f"{k} {v:.2f} px" for k, v in self.rms_px.items())
        super().__init__(
            f"bundle adjustment did not converge: after {iterations} function evaluations the cost is "
            f"{cost:.4g} and the reprojection RMS is {per_cam} (worst camera {worst!r}; limit {max_rms_px:g} px); "
            f"solver: {status_message.rstrip('.')}. Fix: {fix}."
        )


class WandError(CalibrationError):
    """The wand was seen too little to be used."""
