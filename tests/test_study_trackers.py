"""The tracker study (issue 4): a reduced rendered study with a user-registered tracker;
the tables are complete and every count re-derives from the per-video logs."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from eval import tracking_metrics as tm
from mocap.trackers import KalmanTracker, available_trackers, register_tracker, unregister_tracker
from simbench import study_trackers as st

PLUGIN = "study_test_kalman"


def _reduced_study(out):
    """2 videos per category, 30 frames, every registered tracker plus one registered here."""

    @register_tracker(PLUGIN)
    class StudyTestKalman(KalmanTracker):  # a user's tracker: registered, nothing else
        pass

    try:
        cfg = st.StudyConfig(videos_per_category=2, n_frames=30, seed=5, cost_marker_counts=(1, 5), cost_frames=20)
        result = st.run_study(cfg)
        report = st.write_study(result, out)
    finally:
        unregister_tracker(PLUGIN)
    return result, out, report


def test_reduced_study_fills_every_table_consistently_with_its_logs(tmp_path):
    """CI's reduced study (one run, checked four ways below: it renders, so it runs once)."""
    study = _reduced_study(tmp_path)
    _check_every_registered_tracker_is_in_every_table(study)
    _check_loss_counts_rederive_from_the_per_video_logs(study)
    _check_losses_and_errors_recompute_from_the_per_frame_arrays(study)
    _check_rendered_videos_match_their_ground_truth(study)


def _check_every_registered_tracker_is_in_every_table(study):
    result, out, report = study
    names = result.trackers
    assert PLUGIN in names and set(st.SEED_TRACKERS) | {st.OWN_TRACKER} <= set(names)
    assert names[:3] == list(st.SEED_TRACKERS)
    tables = json.loads((out / "tables.json").read_text())
    assert list(tables["table_I_losses"]) == list(st.CATEGORIES)
    for row in tables["table_I_losses"].values():
        assert set(row) == set(names) and all(0 <= v <= 2 for v in row.values())
    assert list(tables["tables_II_IV_prediction_error_px"]) == list(st.ERROR_CATEGORIES)
    for row in tables["tables_II_IV_prediction_error_px"].values():
        assert set(row) == set(names)
        for cell in row.values():
            if cell["samples"] >= 2:
                assert cell["lower"] <= cell["mean"] <= cell["upper"]
    for n in names:
        assert set(tables["tables_V_VII_cost_ms"][n]) == {"1", "5"}
        for c in tables["tables_V_VII_cost_ms"][n].values():
            assert 0 < c["p5_ms"] <= c["median_ms"] <= c["p95_ms"] <= c["max_ms"]
    text = report.read_text()
    for title in ["Table I:", "Table II:", "Table III:", "Table IV:", "Table V:", "Table VI:", "Table VII:"]:
        assert title in text
    sections = {s.split(":")[0]: s for s in text.split("### ")[1:]}
    for title in ["Table I", "Table II", "Table III", "Table IV"]:
        assert PLUGIN in sections[title], title
    assert f"{PLUGIN}, per-frame tracking cost" in text  # its cost table (Tables V-VII layout)
    for png in ["plots/losses.png", "plots/prediction_errors.png", "plots/cost.png"] + [
            f"frames/{c}_annotated.png" for c in st.CATEGORIES]:
        assert (out / png).stat().st_size > 5000, png
    assert "## Discussion" in text and f"more than **{result.config.loss_radius_px:g} px**" in text
    assert PLUGIN not in available_trackers()  # the helper cleaned up


def _check_loss_counts_rederive_from_the_per_video_logs(study):
    result, out, _ = study
    tables = json.loads((out / "tables.json").read_text())
    logs = [json.loads(p.read_text()) for p in sorted((out / "videos").glob("*.json"))]
    assert len(logs) == 2 * len(st.CATEGORIES)
    from_json = tm.count_losses((g["category"], n, any(t["label_lost"])) for g in logs for n, t in g["trackers"].items())
    assert from_json == tables["table_I_losses"] == result.losses
    strict = tm.count_losses((g["category"], n, any(t["label_lost_strict"])) for g in logs for n, t in g["trackers"].items())
    assert strict == tables["table_I_losses_strict"]
    unrecovered = tm.count_losses((g["category"], n, any(t["lost_at_end"])) for g in logs for n, t in g["trackers"].items())
    assert unrecovered == tables["table_I_losses_unrecovered"]
    for c, row in tables["table_I_losses"].items():
        for n, v in row.items():
            assert tables["table_I_losses_unrecovered"][c][n] <= v <= tables["table_I_losses_strict"][c][n]
    with open(out / "losses.csv") as fh:
        rows = list(csv.DictReader(fh))
    lost_videos = {(r["category"], r["video"], r["tracker"]) for r in rows if r["lost"] == "1"}
    from_csv = {c: {n: sum((c, str(k), n) in lost_videos for k in range(2)) for n in result.trackers} for c in st.CATEGORIES}
    assert from_csv == tables["table_I_losses"]
    assert tables["total_losses"] == tm.total_losses(tables["table_I_losses"])


def _check_losses_and_errors_recompute_from_the_per_frame_arrays(study):
    result, out, _ = study
    cfg = result.config
    tables = json.loads((out / "tables.json").read_text())
    pooled = {c: {n: [] for n in result.trackers} for c in st.ERROR_CATEGORIES}
    for log_path in sorted((out / "videos").glob("*.json")):
        log = json.loads(log_path.read_text())
        arr = st.load_video_arrays(log_path.with_suffix(".npz"))
        assert arr["true_xy"].shape == (cfg.n_frames, log["n_labels"], 2)
        for n, t in log["trackers"].items():
            k = st.tracker_key(n)
            losses = tm.label_losses(arr["true_xy"], arr["visible"], arr[f"{k}__estimate"], arr[f"{k}__status"],
                                     arr[f"{k}__measured"], log["loss_radius_px"])
            assert losses.lost.tolist() == t["label_lost"]
            assert losses.first_frame.tolist() == t["first_loss_frame"]
            assert losses.at_end.tolist() == t["lost_at_end"]
            np.testing.assert_array_equal(losses.flags, arr[f"{k}__loss_flags"])
            strict = tm.label_losses(arr["true_xy"], arr["visible_area"], arr[f"{k}__estimate"], arr[f"{k}__status"],
                                     arr[f"{k}__measured"], log["loss_radius_px"])
            assert strict.lost.tolist() == t["label_lost_strict"]
            assert (strict.lost | ~losses.lost).all()  # scoring more frames never removes a loss
            errors = tm.prediction_errors(arr[f"{k}__predicted"], arr[f"{k}__measured"])
            assert len(errors) == t["n_prediction_errors"]
            if t["in_error_table"]:
                pooled[log["category"]][n].append(errors)
    for c, row in pooled.items():
        for n, parts in row.items():
            cell = tables["tables_II_IV_prediction_error_px"][c][n]
            v = np.concatenate(parts) if parts else np.zeros(0)
            assert cell["samples"] == len(v)
            if len(v):
                assert cell["mean"] == pytest.approx(v.mean())


def _check_rendered_videos_match_their_ground_truth(study):
    """Every visible marker is detected near its true projection; hidden ones (barrier) are not."""
    result, _, _ = study
    for r in result.videos:
        v = r.video
        for f, det in enumerate(v.detections):
            for m in np.flatnonzero(v.visible[f]):
                if r.category == "swap" and np.linalg.norm(v.true_xy[f, 0] - v.true_xy[f, 1]) < 8.0:
                    continue  # merged blob
                d = np.linalg.norm(det - v.true_xy[f, m], axis=1)
                assert len(d) and d.min() < 1.0, (r.category, r.index, f, m)
        if r.category == "occlusion":
            hidden = ~v.visible[:, 0]
            assert hidden.sum() >= 2
            assert all(len(v.detections[f]) == 0 for f in np.flatnonzero(v.visible_fraction[:, 0] == 0))


@pytest.mark.parametrize("category", st.CATEGORIES)
def test_video_plans_are_seeded_inside_the_image_and_at_the_category_speeds(category):
    cfg = st.StudyConfig()
    frames = np.arange(cfg.n_frames) / cfg.fps
    speeds_seen = []
    for k in range(6):
        plan = st.plan_video(cfg, category, k)
        again = st.plan_video(cfg, category, k)
        np.testing.assert_array_equal(plan.knot_xy, again.knot_xy)
        xy = plan.xy_at(frames)
        assert st._inside(xy)
        step = np.linalg.norm(np.diff(xy, axis=0), axis=-1)  # px/frame
        speeds_seen.append(np.median(step))
        if category == "occlusion":
            assert plan.barrier.hides(xy[:, 0]).sum() >= 3
        if category == "swap":
            sep = np.linalg.norm(xy[:, 0] - xy[:, 1], axis=1)
            assert sep.min() < 8.0 and sep[0] >= 3 * cfg.loss_radius_px and sep[-1] >= 3 * cfg.loss_radius_px
    assert not np.array_equal(st.plan_video(cfg, category, 0).knot_xy[:5], st.plan_video(cfg, category, 1).knot_xy[:5])
    lo, hi = {"slow": (1.4, 4.1), "rapid": (7.5, 15.5), "acceleration": (1.0, 15.0), "occlusion": (2.9, 7.5),
              "swap": (2.9, 6.1)}[category]
    assert lo <= min(speeds_seen) and max(speeds_seen) <= hi, speeds_seen


def test_cli_names_the_known_trackers_for_an_unknown_one(tmp_path):
    from typer.testing import CliRunner

    from simbench.cli import app

    res = CliRunner().invoke(app, ["study", "trackers", "--out", str(tmp_path), "--trackers", "kalman,nope"])
    assert res.exit_code == 2
    assert "nope" in res.output and "alpha_beta" in res.output and "imm" in res.output
    assert not any(tmp_path.iterdir())  # nothing rendered or written
