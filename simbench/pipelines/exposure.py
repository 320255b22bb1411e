"""A run's scores through changes of light (issue 15): the frames' brightness and the detections
around each ``[[lighting.events]]``, what auto exposure is for.

``detections.recovery_s``: the longest, over the events, time from the event until both the
fraction of visible markers with a blob within 2 px of their true image position (the rate) and
the fraction of blobs within 2 px of a visible marker (the precision: the rest is noise or
clutter) are back to 90 % of their mean over the 0.5 s before and stay there for 5 frames
(:func:`eval.exposure_metrics.recovery_time_s`).
``exposure.brightness_recovery_s``: the same for the frames' mean grey level (back within 10 %
of its level before). The report gets a table of both around each event.
"""

from __future__ import annotations

import numpy as np

from eval.exposure_metrics import detection_precision, detection_rate, recovery_time_s
from mocap.types import Detections
from simbench.scenario import Scenario
from simbench.stage.ground_truth import GroundTruth

__all__ = ["score_light_events"]

#: The report's table around an event: from this long before to this long after (s).
_TABLE_BEFORE_S, _TABLE_AFTER_S = 0.2, 0.7


def score_light_events(scenario: Scenario, gt: GroundTruth, detections: list[list[Detections]],
                       brightness: np.ndarray) -> tuple[dict[str, float], list[str]]:
    """Metrics and the report section of a take with light events.

    brightness : (F, C) mean grey level (0-255) of each camera's frame
    """
    events = [e for e in scenario.lighting.events if gt.times[0] < e.t_s <= gt.times[-1]]
    if not events:
        return {}, []
    blobs = [[d.xy for d in cam] for cam in detections]
    rate = detection_rate(blobs, gt.markers_2d, gt.marker_visible)
    precision = detection_precision(blobs, gt.markers_2d, gt.marker_visible)
    level = np.asarray(brightness, float).mean(axis=1)
    rec, bright_rec = [], []
    for e in events:
        rec.append(max(recovery_time_s(gt.times, rate, e.t_s), recovery_time_s(gt.times, precision, e.t_s)))
        bright_rec.append(recovery_time_s(gt.times, level, e.t_s, fraction=0.9, hold_frames=5))
    metrics = {"detections.recovery_s": _worst(rec), "exposure.brightness_recovery_s": _worst(bright_rec),
               "detections.rate_mean": float(np.nanmean(rate)), "detections.precision_mean": float(np.nanmean(precision))}
    ae = "on" if scenario.sensor.auto_exposure else "off"
    lines = ["## Light events: brightness and detections", "",
             f"Auto exposure {ae}" + (f" (target {scenario.sensor.ae_target}, time constant {scenario.sensor.ae_adapt_s} s, "
                                     f"gain up to {scenario.sensor.ae_max_gain}x)" if ae == "on" else "") + ". "
             "Detection rate: the fraction of visible markers (all cameras) with a blob within 2 px; precision: the "
             "fraction of blobs within 2 px of a visible marker. Recovery: from the event until both are back to 90 % "
             "of their mean over the 0.5 s before, for 5 frames.", ""]
    for e, r, b in zip(events, rec, bright_rec):
        lines += [f"**{e.light} to intensity {e.intensity:g} at {e.t_s:g} s**: detections recover in "
                  f"{_seconds(r)}, brightness in {_seconds(b)}.", "",
                  "| t - event (s) | mean grey level | detection rate | precision |", "|---|---|---|---|"]
        near = np.flatnonzero((gt.times >= e.t_s - _TABLE_BEFORE_S) & (gt.times <= e.t_s + _TABLE_AFTER_S))
        for k in near:
            lines.append(f"| {gt.times[k] - e.t_s:+.3f} | {level[k]:.1f} | {rate[k]:.3f} | {precision[k]:.3f} |")
        lines.append("")
    return metrics, lines


def _worst(values: list[float]) -> float:
    """The longest recovery (inf if one never recovers), NaN if none could be measured."""
    v = np.asarray(values, float)
    return float(v[~np.isnan(v)].max()) if (~np.isnan(v)).any() else float("nan")


def _seconds(v: float) -> str:
    if np.isnan(v):
        return "n/a (no frame before the event)"
    if np.isinf(v):
        return "never within the take"
    return f"{v:.3f} s"
