"""Model-based labelling end to end on rendered frames: no T-pose first frame, real motion.

Labels come from the subject model fitted where it is most confident, not from a T-pose
first frame: the quickstart started mid-wave (issue 12's bar) and a shortened CMU walk.
"""

from __future__ import annotations

import pytest

from simbench.pipelines.run import run_scenario
from simbench.scenario import load_scenario


def test_quickstart_started_mid_wave_meets_the_quickstart_bars() -> None:
    sc = load_scenario("scenarios/quickstart.toml", overrides={"motion.start_s": 1.0, "duration_s": 1.0})
    m = run_scenario(sc, None, write_outputs=False).metrics
    print({k: round(v, 4) for k, v in m.items() if k.startswith(("markers.", "skeleton."))})
    assert m["markers.reconstructed_fraction"] >= 0.98, m
    assert m["markers.rmse_mm"] <= 1.2, m
    assert m["markers.label_swaps"] == 0, m
    assert m["skeleton.joint_angle_rmse_deg"] <= 2.0, m


def test_tracker_labelling_is_still_available_and_needs_the_t_pose() -> None:
    """Seed 000's path (labels from a T-pose first frame, 2D trackers) on the same mid-wave
    start loses labels: the difference is what the model-based labelling buys."""
    over = {"motion.start_s": 1.0, "duration_s": 1.0, "markers_pipeline.solve_skeleton": False}
    model = run_scenario(load_scenario("scenarios/quickstart.toml", overrides=over), None, write_outputs=False).metrics
    tracker = run_scenario(load_scenario("scenarios/quickstart.toml", overrides={**over, "markers_pipeline.labelling": "tracker"}),
                           None, write_outputs=False).metrics
    print("model", model["markers.reconstructed_fraction"], "tracker", tracker["markers.reconstructed_fraction"])
    assert tracker["markers.reconstructed_fraction"] < model["markers.reconstructed_fraction"] - 0.05


@pytest.mark.slow
def test_cmu_walk_labels_every_marker_without_swaps() -> None:
    """1 s of the walk itself (3.5-4.5 s of CMU 131_01, about a stride): a guard, not issue 12's bar
    over the whole window (see the README's real-motion table); the T-pose labelling reconstructed
    0.16. (2026-11-27: reconstructed 1.000, 0 swaps, 0.99 mm, 0.18 deg in 19 CPU-s; 1.5 s gave
    0.999, 0, 1.03 mm, 0.20 deg in 27.)"""
    sc = load_scenario("scenarios/bvh_walk.toml", overrides={"duration_s": 1.0, "motion.start_s": 3.5})
    m = run_scenario(sc, None, write_outputs=False).metrics
    print({k: round(v, 4) for k, v in m.items() if k.startswith(("markers.", "skeleton."))})
    assert m["markers.reconstructed_fraction"] >= 0.96, m
    assert m["markers.label_swaps"] == 0, m
    assert m["markers.rmse_mm"] <= 2.5, m
    assert m["skeleton.joint_angle_rmse_deg"] <= 2.0, m
