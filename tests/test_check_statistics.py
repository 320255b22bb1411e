"""The statistical gate without rendering: seed ensembles against a baseline distribution
(one-sided test, Holm over the check, practical floor), the old one-value baseline still
read, the format-2 round trip, and --calibrate's rates on runs whose effect is known."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from simbench.sweeps import calibrate as cal
from simbench.sweeps import regression as rg
from simbench.sweeps.results_db import RunRecord

PATTERNS = [
    ("markers.rmse_mm", rg.Tolerance(worse="higher", abs=0.05)),
    ("markers.reconstructed_fraction", rg.Tolerance(worse="lower", abs=0.005)),
    ("run.*", rg.Tolerance(worse="either")),
]


def _rec(name: str, seed: int, metrics: dict[str, float], status: str = "ok", error: str = "") -> RunRecord:
    return RunRecord(run_id=f"{name}-{seed}", sweep="check:t", run_index=seed, scenario=name, scenario_hash="h",
                     factors={"scenario": name, "seed": seed}, parameters={}, status=status, error=error, metrics=metrics)


def _ensemble(name: str, seeds, rmse_shift: float = 0.0, frac_shift: float = 0.0, key: int = 0) -> list[RunRecord]:
    out = []
    for s in seeds:
        rng = np.random.default_rng([key, s])
        out.append(_rec(name, s, {"markers.rmse_mm": 1.0 + rmse_shift + rng.normal(0, 0.05),
                                  "markers.reconstructed_fraction": 0.95 + frac_shift + rng.normal(0, 0.005),
                                  "run.frames": 15.0}))
    return out


@pytest.fixture()
def baseline(tmp_path) -> rg.Baseline:
    recs = {"a": _ensemble("a", range(1000, 1024)), "b": _ensemble("b", range(1000, 1024), key=1)}
    return rg.load_baseline(rg.write_baseline(tmp_path / "b.json", "t", recs))


def _status(checks, scenario, metric):
    return next(c for c in checks if c.scenario == scenario and c.metric == metric)


def test_baseline_format_2_holds_every_seed_and_the_median(baseline, tmp_path):
    data = json.loads(baseline.path.read_text())
    a = data["scenarios"]["a"]
    assert data["format"] == 2 and a["seeds"] == list(range(1000, 1024))
    assert len(a["values"]["markers.rmse_mm"]) == 24
    assert a["metrics"]["markers.rmse_mm"] == pytest.approx(np.median(a["values"]["markers.rmse_mm"]))
    assert baseline.values("a", "markers.rmse_mm").shape == (24,)


def test_unchanged_code_on_fresh_seeds_passes(baseline):
    checks = rg.compare({"a": _ensemble("a", range(8)), "b": _ensemble("b", range(8), key=1)}, baseline, PATTERNS)
    assert not rg.failed(checks), [(c.metric, c.status, c.p_value) for c in checks if c.status != "ok"]
    tested = _status(checks, "a", "markers.rmse_mm")
    assert (tested.n_baseline, tested.n_current) == (24, 8) and 0 < tested.p_value <= 1


def test_a_real_shift_regresses_in_the_metrics_direction_and_the_other_way_improves(baseline):
    checks = rg.compare({"a": _ensemble("a", range(8), rmse_shift=0.2, frac_shift=-0.03), "b": _ensemble("b", range(8), key=1)},
                        baseline, PATTERNS)
    assert _status(checks, "a", "markers.rmse_mm").status == "regressed"
    assert _status(checks, "a", "markers.reconstructed_fraction").status == "regressed"  # lower is worse
    assert _status(checks, "b", "markers.rmse_mm").status == "ok"
    assert _status(checks, "a", "markers.rmse_mm").p_value < 0.01
    better = rg.compare({"a": _ensemble("a", range(8), rmse_shift=-0.2)}, baseline, PATTERNS)
    assert _status(better, "a", "markers.rmse_mm").status == "improved" and not rg.failed(better)


def test_a_significant_shift_below_the_practical_floor_passes(baseline):
    # +0.04 mm: 0.8 SD, every one of 8 seeds above most of the baseline, but under the 0.05 mm floor
    tight = [(m, rg.Tolerance(worse="higher", abs=0.05)) if m == "markers.rmse_mm" else (m, t) for m, t in PATTERNS]
    recs = [_rec("a", s, {"markers.rmse_mm": 1.2 + 0.001 * s, "markers.reconstructed_fraction": 0.95, "run.frames": 15.0})
            for s in range(8)]
    base = rg.Baseline("t", {"a": {"scenario_hash": "h", "metrics": {"markers.rmse_mm": 1.16, "markers.reconstructed_fraction": 0.95,
                                                                     "run.frames": 15.0},
                                   "values": {"markers.rmse_mm": list(1.16 + 0.001 * np.arange(24)),
                                              "markers.reconstructed_fraction": [0.95] * 24, "run.frames": [15.0] * 24}}},
                       baseline.path)
    c = _status(rg.compare({"a": recs}, base, tight), "a", "markers.rmse_mm")
    assert c.p_value < 0.01 and c.status == "ok"  # significant, too small to matter
    c = _status(rg.compare({"a": recs}, base, [("markers.rmse_mm", rg.Tolerance(worse="higher", abs=0.01))] + tight),
                "a", "markers.rmse_mm")
    assert c.status == "regressed"


def test_holm_makes_the_threshold_depend_on_how_many_metrics_are_tested(baseline):
    # one metric shifted by a moderate amount: significant on its own, not after Holm over many metrics
    recs = _ensemble("a", range(8), rmse_shift=0.045)
    alone = rg.compare({"a": recs}, baseline, PATTERNS)
    p_alone = _status(alone, "a", "markers.rmse_mm").p_value
    many = rg.compare({"a": recs, "b": _ensemble("b", range(8), key=1)}, baseline, PATTERNS)
    p_many = _status(many, "a", "markers.rmse_mm").p_value
    # Holm multiplies the smallest p-value by the number of tests: 2 tested metrics alone, 4 with scenario b
    assert p_many == pytest.approx(min(1.0, 2 * p_alone))


def test_a_metric_that_can_no_longer_be_computed_regresses(baseline):
    recs = _ensemble("a", range(8))
    for r in recs:
        r.metrics["markers.rmse_mm"] = math.nan
    assert _status(rg.compare({"a": recs}, baseline, PATTERNS), "a", "markers.rmse_mm").status == "regressed"


def test_a_failed_seed_is_one_error_row_naming_it(baseline):
    recs = _ensemble("a", range(8))
    recs[3] = _rec("a", 3, {}, status="failed", error="RuntimeError: boom\ntb")
    checks = rg.compare({"a": recs}, baseline, PATTERNS)
    row = _status(checks, "a", rg.RUN_ROW)
    assert row.status == "error" and row.note == "seed 3: RuntimeError: boom" and rg.exit_code(checks) == 3


def test_old_one_value_baselines_are_still_read_and_judged_by_tolerance(tmp_path):
    old = {"suite": "t", "scenarios": {"a": {"scenario_hash": "h", "metrics": {"markers.rmse_mm": 1.0, "run.frames": 15}}}}
    (tmp_path / "old.json").write_text(json.dumps(old))
    base = rg.load_baseline(tmp_path / "old.json")
    assert base.format == 1 and base.values("a", "markers.rmse_mm").tolist() == [1.0]
    ok = rg.compare({"a": _ensemble("a", range(8))}, base, PATTERNS)
    assert _status(ok, "a", "markers.rmse_mm").status == "ok" and math.isnan(_status(ok, "a", "markers.rmse_mm").p_value)
    bad = rg.compare({"a": _ensemble("a", range(8), rmse_shift=0.3)}, base, PATTERNS)
    assert _status(bad, "a", "markers.rmse_mm").status == "regressed"  # median 1.3 against 1.0 +- 0.05


def test_calibration_rates_on_runs_with_known_effects(baseline, monkeypatch):
    """run_suite replaced by synthetic runs: the injections shift rmse by a known amount (or not at all)."""
    effect = {0.0: 0.0, 0.2: 0.25}  # detection noise -> rmse shift

    def fake_run_suite(specs, workers=None, scheduler=None, seeds=None, detection_noise_px=0.0, on_record=None):
        out = {}
        for sp in specs:
            name = str(sp.factors["scenario"])
            shift = effect[detection_noise_px] + (0.3 if sp.scenario.markers_pipeline.tracker == "alpha_beta" else 0.0)
            out[name] = _ensemble(name, seeds[name], rmse_shift=shift, key=0 if name == "a" else 1)
            for r in out[name]:
                if on_record:
                    on_record(r, 0, 0)
        return out

    class FakeSuites:
        def get(self, name):
            return rg.Suite(scenarios=[rg.SuiteScenario(name="a", file="quickstart.toml"),
                                       rg.SuiteScenario(name="b", file="quickstart.toml")], seeds=8)

        def runs(self, name):
            suites = rg.load_suites("scenarios/suites.toml")
            q = suites.runs("ci", only=["quickstart"])[0]
            return [rg.RunSpec(q.run_id, i, "check:t", {"scenario": n}, q.overrides, q.scenario) for i, n in enumerate("ab")]

        def tolerances_for(self, name):
            return PATTERNS

    monkeypatch.setattr(cal, "run_suite", fake_run_suite)
    injections = (cal.Injection("noise", lambda sc: {}, 0.2),
                  cal.Injection("tracker", lambda sc: {"markers_pipeline.tracker": "alpha_beta"}),
                  cal.Injection("nothing changes", lambda sc: {}))
    seen = []
    res = cal.calibrate(FakeSuites(), "t", baseline, pool=24, checks=25, injections=injections,
                        on_runs=lambda name, n: seen.append((name, n)))
    rates = {r.name: r.rate for r in res.rows}
    assert rates["unchanged code"] <= 0.05
    assert rates["noise"] == 1.0 and rates["tracker"] == 1.0
    assert rates["nothing changes"] == rates["unchanged code"]  # the same runs: the unchanged pool is reused
    assert seen == [("unchanged code", 48), ("noise", 48), ("tracker", 48)]  # nothing-changes ran nothing
    assert next(r for r in res.rows if r.name == "noise").flagged.most_common(1)[0][0].endswith("markers.rmse_mm")
    lo, hi = res.rows[1].interval()
    assert lo > 0.85 and hi == 1.0


def test_the_shipped_injections_are_the_issues_four_and_change_the_ci_suite_as_named():
    """Issue 13's injected regressions, applied to the ci suite's resolved scenarios: the tracker one is
    kalman -> alpha_beta, and the suite holds a scenario where the 2D trackers label a subject that has
    finished blending out of the T-pose (before that, every tracker keeps every label)."""
    from simbench.scenes.motions import T_POSE_BLEND_S, T_POSE_HOLD_S

    assert [i.name for i in cal.INJECTIONS] == ["2D detection noise +0.2 px", "exposure 4 -> 12 ms",
                                                "tracker kalman -> alpha_beta", "one camera fewer"]
    noise, exposure, tracker, camera = cal.INJECTIONS
    assert noise.detection_noise_px == 0.2
    runs = rg.load_suites("scenarios/suites.toml").runs("ci")
    for r in runs:
        sc = r.scenario
        assert tracker.overrides(sc) == ({"markers_pipeline.tracker": "alpha_beta"} if sc.markers_pipeline.tracker == "kalman"
                                         else {})
        assert exposure.overrides(sc) == ({"sensor.exposure_ms": 12.0} if sc.sensor.exposure_ms == 4.0 else {})
        assert camera.overrides(sc) == {"rig.count": sc.rig.count - 1}
        changed = sc.with_overrides(tracker.overrides(sc))
        assert changed.markers_pipeline.tracker in ("alpha_beta", sc.markers_pipeline.tracker)
    tracked = [r.scenario for r in runs if (r.scenario.markers_pipeline.labelling == "tracker" or r.scenario.rig.count < 3)
               and r.scenario.markers_pipeline.tracker == "kalman" and r.scenario.duration_s > T_POSE_HOLD_S + T_POSE_BLEND_S]
    assert tracked, "no ci scenario where the 2D tracker labels a subject in full motion"
