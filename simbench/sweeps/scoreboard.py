"""``simbench scoreboard SUITE``: the project's pipeline and every installed third-party tool
on the same frames, one table (issue 14, part 4).

For each scenario of the suite (``scenarios/suites.toml``, with the suite's overrides):

1. ``simbench run`` renders it once and runs the project's marker pipeline (and, with a
   ``[calibration_scene]``, its calibration session) on the frames: the row ``project``;
2. the same rendered frames' detections, labelled by the exact projections
   (:mod:`simbench.pipelines.exchange.inputs`), are triangulated by the project's own
   triangulation (``mocap.triangulation.triangulate``, robust, and ``triangulate_dlt``):
   the rows ``project (labelled 2D)``, the fair comparison for tools that are handed labels;
3. every installed adapter (:mod:`simbench.pipelines.exchange.adapters`) gets the same
   labelled detections in its own calibration format and runs its own code in its own
   environment, with its defaults and with the settings its README documents; a tool that
   calibrates also calibrates from the same board pictures the project's calibration used.

Every row is scored by the same code (``eval``): 3D RMSE and p95 over the marker-frames the
truth shows in two or more cameras that the system reconstructed, the reconstructed fraction,
label swaps, joint-angle RMSE where a system solves a skeleton (the project only), calibration
errors where a system calibrates (worst camera; rigid alignment of the camera centres), and
time per frame (wall time of the system's own step: the project's whole pipeline from 2D
detections, a tool's triangulation and filtering; not rendering nor blob detection).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from eval import marker_metrics
from eval.calibration_metrics import compare_calibrations
from eval.seed_stats import SeedSummary, bootstrap_summary
from mocap.calibration_formats import load_calibration
from mocap.triangulation import triangulate, triangulate_dlt
from simbench.pipelines.exchange.adapters import ADAPTERS, AdapterError, adapter_version, installed_adapters, run_adapter
from simbench.pipelines.exchange.inputs import labelled_detections, write_inputs
from simbench.pipelines.exchange.results import read_results, score_results
from simbench.pipelines.run import run_scenario
from simbench.stage.build import build_stage
from simbench.sweeps.regression import load_suites

__all__ = ["ScoreRow", "Scoreboard", "run_scoreboard", "write_report", "table_lines"]

COLUMNS = (("markers.rmse_mm", "RMSE mm", "{:.3f}"), ("markers.p95_error_mm", "p95 mm", "{:.2f}"),
           ("markers.reconstructed_fraction", "recon.", "{:.4f}"), ("markers.label_swaps", "swaps", "{:.0f}"),
           ("skeleton.joint_angle_rmse_deg", "angle deg", "{:.2f}"),
           ("calib.focal_error_pct", "focal %", "{:.3f}"), ("calib.principal_point_error_px", "pp px", "{:.2f}"),
           ("calib.rotation_error_deg", "rot deg", "{:.3f}"), ("calib.translation_error_mm", "trans mm", "{:.2f}"),
           ("ms_per_frame", "ms/frame", "{:.2f}"))


@dataclass
class ScoreRow:
    scenario: str
    system: str  # "project", "aniposelib", "pose2sim"
    variant: str
    metrics: dict[str, float]
    errors_mm: np.ndarray | None = None  # per marker-frame 3D errors (for the plots)
    note: str = ""
    seed: int = 0


@dataclass
class Scoreboard:
    suite: str
    rows: list[ScoreRow] = field(default_factory=list)
    versions: dict[str, str] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)
    frames: dict[str, int] = field(default_factory=dict)
    seeds: int = 1

    def summaries(self) -> list[tuple[ScoreRow, dict[str, SeedSummary]]]:
        """One entry per (scenario, system, variant), first row's identity, and per metric the
        seeds' mean with its 95 % bootstrap CI (:func:`eval.seed_stats.bootstrap_summary`, one
        seeded generator per metric so the report is reproducible)."""
        groups: dict[tuple[str, str, str], list[ScoreRow]] = {}
        for r in self.rows:
            groups.setdefault((r.scenario, r.system, r.variant), []).append(r)
        out = []
        for i, rows in enumerate(groups.values()):
            keys = dict.fromkeys(k for r in rows for k in r.metrics)
            out.append((rows[0], {k: bootstrap_summary([r.metrics.get(k, np.nan) for r in rows], rng=np.random.default_rng([i, j]))
                                  for j, k in enumerate(keys)}))
        return out


def _errors_mm(est: np.ndarray, true: np.ndarray, visible: np.ndarray) -> np.ndarray:
    seen = (visible.sum(axis=1) >= 2)  # (F, M): the truth shows the marker in two cameras or more
    e = marker_metrics.marker_errors_m(est, true)[seen] * 1e3
    return e[np.isfinite(e)]


def _labelled_rows(scenario: str, pts: np.ndarray, calibration, gt, ms_scale: float) -> list[ScoreRow]:
    """The project's own triangulation on the labelled detections (robust and plain DLT)."""
    F, C, M, _ = pts.shape
    flat = np.transpose(pts, (1, 0, 2, 3)).reshape(C, F * M, 2)
    rows = []
    for variant, fn in (("triangulate (labelled 2D, 2 px rejection)", lambda: triangulate(flat, calibration).points),
                        ("triangulate_dlt (labelled 2D)", lambda: triangulate_dlt(flat, calibration))):
        t0 = time.perf_counter()
        xyz = np.asarray(fn()).reshape(F, M, 3)
        ms = (time.perf_counter() - t0) * ms_scale
        m = marker_metrics.summarize_markers(xyz, gt.markers_3d, gt.marker_visible)
        m["ms_per_frame"] = ms
        rows.append(ScoreRow(scenario, "project", variant, m, _errors_mm(xyz, gt.markers_3d, gt.marker_visible)))
    return rows


def _project_row(name: str, res, gt) -> ScoreRow:
    keep = [k for k, _, _ in COLUMNS if k in res.metrics]
    m = {k: float(res.metrics[k]) for k in keep}
    F = gt.n_frames
    if "pipeline_s" in res.timings_s and res.capture is not None:
        m["ms_per_frame"] = 1e3 * res.timings_s["pipeline_s"] / F
    err = None
    note = "unlabelled blobs: labels, tracks, fills and solves the skeleton itself"
    if res.capture is not None:
        traj = res.capture.trajectories
        est = traj.xyz[:, [traj.labels.index(n) for n in gt.marker_names]]
        err = _errors_mm(est, gt.markers_3d, gt.marker_visible)
    if "calib.focal_error_pct" in res.metrics:
        note = f"mocap calibrate: board + wand, {res.timings_s.get('calibration_s', float('nan')):.0f} s"
    return ScoreRow(name, "project", "mocap pipeline (scenario settings)" if res.capture is not None else "mocap calibrate",
                    m, err, note)


def _adapter_rows(name: str, adapter: str, sc, stage, gt, detections, folder: Path, sb: Scoreboard) -> list[ScoreRow]:
    spec = ADAPTERS[adapter]
    rows: list[ScoreRow] = []
    calibrate = spec.calibrates and sc.calibration_scene is not None
    inputs = folder / f"inputs_{spec.fmt}"
    write_inputs(inputs, spec.fmt, sc, stage, gt, gt.calibration(), detections if stage.marker_names else None, board=calibrate)
    if stage.marker_names:
        timings = run_adapter(adapter, "triangulate", inputs, folder / adapter)
        secs = timings["seconds"]
        for variant in spec.variants:
            if variant in timings.get("failed", {}):
                rows.append(ScoreRow(name, adapter, variant, {}, note=f"failed in the tool: {timings['failed'][variant]}"))
                continue
            traj = read_results(folder / adapter / f"{variant}.csv")
            m = score_results(traj, gt.markers_3d, gt.marker_visible, gt.marker_names, gt.times, folder / adapter / f"{variant}.csv")
            s = secs.get(variant, secs.get("triangulation_from_best_cameras", np.nan) + secs.get(f"{variant} gaps+filter", 0.0))
            m["ms_per_frame"] = 1e3 * s / gt.n_frames
            est = read_results(folder / adapter / f"{variant}.csv").xyz
            idx = {n: i for i, n in enumerate(traj.labels)}
            full = np.full(gt.markers_3d.shape, np.nan)
            for j, n in enumerate(gt.marker_names):
                if n in idx:
                    full[:, j] = est[:, idx[n]]
            rows.append(ScoreRow(name, adapter, variant, m, _errors_mm(full, gt.markers_3d, gt.marker_visible)))
    if calibrate:
        timings = run_adapter(adapter, "calibrate", inputs, folder / f"{adapter}_calibration")
        est = load_calibration(folder / f"{adapter}_calibration" / "calibration.toml")
        summary = compare_calibrations(est, gt.calibration(), align="rigid")["summary"]
        m = {f"calib.{k}": float(summary[k]) for k in ("focal_error_pct", "principal_point_error_px", "rotation_error_deg",
                                                       "translation_error_mm")}
        boards = timings.get("boards_detected", [])
        rows.append(ScoreRow(name, adapter, "calibrate_videos (board videos)", m,
                             note=f"boards detected per camera {boards}, its RMS {timings.get('reprojection_error_px', float('nan')):.3f} px, "
                                  f"{timings['seconds']['calibrate_videos']:.0f} s"))
    return rows


def run_scoreboard(suites_file: Path, suite: str, out: Path, systems: list[str] | None = None,
                   progress=None, seeds: int = 1) -> Scoreboard:
    """Run every scenario of ``suite`` through the project and each installed adapter (module doc).
    ``systems``: adapters to include (default: every installed one). ``seeds``: each scenario on
    seeds ``seed .. seed + seeds - 1`` (every system on each seed's frames); the table then gives
    each figure's mean over the seeds and its 95 % bootstrap confidence interval."""
    suites = load_suites(suites_file)
    runs, unrunnable = suites.resolve(suite)
    sb = Scoreboard(suite, failures=[f"{n}: {e}" for n, e in unrunnable.items()], seeds=seeds)
    adapters = [a for a in installed_adapters() if systems is None or a in systems]
    sb.versions = {a: adapter_version(a) for a in ADAPTERS}
    out.mkdir(parents=True, exist_ok=True)
    for spec, i in ((spec, i) for spec in runs for i in range(seeds)):
        name = str(spec.factors["scenario"])
        sc = spec.scenario.with_overrides({"seed": spec.scenario.seed + i}) if i else spec.scenario
        folder = out / name / (f"seed-{sc.seed:04d}" if seeds > 1 else "")
        first = len(sb.rows)
        res = run_scenario(sc, folder / "project_run")
        gt = res.sequence.ground_truth
        sb.frames[name] = gt.n_frames
        sb.failures += [f"{name}: project: {f.line()}" for f in res.failures]
        sb.rows.append(_project_row(name, res, gt))
        stage = build_stage(sc)
        detections = res.capture.detections if res.capture is not None else None
        if stage.marker_names and detections is not None:
            pts, _ = labelled_detections(detections, gt)
            sb.rows += _labelled_rows(name, pts, gt.calibration(), gt, 1e3 / gt.n_frames)
        for adapter in adapters:
            try:
                sb.rows += _adapter_rows(name, adapter, sc, stage, gt, detections, folder, sb)
            except AdapterError as exc:
                sb.failures.append(f"{name}: {exc}")
        for r in sb.rows[first:]:
            r.seed = sc.seed
        if progress is not None:
            progress(1)
    return sb


def _fmt(v, f: str) -> str:
    return "-" if v is None or not np.isfinite(v) else f.format(v)


def _cell(summary: SeedSummary | None, f: str) -> str:
    if summary is None or not np.isfinite(summary.mean):
        return "-"
    if summary.n_finite < 2:
        return f.format(summary.mean)
    return f"{f.format(summary.mean)} [{f.format(summary.ci_low)}, {f.format(summary.ci_high)}]"


def table_lines(sb: Scoreboard, markdown: bool = False) -> list[str]:
    """The table: one line per system and variant of each scenario; with several seeds each figure is
    the seeds' mean and its 95 % bootstrap CI ``[low, high]``."""
    head = ["scenario", "system", "variant"] + [h for _, h, _ in COLUMNS]
    body = [[r.scenario, r.system, r.variant] + [_cell(m.get(k), f) for k, _, f in COLUMNS] for r, m in sb.summaries()]
    if markdown:
        return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] + ["| " + " | ".join(b) + " |" for b in body]
    widths = [max(len(x) for x in col) for col in zip(head, *body)]
    line = lambda cells: "  ".join(c.ljust(w) if i < 3 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths)))  # noqa: E731
    return [line(head), "  ".join("-" * w for w in widths)] + [line(b) for b in body]


def _plot_errors(sb: Scoreboard, scenario: str, path: Path) -> bool:
    pooled: dict[tuple[str, str], list[np.ndarray]] = {}
    for r in sb.rows:
        if r.scenario == scenario and r.errors_mm is not None and r.errors_mm.size:
            pooled.setdefault((r.system, r.variant), []).append(r.errors_mm)
    rows = [ScoreRow(scenario, s, v, {}, np.concatenate(e)) for (s, v), e in pooled.items()]  # every seed's marker-frames
    if not rows:
        return False
    fig = Figure(figsize=(8.5, 4.8))
    ax = fig.add_subplot(1, 1, 1)
    for r in rows:
        e = np.sort(r.errors_mm)
        ax.plot(np.maximum(e, 1e-3), np.arange(1, e.size + 1) / e.size, label=f"{r.system}: {r.variant}",
                linestyle={"project": "-", "aniposelib": "--"}.get(r.system, ":"), linewidth=1.6)
    ax.set_xscale("log")
    ax.set_xlabel("3D error of a reconstructed marker-frame (mm, log scale)")
    ax.set_ylabel("fraction of marker-frames")
    ax.set_title(f"{scenario}: cumulative 3D error, same frames for every system")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return True


def _plot_calibration(sb: Scoreboard, path: Path) -> bool:
    rows = [ScoreRow(r.scenario, r.system, r.variant, {k: v.mean for k, v in m.items()})
            for r, m in sb.summaries() if "calib.focal_error_pct" in m]
    if not rows:
        return False
    keys = [(k, h) for k, h, _ in COLUMNS if k.startswith("calib.")]
    fig = Figure(figsize=(10, 3.2))
    for i, (k, h) in enumerate(keys):
        ax = fig.add_subplot(1, len(keys), i + 1)
        ax.bar(range(len(rows)), [r.metrics[k] for r in rows], color=["C0" if r.system == "project" else "C1" for r in rows])
        ax.set_xticks(range(len(rows)), [r.system for r in rows], fontsize=8)
        ax.set_title(h, fontsize=9)
    fig.suptitle("calibration against the true cameras (worst camera)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return True


def write_report(sb: Scoreboard, out: Path) -> Path:
    """``out/scoreboard.md`` (table, versions, settings, plots) and ``out/scoreboard.json``."""
    plots = out / "plots"
    plots.mkdir(parents=True, exist_ok=True)
    lines = [f"# simbench scoreboard: suite {sb.suite}", "",
             "Every system on the same rendered frames (same scenario, seed and overrides); scored by `eval` against the "
             "exact ground truth. Adapters and the `project (labelled 2D)` rows get the bench's own blob centroids labelled "
             "by the exact projections; the `mocap pipeline` row labels unlabelled blobs itself.", "",
             *table_lines(sb, markdown=True), "",
             *([f"Each figure: mean over {sb.seeds} seeds [95 % bootstrap CI of the mean] (eval.seed_stats.bootstrap_summary).", ""]
               if sb.seeds > 1 else []),
             "Versions: " + ", ".join(f"{k} {v}" for k, v in sb.versions.items()), ""]
    lines += ["## Settings", ""] + [f"- **{a.name}**: {a.settings}" for a in ADAPTERS.values()] + [""]
    notes = list(dict.fromkeys(f"- {r.scenario} / {r.system} / {r.variant}" + (f" (seed {r.seed})" if sb.seeds > 1 else "")
                               + f": {r.note}" for r in sb.rows if r.note))
    if notes:
        lines += ["## Notes", ""] + notes + [""]
    if sb.failures:
        lines += ["## Failures", ""] + [f"- {f}" for f in sb.failures] + [""]
    lines += ["## Plots", ""]
    for scenario in dict.fromkeys(r.scenario for r in sb.rows):
        p = plots / f"errors_{scenario}.png"
        if _plot_errors(sb, scenario, p):
            lines += [f"![{scenario}](plots/{p.name})", ""]
    if _plot_calibration(sb, plots / "calibration.png"):
        lines += ["![calibration](plots/calibration.png)", ""]
    (out / "scoreboard.md").write_text("\n".join(lines) + "\n")
    fin = lambda v: None if v is None or not np.isfinite(v) else float(v)  # noqa: E731
    data = {"suite": sb.suite, "seeds": sb.seeds, "versions": sb.versions, "frames": sb.frames, "failures": sb.failures,
            "rows": [{"scenario": r.scenario, "system": r.system, "variant": r.variant, "seed": r.seed, "note": r.note,
                      "metrics": {k: fin(v) for k, v in r.metrics.items()}} for r in sb.rows],
            "summary": [{"scenario": r.scenario, "system": r.system, "variant": r.variant,
                         "metrics": {k: {"mean": fin(v.mean), "ci_low": fin(v.ci_low), "ci_high": fin(v.ci_high), "n": v.n_finite}
                                     for k, v in m.items()}} for r, m in sb.summaries()]}
    (out / "scoreboard.json").write_text(json.dumps(data, indent=1) + "\n")
    return out / "scoreboard.md"
