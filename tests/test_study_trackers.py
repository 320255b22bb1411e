"""The tracker study (issues 4, 19): a reduced rendered study at the calibrated difficulty
with a user-registered tracker; the tables are complete and every count re-derives from
the per-video logs; the calibrated difficulty reproduces seed 000's prediction errors;
the findings' statistics on constructed results with known answers."""

from __future__ import annotations

import csv
import dataclasses
import json

import numpy as np
import pytest

from types import SimpleNamespace

from eval import tracking_metrics as tm
from mocap.trackers import KalmanTracker, available_trackers, register_tracker, unregister_tracker
from simbench.studies import trackers as st
from simbench.studies.trackers import fit as sf
from simbench.studies.trackers import videos

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
    assert PLUGIN in names and set(st.SEED_TRACKERS) | set(st.BENCH_TRACKERS) <= set(names)
    assert names[:7] == list(st.SEED_TRACKERS + st.BENCH_TRACKERS)
    assert result.config.difficulty == st.CALIBRATED_DIFFICULTY  # CI runs at the paper's difficulty
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
    assert tables["config"]["difficulty"]["slow"]["speed_px_per_frame"] == list(st.CALIBRATED_DIFFICULTY.slow.speed_px_per_frame)
    text = report.read_text()
    for title in ["Table I:", "Table II:", "Table III:", "Table IV:", "Table V:", "Table VI:", "Table VII:"]:
        assert title in text
    # The findings, one line each with a verdict, and the cost ratios beside the paper's.
    block = text.split("## Seed 000's findings, checked")[1].split("## Results")[0]
    rows = [r for r in block.splitlines() if r.startswith("| ") and "verdict" not in r]
    assert len(rows) == 4 and all(any(f"**{v}**" in r for v in (st.REPRODUCED, st.NOT_REPRODUCED, st.UNDECIDED))
                                  for r in rows)
    ratios = st.cost_ratios(result)
    cost = tables["tables_V_VII_cost_ms"]
    for n in names:
        assert ratios[n][0] == pytest.approx(cost[n]["5"]["median_ms"] / cost[n]["1"]["median_ms"])
    assert ratios["alpha_beta"][1] == pytest.approx(0.067 / 0.046)  # the paper's, at the same marker counts
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
        M, L = log["n_markers"], log["n_labels"]
        assert arr["true_xy"].shape == (cfg.n_frames, M, 2)
        assert (M, L) == ((2, 1) if log["category"] == "swap" else (1, 1))  # swap: a labelled and a NULL marker
        for n, t in log["trackers"].items():
            k = st.tracker_key(n)
            assert arr[f"{k}__estimate"].shape == (cfg.n_frames, L, 2)
            # The NULL marker enters the scoring as a phantom label that is never visible.
            F = cfg.n_frames
            est = np.concatenate([arr[f"{k}__estimate"], arr["true_xy"][:, L:]], axis=1)
            stat = np.concatenate([arr[f"{k}__status"], np.ones((F, M - L), dtype=int)], axis=1)
            meas = np.concatenate([arr[f"{k}__measured"], np.full((F, M - L, 2), np.nan)], axis=1)
            vis, vis_area = arr["visible"].copy(), arr["visible_area"].copy()
            vis[:, L:] = vis_area[:, L:] = False
            losses = tm.label_losses(arr["true_xy"], vis, est, stat, meas, log["loss_radius_px"])
            assert losses.lost[:L].tolist() == t["label_lost"]
            assert losses.first_frame[:L].tolist() == t["first_loss_frame"]
            assert losses.at_end[:L].tolist() == t["lost_at_end"]
            np.testing.assert_array_equal(losses.flags[:, :L], arr[f"{k}__loss_flags"])
            strict = tm.label_losses(arr["true_xy"], vis_area, est, stat, meas, log["loss_radius_px"])
            strict = SimpleNamespace(lost=strict.lost[:L])
            losses = SimpleNamespace(lost=losses.lost[:L])
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
            # The interval across videos: the mean of the per-video means, bootstrapped over videos.
            means = [p.mean() for p in parts if len(p)]
            across = cell["across_videos"]
            assert across["videos"] == len(means)
            if means:
                assert across["mean"] == pytest.approx(np.mean(means))
            if len(set(means)) > 1:
                assert across["ci95"][0] < np.mean(means) < across["ci95"][1]


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
                # A ~6 px blur streak (8 ms at ~24 px/frame) that bends at a zigzag corner has
                # its centroid off the mid-exposure position by up to ~1.5 px; a marker partly
                # behind the barrier, the centroid of the part that shows.
                tol = 2.0 if v.visible_fraction[f, m] > 0.99 else 3.0
                assert len(d) and d.min() < tol, (r.category, r.index, f, m)
        if r.category == "occlusion":
            hidden = ~v.visible[:, 0]
            assert hidden.sum() >= 1
            b = r.barrier
            off = np.abs(v.true_xy[:, 0] - np.array(b.centre_px))
            deep = (off[:, 0] < b.width_px / 2 - 8.0) & (off[:, 1] < b.height_px / 2 - 8.0)  # blob and blur hidden
            assert (v.visible_fraction[deep, 0] == 0).all()
            assert all(len(v.detections[f]) == 0 for f in np.flatnonzero(deep))


@pytest.mark.parametrize("category", st.CATEGORIES)
def test_video_plans_are_seeded_start_in_the_image_and_move_at_the_category_speeds(category):
    cfg = st.StudyConfig()
    d = cfg.difficulty
    frames = np.arange(cfg.n_frames) / cfg.fps
    speeds_seen = []
    for k in range(6):
        plan = st.plan_video(cfg, category, k)
        again = st.plan_video(cfg, category, k)
        np.testing.assert_array_equal(plan.knot_xy, again.knot_xy)
        xy = plan.xy_at(frames)
        assert videos._inside(xy[:3])
        if category in ("slow", "rapid", "acceleration"):
            assert videos._inside(xy)  # the fitted motions stay in the image
        step = np.linalg.norm(np.diff(xy, axis=0), axis=-1)  # px/frame
        speeds_seen.append(np.median(step))
        if category == "occlusion":
            assert plan.barrier.hides(xy[:, 0]).sum() >= 1
            assert d.occlusion.barrier_width_px[0] <= plan.barrier.width_px <= d.occlusion.barrier_width_px[1]
        if category == "swap":
            sep = np.linalg.norm(xy[:, 0] - xy[:, 1], axis=1)
            assert sep.min() < 8.0 and sep[0] >= 3 * cfg.loss_radius_px
            assert st.n_labels(plan) == 1  # a labelled marker and a NULL one
    assert not np.array_equal(st.plan_video(cfg, category, 0).knot_xy[:5], st.plan_video(cfg, category, 1).knot_xy[:5])
    lo, hi = {"slow": d.slow.speed_px_per_frame, "rapid": d.rapid.speed_px_per_frame,
              "acceleration": (d.acceleration.start_speed_px_per_frame[0], d.acceleration.top_speed_px_per_frame[1]),
              "occlusion": d.occlusion.speed_px_per_frame, "swap": d.swap.speed_px_per_frame}[category]
    assert lo * 0.95 <= min(speeds_seen) and max(speeds_seen) <= hi * 1.02, speeds_seen


def test_calibrated_difficulty_reproduces_the_papers_prediction_errors():
    """Acceptance of the fit, without rendering: at the calibrated difficulty the paper's
    alpha-beta and Kalman filters' mean prediction errors are within 25 % of Tables
    II-IV on the study's own videos (seed 0, 20 per category); the rendered study
    confirms it (its Tables II-IV)."""
    cfg = st.StudyConfig()
    for c in st.ERROR_CATEGORIES:
        means, _ = sf.mean_errors(cfg, c, 20, noise_px=0.08, trackers=("alpha_beta", "kalman_openmocap"))
        for n, m in means.items():
            assert 0.75 <= m / st.PAPER_ERRORS[c][n][2] <= 1.25, (c, n, m)


def test_fit_recovers_a_known_difficulty():
    """Targets made from a known acceleration difficulty are fitted back from a start
    30 % off. On 5 videos (2026-11-27: 18.03 px/frame, 0.80 s, objective 2.7e-5 after 33
    evaluations, 8.3 CPU-s); 8 gave 18.18, 0.81, 3.2e-4 after 42 in 15.5 CPU-s, and 4 gave
    17.23, 0.74: too near the bars."""
    truth = (18.0, 0.8)
    cfg = st.StudyConfig(seed=3)
    cfg = dataclasses.replace(cfg, difficulty=dataclasses.replace(cfg.difficulty, acceleration=sf.acceleration_difficulty(*truth)))
    means, _ = sf.mean_errors(cfg, "acceleration", 5, noise_px=0.08)
    fit = sf.fit_category("acceleration", n_videos=5, seed=3, start=(truth[0] * 1.3, truth[1] * 0.7),
                          max_evaluations=60, paper=means)
    assert fit.centre["top_speed_px_per_frame"] == pytest.approx(truth[0], rel=0.1)
    assert fit.centre["period_s"] == pytest.approx(truth[1], rel=0.15)
    assert fit.objective < 0.01


def test_score_labels_counts_a_label_taking_the_null_marker():
    F = 6
    true = np.zeros((F, 2, 2))
    true[:, 0] = np.array([100.0, 100.0]) + np.arange(F)[:, None] * np.array([5.0, 0.0])
    true[:, 1] = np.array([100.0, 160.0]) + np.arange(F)[:, None] * np.array([5.0, -8.0])
    measured = true[:, :1].copy()
    measured[4, 0] = true[4, 1]  # frame 4: the label takes the NULL marker's blob (they are 28 px apart)
    estimate = measured.copy()
    status = np.ones((F, 1), dtype=int)
    visible = np.ones((F, 2), dtype=bool)
    losses = st.score_labels(true, visible, estimate, status, measured, 10.0)
    assert losses.lost.tolist() == [True] and losses.first_frame.tolist() == [4]
    assert losses.flags[:, 0].tolist() == [0, 0, 0, 0, tm.REASON_FAR, 0]  # far wins over other at frame 4
    measured[4, 0] = true[4, 0] + np.array([0.0, 6.0])  # near its own marker: no loss
    assert not st.score_labels(true, visible, measured, status, measured, 10.0).lost.any()


def test_loss_rate_is_the_clopper_pearson_interval():
    r = st.loss_rate(0, 20, 0.99)
    assert r.lower == 0.0 and r.upper == pytest.approx(1 - 0.005 ** (1 / 20))
    r = st.loss_rate(20, 20, 0.99)
    assert r.upper == 1.0 and r.lower == pytest.approx(0.005 ** (1 / 20))


def _fake_result(lost: dict[str, list[bool]], errors: dict[str, dict[str, np.ndarray]]):
    """A StudyResult-shaped object with given per-video losses (all in 'slow') and error samples."""
    n = len(next(iter(lost.values())))
    videos = [SimpleNamespace(category="slow", runs={t: SimpleNamespace(lost=v[k]) for t, v in lost.items()})
              for k in range(n)]
    summaries = {c: {t: tm.summarise_errors(x) for t, x in row.items()} for c, row in errors.items()}
    return SimpleNamespace(trackers=list(lost), videos=videos, config=SimpleNamespace(confidence=0.99),
                           losses={"slow": {t: sum(v) for t, v in lost.items()}, "swap": {t: 0 for t in lost}},
                           error_samples=errors, errors=summaries)


def test_findings_verdicts_on_known_results():
    rng = np.random.default_rng(0)
    n = 60
    lost = {"alpha_beta": [k < 20 for k in range(n)], "kalman_openmocap": [False] * n,
            "condensation": [k < 12 for k in range(n)], "alpha_beta_adaptive": [k == 0 for k in range(n)]}
    errors = {"slow": {"alpha_beta": rng.normal(7, 2, 500), "kalman_openmocap": rng.normal(10, 2, 500),
                       "condensation": rng.normal(39, 3, 500), "alpha_beta_adaptive": rng.normal(7, 2, 500)}}
    verdicts = [f.verdict for f in st.findings(_fake_result(lost, errors))]
    assert verdicts == [st.REPRODUCED] * 4
    # McNemar on 20 vs 3 discordant videos: p = 2 * P(X >= 17 | 20, 1/2) ~ 2.6e-4
    pair = st.paired_losses(_fake_result(lost, errors), "alpha_beta", "condensation")
    assert (pair.only_a, pair.only_b, pair.direction) == (8, 0, 1)
    assert pair.p_value == pytest.approx(2 * 0.5**8)  # exact McNemar: all 8 discordant videos one way
    # Kalman now loses as often as CONDENSATION: not decidable; CONDENSATION with the lowest
    # errors: not reproduced; the growing area losing more: not reproduced.
    lost2 = dict(lost, kalman_openmocap=lost["condensation"], alpha_beta_adaptive=[k < 40 for k in range(n)])
    errors2 = {"slow": dict(errors["slow"], condensation=rng.normal(2, 1, 500))}
    v2 = [f.verdict for f in st.findings(_fake_result(lost2, errors2))]
    assert v2[1] == st.UNDECIDED and v2[2] == st.NOT_REPRODUCED and v2[3] == st.NOT_REPRODUCED
    assert v2[0] == st.NOT_REPRODUCED  # alpha-beta's error is no longer below CONDENSATION's


def test_cli_names_the_known_trackers_for_an_unknown_one(tmp_path):
    from typer.testing import CliRunner

    from simbench.cli import app

    res = CliRunner().invoke(app, ["study", "trackers", "--out", str(tmp_path), "--trackers", "kalman,nope"])
    assert res.exit_code == 2
    assert "nope" in res.output and "alpha_beta" in res.output and "imm" in res.output
    assert not any(tmp_path.iterdir())  # nothing rendered or written
